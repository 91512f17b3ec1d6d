//! `stylet session …`: inspect, verify, export and recover session files (docs/session-format.md).

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::{Args, Subcommand};
use serde_json::{Value, json};
use stylet_recorder::reader::{self, Session};

#[derive(Debug, Subcommand)]
pub enum SessionCommand {
    /// Header, duration, counts and state of a session file (works on damaged files too).
    Inspect(InspectArgs),
    /// Check a session file: intact, finished, nothing dropped. Exit 0 if good, 1 with the reason.
    Verify { file: PathBuf },
    /// Write the session as CSV files (ticks, events, digests, annotations, header) into a directory.
    Export(ExportArgs),
    /// Rewrite what is intact of a damaged or cut file as a finished file marked incomplete.
    Recover(RecoverArgs),
}

#[derive(Debug, Args)]
pub struct InspectArgs {
    pub file: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

#[derive(Debug, Args)]
pub struct ExportArgs {
    pub file: PathBuf,
    /// Directory for the CSV files (created if missing).
    #[arg(long, value_name = "DIR")]
    pub csv: PathBuf,
}

#[derive(Debug, Args)]
pub struct RecoverArgs {
    pub file: PathBuf,
    /// Where to write the recovered session.
    #[arg(long)]
    pub out: PathBuf,
}

pub fn run(cmd: SessionCommand) -> anyhow::Result<()> {
    match cmd {
        SessionCommand::Inspect(a) => inspect(&a),
        SessionCommand::Verify { file } => verify(&file),
        SessionCommand::Export(a) => export(&a),
        SessionCommand::Recover(a) => recover(&a),
    }
}

fn read_any(file: &Path) -> anyhow::Result<Session> {
    reader::recover(file).map_err(|e| anyhow::anyhow!("{}: {e}", file.display()))
}

/// One word for the file's state, and the details.
fn state(s: &Session) -> (&'static str, String) {
    match (&s.damage, &s.end) {
        (Some(d), _) => ("damaged", d.to_string()),
        (None, Some(e)) if !e.complete => ("incomplete", e.reason.clone()),
        (None, Some(_)) if s.finished => ("complete", "finished".into()),
        _ => ("unfinished", "no end record".into()),
    }
}

/// Ticks whose forces and torques the file stores rounded, their exact bits pinned by a block
/// digest (docs/session-format.md "Rounded outputs").
fn rounded_output_ticks(s: &Session) -> u64 {
    s.output_checks.iter().map(|c| u64::from(c.count)).sum()
}

/// The JSON of `inspect --json`: header fields at the top level, then counts and state.
pub fn inspect_json(s: &Session) -> Value {
    let h = &s.header;
    let mut v = json!({
        "schema_version": h.schema_version,
        "session_id": h.session_id,
        "trainee": h.trainee,
        "scenario": h.scenario,
        "difficulty": h.difficulty,
        "atlas_id": h.atlas_id,
        "atlas_hash": h.atlas_hash,
        "software_version": h.software_version,
        "physics_version": h.physics_version,
        "tick_rate_hz": h.tick_rate_hz,
        "seed": h.seed,
        "device": h.device,
        "initial_tool": h.initial_tool.name(),
        "wall_clock_start": h.wall_clock_start,
        "duration_s": s.duration_s(),
        "ticks": s.ticks.len(),
        "first_tick": s.ticks.first().map(|t| t.tick),
        "last_tick": s.ticks.last().map(|t| t.tick),
        "events": s.events.len(),
        "digests": s.digests.len(),
        "annotations": s.annotations.len(),
        "chunks": s.chunks.len(),
        "rounded_output_blocks": s.output_checks.len(),
        "rounded_output_ticks": rounded_output_ticks(s),
        "event_list": s.events.iter().map(|e| {
            let mut ev = serde_json::to_value(e).expect("events serialise");
            ev["t_s"] = json!(e.tick as f64 / h.tick_rate_hz as f64);
            ev
        }).collect::<Vec<_>>(),
    });
    v["world"] = Value::Object(
        h.world_settings()
            .into_iter()
            .map(|(part, settings)| {
                let values = settings
                    .into_iter()
                    .map(|(k, text)| {
                        // Whole numbers as integers, reals as numbers, names as strings.
                        let value = match (text.parse::<u64>(), text.parse::<f64>()) {
                            (Ok(n), _) => json!(n),
                            (_, Ok(x)) => json!(x),
                            _ => json!(text),
                        };
                        (k, value)
                    })
                    .collect();
                (part.to_string(), Value::Object(values))
            })
            .collect(),
    );
    if let Some(hw) = &h.hardware {
        v["hardware"] = json!({
            "backend": hw.backend,
            "model": hw.model,
            "max_force_n": hw.max_force_n,
            "max_continuous_force_n": hw.max_continuous_force_n,
        });
        let f = &s.device_forces;
        v["device_forces"] = json!({
            "ticks": f.len(),
            "zeroed_ticks": f.iter().filter(|r| r.zeroed()).count(),
            "limited_ticks": f.iter().filter(|r| r.limited()).count(),
        });
    }
    if let Some(hand) = &h.second_hand {
        v["second_hand"] = json!({
            "device": hand.device,
            "initial_tool": hand.initial_tool.map(|t| t.tool_spec().name()),
            "ticks": s.ticks.iter().filter(|t| t.second_hand.is_some()).count(),
        });
    }
    let (word, detail) = state(s);
    v["state"] = json!(word);
    v["state_detail"] = json!(detail);
    v["complete"] = json!(s.complete());
    if let Some(e) = &s.end {
        v["dropped_ticks"] = json!(e.dropped_ticks);
    }
    v
}

fn inspect(a: &InspectArgs) -> anyhow::Result<()> {
    let s = read_any(&a.file)?;
    if a.json {
        sayf!("{}", serde_json::to_string_pretty(&inspect_json(&s))?);
        return Ok(());
    }
    let h = &s.header;
    let (word, detail) = state(&s);
    sayf!("session   {} (schema {})", h.session_id, h.schema_version);
    sayf!("trainee   {}", h.trainee);
    sayf!("scenario  {} at {}", h.scenario, h.difficulty);
    sayf!("atlas     {} ({})", h.atlas_id, h.atlas_hash);
    sayf!(
        "software  {}, physics version {}",
        h.software_version,
        h.physics_version
    );
    sayf!(
        "device    {} at {} Hz, seed {}, starting with {}",
        h.device,
        h.tick_rate_hz,
        h.seed,
        h.initial_tool.name()
    );
    if let Some(hw) = &h.hardware {
        let f = &s.device_forces;
        sayf!(
            "hardware  {} ({}), {:.2} N peak, {:.2} N continuous; force sent on {} ticks: zero on {}, reduced on {}",
            hw.model,
            hw.backend,
            hw.max_force_n,
            hw.max_continuous_force_n,
            f.len(),
            f.iter().filter(|r| r.zeroed()).count(),
            f.iter().filter(|r| r.limited()).count()
        );
    }
    if let Some(hand) = &h.second_hand {
        sayf!(
            "hand 2    {}, starting with {}; reported on {} ticks",
            hand.device,
            hand.initial_tool.map_or("nothing", |t| t.tool_spec().name()),
            s.ticks.iter().filter(|t| t.second_hand.is_some()).count()
        );
    }
    sayf!("started   {}", h.wall_clock_start);
    for (i, line) in world_lines(h).iter().enumerate() {
        sayf!("{}{line}", if i == 0 { "world     " } else { "          " });
    }
    sayf!(
        "recorded  {:.3} s: {} ticks, {} events, {} digests, {} notes in {} chunks",
        s.duration_s(),
        s.ticks.len(),
        s.events.len(),
        s.digests.len(),
        s.annotations.len(),
        s.chunks.len()
    );
    let rounded = rounded_output_ticks(&s);
    if rounded == 0 {
        sayf!("outputs   forces and torques stored exactly");
    } else {
        sayf!(
            "outputs   forces and torques of {rounded} ticks stored rounded (2^-16 N, 2^-12 N·mm) in {} blocks, \
             their exact bits checked by each block's digest; {} ticks stored exactly",
            s.output_checks.len(),
            (s.ticks.len() as u64).saturating_sub(rounded)
        );
    }
    for e in &s.events {
        sayf!("  {:>10.3} s  {}", e.tick as f64 / h.tick_rate_hz as f64, event_text(e));
    }
    for n in &s.annotations {
        sayf!("  {:>10.3} s  note: {}", n.tick as f64 / h.tick_rate_hz as f64, n.text);
    }
    sayf!("state     {word}: {detail}");
    Ok(())
}

/// The world model the session was recorded with (and replays with), one line per part:
/// "deformation off", "contrast: update_every_ticks 10, …", "breathing on: model synthetic, …".
fn world_lines(h: &stylet_recorder::SessionHeader) -> Vec<String> {
    h.world_settings()
        .into_iter()
        .map(|(part, settings)| {
            let enabled = settings.iter().find(|(k, _)| k == "enabled").map(|(_, v)| v == "1");
            let rest: Vec<String> = settings
                .iter()
                .filter(|(k, _)| k != "enabled")
                .map(|(k, v)| format!("{k} {v}"))
                .collect();
            match enabled {
                Some(false) => format!("{part} off"),
                Some(true) => format!("{part} on: {}", rest.join(", ")),
                None => format!("{part}: {}", rest.join(", ")),
            }
        })
        .collect()
}

fn event_text(e: &stylet_recorder::EventRecord) -> String {
    match e.to_event() {
        Ok(stylet_physics::Event::SelectTool(t)) => format!("select tool: {}", t.name()),
        Ok(stylet_physics::Event::ContrastInject { ml }) => format!("contrast injected: {ml} ml"),
        _ => e.name.clone(),
    }
}

fn verify(file: &Path) -> anyhow::Result<()> {
    match reader::verify(file) {
        Ok(s) => {
            sayf!(
                "{}: good — {} ticks ({:.3} s), {} events, {} digests",
                file.display(),
                s.ticks.len(),
                s.duration_s(),
                s.events.len(),
                s.digests.len()
            );
            Ok(())
        }
        Err(e) => bail!("{}: {e}", file.display()),
    }
}

/// Header of `ticks.csv`. Numbers are written in Rust's shortest round-trip form: parsing them
/// gives back the exact recorded bits.
pub const TICKS_CSV_HEADER: &str =
    "tick,t_s,x_mm,y_mm,z_mm,qw,qx,qy,qz,buttons,fx_n,fy_n,fz_n,tx_nmm,ty_nmm,tz_nmm,tip_label,inserted_mm";

/// Header of `second_hand.csv` (two-handed sessions): the second device's pose, buttons and
/// force at every tick it reported, in the same exact number form.
pub const SECOND_HAND_CSV_HEADER: &str =
    "tick,t_s,x_mm,y_mm,z_mm,qw,qx,qy,qz,buttons,fx_n,fy_n,fz_n,tx_nmm,ty_nmm,tz_nmm";

fn export(a: &ExportArgs) -> anyhow::Result<()> {
    let s = reader::read(&a.file).map_err(|e| {
        anyhow::anyhow!(
            "{}: {e} (run `stylet session recover` first to export what is intact)",
            a.file.display()
        )
    })?;
    std::fs::create_dir_all(&a.csv).with_context(|| format!("cannot create {}", a.csv.display()))?;
    let rate = s.header.tick_rate_hz as f64;
    let write = |name: &str, header: &str, rows: &mut dyn Iterator<Item = String>| -> anyhow::Result<()> {
        let path = a.csv.join(name);
        let tmp = a.csv.join(format!(".{name}.partial"));
        let mut w = std::io::BufWriter::new(
            std::fs::File::create(&tmp).with_context(|| format!("cannot create {}", tmp.display()))?,
        );
        writeln!(w, "{header}")?;
        for r in rows {
            writeln!(w, "{r}")?;
        }
        w.into_inner().map_err(|e| e.into_error())?.sync_all()?;
        std::fs::rename(&tmp, &path).with_context(|| format!("cannot write {}", path.display()))?;
        Ok(())
    };
    write(
        "ticks.csv",
        TICKS_CSV_HEADER,
        &mut s.ticks.iter().map(|t| {
            let p = t.position_mm;
            let q = t.orientation;
            let f = t.force_n;
            let m = t.torque_nmm;
            format!(
                "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
                t.tick,
                t.tick as f64 / rate,
                p[0],
                p[1],
                p[2],
                q[0],
                q[1],
                q[2],
                q[3],
                t.buttons,
                f[0],
                f[1],
                f[2],
                m[0],
                m[1],
                m[2],
                t.tip_label,
                t.inserted_mm
            )
        }),
    )?;
    if s.header.second_hand.is_some() {
        write(
            "second_hand.csv",
            SECOND_HAND_CSV_HEADER,
            &mut s.ticks.iter().filter_map(|t| {
                let h = t.second_hand?;
                let numbers: Vec<String> = [h.position_mm.as_slice(), &h.orientation]
                    .concat()
                    .iter()
                    .map(f64::to_string)
                    .chain(std::iter::once(h.buttons.to_string()))
                    .chain([h.force_n, h.torque_nmm].concat().iter().map(f64::to_string))
                    .collect();
                Some(format!("{},{},{}", t.tick, t.tick as f64 / rate, numbers.join(",")))
            }),
        )?;
    }
    let opt = |v: Option<String>| v.unwrap_or_default();
    write(
        "events.csv",
        "tick,t_s,name,tool,gauge,length_mm,stylet_in,ml",
        &mut s.events.iter().map(|e| {
            format!(
                "{},{},{},{},{},{},{},{}",
                e.tick,
                e.tick as f64 / rate,
                e.name,
                opt(e.tool.clone()),
                opt(e.gauge.map(|g| g.to_string())),
                opt(e.length_mm.map(|g| g.to_string())),
                opt(e.stylet_in.map(|g| g.to_string())),
                opt(e.ml.map(|g| g.to_string()))
            )
        }),
    )?;
    write(
        "digests.csv",
        "tick,digest_hex",
        &mut s.digests.iter().map(|d| format!("{},{:016x}", d.tick, d.digest)),
    )?;
    write(
        "annotations.csv",
        "tick,t_s,text",
        &mut s
            .annotations
            .iter()
            .map(|n| format!("{},{},{}", n.tick, n.tick as f64 / rate, csv_text(&n.text))),
    )?;
    let mut header = inspect_json(&s);
    if let Some(o) = header.as_object_mut() {
        o.remove("event_list");
    }
    write(
        "header.csv",
        "field,value",
        &mut header
            .as_object()
            .expect("an object")
            .iter()
            .map(|(k, v)| format!("{k},{}", csv_text(v.to_string().trim_matches('"')))),
    )?;
    sayf!(
        "{} ticks, {} events, {} digests, {} notes → {}/{{ticks,events,digests,annotations,header}}.csv",
        s.ticks.len(),
        s.events.len(),
        s.digests.len(),
        s.annotations.len(),
        a.csv.display()
    );
    Ok(())
}

/// Quotes a CSV field when it needs it (RFC 4180).
fn csv_text(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

fn recover(a: &RecoverArgs) -> anyhow::Result<()> {
    let s = read_any(&a.file)?;
    let (word, detail) = state(&s);
    let summary = stylet_recorder::rewrite_recovered(&s, &a.file.display().to_string(), &a.out)?;
    sayf!("{}: {word} ({detail})", a.file.display());
    sayf!(
        "recovered {} ticks ({:.3} s), {} events, {} digests → {}{}",
        summary.ticks,
        s.duration_s(),
        s.events.len(),
        s.digests.len(),
        a.out.display(),
        if summary.complete { "" } else { " (marked incomplete)" }
    );
    Ok(())
}
