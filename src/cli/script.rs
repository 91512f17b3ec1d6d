//! `stylet script run`: a script on an atlas, headless and faster than real time, with a CSV of
//! every tick and the force plot (thesis Fig. 3.12).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::Context;
use clap::{Args, Subcommand};
use stylet_dashboard::plot::{LineChart, Series, palette, write_chart};
use stylet_devices::script::{ScriptedDevice, parse, scripted_simulation};
use stylet_physics::glam::DVec3;
use stylet_physics::{Event, Simulation, TickInput, TickOutput};

use stylet_recorder::{Recording, SessionInfo, WriterOptions};
use stylet_scoring::Difficulty;

#[derive(Debug, Subcommand)]
pub enum ScriptCommand {
    /// Run a script on an atlas, headless.
    Run(RunArgs),
}

#[derive(Debug, Args)]
pub struct RunArgs {
    /// Atlas directory.
    #[arg(long)]
    pub atlas: PathBuf,
    /// Script file (docs/scripts.md).
    #[arg(long)]
    pub script: PathBuf,
    /// Write one CSV row per tick here.
    #[arg(long)]
    pub csv: Option<PathBuf>,
    /// Write the force plot here (.svg or .png).
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// Record the session to this file (docs/session-format.md), as the desktop app does.
    #[arg(long)]
    pub out: Option<PathBuf>,
    #[command(flatten)]
    pub session: SessionArgs,
    /// Pace the ticks to the wall clock (1 kHz real time) and record without ever blocking, as the
    /// haptic loop does.
    #[arg(long)]
    pub realtime: bool,
    /// Print `tick N` on stdout every N ticks (for supervising processes and tests).
    #[arg(long, value_name = "N")]
    pub progress: Option<u64>,
}

/// Who and what a session recorded from a script is about (`stylet script run`, `stylet sim`).
#[derive(Debug, Args)]
pub struct SessionArgs {
    /// Trainee for the session header: their account username on the scoring service.
    #[arg(long, default_value = "demo-trainee")]
    pub trainee: String,
    /// Difficulty level the session is graded at.
    #[arg(long, default_value_t = Difficulty::Beginner, value_parser = difficulty_arg())]
    pub difficulty: Difficulty,
    /// Scenario name for the session header (default: the script's file name without extension).
    #[arg(long)]
    pub scenario: Option<String>,
    /// Seed of the session's random generators (breathing variation, speckle), recorded in the header.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

impl SessionArgs {
    /// The scenario: `--scenario`, else the script's file name without extension.
    pub fn scenario_of(&self, script: &Path) -> String {
        self.scenario.clone().unwrap_or_else(|| {
            script
                .file_stem()
                .map_or_else(String::new, |n| n.to_string_lossy().into_owned())
        })
    }

    /// Starts recording `sim` on `atlas` to `out` (real time: never blocking; else waiting).
    pub fn start_recording(
        &self,
        sim: &Simulation,
        atlas: &stylet_atlas::Atlas,
        script: &Path,
        out: &Path,
        realtime: bool,
    ) -> anyhow::Result<Recording> {
        let scenario = self.scenario_of(script);
        let info = SessionInfo {
            trainee: &self.trainee,
            scenario: &scenario,
            difficulty: self.difficulty.as_str(),
            seed: self.seed,
            atlas_id: &atlas.manifest.name,
            atlas_hash: &atlas.content_hash,
        };
        let header = stylet_recorder::recording::header(sim, &info);
        Recording::start(out, &header, realtime, WriterOptions::default())
            .with_context(|| format!("cannot record to {}", out.display()))
    }
}

/// `--difficulty`: one of the levels by name (listed in `--help` and in the error).
pub fn difficulty_arg() -> impl clap::builder::TypedValueParser<Value = Difficulty> {
    use clap::builder::TypedValueParser as _;
    clap::builder::PossibleValuesParser::new(Difficulty::ALL.map(Difficulty::as_str))
        .try_map(|name| name.parse::<Difficulty>())
}

pub fn run(cmd: ScriptCommand) -> anyhow::Result<()> {
    match cmd {
        ScriptCommand::Run(a) => run_script(&a),
    }
}

/// The CSV header; one row per tick. Forces "along insertion" are the resistance the hand feels
/// along the insertion direction d (−F·d): positive against pushing in.
pub const CSV_HEADER: &str = "tick,t_s,x_mm,y_mm,z_mm,qw,qx,qy,qz,fx_n,fy_n,fz_n,tx_nmm,ty_nmm,tz_nmm,\
f_insert_n,cut_n,friction_n,base_n,skin_n,slide_n,bone_n,tip_label,tip_name,inserted_mm,tip_depth_mm,\
indentation_mm,contacts,stylet_in,xray_on,contrast_ml,contrast_in_ducts_ml,extravasated_ml,contrast_extent_mm,events";

/// The simulation a script file starts with, and its device.
pub fn script_simulation(atlas: &stylet_atlas::Atlas, path: &Path) -> anyhow::Result<(Simulation, ScriptedDevice)> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    script_text_simulation(atlas, &text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

/// The simulation a script text starts with, and its device (bound to the atlas' named paths).
pub fn script_text_simulation(
    atlas: &stylet_atlas::Atlas,
    text: &str,
) -> Result<(Simulation, ScriptedDevice), ScriptSetupError> {
    let script = parse(text)?;
    Ok(scripted_simulation(
        Arc::clone(&atlas.model),
        &atlas.planned_paths(),
        &script,
    )?)
}

/// Why a device script cannot start a simulation: it does not parse, it cannot be bound to the
/// atlas' paths, or the simulation refuses its settings.
#[derive(Debug, thiserror::Error)]
pub enum ScriptSetupError {
    #[error(transparent)]
    Parse(#[from] stylet_devices::script::ParseError),
    #[error(transparent)]
    Setup(#[from] stylet_devices::script::SetupError),
}

/// Runs a script text headless and records it to `out` (offline: the recorder may wait).
pub fn record_script_text(
    atlas: &stylet_atlas::Atlas,
    text: &str,
    out: &Path,
    info: &SessionInfo,
) -> anyhow::Result<stylet_recorder::WriteSummary> {
    // The message alone, as `script_simulation` gives it (not the chain of its sources).
    let (mut sim, mut device) = script_text_simulation(atlas, text).map_err(|e| anyhow::anyhow!("{e}"))?;
    let header = stylet_recorder::recording::header(&sim, info);
    let mut rec = Recording::start(out, &header, false, WriterOptions::default())
        .with_context(|| format!("cannot record to {}", out.display()))?;
    stylet_devices::run_headless(&mut sim, &mut device, |i, o, s| rec.tick(i, o, s));
    rec.finish().with_context(|| format!("recording {}", out.display()))
}

fn csv_row(i: &TickInput, o: &TickOutput, name: &str) -> String {
    let along = |v: DVec3| -v.dot(o.insertion_dir);
    let q = i.orientation.normalize();
    let c = &o.components;
    let events: Vec<String> = i
        .events
        .iter()
        .map(|e| match e {
            Event::SelectTool(t) => format!("tool:{}", t.name().replace(' ', "-")),
            Event::ContrastInject { ml } => format!("contrast-inject:{ml}"),
            e => e.name().to_string(),
        })
        .collect();
    format!(
        "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
        o.tick,
        o.time_s,
        i.position_mm.x,
        i.position_mm.y,
        i.position_mm.z,
        q.w,
        q.x,
        q.y,
        q.z,
        o.force_n.x,
        o.force_n.y,
        o.force_n.z,
        o.torque_nmm.x,
        o.torque_nmm.y,
        o.torque_nmm.z,
        along(o.force_n),
        along(c.cut),
        along(c.friction),
        along(c.base),
        along(c.skin),
        along(c.slide),
        along(c.bone),
        o.tip_label,
        name,
        o.inserted_mm,
        o.tip_depth_mm,
        o.indentation_mm,
        o.contacts,
        u8::from(o.stylet_in),
        u8::from(o.xray_on),
        o.contrast_ml,
        o.contrast_in_ducts_ml,
        o.extravasated_ml,
        o.contrast_extent_mm,
        events.join(";"),
    )
}

fn run_script(a: &RunArgs) -> anyhow::Result<()> {
    let atlas = stylet_atlas::load(&a.atlas)?;
    let (mut sim, mut device) = script_simulation(&atlas, &a.script)?;
    let table = atlas.model.label_table().clone();
    let name_of = |id: u16| {
        table
            .get(id)
            .map_or_else(|| "-".to_string(), |l| l.name.replace(',', ";"))
    };
    let mut csv = match &a.csv {
        Some(p) => {
            let f = std::fs::File::create(p).with_context(|| format!("cannot create {}", p.display()))?;
            let mut w = std::io::BufWriter::new(f);
            writeln!(w, "{CSV_HEADER}")?;
            Some(w)
        }
        None => None,
    };
    let mut trace: Vec<(f64, f64, f64, f64, f64)> = Vec::new();
    // Contact tools: (cranio-caudal position z, indentation) while touching (Fig. 3.14).
    let mut palpation: Vec<(f64, f64)> = Vec::new();
    let mut markers: Vec<(f64, String)> = Vec::new();
    let mut visited: Vec<u16> = Vec::new();
    let (mut max_f, mut max_depth) = (0.0f64, 0.0f64);
    let mut io_error = None;
    let script_name = a
        .script
        .file_name()
        .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
    let mut recording = match &a.out {
        Some(path) => Some(a.session.start_recording(&sim, &atlas, &a.script, path, a.realtime)?),
        None => None,
    };
    let rate_hz = sim.tick_rate_hz() as f64;
    let started = Instant::now();
    let ticks = stylet_devices::run_headless(&mut sim, &mut device, |i, o, s| {
        if let Some(r) = recording.as_mut() {
            r.tick(i, o, s);
        }
        if a.realtime {
            // Tick k ends at start + (k+1)/rate; behind schedule, catch up without sleeping.
            let due = started + Duration::from_secs_f64((o.tick + 1) as f64 / rate_hz);
            if let Some(wait) = due.checked_duration_since(Instant::now()) {
                std::thread::sleep(wait);
            }
        }
        if a.progress.is_some_and(|n| n > 0 && o.tick % n == 0) {
            super::say(&format!("tick {}", o.tick));
        }
        if let Some(w) = csv.as_mut()
            && io_error.is_none()
            && let Err(e) = writeln!(w, "{}", csv_row(i, o, &name_of(o.tip_label)))
        {
            io_error = Some(e);
        }
        let along = |v: DVec3| -v.dot(o.insertion_dir);
        let c = &o.components;
        trace.push((
            o.time_s,
            along(o.force_n),
            along(c.cut),
            along(c.friction),
            along(c.base),
        ));
        for e in &i.events {
            markers.push((o.time_s, e.name().to_string()));
        }
        if o.tip_label != 0 && visited.last() != Some(&o.tip_label) && o.inserted_mm > 0.0 {
            visited.push(o.tip_label);
        }
        if o.contacts > 0 {
            palpation.push((i.position_mm.z, o.indentation_mm));
        }
        max_f = max_f.max(o.force_n.length());
        max_depth = max_depth.max(o.inserted_mm);
    });
    let wall = started.elapsed().as_secs_f64();
    if let (Some(r), Some(path)) = (recording, &a.out) {
        let summary = r.finish().context("recording the session")?;
        let complete = if summary.complete {
            "complete".to_string()
        } else {
            format!("INCOMPLETE: {} items dropped (queue full)", summary.dropped)
        };
        super::say(&format!(
            "session recorded to {}: {} ticks, {:.1} KiB, {complete}",
            path.display(),
            summary.ticks,
            summary.bytes as f64 / 1024.0
        ));
    }
    if let Some(e) = io_error {
        return Err(e).context("writing the CSV");
    }
    if let Some(mut w) = csv {
        w.flush().context("writing the CSV")?;
    }
    let sim_s = ticks as f64 / sim.tick_rate_hz() as f64;
    super::say(&format!(
        "{} ticks = {:.3} s simulated in {:.3} s ({:.0}× real time), device {}, tool {}",
        ticks,
        sim_s,
        wall,
        sim_s / wall.max(1e-9),
        sim.device().name,
        sim.tool_spec().name()
    ));
    super::say(&format!(
        "largest force {max_f:.2} N, deepest insertion {max_depth:.1} mm"
    ));
    if !visited.is_empty() {
        let names: Vec<String> = visited.iter().map(|&l| name_of(l)).collect();
        super::say(&format!("needle tip passed: {}", names.join(" → ")));
    }
    if let (Some(p), false) = (&a.plot, palpation.is_empty()) {
        let chart = LineChart {
            title: format!("Indentation along the sweep — {script_name} on {}", atlas.manifest.name),
            x_label: "cranio-caudal position z (mm)".into(),
            y_label: "indentation under the skin (mm)".into(),
            series: vec![Series {
                name: sim.tool_spec().name().into(),
                color: palette::SKIN,
                bold: true,
                dashed: false,
                dots: false,
                points: palpation,
            }],
            markers: Vec::new(),
            ..Default::default()
        };
        write_chart(&chart, p, (1200, 600))?;
        super::say(&format!("indentation plot written to {}", p.display()));
    } else if let Some(p) = &a.plot {
        let series = |name: &str, color, k: usize, bold| Series {
            name: name.into(),
            color,
            bold,
            dashed: false,
            dots: false,
            points: trace.iter().map(|r| (r.0, [r.1, r.2, r.3, r.4][k])).collect(),
        };
        let chart = LineChart {
            title: format!(
                "Force in insertion direction — {script_name} on {}",
                atlas.manifest.name
            ),
            x_label: "time (s)".into(),
            y_label: "force against insertion (N)".into(),
            series: vec![
                series("total", palette::TOTAL, 0, true),
                series("cutting", palette::CUTTING, 1, false),
                series("friction", palette::FRICTION, 2, false),
                series("base", palette::BASE, 3, false),
            ],
            markers,
            ..Default::default()
        };
        write_chart(&chart, p, (1200, 600))?;
        super::say(&format!("force plot written to {}", p.display()));
    }
    Ok(())
}
