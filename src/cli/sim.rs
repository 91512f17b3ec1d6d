//! `stylet sim`: the desktop simulator (docs/simulator.md). With no flags it opens the window on
//! the phantom patient; `--headless --script FILE` runs the same haptic loop without a window,
//! driven by a device script, and reports its rate and the views' frame rates.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use stylet_app::haptic::{Ended, HapticLoop, LoopOptions};
use stylet_app::views::{Backend, ViewKind, ViewRenderer, ViewSettings};
use stylet_render::views::SessionLabels;

use super::script::{SessionArgs, script_simulation};

#[derive(Debug, Args)]
pub struct SimArgs {
    /// Atlas directory (the patient); repeat to offer several. Default: the phantom in the data
    /// folder, built there on first use.
    #[arg(long)]
    pub atlas: Vec<PathBuf>,
    /// Where sessions, the outbox and the built phantom are kept (default: the user's data
    /// folder, e.g. ~/.local/share/stylet).
    #[arg(long)]
    pub data_dir: Option<PathBuf>,
    /// Serve the tablet page (tool, mode and event buttons for a tablet beside the workbench) on
    /// this address, e.g. 0.0.0.0:8765; off by default. The window shows its pairing code.
    #[arg(long, conflicts_with = "headless")]
    pub tablet: Option<std::net::SocketAddr>,
    /// Offer the raw-HID haptic device this profile describes (docs/devices.md "HID profiles")
    /// in the devices dialog, for either hand; it is checked before the window opens.
    #[arg(long, conflicts_with = "headless")]
    pub hid_profile: Option<PathBuf>,
    /// Offer this force-feedback device (docs/devices.md "Haptic devices") in the devices dialog,
    /// for either hand: its vendor library or service is found before the window opens, the
    /// device opened when a session starts. With --hid-profile too, each device may move a hand.
    #[arg(long, value_enum, conflicts_with = "headless")]
    pub device: Option<super::device::BackendArg>,
    /// The device's vendor library (openhaptics, dhd; default: the usual names and paths).
    #[arg(long, requires = "device")]
    pub device_library: Option<PathBuf>,
    /// Haply's Inverse Service (default ws://localhost:10001).
    #[arg(long, requires = "device")]
    pub device_url: Option<String>,
    /// Tool millimetres per millimetre of the device's stylus (0.25 … 4; 1: the needle moves as
    /// far as the hand).
    #[arg(long, requires = "device", default_value_t = 1.0)]
    pub device_scale: f64,
    /// Open this session file in the replay viewer.
    #[arg(long, conflicts_with = "headless")]
    pub replay: Option<PathBuf>,
    /// Run without a window: the haptic loop driven by the device script given with --script.
    #[arg(long, requires = "script")]
    pub headless: bool,
    /// Device script (docs/scripts.md): drives --headless runs; in the window, sessions are then
    /// driven by the script instead of by hand (a demonstration).
    #[arg(long)]
    pub script: Option<PathBuf>,
    /// Record the session to this file (docs/session-format.md).
    #[arg(long)]
    pub out: Option<PathBuf>,
    #[command(flatten)]
    pub session: SessionArgs,
    /// Tick as fast as the CPU allows instead of at the simulation's rate (same session file).
    #[arg(long)]
    pub unpaced: bool,
    /// While the loop runs, draw these views from its snapshots one after the other, as the
    /// window does, and report each view's frame rate: 3d, axial, needle, ultrasound, xray.
    #[arg(long, value_delimiter = ',', value_parser = parse_view)]
    pub views: Vec<ViewKind>,
    /// Size of each drawn view on screen, WIDTHxHEIGHT.
    #[arg(long, default_value = "1280x800", value_parser = parse_view_size)]
    pub view_size: (u32, u32),
    /// What draws the views: gpu (wgpu; a software Vulkan will do), cpu (the reference
    /// renderers), or auto: the GPU when the machine has a real one, else the CPU.
    #[arg(long, default_value = "auto", value_parser = parse_renderer)]
    pub renderer: Backend,
}

/// A `stylet sim` flag value that names no renderer or view, or no size the views can take.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SimArgError {
    #[error("unknown renderer '{0}' (auto, cpu or gpu)")]
    Renderer(String),
    #[error("unknown view '{name}' (views: {})", view_names())]
    View { name: String },
    #[error("'{0}' is not WIDTHxHEIGHT with each 16 … 4096")]
    ViewSize(String),
}

/// The views `--views` takes, comma-separated.
fn view_names() -> String {
    let names: Vec<&str> = ViewKind::ALL.iter().map(|v| v.name()).collect();
    names.join(", ")
}

fn parse_renderer(s: &str) -> Result<Backend, SimArgError> {
    Backend::parse(s).ok_or_else(|| SimArgError::Renderer(s.to_string()))
}

fn parse_view(s: &str) -> Result<ViewKind, SimArgError> {
    ViewKind::parse(s).ok_or_else(|| SimArgError::View { name: s.to_string() })
}

fn parse_view_size(s: &str) -> Result<(u32, u32), SimArgError> {
    let bad = || SimArgError::ViewSize(s.to_string());
    let (w, h) = s.split_once('x').ok_or_else(bad)?;
    let (w, h): (u32, u32) = (w.parse().map_err(|_| bad())?, h.parse().map_err(|_| bad())?);
    if !(16..=4096).contains(&w) || !(16..=4096).contains(&h) {
        return Err(bad());
    }
    Ok((w, h))
}

/// Frames drawn of one view while the loop ran.
#[derive(Default)]
struct ViewTally {
    frames: u64,
    drawing: std::time::Duration,
    scale_sum: f64,
    failed: Option<String>,
}

/// The data folder: --data-dir, else the user's data folder.
fn data_dir(a: &SimArgs) -> anyhow::Result<PathBuf> {
    match &a.data_dir {
        Some(d) => Ok(d.clone()),
        None => dirs::data_dir()
            .map(|d| d.join("stylet"))
            .context("this system has no user data folder: give --data-dir"),
    }
}

/// The patients: --atlas, else the phantom in the data folder (built on first use).
fn atlases(a: &SimArgs, data: &std::path::Path) -> anyhow::Result<Vec<PathBuf>> {
    if !a.atlas.is_empty() {
        for dir in &a.atlas {
            if !dir.join("atlas.toml").is_file() {
                anyhow::bail!(
                    "{} is not an atlas (no atlas.toml): build one with `stylet atlas phantom` or `stylet atlas build` (docs/atlas.md)",
                    dir.display()
                );
            }
        }
        return Ok(a.atlas.clone());
    }
    let phantom = data.join("atlases/phantom");
    if !phantom.join("atlas.toml").exists() {
        super::say(&format!("building the phantom patient in {} (once)", phantom.display()));
        super::atlas::build_phantom(&phantom, &stylet_atlas::phantom::PhantomConfig::default(), true)?;
    }
    Ok(vec![phantom])
}

pub fn run(a: SimArgs) -> anyhow::Result<()> {
    let data = data_dir(&a)?;
    let atlases = atlases(&a, &data)?;
    let Some(script) = a.script.as_ref().filter(|_| a.headless) else {
        return window(a, data, atlases);
    };
    let atlas = stylet_atlas::load(&atlases[0])?;
    let (sim, device) = script_simulation(&atlas, script)?;
    let paced = !a.unpaced;
    // Real time: the recorder must never block the loop (a full queue marks the session
    // incomplete); unpaced: it may wait, nothing is lost.
    let recording = match &a.out {
        Some(path) => Some(a.session.start_recording(&sim, &atlas, script, path, paced)?),
        None => None,
    };
    let rate_hz = sim.tick_rate_hz();
    let labels = SessionLabels {
        scenario: a.session.scenario_of(script),
        difficulty: a.session.difficulty,
        seed: a.session.seed,
    };
    let atlas = std::sync::Arc::new(atlas);
    let mut renderer = match a.views.is_empty() {
        true => None,
        false => {
            // As in the window: the drawing threads run on the other cores, the paced loop on
            // one of its own (where there is more than one).
            if paced && let Some(core) = stylet_app::priority::reserve_a_core_for_the_haptic_loop() {
                super::say(&format!("the haptic loop keeps core {core} to itself"));
            }
            let r = ViewRenderer::new(
                std::sync::Arc::clone(&atlas),
                ViewSettings {
                    backend: a.renderer,
                    ..ViewSettings::default()
                },
            )?;
            super::say(&format!("views drawn by {}", r.drawn_by()));
            Some(r)
        }
    };
    let haptic = HapticLoop::spawn(
        sim,
        Box::new(device),
        recording,
        labels,
        LoopOptions {
            paced,
            ..LoopOptions::default()
        },
    )?;
    let mut tallies: Vec<ViewTally> = a.views.iter().map(|_| ViewTally::default()).collect();
    if let Some(r) = renderer.as_mut() {
        let (w, h) = a.view_size;
        while !haptic.is_finished() {
            let Some(snap) = haptic.snapshot() else {
                std::thread::sleep(std::time::Duration::from_millis(1));
                continue;
            };
            let mut drawn = false;
            for (kind, tally) in a.views.iter().zip(tallies.iter_mut()) {
                if tally.failed.is_some() {
                    continue;
                }
                match r.draw(*kind, &snap.moment, w, h) {
                    Ok(frame) => {
                        drawn = true;
                        tally.frames += 1;
                        tally.drawing += frame.took;
                        tally.scale_sum += f64::from(frame.scale);
                    }
                    // A view with nothing to show yet (the needle before it is taken) is
                    // skipped this time, not counted.
                    Err(stylet_render::views::ViewError::NoNeedle { .. }) => {}
                    Err(e) => tally.failed = Some(e.to_string()),
                }
            }
            if !drawn {
                // Nothing to draw yet (or every view failed): do not spin.
                std::thread::sleep(std::time::Duration::from_millis(10));
            }
        }
    }
    let report = haptic.join()?;
    let s = report.stats;
    let wall_s = report.wall.as_secs_f64();
    super::say(&format!(
        "haptic loop {}: {} ticks = {:.3} s simulated in {:.3} s ({:.1} ticks/s), {} missed their deadline (worst {:.2} ms late), {} periods skipped",
        if paced { "paced" } else { "unpaced" },
        s.ticks,
        s.ticks as f64 / f64::from(rate_hz),
        wall_s,
        s.ticks as f64 / wall_s.max(1e-9),
        s.missed,
        s.worst_late.as_secs_f64() * 1e3,
        s.skipped_periods
    ));
    let (w, h) = a.view_size;
    for (kind, t) in a.views.iter().zip(&tallies) {
        let ms = t.drawing.as_secs_f64() * 1e3 / t.frames.max(1) as f64;
        match &t.failed {
            Some(e) => super::say(&format!("view {}: failed: {e}", kind.name())),
            None => super::say(&format!(
                "view {} at {w}x{h}: {} frames, {:.1} ms each ({:.1} per second), mean scale {:.2}",
                kind.name(),
                t.frames,
                ms,
                1e3 / ms.max(1e-9),
                t.scale_sum / t.frames.max(1) as f64
            )),
        }
    }
    if report.ended == Ended::Stopped {
        super::say("stopped before the script's end");
    }
    if let (Some(result), Some(path)) = (report.recording, &a.out) {
        let summary = result.context("recording the session")?;
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
    Ok(())
}

#[cfg(feature = "window")]
fn window(a: SimArgs, data: PathBuf, atlases: Vec<PathBuf>) -> anyhow::Result<()> {
    let options = stylet_app::window::AppOptions {
        atlases,
        sessions_dir: data.join("sessions"),
        outbox_dir: data.join("outbox"),
        config_dir: match &a.data_dir {
            Some(d) => Some(d.join("config")),
            None => stylet_app::credentials::config_dir().ok(),
        },
        script: a.script,
        paced: !a.unpaced,
        view_budget: std::time::Duration::from_millis(50),
        renderer: a.renderer,
        replay: a.replay,
        tablet: a.tablet,
        hid_profile: match &a.hid_profile {
            Some(p) => {
                let text = std::fs::read_to_string(p).with_context(|| format!("cannot read {}", p.display()))?;
                Some(
                    stylet_devices::hid_profile::HidProfile::parse(&text)
                        .map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?,
                )
            }
            None => None,
        },
        haptic_device: match a.device {
            Some(backend) => {
                let choice = super::device::choice(backend, a.device_library.as_deref(), a.device_url.as_deref())?;
                if !(0.25..=4.0).contains(&a.device_scale) {
                    anyhow::bail!("--device-scale takes 0.25 … 4, not {}", a.device_scale);
                }
                let at = choice.find()?;
                sayf!(
                    "{}: found at {at}; the device opens when a session starts",
                    choice.backend
                );
                let mapping = stylet_devices::haptic::pose::Mapping {
                    scale: a.device_scale,
                    ..Default::default()
                };
                Some((choice, mapping))
            }
            None => None,
        },
    };
    stylet_app::window::run(options).map_err(|e| {
        anyhow::anyhow!(
            "{e}\n(without a display, `stylet sim --headless --script FILE` runs the simulator's haptic loop)"
        )
    })
}

#[cfg(not(feature = "window"))]
fn window(_: SimArgs, _: PathBuf, _: Vec<PathBuf>) -> anyhow::Result<()> {
    anyhow::bail!(
        "this build of stylet has no window (built without the `window` feature); use --headless --script FILE"
    )
}
