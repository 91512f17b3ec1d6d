//! Checking an uploaded session file before anything is stored, cheapest and most decisive first:
//! the header alone (a few records, nothing decompressed) says who the session belongs to, so
//! the uploader is authorised before any expensive work; then the header's fields are checked
//! against what this server knows (atlas, difficulty, device, physics version); only then are the
//! ticks verified, streamed block by block with memory bounded by [`Limits::for_upload`] and the
//! longest session accepted, whatever the file declares.

use axum::http::StatusCode;
use stylet_recorder::SessionHeader;
use stylet_recorder::reader::{self, Limits, Verified};

use super::AppState;
use super::api::{ApiError, err};
use super::store::User;

/// A checked upload: its header, the trainee it belongs to, what verification found.
pub struct CheckedUpload {
    pub header: SessionHeader,
    pub trainee: User,
    pub verified: Verified,
}

/// Runs every check of an upload (see the module doc); the error says what was wrong.
pub async fn check(s: &AppState, user: &User, bytes: &axum::body::Bytes) -> Result<CheckedUpload, ApiError> {
    let header = reader::read_header(bytes).map_err(|e| {
        err(
            StatusCode::UNPROCESSABLE_ENTITY,
            format!("not a valid session file: {e}"),
        )
    })?;
    let trainee = authorise(s, user, &header.trainee).await?;
    check_header(s, &header)?;
    let limits = Limits::for_upload(bytes.len() as u64, header.tick_rate_hz, s.config.limits.max_session_s);
    let data = bytes.clone();
    // At most a few verifications at once: each holds a chunk and a block in memory.
    // The permit goes with the thread: a request dropped meanwhile still counts until it ends.
    let permit = s.verify_permits.clone().acquire_owned().await.map_err(|_| busy())?;
    let verified = tokio::task::spawn_blocking(move || {
        let _permit = permit;
        reader::verify_streaming(&data, &limits)
    })
    .await
    .map_err(|_| err(StatusCode::INTERNAL_SERVER_ERROR, "validation failed"))?
    .map_err(|e| {
        let hint = if e.contains("more than") && e.contains("ticks") {
            format!(
                " (this server accepts sessions of up to {} minutes)",
                s.config.limits.max_session_s / 60
            )
        } else {
            // A cut or damaged recording: what was saved can still be kept (and reviewed; it is
            // not gradeable).
            " — if the recording was cut off or damaged, run `stylet session recover FILE --out FIXED.mcap` \
             and upload the recovered file: it keeps what was saved and is shown as not gradeable"
                .to_string()
        };
        err(
            StatusCode::UNPROCESSABLE_ENTITY,
            format!("not a valid session file: {e}{hint}"),
        )
    })?;
    if verified.session.header != header {
        return Err(err(
            StatusCode::UNPROCESSABLE_ENTITY,
            "not a valid session file: it holds more than one session header",
        ));
    }
    Ok(CheckedUpload {
        header,
        trainee,
        verified,
    })
}

fn busy() -> ApiError {
    err(StatusCode::SERVICE_UNAVAILABLE, "the server is shutting down")
}

/// Who may upload a session of `trainee_name`: the trainee themself, an instructor of their
/// cohort, an admin. "No such trainee" and "not yours" get the same answer unless the caller may
/// see every account (admins), so an upload cannot probe which accounts exist.
async fn authorise(s: &AppState, user: &User, trainee_name: &str) -> Result<User, ApiError> {
    let refused = || {
        err(
            StatusCode::FORBIDDEN,
            format!("{} may not upload sessions of trainee '{trainee_name}'", user.username),
        )
    };
    let trainee = || async {
        Ok::<_, ApiError>(
            s.store
                .user_by_name(trainee_name)
                .await?
                .filter(|t| t.role == "trainee"),
        )
    };
    match user.role.as_str() {
        "trainee" if user.username == trainee_name => Ok(user.clone()),
        "instructor" => match trainee().await? {
            Some(t) if s.store.teaches(&user.id, &t.id).await? => Ok(t),
            _ => Err(refused()),
        },
        "admin" => trainee().await?.ok_or_else(|| {
            err(
                StatusCode::UNPROCESSABLE_ENTITY,
                format!("the session's trainee '{trainee_name}' has no trainee account"),
            )
        }),
        _ => Err(refused()),
    }
}

/// The header's fields against what this server knows; 422 with the reason.
fn check_header(s: &AppState, h: &SessionHeader) -> Result<(), ApiError> {
    let bad = |m: String| err(StatusCode::UNPROCESSABLE_ENTITY, m);
    let Some(scorer) = s.catalogue.scorer(&h.atlas_hash) else {
        return Err(bad(format!(
            "the session was recorded on atlas '{}' ({}), which this server does not know",
            h.atlas_id, h.atlas_hash
        )));
    };
    // The limits on an upload's ticks follow from its rate: only the rate the simulator runs at.
    if h.tick_rate_hz != stylet_physics::DEFAULT_TICK_RATE_HZ {
        return Err(bad(format!(
            "the session ticks at {} Hz; this server accepts {} Hz",
            h.tick_rate_hz,
            stylet_physics::DEFAULT_TICK_RATE_HZ
        )));
    }
    if !stylet_scoring::rubric::LEVELS.contains(&h.difficulty.as_str()) {
        return Err(bad(format!(
            "unknown difficulty '{}' (beginner, advanced, expert)",
            h.difficulty
        )));
    }
    if stylet_physics::DeviceProfile::by_name(&h.device).is_none() {
        let known: Vec<&str> = stylet_physics::DeviceProfile::ALL.iter().map(|d| d.name).collect();
        return Err(bad(format!("unknown device '{}' ({})", h.device, known.join(", "))));
    }
    if h.physics_version != stylet_physics::PHYSICS_VERSION {
        return Err(bad(format!(
            "the session was recorded with physics version {}; this server replays version {}",
            h.physics_version,
            stylet_physics::PHYSICS_VERSION
        )));
    }
    // A scoring worker replays the deformation the header asks for: no more than the
    // simulator's default costs, in memory and in work per tick.
    let (asked, budget) = (h.deformation.cost(), stylet_physics::DeformCost::replay_budget());
    if !asked.within(&budget) {
        return Err(bad(format!(
            "the session's tissue deformation ({} cells, a solve every {} ticks) costs {:.1}× the work per tick \
             and {:.1}× the memory this server allows (the simulator's default, with a quarter's headroom for work)",
            h.deformation.cells,
            h.deformation.every_ticks,
            asked.node_updates_per_tick / budget.node_updates_per_tick,
            asked.nodes as f64 / budget.nodes as f64,
        )));
    }
    // Likewise the contrast agent's diffusion: no larger a grid, no more work per tick.
    let contrast = stylet_physics::ContrastSettings::default();
    if h.contrast.grid_nodes > contrast.grid_nodes
        || h.contrast.node_updates_per_tick() > contrast.node_updates_per_tick()
    {
        return Err(bad(format!(
            "the session's contrast agent ({}³ nodes, {} steps every {} ticks) costs {:.1}× the work per tick \
             of the simulator's default ({}³ nodes); this server replays at most the default",
            h.contrast.grid_nodes,
            h.contrast.steps_per_update,
            h.contrast.update_every_ticks,
            h.contrast.node_updates_per_tick() / contrast.node_updates_per_tick(),
            contrast.grid_nodes,
        )));
    }
    if !scorer.knows_scenario(&h.scenario) {
        return Err(bad(format!(
            "unknown scenario '{}' for atlas '{}' (its scenarios: {})",
            h.scenario,
            h.atlas_id,
            scorer.scenario_names().join(", ")
        )));
    }
    Ok(())
}
