//! `stylet render`: one picture of an atlas, or of a recorded session at a moment (replayed to
//! that tick through the physics), as a PNG: the 3D ray-cast view or a slice (docs/rendering.md).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, bail};
use clap::{Args, ValueEnum};
use stylet_render::image::Image;
use stylet_render::mpr::{self, Plane, SliceSpec};
use stylet_render::presets::Preset;
use stylet_render::scene::{MotionHook, Scene, Tagging};
use stylet_render::ultrasound::{self, EchoTable, FlowField, UltrasoundScene};
use stylet_render::views::{self, Moment, SessionLabels, ViewError};
use stylet_render::volume::RenderVolume;
use stylet_render::xray::{self, Radiograph, XrayScene};

use super::script::difficulty_arg;
use stylet_scoring::Difficulty;

/// The largest image side `--size` accepts.
pub const MAX_SIDE_PX: u32 = 8192;

#[derive(Debug, Args)]
pub struct RenderArgs {
    /// Atlas directory (e.g. one written by `stylet atlas phantom` or `stylet atlas import`).
    #[arg(long)]
    pub atlas: PathBuf,
    /// A recorded session (docs/session-format.md) to show at `--at`; it must have been recorded
    /// on this atlas.
    #[arg(long, requires = "at")]
    pub session: Option<PathBuf>,
    /// The moment of the session to show, in seconds from its start (replayed to tick
    /// round(at · tick rate)).
    #[arg(long, value_name = "SECONDS", requires = "session", allow_negative_numbers = true)]
    pub at: Option<f64>,
    /// What to draw.
    #[arg(long, value_enum)]
    pub view: View,
    /// Transfer-function preset of the 3D view, from the atlas' `[render.presets]`.
    #[arg(long, value_enum, default_value_t = PresetArg::Skin)]
    pub preset: PresetArg,
    /// What the clipping plane shows (3D view). Any mode but `off` cuts the volume along the
    /// tool (or the atlas' first planned path).
    #[arg(long, value_enum, default_value_t = TaggingArg::Off)]
    pub tagging: TaggingArg,
    /// Image size in pixels, WIDTHxHEIGHT (each 1 … 8192; the X-ray at most 4096). Default
    /// 1225x1016, the X-ray 512x512.
    #[arg(long, value_parser = parse_size)]
    pub size: Option<Size>,
    /// The scenario whose C-arm the X-ray uses (`[scenarios.c_arm]`) when no session names one;
    /// default: the atlas' first scenario.
    #[arg(long)]
    pub scenario: Option<String>,
    /// Turns the C-arm for the X-ray: > 0 LAO, < 0 RAO (degrees; overrides the scenario's).
    #[arg(long, value_name = "DEG", allow_negative_numbers = true)]
    pub lao_deg: Option<f64>,
    /// Tilts the C-arm for the X-ray: > 0 cranial, < 0 caudal (degrees; overrides the scenario's).
    #[arg(long, value_name = "DEG", allow_negative_numbers = true)]
    pub cranial_deg: Option<f64>,
    /// Distance between samples along a ray in the 3D view (mm; default half the finest voxel
    /// spacing).
    #[arg(long, value_name = "MM")]
    pub step_mm: Option<f32>,
    /// The probe of the ultrasound view when the session holds none (default convex); the view
    /// then images the atlas' first planned path in plane, from beside its skin entry.
    #[arg(long, value_enum)]
    pub probe: Option<ProbeArg>,
    /// Colour Doppler over the vessels in the ultrasound view.
    #[arg(long)]
    pub doppler: bool,
    /// The difficulty whose aids the ultrasound view shows (guide line, outlined target; from the
    /// atlas' `[difficulty]` presets); default the session's, else beginner.
    #[arg(long, value_parser = difficulty_arg())]
    pub difficulty: Option<Difficulty>,
    /// Draw the 3D view on the GPU (wgpu; a software Vulkan such as lavapipe will do).
    #[arg(long, conflicts_with = "cpu")]
    pub gpu: bool,
    /// Draw on the CPU reference renderer (the default).
    #[arg(long)]
    pub cpu: bool,
    /// Output PNG; written only when the whole picture is drawn.
    #[arg(long)]
    pub out: PathBuf,
    /// With `--view xray`: also write each detector pixel's line integral a = ∫μ dl as 32-bit
    /// floats, unwindowed, to a NIfTI-1 file (`.nii` or `.nii.gz`) whose sform places the pixels
    /// on the detector and whose description gives the X-ray source (docs/xray.md "Line
    /// integrals").
    #[arg(long, value_name = "FILE.nii.gz")]
    pub line_integrals: Option<PathBuf>,
}

/// The view to draw.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum View {
    /// The ray-cast volume with the tools.
    #[value(name = "3d")]
    ThreeD,
    Axial,
    Coronal,
    Sagittal,
    /// The oblique slice along the needle (needs a session with the needle in use).
    Needle,
    /// The C-arm's radiograph with the needle, guide wire, dilator or catheter and the contrast medium of the moment (docs/xray.md).
    Xray,
    /// The ultrasound image of the probe of the moment, or of one beside the planned path
    /// (docs/ultrasound.md).
    Ultrasound,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ProbeArg {
    Linear,
    Convex,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum PresetArg {
    Skin,
    Soft,
    Bone,
}

impl From<PresetArg> for Preset {
    fn from(p: PresetArg) -> Preset {
        match p {
            PresetArg::Skin => Preset::Skin,
            PresetArg::Soft => Preset::Soft,
            PresetArg::Bone => Preset::Bone,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum TaggingArg {
    Off,
    Risk,
    Labels,
}

impl From<TaggingArg> for Tagging {
    fn from(t: TaggingArg) -> Tagging {
        match t {
            TaggingArg::Off => Tagging::Off,
            TaggingArg::Risk => Tagging::Risk,
            TaggingArg::Labels => Tagging::Labels,
        }
    }
}

/// Image size in pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Size {
    pub width: u32,
    pub height: u32,
}

/// A `--size` that is not WIDTHxHEIGHT with each side within the renderer's limit.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("'{0}' is not a size: expected WIDTHxHEIGHT, each 1 … {MAX_SIDE_PX} pixels")]
pub struct BadSize(String);

fn parse_size(s: &str) -> Result<Size, BadSize> {
    let bad = || BadSize(s.to_string());
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(bad)?;
    let side = |v: &str| v.trim().parse::<u32>().ok().filter(|n| (1..=MAX_SIDE_PX).contains(n));
    match (side(w), side(h)) {
        (Some(width), Some(height)) => Ok(Size { width, height }),
        _ => Err(bad()),
    }
}

pub fn run(a: RenderArgs) -> anyhow::Result<()> {
    if let Some(path) = &a.line_integrals {
        if a.view != View::Xray {
            bail!(
                "--line-integrals {}: only the X-ray has line integrals; add --view xray",
                path.display()
            );
        }
        let name = path.file_name().map(|n| n.to_string_lossy()).unwrap_or_default();
        if !(name.ends_with(".nii") || name.ends_with(".nii.gz")) {
            bail!(
                "--line-integrals {}: the file must end in .nii or .nii.gz (NIfTI-1)",
                path.display()
            );
        }
    }
    let atlas = stylet_atlas::load(&a.atlas)?;
    let moment = match (&a.session, a.at) {
        (Some(path), Some(at_s)) => Some(replay_to(&atlas, path, at_s)?),
        _ => None,
    };
    let size = a.size.unwrap_or(match a.view {
        View::Xray => Size {
            width: 512,
            height: 512,
        },
        View::Ultrasound => Size {
            width: 640,
            height: 512,
        },
        _ => Size {
            width: 1225,
            height: 1016,
        },
    });
    let image = match a.view {
        View::ThreeD => render_3d(&atlas, moment.as_ref(), &a, size)?,
        View::Axial => render_plane(&atlas, moment.as_ref(), Plane::Axial, size, a.gpu)?,
        View::Coronal => render_plane(&atlas, moment.as_ref(), Plane::Coronal, size, a.gpu)?,
        View::Sagittal => render_plane(&atlas, moment.as_ref(), Plane::Sagittal, size, a.gpu)?,
        View::Needle => render_needle(&atlas, moment.as_ref(), size, a.gpu)?,
        View::Xray => {
            let (radiograph, window, c_arm) = render_xray(&atlas, moment.as_ref(), &a, size)?;
            if let Some(path) = &a.line_integrals {
                write_line_integrals(&radiograph, &c_arm, path)?;
                sayf!("line integrals (∫μ dl, float32) written to {}", path.display());
            }
            radiograph.to_image(window)
        }
        View::Ultrasound => render_ultrasound(&atlas, moment.as_ref(), &a, size)?,
    };
    write_atomically(&a.out, "--out", |tmp| image.write_png(tmp).map_err(anyhow::Error::from))?;
    match &moment {
        Some(m) => sayf!(
            "{} view of '{}' at tick {}{} written to {}",
            view_name(a.view),
            atlas.manifest.name,
            m.tick,
            match (a.view, m.xray_on) {
                (View::Xray, true) => " (fluoroscopy on)",
                (View::Xray, false) => " (X-ray off then: the picture the C-arm would take)",
                _ => "",
            },
            a.out.display()
        ),
        None => sayf!(
            "{} view of '{}' written to {}",
            view_name(a.view),
            atlas.manifest.name,
            a.out.display()
        ),
    }
    Ok(())
}

fn view_name(v: View) -> &'static str {
    match v {
        View::ThreeD => "3d",
        View::Axial => "axial",
        View::Coronal => "coronal",
        View::Sagittal => "sagittal",
        View::Needle => "needle",
        View::Xray => "xray",
        View::Ultrasound => "ultrasound",
    }
}

/// Reads a session, checks it belongs to `atlas`, and replays it up to tick round(at_s · rate).
fn replay_to(atlas: &stylet_atlas::Atlas, path: &Path, at_s: f64) -> anyhow::Result<Moment> {
    let session = stylet_recorder::reader::recover(path)
        .map_err(|e| anyhow::anyhow!("cannot read the session {}: {e}", path.display()))?;
    let h = &session.header;
    if h.atlas_hash != atlas.content_hash {
        bail!(
            "the session {} was recorded on atlas '{}' (content hash {}), not on '{}' (content hash {}): \
             render it with the atlas it was recorded on",
            path.display(),
            h.atlas_id,
            h.atlas_hash,
            atlas.manifest.name,
            atlas.content_hash
        );
    }
    let duration_s = session.duration_s();
    if !at_s.is_finite() || at_s < 0.0 {
        bail!("--at {at_s}: the moment must be a number of seconds ≥ 0");
    }
    let tick = (at_s * h.tick_rate_hz as f64).round() as u64;
    if !session.ticks.iter().any(|t| t.tick == tick) {
        bail!(
            "--at {at_s} s is beyond the session {} ({duration_s:.3} s recorded{})",
            path.display(),
            if session.damage.is_some() {
                ", the rest damaged"
            } else {
                ""
            }
        );
    }
    let labels = SessionLabels {
        scenario: h.scenario.clone(),
        difficulty: h.difficulty.parse()?,
        seed: h.seed,
    };
    let mut replayer = stylet_scoring::Replayer::new(&session, Arc::clone(&atlas.model))
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    let step = replayer.step_to(tick);
    if step.is_err() {
        // The moment is recorded, so a gap comes before it: replay up to the gap, so that the
        // warning names the first difference there or before.
        while replayer.step().is_some() {}
    }
    if let Some(d) = &replayer.report().divergence
        && d.tick <= tick
    {
        eprintln!(
            "warning: the replay of {} differs from the recording from tick {} ({}); the picture shows the replayed state",
            path.display(),
            d.tick,
            d.stream
        );
    }
    let (input, out) = step.map_err(|_| {
        anyhow::anyhow!(
            "--at {at_s} s: the session {} cannot be replayed to tick {tick} (the recording has a gap before it)",
            path.display()
        )
    })?;
    Ok(Moment::of_simulation(replayer.simulation(), &input, &out, &labels))
}

/// A standard plane through the focus covering the whole atlas, scaled to fit the image, with the
/// label overlay, the needle (at a moment), the scale bar and the orientation letters.
fn render_plane(
    atlas: &stylet_atlas::Atlas,
    moment: Option<&Moment>,
    plane: Plane,
    size: Size,
    gpu: bool,
) -> anyhow::Result<Image> {
    let spec = views::plane_spec(atlas, moment, plane, size.width, size.height);
    slice_image(atlas, moment, &spec, gpu)
}

/// The oblique slice along the needle at the moment, centred on the tip, wide enough for the
/// whole needle on either side.
fn render_needle(atlas: &stylet_atlas::Atlas, moment: Option<&Moment>, size: Size, gpu: bool) -> anyhow::Result<Image> {
    let spec = views::needle_spec(atlas, moment, size.width, size.height).map_err(|e| match e {
        ViewError::NoMoment => {
            anyhow::anyhow!("--view needle shows the needle of a session: give --session FILE --at SECONDS")
        }
        e => anyhow::anyhow!("--view needle: {e}"),
    })?;
    slice_image(atlas, moment, &spec, gpu)
}

/// Draws a slice (CPU or GPU) and its annotations (always on the CPU).
fn slice_image(
    atlas: &stylet_atlas::Atlas,
    moment: Option<&Moment>,
    spec: &SliceSpec,
    gpu: bool,
) -> anyhow::Result<Image> {
    if !gpu {
        return views::slice_image(atlas, moment, spec).map_err(|e| anyhow::anyhow!("slice: {e}"));
    }
    let field = moment.and_then(|m| m.deformation.as_deref());
    let breathing = moment.and_then(|m| m.breathing.as_ref());
    Ok(views::annotated_slice(
        &slice_gpu(atlas, spec, breathing, field)?,
        moment,
    )?)
}

/// The ray-cast view from anterior, framing the volume, with the tools of the moment.
fn render_3d(
    atlas: &stylet_atlas::Atlas,
    moment: Option<&Moment>,
    a: &RenderArgs,
    size: Size,
) -> anyhow::Result<Image> {
    // Two samples per voxel along the finest axis by default (Nyquist for trilinear interpolation).
    let step_mm = match a.step_mm {
        Some(s) if s.is_finite() && (0.05..=10.0).contains(&s) => s,
        Some(s) => bail!("--step-mm {s}: the sample distance must be 0.05 … 10 mm"),
        None => views::default_step_mm(atlas),
    };
    let scene = views::scene_3d(atlas, moment, Preset::from(a.preset), Tagging::from(a.tagging), step_mm)?;
    let volume = RenderVolume::new(Arc::clone(&atlas.model));
    if a.gpu {
        return render_gpu(&volume, &scene, size);
    }
    Ok(stylet_render::raycast::render(&volume, &scene, size.width, size.height).image)
}

/// The radiograph of the scenario's C-arm (the session's scenario, else `--scenario`, else the
/// atlas' first), with the needle and the contrast medium of the moment; its display window and
/// C-arm.
fn render_xray(
    atlas: &stylet_atlas::Atlas,
    moment: Option<&Moment>,
    a: &RenderArgs,
    size: Size,
) -> anyhow::Result<(Radiograph, xray::XrayWindow, xray::CArm)> {
    let scenarios = &atlas.manifest.scenarios;
    if let (Some(m), Some(asked)) = (moment, a.scenario.as_deref())
        && m.scenario != asked
    {
        bail!(
            "--scenario {asked}: the session was recorded for scenario '{}', whose C-arm the X-ray uses; leave --scenario out",
            m.scenario
        );
    }
    let wanted = moment.map(|m| m.scenario.as_str()).or(a.scenario.as_deref());
    let scenario = match wanted {
        Some(name) => match scenarios.iter().find(|s| s.name == name) {
            Some(s) => Some(s),
            // A session of a scenario the atlas no longer declares still has a picture.
            None if moment.is_some() => None,
            None => bail!(
                "--scenario {name}: atlas '{}' has no such scenario (it has: {})",
                atlas.manifest.name,
                scenarios.iter().map(|s| s.name.as_str()).collect::<Vec<_>>().join(", ")
            ),
        },
        None => scenarios.first(),
    };
    let (scene, window) = views::xray_scene(atlas, moment, scenario, a.lao_deg, a.cranial_deg)?;
    let breathing = moment.and_then(|m| m.breathing.as_ref());
    let radiograph = if a.gpu {
        xray_gpu(atlas, &scene, breathing, size)?
    } else {
        xray::render_moving(&atlas.model, &scene, breathing, size.width, size.height)
            .map_err(|e| anyhow::anyhow!("--view xray: {e}"))?
    };
    Ok((radiograph, window, scene.c_arm))
}

/// The radiograph's line integrals as a 2D float32 NIfTI: pixel (col, row) at its detector
/// pixel's centre (RAS+ mm), the beam direction completing the affine, the source in the
/// description. Written whole or not at all.
fn write_line_integrals(radiograph: &Radiograph, c_arm: &xray::CArm, path: &Path) -> anyhow::Result<()> {
    let p = c_arm.projection(radiograph.width, radiograph.height);
    let v = |v: stylet_physics::glam::Vec3| [v.x as f64, v.y as f64, v.z as f64];
    let s = p.source_mm;
    let description = format!(
        "Stylet X-ray line integrals a=int mu dl; source_mm={:.2},{:.2},{:.2}",
        s.x, s.y, s.z
    );
    let image = stylet_atlas::nifti_io::PlaneImage {
        width: radiograph.width as usize,
        height: radiograph.height as usize,
        origin_mm: v(p.pixel00_mm),
        col_mm: v(p.col_mm),
        row_mm: v(p.row_mm),
        normal: v(c_arm.beam_direction()),
        values: &radiograph.attenuation,
    };
    write_atomically(path, "--line-integrals", |tmp| {
        stylet_atlas::nifti_io::write_plane_f32(tmp, &image, &description, "line integral").map_err(anyhow::Error::from)
    })
}

/// The ultrasound frame of the moment's probe, else of a probe beside the atlas' first planned
/// path imaging it in plane; the needle of the moment; the aids of the difficulty.
fn render_ultrasound(
    atlas: &stylet_atlas::Atlas,
    moment: Option<&Moment>,
    a: &RenderArgs,
    size: Size,
) -> anyhow::Result<Image> {
    if let (Some(p), Some(asked)) = (moment.and_then(|m| m.tools.probe), a.probe)
        && (asked == ProbeArg::Linear) != (p.kind == stylet_physics::ProbeKind::Linear)
    {
        bail!(
            "--probe {asked:?}: the session holds a {:?} probe; leave --probe out",
            p.kind
        );
    }
    let kind = a.probe.map(|p| match p {
        ProbeArg::Linear => stylet_physics::ProbeKind::Linear,
        ProbeArg::Convex => stylet_physics::ProbeKind::Convex,
    });
    let level = match (a.difficulty, moment) {
        (Some(d), _) => d,
        (None, Some(m)) => m.difficulty,
        (None, None) => Difficulty::Beginner,
    };
    let echo = Arc::new(EchoTable::of_atlas(atlas));
    let doppler = a.doppler.then(|| Arc::new(FlowField::build(&atlas.model, &echo)));
    let scene = views::ultrasound_scene(atlas, moment, kind, level, echo, doppler).map_err(|e| match e {
        ViewError::NoProbe { .. } => anyhow::anyhow!("--view {e}"),
        e => anyhow::anyhow!(e),
    })?;
    let frame = if a.gpu {
        ultrasound_gpu(atlas, &scene)?
    } else {
        ultrasound::render(&atlas.model, &scene).map_err(|e| anyhow::anyhow!("--view ultrasound: {e}"))?
    };
    Ok(frame.to_image(size.width, size.height))
}

/// A GPU device and the atlas uploaded to it (wgpu; lavapipe will do).
#[cfg(feature = "gpu")]
fn gpu_upload(volume: &RenderVolume) -> anyhow::Result<(stylet_render_gpu::GpuContext, stylet_render_gpu::GpuVolume)> {
    let ctx = stylet_render_gpu::GpuContext::new().map_err(|e| anyhow::anyhow!("--gpu: {e}"))?;
    let gpu_volume = stylet_render_gpu::GpuVolume::upload(&ctx, volume).map_err(|e| on_gpu(&ctx, e))?;
    Ok((ctx, gpu_volume))
}

/// A GPU failure, naming the adapter.
#[cfg(feature = "gpu")]
fn on_gpu(ctx: &stylet_render_gpu::GpuContext, e: stylet_render_gpu::GpuError) -> anyhow::Error {
    anyhow::anyhow!("--gpu on {}: {e}", ctx.adapter().name)
}

#[cfg(feature = "gpu")]
fn xray_gpu(
    atlas: &stylet_atlas::Atlas,
    scene: &XrayScene,
    breathing: Option<&MotionHook>,
    size: Size,
) -> anyhow::Result<Radiograph> {
    let (ctx, gpu_volume) = gpu_upload(&RenderVolume::new(Arc::clone(&atlas.model)))?;
    stylet_render_gpu::GpuXray::new(&ctx)
        .render_moving(&ctx, &gpu_volume, scene, breathing, size.width, size.height)
        .map_err(|e| on_gpu(&ctx, e))
}

#[cfg(feature = "gpu")]
fn ultrasound_gpu(atlas: &stylet_atlas::Atlas, scene: &UltrasoundScene) -> anyhow::Result<ultrasound::Sonogram> {
    let (ctx, gpu_volume) = gpu_upload(&RenderVolume::new(Arc::clone(&atlas.model)))?;
    stylet_render_gpu::GpuUltrasound::new(&ctx)
        .render(&ctx, &gpu_volume, scene)
        .map_err(|e| on_gpu(&ctx, e))
}

#[cfg(not(feature = "gpu"))]
fn ultrasound_gpu(_: &stylet_atlas::Atlas, _: &UltrasoundScene) -> anyhow::Result<ultrasound::Sonogram> {
    bail!("--gpu: this stylet was built without the GPU renderer (cargo feature `gpu`); use --cpu")
}

#[cfg(not(feature = "gpu"))]
fn xray_gpu(_: &stylet_atlas::Atlas, _: &XrayScene, _: Option<&MotionHook>, _: Size) -> anyhow::Result<Radiograph> {
    bail!("--gpu: this stylet was built without the GPU renderer (cargo feature `gpu`); use --cpu")
}

/// The same scene on the GPU renderer (wgpu).
#[cfg(feature = "gpu")]
fn render_gpu(volume: &RenderVolume, scene: &Scene, size: Size) -> anyhow::Result<Image> {
    let (ctx, gpu_volume) = gpu_upload(volume)?;
    stylet_render_gpu::GpuRenderer::new(&ctx)
        .render(&ctx, &gpu_volume, scene, size.width, size.height)
        .map_err(|e| on_gpu(&ctx, e))
}

/// A slice on the GPU renderer.
#[cfg(feature = "gpu")]
fn slice_gpu(
    atlas: &stylet_atlas::Atlas,
    spec: &SliceSpec,
    breathing: Option<&MotionHook>,
    field: Option<&stylet_physics::DeformField>,
) -> anyhow::Result<mpr::MprImage> {
    let (ctx, gpu_volume) = gpu_upload(&RenderVolume::new(Arc::clone(&atlas.model)))?;
    let mut mpr = stylet_render_gpu::GpuMpr::new(&ctx);
    match (breathing, field) {
        (Some(_), _) => mpr.render_moving(&ctx, &gpu_volume, spec, breathing, field),
        (None, Some(field)) => mpr.render_deformed(&ctx, &gpu_volume, spec, field),
        (None, None) => mpr.render(&ctx, &gpu_volume, spec),
    }
    .map_err(|e| on_gpu(&ctx, e))
}

#[cfg(not(feature = "gpu"))]
fn slice_gpu(
    _: &stylet_atlas::Atlas,
    _: &SliceSpec,
    _: Option<&MotionHook>,
    _: Option<&stylet_physics::DeformField>,
) -> anyhow::Result<mpr::MprImage> {
    bail!("--gpu: this stylet was built without the GPU renderer (cargo feature `gpu`); use --cpu")
}

#[cfg(not(feature = "gpu"))]
fn render_gpu(_: &RenderVolume, _: &Scene, _: Size) -> anyhow::Result<Image> {
    bail!("--gpu: this stylet was built without the GPU renderer (cargo feature `gpu`); use --cpu")
}

/// Writes the PNG beside its destination and renames it into place, so a failure leaves no
/// half-written picture.
/// Writes `out` through `write` into a temporary file beside it (same extension), then renames
/// it: the file is whole or absent. `flag` names the option in errors.
fn write_atomically(out: &Path, flag: &str, write: impl FnOnce(&Path) -> anyhow::Result<()>) -> anyhow::Result<()> {
    let name = out
        .file_name()
        .with_context(|| format!("{flag} {}: not a file name", out.display()))?;
    let dir = out
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    if !dir.is_dir() {
        bail!("{flag} {}: the folder {} does not exist", out.display(), dir.display());
    }
    let tmp = dir.join(format!(".tmp-{}-{}", std::process::id(), name.to_string_lossy()));
    let written = write(&tmp)
        .and_then(|()| std::fs::rename(&tmp, out).with_context(|| format!("cannot write {}", out.display())));
    if written.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    written
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_within_bounds() {
        assert_eq!(
            parse_size("1225x1016"),
            Ok(Size {
                width: 1225,
                height: 1016
            })
        );
        assert_eq!(parse_size("8192X1").map(|s| s.width), Ok(8192));
        for bad in ["0x10", "10x0", "8193x10", "10", "axb", "-1x5", ""] {
            assert!(parse_size(bad).is_err(), "{bad}");
        }
    }
}
