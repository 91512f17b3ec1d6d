//! `stylet demo`: the main job on the embedded default. Build the phantom atlas, load it back
//! through the validating loader and print its summary; record the example scripts as sessions
//! of demo trainees; replay and score them and print the scores; then serve the dashboard on
//! them with demo accounts (SQLite in the demo folder), the sessions uploaded and scored by the
//! service like any others and dated back over the past four weeks.

use std::path::PathBuf;
use std::time::{Duration, Instant, SystemTime};

use anyhow::Context;
use clap::Args;

#[derive(Debug, Args)]
pub struct DemoArgs {
    /// Where to write the demo's files.
    #[arg(long, default_value = "target/stylet-demo")]
    pub out: PathBuf,
    /// Phantom seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Where the dashboard listens (port 0 picks a free port).
    #[arg(long, default_value = "127.0.0.1:8080")]
    pub bind: String,
    /// Stop after the scores instead of serving the dashboard.
    #[arg(long)]
    pub no_serve: bool,
}

/// The demo's accounts: (username, role); every password is [`DEMO_PASSWORD`].
const DEMO_ACCOUNTS: [(&str, &str); 6] = [
    ("demo-admin", "admin"),
    ("demo-ivan", "instructor"),
    ("demo-cora", "curriculum"),
    ("demo-alice", "trainee"),
    ("demo-bob", "trainee"),
    ("demo-carol", "trainee"),
];
const DEMO_PASSWORD: &str = "stylet-demo";
const DEMO_COHORT: &str = "demo-cohort";

pub fn run(args: DemoArgs) -> anyhow::Result<()> {
    let atlas_dir = args.out.join("atlases/phantom");
    let t0 = Instant::now();
    super::atlas::build_phantom(
        &atlas_dir,
        &stylet_atlas::phantom::PhantomConfig {
            seed: args.seed,
            ..Default::default()
        },
        true,
    )?;
    let built = t0.elapsed();
    let t1 = Instant::now();
    let atlas = stylet_atlas::load(&atlas_dir)?;
    let loaded = t1.elapsed();
    sayf!("{}", stylet_atlas::summary::Summary::of(&atlas).to_text());
    sayf!(
        "phantom generated and written in {:.2} s, loaded and validated in {:.2} s",
        built.as_secs_f64(),
        loaded.as_secs_f64()
    );
    let png = args.out.join("phantom.png");
    stylet_render::figure::atlas_figure(
        &atlas.model,
        &atlas.manifest.name,
        &super::atlas::insertion_paths(&atlas),
        &png,
    )?;
    sayf!("three orthogonal slices with the label overlay: {}", png.display());

    // Sessions: the example scripts, embedded, as demo trainees would have done them.
    let sessions_dir = args.out.join("sessions");
    std::fs::create_dir_all(&sessions_dir)?;
    let t2 = Instant::now();
    let mut files = Vec::new();
    let mut uploads = Vec::new();
    let mut simulated_s = 0.0;
    let mut pictured = None;
    for (name, trainee, days_ago, text) in DEMO_SCRIPTS {
        let out = sessions_dir.join(format!("{trainee}-{name}.mcap"));
        let info = stylet_recorder::SessionInfo {
            trainee,
            scenario: name,
            difficulty: "beginner",
            seed: args.seed,
            atlas_id: &atlas.manifest.name,
            atlas_hash: &atlas.content_hash,
        };
        let summary = super::script::record_script_text(&atlas, text, &out, &info)
            .with_context(|| format!("recording the demo script {name}"))?;
        simulated_s += summary.ticks as f64 / 1000.0;
        if name == PICTURED_SESSION && pictured.is_none() {
            pictured = Some((out.clone(), summary.ticks));
        }
        uploads.push(DemoUpload {
            file: out.clone(),
            trainee,
            days_ago,
        });
        files.push(out);
    }
    // The session `stylet score` is suggested for, for its details.
    let detailed = pictured.as_ref().map_or_else(|| files[0].clone(), |(f, _)| f.clone());
    sayf!(
        "{} sessions ({simulated_s:.0} s at 1 kHz) recorded in {:.2} s to {}",
        files.len(),
        t2.elapsed().as_secs_f64(),
        sessions_dir.display()
    );

    // The successful puncture at 60 % of its course (the tip in the duct, contrast injected), ray
    // cast (docs/rendering.md): soft-tissue preset, the volume cut along the needle with target
    // and risk structures tagged on the cut.
    if let Some((session, ticks)) = pictured {
        let args_for = |at_s: f64, view, size, out: &str| super::render::RenderArgs {
            atlas: atlas_dir.clone(),
            session: Some(session.clone()),
            at: Some(at_s),
            view,
            preset: super::render::PresetArg::Soft,
            tagging: super::render::TaggingArg::Risk,
            size: Some(size),
            scenario: None,
            lao_deg: None,
            cranial_deg: None,
            probe: None,
            doppler: false,
            difficulty: None,
            step_mm: None,
            gpu: false,
            cpu: true,
            out: args.out.join(format!("{PICTURED_SESSION}-{out}.png")),
            line_integrals: None,
        };
        super::render::run(args_for(
            ticks as f64 * 0.6 / 1000.0,
            super::render::View::ThreeD,
            super::render::Size {
                width: 900,
                height: 746,
            },
            "3d",
        ))
        .context("ray casting the demo puncture")?;
        // Under fluoroscopy 1.2 s after the injection began (67 % of its course, docs/xray.md):
        // the needle in the duct and the contrast spreading along it.
        super::render::run(args_for(
            ticks as f64 * 0.67 / 1000.0,
            super::render::View::Xray,
            super::render::Size {
                width: 512,
                height: 512,
            },
            "xray",
        ))
        .context("the X-ray of the demo puncture")?;
        // The same moment in ultrasound (docs/ultrasound.md): a convex probe beside the path
        // images it in plane, the needle and its comet tail in the outlined duct, veins in colour.
        let mut us = args_for(
            ticks as f64 * 0.6 / 1000.0,
            super::render::View::Ultrasound,
            super::render::Size {
                width: 640,
                height: 512,
            },
            "ultrasound",
        );
        us.doppler = true;
        super::render::run(us).context("the ultrasound of the demo puncture")?;
    }

    // Scores: every session replayed through the physics and graded at its difficulty.
    let t3 = Instant::now();
    let scorer = stylet_scoring::Scorer::new(&atlas, stylet_scoring::Rubric::default_rubric(), None)
        .map_err(|e| anyhow::anyhow!(e))?;
    let jobs = std::thread::available_parallelism().map_or(1, |n| n.get());
    let results = scorer
        .score_files(&files, jobs, &|| {})
        .map_err(|e| anyhow::anyhow!(e))?;
    sayf!("");
    super::score::print_table(&results);
    sayf!("");
    sayf!(
        "replayed and scored in {:.2} s ({} rubric v{}); details: stylet score {} --atlas {}",
        t3.elapsed().as_secs_f64(),
        scorer.rubric().name,
        scorer.rubric().version,
        detailed.display(),
        atlas_dir.display()
    );
    if let Some((f, Err(e))) = results.iter().find(|r| r.1.is_err()) {
        anyhow::bail!("{}: {e}", f.display());
    }
    if args.no_serve {
        return Ok(());
    }
    serve_dashboard(&args, &uploads)
}

/// A recorded demo session to upload: its file, its trainee, and how many days before now the
/// dashboard dates it.
struct DemoUpload {
    file: PathBuf,
    trainee: &'static str,
    days_ago: u32,
}

/// When a session done `days_ago` days before `now` took place.
fn days_before(now: SystemTime, days_ago: u32) -> SystemTime {
    now - Duration::from_secs(u64::from(days_ago) * 86_400)
}

/// Serves the dashboard on a fresh demo database: the demo accounts, and the recorded sessions
/// uploaded by their trainees, dated over the past weeks and scored by the service's workers.
fn serve_dashboard(args: &DemoArgs, uploads: &[DemoUpload]) -> anyhow::Result<()> {
    use stylet_service::{self as service, Config, Store};
    let data = args.out.join("data");
    if data.exists() {
        std::fs::remove_dir_all(&data).with_context(|| format!("cannot clear {}", data.display()))?;
    }
    std::fs::create_dir_all(&data)?;
    let config = Config {
        bind: args.bind.clone(),
        admin_bind: None,
        data_dir: data.clone(),
        database_url: None,
        storage_url: None,
        atlases_dir: Some(args.out.join("atlases")),
        workers: std::thread::available_parallelism().map_or(1, |n| n.get()),
        max_upload_bytes: 64 << 20,
        secure_cookies: false,
        limits: Default::default(),
        lrs: None,
    };
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    rt.block_on(async {
        let store = Store::open(&config.database_url()).await?;
        for (name, role) in DEMO_ACCOUNTS {
            let cohort = matches!(role, "trainee" | "instructor").then_some(DEMO_COHORT);
            store.add_user(name, role, DEMO_PASSWORD, cohort, None).await?;
        }
        store.pool.close().await;
        let sessions: Vec<(&'static str, u32, Vec<u8>)> = uploads
            .iter()
            .map(|u| Ok((u.trainee, u.days_ago, std::fs::read(&u.file)?)))
            .collect::<anyhow::Result<_>>()?;
        service::serve(config, Some(stylet_dashboard::MOUNT), move |addr, state| {
            sayf!("");
            sayf!(
                "dashboard running at http://{addr}/ (demo data in {}; Ctrl-C stops it)",
                data.display()
            );
            sayf!("demo accounts, password '{DEMO_PASSWORD}' for all:");
            for (name, role) in DEMO_ACCOUNTS {
                sayf!("  {name:<12} {role}");
            }
            // Each trainee uploads their sessions through the service's own checks; each session
            // is then dated back to when the trainee did it.
            tokio::spawn(async move {
                let now = SystemTime::now();
                for (trainee, days_ago, bytes) in sessions {
                    let user = match state.store.user_by_name(trainee).await {
                        Ok(Some(u)) => u,
                        _ => continue,
                    };
                    match service::api::accept_upload_bytes(&state, &user, bytes).await {
                        Ok((id, _, _)) => {
                            if let Err(e) = state.store.set_session_times(&id, days_before(now, days_ago)).await {
                                eprintln!("demo session {id} of {trainee} not dated back: {e}");
                            }
                        }
                        Err(e) => eprintln!("demo upload of a session of {trainee} refused: {}", e.message()),
                    }
                }
            });
        })
        .await?;
        anyhow::Ok(())
    })
}

/// The session the demo draws in 3D at the end of its puncture (the first trainee's).
const PICTURED_SESSION: &str = "success-intercostal";

/// The example scripts of the phantom (atlases/phantom/scripts).
const PALPATION_SWEEP: &str = include_str!("../../atlases/phantom/scripts/palpation-sweep.txt");
const PROBE_PARALLEL: &str = include_str!("../../atlases/phantom/scripts/probe-parallel.txt");
const PROBE_ACROSS: &str = include_str!("../../atlases/phantom/scripts/probe-across.txt");
const SUCCESS_INTERCOSTAL: &str = include_str!("../../atlases/phantom/scripts/success-intercostal.txt");
const TWO_ATTEMPTS: &str = include_str!("../../atlases/phantom/scripts/two-attempts.txt");
const LUNG_HIT: &str = include_str!("../../atlases/phantom/scripts/lung-hit.txt");
const VESSEL_HIT: &str = include_str!("../../atlases/phantom/scripts/vessel-hit.txt");
const BREATH_HOLD: &str = include_str!("../../atlases/phantom/scripts/breath-hold.txt");

/// The demo trainees' sessions: (script, trainee, days ago, script text). Each trainee practises
/// over three to four weeks, oldest first, at least three punctures each and better over time,
/// so that their progress charts and the cohort's weekly pass rates have lines. The dashboard
/// dates each uploaded session `days ago` days before the demo runs.
const DEMO_SCRIPTS: [(&str, &str, u32, &str); 14] = [
    ("lung-hit", "demo-alice", 27, LUNG_HIT),
    ("palpation-sweep", "demo-alice", 24, PALPATION_SWEEP),
    ("two-attempts", "demo-alice", 20, TWO_ATTEMPTS),
    ("probe-parallel", "demo-alice", 13, PROBE_PARALLEL),
    ("success-intercostal", "demo-alice", 6, SUCCESS_INTERCOSTAL),
    ("vessel-hit", "demo-bob", 25, VESSEL_HIT),
    ("lung-hit", "demo-bob", 18, LUNG_HIT),
    ("two-attempts", "demo-bob", 11, TWO_ATTEMPTS),
    ("success-intercostal", "demo-bob", 3, SUCCESS_INTERCOSTAL),
    ("lung-hit", "demo-carol", 24, LUNG_HIT),
    ("vessel-hit", "demo-carol", 17, VESSEL_HIT),
    ("probe-across", "demo-carol", 12, PROBE_ACROSS),
    ("breath-hold", "demo-carol", 10, BREATH_HOLD),
    ("success-intercostal", "demo-carol", 2, SUCCESS_INTERCOSTAL),
];

#[cfg(test)]
mod tests {
    use super::*;

    /// The scripts that are no puncture (palpation and ultrasound-survey exercises).
    fn is_puncture(script: &str) -> bool {
        script != "palpation-sweep" && !script.starts_with("probe-")
    }

    #[test]
    fn each_demo_trainee_practises_over_weeks_oldest_first() {
        for trainee in ["demo-alice", "demo-bob", "demo-carol"] {
            let days: Vec<u32> = DEMO_SCRIPTS.iter().filter(|s| s.1 == trainee).map(|s| s.2).collect();
            assert!(days.windows(2).all(|w| w[0] > w[1]), "{trainee}: {days:?}");
            assert!(days[0] - days[days.len() - 1] >= 14, "{trainee}: {days:?}");
            let punctures = DEMO_SCRIPTS
                .iter()
                .filter(|s| s.1 == trainee && is_puncture(s.0))
                .count();
            assert!(punctures >= 3, "{trainee}: {punctures} punctures");
            // Their latest puncture is the successful one.
            let last = DEMO_SCRIPTS.iter().rev().find(|s| s.1 == trainee).unwrap();
            assert_eq!(last.0, PICTURED_SESSION, "{trainee}");
        }
        // Every example script is in the demo, and every trainee is a demo account.
        for script in [
            "palpation-sweep",
            "probe-parallel",
            "probe-across",
            "success-intercostal",
            "two-attempts",
            "lung-hit",
            "vessel-hit",
            "breath-hold",
        ] {
            assert!(DEMO_SCRIPTS.iter().any(|s| s.0 == script), "{script}");
        }
        for s in &DEMO_SCRIPTS {
            assert!(DEMO_ACCOUNTS.contains(&(s.1, "trainee")), "{}", s.1);
        }
    }

    #[test]
    fn sessions_are_dated_whole_days_back() {
        let day = Duration::from_secs(86_400);
        let now = SystemTime::UNIX_EPOCH + 30 * day;
        assert_eq!(days_before(now, 0), now);
        assert_eq!(days_before(now, 27), SystemTime::UNIX_EPOCH + 3 * day);
    }
}
