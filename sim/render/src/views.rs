//! The simulator's views, composed from an atlas and a moment of a session: what
//! `stylet render`, the desktop simulator and the dashboard draw, so the three show the same
//! picture of the same tick. Each function builds the scene of one view (camera, plane, C-arm,
//! probe, aids by difficulty); the renderers draw it.

use std::sync::Arc;

use stylet_atlas::{Atlas, Difficulty};
use stylet_physics::complications::Site;
use stylet_physics::glam::{DVec3, Vec3};
use stylet_physics::{DeformField, ProbeKind, Simulation, TickInput, TickOutput};

use crate::RenderError;
use crate::annotate::{Annotations, annotate};
use crate::consequences::{self, ConsequenceScene};
use crate::image::Image;
use crate::mpr::{self, Plane, SliceSpec};
use crate::presets::{self, Preset};
use crate::scene::{Camera, ClipPlane, DeformedRegion, Light, MotionHook, Quality, Scene, Tagging};
use crate::tools::ToolState;
use crate::transfer::TransferFunction;
use crate::ultrasound::{self, EchoTable, FlowField, UltrasoundScene, UltrasoundSettings};
use crate::xray::attenuation::DEFAULT_IODINE_MG_PER_ML;
use crate::xray::{CArm, ContrastOverlay, XrayScene, XrayWindow};

/// The state of a session at one tick, as the views need it.
#[derive(Debug, Clone)]
pub struct Moment {
    pub tools: ToolState,
    /// The contrast medium in the patient (CT voxels, μ_c), if any was injected. Shared: the
    /// haptic loop publishes a moment many times a second and must not copy the overlay each time.
    pub contrast: Option<Arc<ContrastOverlay>>,
    /// What wrong punctures have let out so far (docs/complications.md): the views draw
    /// haematomas, bile leaks and pneumothoraces from these.
    pub consequences: Vec<Site>,
    /// The scenario the session is for (its C-arm).
    pub scenario: String,
    pub xray_on: bool,
    /// The session's seed (the ultrasound's speckle), time (s) and difficulty.
    pub seed: u64,
    pub time_s: f64,
    pub difficulty: Difficulty,
    pub device_mm: DVec3,
    /// The device's axis (orientation · +z).
    pub axis: DVec3,
    pub tick: u64,
    /// The tissue deformation in effect (thesis Chapter 4), if any: the slices invert it per
    /// pixel and the 3D view samples the deformed sub-image J inside its lattice.
    pub deformation: Option<Arc<DeformField>>,
    /// The breathing motion at this moment (thesis Chapter 5), if the patient breathes: the
    /// slices invert u per pixel and the 3D view warps its rays (eqs. 5.4.1–5.4.2).
    pub breathing: Option<MotionHook>,
}

/// Who the session is for, to label a [`Moment`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SessionLabels {
    pub scenario: String,
    pub difficulty: Difficulty,
    pub seed: u64,
}

impl Moment {
    /// The moment after the tick that produced `out` from `input`.
    pub fn of_simulation(sim: &Simulation, input: &TickInput, out: &TickOutput, labels: &SessionLabels) -> Moment {
        let ct_dims = sim.atlas().ct().grid().dims();
        let contrast = ContrastOverlay::from_agent(sim.contrast(), ct_dims, DEFAULT_IODINE_MG_PER_ML);
        Moment::with_contrast(sim, input, out, labels, contrast.map(Arc::new))
    }

    /// [`Self::of_simulation`] with the contrast overlay given (the haptic loop rebuilds it only
    /// when the contrast changed).
    pub fn with_contrast(
        sim: &Simulation,
        input: &TickInput,
        out: &TickOutput,
        labels: &SessionLabels,
        contrast: Option<Arc<ContrastOverlay>>,
    ) -> Moment {
        let q = input.orientation;
        Moment {
            tools: ToolState::from_simulation(sim, input),
            contrast,
            consequences: sim
                .complications()
                .sites()
                .iter()
                .copied()
                .filter(|s| s.volume_ml > 0.0)
                .collect(),
            scenario: labels.scenario.clone(),
            xray_on: out.xray_on,
            seed: labels.seed,
            time_s: out.tick as f64 / f64::from(sim.tick_rate_hz()),
            difficulty: labels.difficulty,
            device_mm: out.tip_mm,
            axis: if q.is_finite() && q.length_squared() > 1e-12 {
                q.normalize() * DVec3::Z
            } else {
                out.insertion_dir
            },
            tick: out.tick,
            deformation: sim.deformation().field().cloned(),
            breathing: sim.breathes().then(|| MotionHook {
                model: Arc::clone(sim.motion()),
                t_s: sim.motion_time_s(),
            }),
        }
    }
}

/// Why a view cannot be drawn.
#[derive(Debug, thiserror::Error)]
pub enum ViewError {
    #[error("the view along the needle needs a moment of a session")]
    NoMoment,
    #[error("the needle is not in use at tick {tick} (the tool then is the finger or a probe)")]
    NoNeedle { tick: u64 },
    #[error(
        "the ultrasound view needs a probe: a session holding one, or an atlas with a planned path to image ('{atlas}' has none)"
    )]
    NoProbe { atlas: String },
    #[error("the planned path '{0}' has no length")]
    DegeneratePath(String),
    #[error("render preset '{preset}' of atlas '{atlas}': {reason}")]
    Preset {
        preset: &'static str,
        atlas: String,
        reason: String,
    },
    #[error("the C-arm: {0}")]
    CArm(stylet_atlas::manifest::CArmError),
    #[error("{0}")]
    Slice(#[from] mpr::MprError),
    #[error("{0}")]
    Render(#[from] RenderError),
}

/// Where the slices pass and the clipping plane cuts: the needle tip (or the contact tool) at
/// the moment, else the atlas' first planned path (its target), else the volume's centre; and
/// the direction there.
pub fn focus(atlas: &Atlas, moment: Option<&Moment>) -> (DVec3, DVec3) {
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

/// A standard plane through the focus covering the whole atlas, scaled to fit `width` × `height`.
pub fn plane_spec(atlas: &Atlas, moment: Option<&Moment>, plane: Plane, width: u32, height: u32) -> SliceSpec {
    let window = presets::slice_window(&presets::render_settings(&atlas.manifest));
    let (focus_mm, _) = focus(atlas, moment);
    let grid = atlas.model.ct().grid();
    let (lo, hi) = grid.world_bounds();
    let s = DVec3::from_array(grid.spacing_mm());
    let (lo, hi) = (lo - s * 0.5, hi + s * 0.5);
    let (right, down) = plane.axes();
    let normal = right.cross(down);
    // In the plane: the volume's centre; across it: the focus.
    let middle = (lo + hi) * 0.5;
    let center_mm = middle + normal * (focus_mm - middle).dot(normal);
    let (eu, ev) = ((hi - lo).dot(right.abs()), (hi - lo).dot(down.abs()));
    let pixel_mm = (eu / f64::from(width.max(1))).max(ev / f64::from(height.max(1)));
    SliceSpec {
        center_mm,
        right,
        down,
        pixel_mm,
        width: width as usize,
        height: height as usize,
        window,
    }
}

/// The oblique slice along the needle of the moment, centred on the tip, wide enough for the
/// whole needle on either side.
pub fn needle_spec(atlas: &Atlas, moment: Option<&Moment>, width: u32, height: u32) -> Result<SliceSpec, ViewError> {
    let m = moment.ok_or(ViewError::NoMoment)?;
    let needle = m
        .tools
        .needle
        .as_ref()
        .filter(|n| n.nodes_mm.len() >= 2)
        .ok_or(ViewError::NoNeedle { tick: m.tick })?;
    let window = presets::slice_window(&presets::render_settings(&atlas.manifest));
    let reach_mm = f64::from(needle.length_mm() + needle.hub_length_mm) + 10.0;
    let pixel_mm = 2.0 * reach_mm / f64::from(width.min(height).max(1));
    Ok(SliceSpec::oblique_along_needle(
        needle.tip_mm().as_dvec3(),
        needle.tip_tangent().as_dvec3(),
        pixel_mm,
        width as usize,
        height as usize,
        window,
    )?)
}

/// A drawn slice with its annotations: the needle of the moment, the scale bar, the letters,
/// and with a deformation at the moment (a slice drawn by `render_spec_deformed` or its GPU
/// port) the displacement colour map's legend.
pub fn annotated_slice(slice: &mpr::MprImage, moment: Option<&Moment>) -> Result<Image, ViewError> {
    let mut image = slice.to_image();
    let needle_mm = moment
        .and_then(|m| m.tools.needle.as_ref())
        .map(|n| n.nodes_mm.iter().map(|p| p.as_dvec3()).collect())
        .unwrap_or_default();
    let ann = Annotations {
        needle_mm,
        scale_bar: true,
        letters: true,
    };
    annotate(&mut image, &slice.spec, &ann)?;
    if let Some(field) = moment.and_then(|m| m.deformation.as_deref()) {
        crate::annotate::displacement_legend(&mut image, mpr::displacement_scale_mm(field))?;
    }
    Ok(image)
}

/// A slice drawn on the CPU reference renderer, annotated; with a deformation at the moment, the
/// deformed patient with its displacement colour map and legend.
pub fn slice_image(atlas: &Atlas, moment: Option<&Moment>, spec: &SliceSpec) -> Result<Image, ViewError> {
    let deformation = moment.and_then(|m| m.deformation.as_deref());
    let breathing = moment.and_then(|m| m.breathing.as_ref());
    let slice = match (breathing, deformation) {
        (Some(_), _) => mpr::render_spec_moving(&atlas.model, spec, breathing, deformation)?,
        (None, Some(field)) => mpr::render_spec_deformed(&atlas.model, spec, field)?,
        (None, None) => mpr::render_spec(&atlas.model, spec)?,
    };
    annotated_slice(&slice, moment)
}

/// The default sample distance of the 3D view: two samples per voxel along the finest axis
/// (Nyquist for trilinear interpolation).
pub fn default_step_mm(atlas: &Atlas) -> f32 {
    let s = atlas.model.ct().grid().spacing_mm();
    0.5 * s[0].min(s[1]).min(s[2]) as f32
}

/// The ray-cast view from anterior framing the volume, with the tools of the moment; with
/// tagging on, the volume cut along the tool (or the first planned path).
pub fn scene_3d(
    atlas: &Atlas,
    moment: Option<&Moment>,
    preset: Preset,
    tagging: Tagging,
    step_mm: f32,
) -> Result<Scene, ViewError> {
    let transfer = transfer_of(atlas, preset)?;
    let (lo, hi) = atlas.model.ct().grid().world_bounds();
    let camera = Camera::framing(lo.as_vec3(), hi.as_vec3(), 0.0, 0.0);
    let cut = (tagging != Tagging::Off).then(|| focus(atlas, moment));
    let tools = moment.map(|m| m.tools.clone()).unwrap_or_default();
    let mut scene = scene_3d_from(camera, transfer, tagging, cut, tools, step_mm);
    scene.deformed = moment
        .and_then(|m| m.deformation.as_deref())
        .map(|field| DeformedRegion {
            volume: Arc::new(stylet_physics::deform::resample::deformed_ct(&atlas.model, field)),
        });
    scene.motion = moment.and_then(|m| m.breathing.clone());
    Ok(scene)
}

/// The ray-cast view of the atlas from `azimuth_deg`/`elevation_deg` (see [`Camera::orbit`])
/// framing the box `frame_mm` (world bounds), no tools, the volume cut along the line through `cut_point_mm` in
/// direction `cut_axis` (tagging shows the target and the risk structures on the cut): the
/// frames of the dashboard's 3D overview.
pub fn scene_3d_orbit(
    atlas: &Atlas,
    preset: Preset,
    tagging: Tagging,
    (cut_point_mm, cut_axis): (DVec3, DVec3),
    step_mm: f32,
    (azimuth_deg, elevation_deg): (f32, f32),
    (lo, hi): (DVec3, DVec3),
) -> Result<Scene, ViewError> {
    let transfer = transfer_of(atlas, preset)?;
    let camera = Camera::framing(lo.as_vec3(), hi.as_vec3(), azimuth_deg, elevation_deg);
    let cut = Some((cut_point_mm, cut_axis));
    Ok(scene_3d_from(
        camera,
        transfer,
        tagging,
        cut,
        ToolState::default(),
        step_mm,
    ))
}

fn transfer_of(atlas: &Atlas, preset: Preset) -> Result<TransferFunction, ViewError> {
    let render = presets::render_settings(&atlas.manifest);
    TransferFunction::from_preset(preset.of(&render)).map_err(|e| ViewError::Preset {
        preset: preset.as_str(),
        atlas: atlas.manifest.name.clone(),
        reason: e.to_string(),
    })
}

fn scene_3d_from(
    camera: Camera,
    transfer: TransferFunction,
    tagging: Tagging,
    cut: Option<(DVec3, DVec3)>,
    tools: ToolState,
    step_mm: f32,
) -> Scene {
    let clip = cut.map(|(point, axis)| ClipPlane::through_tool(point.as_vec3(), axis.as_vec3(), &camera));
    Scene {
        camera,
        transfer,
        light: Light::over_shoulder(&camera),
        clip,
        tagging,
        quality: Quality::fast(step_mm),
        tools,
        background: Vec3::new(0.05, 0.06, 0.08),
        deformed: None,
        motion: None,
    }
}

/// The radiograph scene of a scenario's C-arm (`scenario`: its name; `None`: the atlas' first
/// scenario's, or defaults when it has none) with optional LAO/cranial angles, the needle and the
/// contrast medium of the moment; and the display window.
pub fn xray_scene(
    atlas: &Atlas,
    moment: Option<&Moment>,
    scenario: Option<&stylet_atlas::manifest::ScenarioToml>,
    lao_deg: Option<f64>,
    cranial_deg: Option<f64>,
) -> Result<(XrayScene, XrayWindow), ViewError> {
    let mut toml = scenario.and_then(|s| s.c_arm).unwrap_or_default();
    if let Some(v) = lao_deg {
        toml.lao_deg = v;
    }
    if let Some(v) = cranial_deg {
        toml.cranial_deg = v;
    }
    toml.check().map_err(ViewError::CArm)?;
    let isocenter_mm = match atlas.planned_paths().first() {
        Some(p) => p.target_mm,
        None => {
            let (lo, hi) = atlas.model.ct().grid().world_bounds();
            (lo + hi) * 0.5
        }
    };
    let scene = XrayScene {
        c_arm: CArm::from_toml(&toml, isocenter_mm.as_vec3()),
        needle: moment.and_then(|m| m.tools.needle.clone()),
        lines: moment.map(|m| m.tools.lines.clone()).unwrap_or_default(),
        contrast: moment.and_then(|m| xray_overlay(&atlas.model, m)),
    };
    Ok((scene, XrayWindow::from_toml(&toml.window)))
}

/// The X-ray's overlay of a moment: its contrast medium and what its wrong punctures changed.
fn xray_overlay(atlas: &stylet_physics::PunctureAtlas, m: &Moment) -> Option<ContrastOverlay> {
    if m.consequences.is_empty() {
        return m.contrast.as_deref().cloned();
    }
    let changes = consequences::xray_voxels(atlas, &m.consequences);
    ContrastOverlay::merged(m.contrast.as_deref(), &changes, atlas.ct().grid().dims())
}

/// The ultrasound scene of the moment's probe, else of a probe of kind `probe` (default convex)
/// beside the atlas' first planned path imaging it in plane; the needle of the moment; the aids
/// of `difficulty` (the atlas' `[difficulty]` presets). `echo` and
/// `doppler` are built once per atlas by the caller ([`EchoTable::of_atlas`], [`FlowField::build`]).
pub fn ultrasound_scene(
    atlas: &Atlas,
    moment: Option<&Moment>,
    probe: Option<ProbeKind>,
    difficulty: Difficulty,
    echo: Arc<EchoTable>,
    doppler: Option<Arc<FlowField>>,
) -> Result<UltrasoundScene, ViewError> {
    let path = atlas.planned_paths().first().cloned();
    let probe = match (moment.and_then(|m| m.tools.probe), &path) {
        (Some(p), _) => p,
        (None, Some(path)) => ultrasound::probe::facing_path(
            &atlas.model,
            probe.unwrap_or(ProbeKind::Convex),
            path.entry_mm,
            path.target_mm,
        )
        .ok_or_else(|| ViewError::DegeneratePath(path.name.clone()))?,
        (None, None) => {
            return Err(ViewError::NoProbe {
                atlas: atlas.manifest.name.clone(),
            });
        }
    };
    let aids = atlas.manifest.difficulty.of(difficulty);
    let needle = moment.and_then(|m| m.tools.needle.clone());
    // The guide: where the needle goes on from its tip; with no needle, the planned path.
    let guide_mm = aids.needle_guide.then(|| match &needle {
        Some(n) if n.nodes_mm.len() >= 2 => Some([n.tip_mm(), n.tip_mm() + n.tip_tangent() * 100.0]),
        _ => path.as_ref().map(|p| [p.entry_mm.as_vec3(), p.target_mm.as_vec3()]),
    });
    Ok(UltrasoundScene {
        probe,
        settings: UltrasoundSettings::for_probe(probe.kind),
        seed: moment.map_or(0, |m| m.seed),
        time_s: moment.map_or(0.0, |m| m.time_s),
        needle,
        lines: moment.map_or_else(Vec::new, |m| m.tools.lines.clone()),
        echo,
        doppler,
        guide_mm: guide_mm.flatten(),
        outline_target: aids.target_overlay,
        breathing: moment.and_then(|m| m.breathing.clone()),
        consequences: moment.map_or_else(Default::default, |m| ConsequenceScene::of_sites(&m.consequences)),
    })
}
