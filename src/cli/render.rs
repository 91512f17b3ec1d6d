//! `stylet render`: one picture of an atlas, or of a recorded session at a moment (replayed to
//! that tick through the physics), as a PNG: the 3D ray-cast view or a slice (docs/rendering.md).

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, bail};
use clap::{Args, ValueEnum};
use stylet_physics::glam::{DVec3, Vec3};
use stylet_render::image::Image;
use stylet_render::mpr::{self, Plane};
use stylet_render::presets::{self, Preset};
use stylet_render::scene::{Camera, ClipPlane, Light, Quality, Scene, Tagging};
use stylet_render::tools::ToolState;
use stylet_render::transfer::TransferFunction;
use stylet_render::volume::RenderVolume;

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
    /// Image size in pixels, WIDTHxHEIGHT (each 1 … 8192).
    #[arg(long, default_value = "1225x1016", value_parser = parse_size)]
    pub size: Size,
    /// Distance between samples along a ray in the 3D view (mm; default half the finest voxel
    /// spacing).
    #[arg(long, value_name = "MM")]
    pub step_mm: Option<f32>,
    /// Draw the 3D view on the GPU (wgpu; a software Vulkan such as lavapipe will do).
    #[arg(long, conflicts_with = "cpu")]
    pub gpu: bool,
    /// Draw on the CPU reference renderer (the default).
    #[arg(long)]
    pub cpu: bool,
    /// Output PNG; written only when the whole picture is drawn.
    #[arg(long)]
    pub out: PathBuf,
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

fn parse_size(s: &str) -> Result<Size, String> {
    let bad = || format!("'{s}' is not a size: expected WIDTHxHEIGHT, each 1 … {MAX_SIDE_PX} pixels");
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(bad)?;
    let side = |v: &str| v.trim().parse::<u32>().ok().filter(|n| (1..=MAX_SIDE_PX).contains(n));
    match (side(w), side(h)) {
        (Some(width), Some(height)) => Ok(Size { width, height }),
        _ => Err(bad()),
    }
}

/// The tools at the requested moment of a session, and where the device was.
struct Moment {
    tools: ToolState,
    device_mm: DVec3,
    /// The device's axis (orientation · +z).
    axis: DVec3,
    tick: u64,
}

pub fn run(a: RenderArgs) -> anyhow::Result<()> {
    let atlas = stylet_atlas::load(&a.atlas)?;
    let moment = match (&a.session, a.at) {
        (Some(path), Some(at_s)) => Some(replay_to(&atlas, path, at_s)?),
        _ => None,
    };
    let image = match a.view {
        View::ThreeD => render_3d(&atlas, moment.as_ref(), &a)?,
        View::Axial => render_plane(&atlas, moment.as_ref(), Plane::Axial, a.size),
        View::Coronal => render_plane(&atlas, moment.as_ref(), Plane::Coronal, a.size),
        View::Sagittal => render_plane(&atlas, moment.as_ref(), Plane::Sagittal, a.size),
        View::Needle => bail!("--view needle: the oblique slice along the needle is not available yet"),
    };
    write_atomically(&image, &a.out)?;
    match &moment {
        Some(m) => sayf!(
            "{} view of '{}' at tick {} written to {}",
            view_name(a.view),
            atlas.manifest.name,
            m.tick,
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
    }
}

/// Reads a session, checks it belongs to `atlas`, and replays it up to tick round(at_s · rate).
fn replay_to(atlas: &stylet_atlas::Atlas, path: &Path, at_s: f64) -> anyhow::Result<Moment> {
    let mut session = stylet_recorder::reader::recover(path)
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
    let Some(last) = session.ticks.iter().position(|t| t.tick == tick) else {
        bail!(
            "--at {at_s} s is beyond the session {} ({duration_s:.3} s recorded{})",
            path.display(),
            if session.damage.is_some() {
                ", the rest damaged"
            } else {
                ""
            }
        );
    };
    // The ticks after the moment are not needed: replaying a prefix is bit-exact for the prefix.
    session.ticks.truncate(last + 1);
    let mut moment = None;
    let report = stylet_scoring::replay(&session, Arc::new(atlas.model.clone()), &mut |input, out, sim| {
        if out.tick == tick {
            let q = input.orientation;
            moment = Some(Moment {
                tools: ToolState::from_simulation(sim, input),
                device_mm: out.tip_mm,
                axis: if q.is_finite() && q.length_squared() > 1e-12 {
                    q.normalize() * DVec3::Z
                } else {
                    out.insertion_dir
                },
                tick,
            });
        }
    })
    .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    if let Some(d) = &report.divergence
        && d.tick <= tick
    {
        eprintln!(
            "warning: the replay of {} differs from the recording from tick {} ({}); the picture shows the replayed state",
            path.display(),
            d.tick,
            d.stream
        );
    }
    moment.ok_or_else(|| {
        anyhow::anyhow!(
            "--at {at_s} s: the session {} cannot be replayed to tick {tick} (the recording has a gap before it)",
            path.display()
        )
    })
}

/// Where the slices pass and the clipping plane cuts: the needle tip (or the contact tool) at
/// the moment, else the atlas' first planned path (its target), else the volume's centre.
fn focus(atlas: &stylet_atlas::Atlas, moment: Option<&Moment>) -> (DVec3, DVec3) {
    if let Some(m) = moment {
        return match &m.tools.needle {
            Some(n) if n.nodes_mm.len() >= 2 => (n.tip_mm().as_dvec3(), n.tip_tangent().as_dvec3()),
            _ => (m.device_mm, m.axis),
        };
    }
    if let Some(p) = atlas.planned_paths().first() {
        return (p.target_mm, p.direction().unwrap_or(DVec3::Z));
    }
    let (lo, hi) = atlas.model.ct().grid().world_bounds();
    ((lo + hi) * 0.5, DVec3::Z)
}

/// A slice through the focus, fitted into the image with the aspect kept (black margins).
fn render_plane(atlas: &stylet_atlas::Atlas, moment: Option<&Moment>, plane: Plane, size: Size) -> Image {
    let render = presets::render_settings(&atlas.manifest);
    let window = presets::slice_window(&render);
    let (center, _) = focus(atlas, moment);
    // The slice's extent as mpr::render_slice computes it, to pick a pixel size that fits.
    let grid = atlas.model.ct().grid();
    let (lo, hi) = grid.world_bounds();
    let s = DVec3::from_array(grid.spacing_mm());
    let extent = (hi - lo) + s;
    let (u, v) = plane.axes();
    let (eu, ev) = (extent.dot(u.abs()), extent.dot(v.abs()));
    let scale = (size.width as f64 / eu).min(size.height as f64 / ev);
    let max_px = ((eu.max(ev) * scale).floor() as usize).max(1);
    let slice = mpr::render_slice(&atlas.model, plane, center, window, max_px);
    let mut image = Image::new(size.width, size.height);
    let (w, h) = (
        slice.width.min(size.width as usize),
        slice.height.min(size.height as usize),
    );
    let (x0, y0) = ((size.width as usize - w) / 2, (size.height as usize - h) / 2);
    for row in 0..h {
        for col in 0..w {
            let [r, g, b] = slice.rgb[row * slice.width + col];
            image.set((x0 + col) as u32, (y0 + row) as u32, [r, g, b, 255]);
        }
    }
    image
}

/// The ray-cast view from anterior, framing the volume, with the tools of the moment.
fn render_3d(atlas: &stylet_atlas::Atlas, moment: Option<&Moment>, a: &RenderArgs) -> anyhow::Result<Image> {
    let render = presets::render_settings(&atlas.manifest);
    let preset = Preset::from(a.preset);
    let transfer = TransferFunction::from_preset(preset.of(&render)).map_err(|e| {
        anyhow::anyhow!(
            "render preset '{}' of atlas '{}': {e}",
            preset.as_str(),
            atlas.manifest.name
        )
    })?;
    let grid = *atlas.model.ct().grid();
    let (lo, hi) = grid.world_bounds();
    let camera = Camera::framing(lo.as_vec3(), hi.as_vec3(), 0.0, 0.0);
    let tagging = Tagging::from(a.tagging);
    let clip = (tagging != Tagging::Off).then(|| {
        let (point, axis) = focus(atlas, moment);
        ClipPlane::through_tool(point.as_vec3(), axis.as_vec3(), &camera)
    });
    let spacing = grid.spacing_mm();
    // Two samples per voxel along the finest axis (Nyquist for trilinear interpolation).
    let step_mm = match a.step_mm {
        Some(s) if s.is_finite() && (0.05..=10.0).contains(&s) => s,
        Some(s) => bail!("--step-mm {s}: the sample distance must be 0.05 … 10 mm"),
        None => 0.5 * spacing[0].min(spacing[1]).min(spacing[2]) as f32,
    };
    let scene = Scene {
        camera,
        transfer,
        light: Light::over_shoulder(&camera),
        clip,
        tagging,
        quality: Quality::fast(step_mm),
        tools: moment.map(|m| m.tools.clone()).unwrap_or_default(),
        background: Vec3::new(0.05, 0.06, 0.08),
        deformed: None,
        motion: None,
    };
    if a.gpu {
        bail!("--gpu: the GPU renderer is not available in this build yet; use --cpu");
    }
    let volume = RenderVolume::new(Arc::new(atlas.model.clone()));
    Ok(stylet_render::raycast::render(&volume, &scene, a.size.width, a.size.height).image)
}

/// Writes the PNG beside its destination and renames it into place, so a failure leaves no
/// half-written picture.
fn write_atomically(image: &Image, out: &Path) -> anyhow::Result<()> {
    let name = out
        .file_name()
        .with_context(|| format!("--out {}: not a file name", out.display()))?;
    let dir = out
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    if !dir.is_dir() {
        bail!("--out {}: the folder {} does not exist", out.display(), dir.display());
    }
    let tmp = dir.join(format!(".{}.tmp-{}", name.to_string_lossy(), std::process::id()));
    let written = image
        .write_png(&tmp)
        .map_err(anyhow::Error::from)
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
