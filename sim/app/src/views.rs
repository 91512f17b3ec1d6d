//! The simulator's views drawn from the haptic loop's snapshots on the CPU reference renderers
//! (`stylet_render::views` composes each scene, so the window shows what `stylet render` and
//! the dashboard show for the same tick). Each view keeps a frame budget by adapting its
//! resolution: a frame over budget lowers the scale, one well under raises it again.
//!
//! Drawing runs in a thread pool of its own that leaves one core to the haptic loop, so the loop
//! never pays for drawing (docs/simulator.md "Views").

use std::sync::Arc;
use std::time::{Duration, Instant};

use stylet_atlas::Atlas;
use stylet_physics::ProbeKind;
use stylet_render::image::Image;
use stylet_render::mpr::Plane;
use stylet_render::presets::Preset;
use stylet_render::scene::Tagging;
use stylet_render::ultrasound::{self, EchoTable, FlowField};
use stylet_render::views::{self, Moment, ViewError};
use stylet_render::volume::RenderVolume;

/// The views a trainee can arrange.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ViewKind {
    /// The ray-cast patient with the tools.
    ThreeD,
    /// The axial slice through the tip.
    Axial,
    /// The oblique slice along the needle.
    Needle,
    Ultrasound,
    Xray,
}

impl ViewKind {
    pub const ALL: [ViewKind; 5] = [
        ViewKind::ThreeD,
        ViewKind::Axial,
        ViewKind::Needle,
        ViewKind::Ultrasound,
        ViewKind::Xray,
    ];

    pub fn name(self) -> &'static str {
        match self {
            ViewKind::ThreeD => "3d",
            ViewKind::Axial => "axial",
            ViewKind::Needle => "needle",
            ViewKind::Ultrasound => "ultrasound",
            ViewKind::Xray => "xray",
        }
    }

    pub fn parse(s: &str) -> Option<ViewKind> {
        ViewKind::ALL.into_iter().find(|v| v.name() == s)
    }
}

/// Smallest and largest resolution scale of a view.
pub const MIN_SCALE: f32 = 0.25;
pub const MAX_SCALE: f32 = 1.0;

/// How the views are drawn.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewSettings {
    pub preset: Preset,
    pub tagging: Tagging,
    pub doppler: bool,
    /// Time one view may take per frame.
    pub budget: Duration,
}

impl Default for ViewSettings {
    fn default() -> Self {
        ViewSettings {
            preset: Preset::Skin,
            tagging: Tagging::Off,
            doppler: true,
            budget: Duration::from_millis(50),
        }
    }
}

/// One drawn frame.
#[derive(Debug, Clone)]
pub struct Frame {
    pub image: Image,
    /// The scale it was drawn at (then enlarged to the asked size).
    pub scale: f32,
    pub took: Duration,
}

/// Draws the views of one atlas.
pub struct ViewRenderer {
    atlas: Arc<Atlas>,
    volume: RenderVolume,
    echo: Arc<EchoTable>,
    doppler: Option<Arc<FlowField>>,
    settings: ViewSettings,
    step_mm: f32,
    scales: [f32; 5],
    pool: rayon::ThreadPool,
}

/// Threads for drawing: every core but one, which the haptic loop keeps.
pub fn drawing_threads() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get().saturating_sub(1).max(1))
}

impl ViewRenderer {
    /// Prepares the atlas for drawing (the 3D volume, the echo table and, with Doppler, the
    /// vessels' flow field: once per atlas).
    pub fn new(atlas: Arc<Atlas>, settings: ViewSettings) -> Result<ViewRenderer, ViewError> {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(drawing_threads())
            .thread_name(|i| format!("stylet-draw-{i}"))
            .build()
            .map_err(|e| ViewError::Render(stylet_render::RenderError::Draw(e.to_string())))?;
        let (volume, echo, doppler) = pool.install(|| {
            let volume = RenderVolume::new(Arc::new(atlas.model.clone()));
            let echo = Arc::new(EchoTable::of_atlas(&atlas));
            let doppler = settings
                .doppler
                .then(|| Arc::new(FlowField::build(&atlas.model, &echo)));
            (volume, echo, doppler)
        });
        Ok(ViewRenderer {
            step_mm: views::default_step_mm(&atlas),
            atlas,
            volume,
            echo,
            doppler,
            settings,
            scales: [MAX_SCALE; 5],
            pool,
        })
    }

    /// The current resolution scale of a view.
    pub fn scale(&self, kind: ViewKind) -> f32 {
        self.scales[kind as usize]
    }

    /// Draws `kind` at the moment, `width` × `height` pixels on screen, and adapts the view's
    /// scale to its budget.
    pub fn draw(&mut self, kind: ViewKind, moment: &Moment, width: u32, height: u32) -> Result<Frame, ViewError> {
        let scale = self.scales[kind as usize];
        let w = ((width as f32 * scale).round() as u32).max(1);
        let h = ((height as f32 * scale).round() as u32).max(1);
        let t0 = Instant::now();
        let image = self.pool.install(|| self.draw_at(kind, moment, w, h))?;
        let took = t0.elapsed();
        let budget = self.settings.budget;
        let next = if took > budget {
            scale * 0.8
        } else if took < budget / 2 {
            scale * 1.1
        } else {
            scale
        };
        self.scales[kind as usize] = next.clamp(MIN_SCALE, MAX_SCALE);
        let image = if (w, h) == (width, height) {
            image
        } else {
            image.upscale(width, height)
        };
        Ok(Frame { image, scale, took })
    }

    fn draw_at(&self, kind: ViewKind, moment: &Moment, w: u32, h: u32) -> Result<Image, ViewError> {
        let atlas = &*self.atlas;
        let m = Some(moment);
        match kind {
            ViewKind::ThreeD => {
                let scene = views::scene_3d(atlas, m, self.settings.preset, self.settings.tagging, self.step_mm)?;
                Ok(stylet_render::raycast::render(&self.volume, &scene, w, h).image)
            }
            ViewKind::Axial => views::slice_image(atlas, m, &views::plane_spec(atlas, m, Plane::Axial, w, h)),
            ViewKind::Needle => views::slice_image(atlas, m, &views::needle_spec(atlas, m, w, h)?),
            ViewKind::Ultrasound => {
                let scene = views::ultrasound_scene(
                    atlas,
                    m,
                    Some(ProbeKind::Convex),
                    &moment.difficulty,
                    Arc::clone(&self.echo),
                    self.doppler.clone(),
                )?;
                Ok(ultrasound::render(&atlas.model, &scene)?.to_image(w, h))
            }
            ViewKind::Xray => {
                let scenario = atlas.manifest.scenarios.iter().find(|s| s.name == moment.scenario);
                let (scene, window) = views::xray_scene(atlas, m, scenario, None, None)?;
                Ok(stylet_render::xray::render(&atlas.model, &scene, w, h)?.to_image(window))
            }
        }
    }
}
