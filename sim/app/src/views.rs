//! The simulator's views drawn from the haptic loop's snapshots (`stylet_render::views` composes
//! each scene, so the window shows what `stylet render` and the dashboard show for the same tick),
//! on the CPU reference renderers or, with the feature `gpu`, on the wgpu renderers of
//! `stylet-render-gpu` (the same per-ray algorithms; slices are annotated on the CPU either way).
//! Each view keeps a frame budget by adapting its resolution: a frame over budget lowers the
//! scale, one well under raises it again.
//!
//! CPU drawing runs in a thread pool of its own that leaves one core to the haptic loop, so the
//! loop never pays for drawing (docs/simulator.md "Views").

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
    /// The coronal slice through the tip.
    Coronal,
    /// The sagittal slice through the tip.
    Sagittal,
    /// The oblique slice along the needle.
    Needle,
    Ultrasound,
    Xray,
}

impl ViewKind {
    pub const ALL: [ViewKind; 7] = [
        ViewKind::ThreeD,
        ViewKind::Axial,
        ViewKind::Coronal,
        ViewKind::Sagittal,
        ViewKind::Needle,
        ViewKind::Ultrasound,
        ViewKind::Xray,
    ];

    pub fn name(self) -> &'static str {
        match self {
            ViewKind::ThreeD => "3d",
            ViewKind::Axial => "axial",
            ViewKind::Coronal => "coronal",
            ViewKind::Sagittal => "sagittal",
            ViewKind::Needle => "needle",
            ViewKind::Ultrasound => "ultrasound",
            ViewKind::Xray => "xray",
        }
    }

    /// The view's title in the window.
    pub fn title(self) -> &'static str {
        match self {
            ViewKind::ThreeD => "3D",
            ViewKind::Axial => "Axial",
            ViewKind::Coronal => "Coronal",
            ViewKind::Sagittal => "Sagittal",
            ViewKind::Needle => "Along the needle",
            ViewKind::Ultrasound => "Ultrasound",
            ViewKind::Xray => "X-ray",
        }
    }

    pub fn parse(s: &str) -> Option<ViewKind> {
        ViewKind::ALL.into_iter().find(|v| v.name() == s)
    }
}

/// Smallest and largest resolution scale of a view.
pub const MIN_SCALE: f32 = 0.25;
pub const MAX_SCALE: f32 = 1.0;

/// What draws the views.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Backend {
    /// The CPU reference renderers.
    #[default]
    Cpu,
    /// The wgpu renderers (feature `gpu`): any adapter, Mesa's software Vulkan included.
    Gpu,
    /// The GPU when the first adapter is a real GPU, else the CPU: a software adapter
    /// (lavapipe) runs on the very cores the CPU renderers and the haptic loop share.
    Auto,
}

impl Backend {
    pub fn parse(s: &str) -> Option<Backend> {
        match s {
            "cpu" => Some(Backend::Cpu),
            "gpu" => Some(Backend::Gpu),
            "auto" => Some(Backend::Auto),
            _ => None,
        }
    }
}

/// How the views are drawn.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewSettings {
    pub backend: Backend,
    pub preset: Preset,
    pub tagging: Tagging,
    pub doppler: bool,
    /// Time one view may take per frame.
    pub budget: Duration,
}

impl Default for ViewSettings {
    fn default() -> Self {
        ViewSettings {
            backend: Backend::Cpu,
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
    scales: [f32; ViewKind::ALL.len()],
    pool: rayon::ThreadPool,
    #[cfg(feature = "gpu")]
    gpu: Option<GpuViews>,
}

/// The wgpu renderers and the atlas uploaded to them.
#[cfg(feature = "gpu")]
struct GpuViews {
    ctx: stylet_render_gpu::GpuContext,
    volume: stylet_render_gpu::GpuVolume,
    raycast: stylet_render_gpu::GpuRenderer,
    mpr: stylet_render_gpu::GpuMpr,
    xray: stylet_render_gpu::GpuXray,
    ultrasound: stylet_render_gpu::GpuUltrasound,
}

#[cfg(feature = "gpu")]
impl GpuViews {
    /// Opens the GPU and uploads the atlas; `None` for [`Backend::Auto`] on a software adapter.
    fn open(backend: Backend, volume: &RenderVolume) -> Result<Option<GpuViews>, ViewError> {
        let ctx = match stylet_render_gpu::GpuContext::new() {
            Ok(ctx) => ctx,
            Err(_) if backend == Backend::Auto => return Ok(None),
            Err(e) => return Err(gpu_error(e)),
        };
        if backend == Backend::Auto && ctx.adapter().device_type == "Cpu" {
            return Ok(None);
        }
        let uploaded = stylet_render_gpu::GpuVolume::upload(&ctx, volume).map_err(gpu_error)?;
        Ok(Some(GpuViews {
            volume: uploaded,
            raycast: stylet_render_gpu::GpuRenderer::new(&ctx),
            mpr: stylet_render_gpu::GpuMpr::new(&ctx),
            xray: stylet_render_gpu::GpuXray::new(&ctx),
            ultrasound: stylet_render_gpu::GpuUltrasound::new(&ctx),
            ctx,
        }))
    }
}

#[cfg(feature = "gpu")]
fn gpu_error(e: stylet_render_gpu::GpuError) -> ViewError {
    ViewError::Render(stylet_render::RenderError::Draw(format!("GPU: {e}")))
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
            .start_handler(|_| {
                crate::priority::lower_this_thread(crate::priority::DRAWING_NICENESS);
            })
            .build()
            .map_err(|e| ViewError::Render(stylet_render::RenderError::Draw(e.to_string())))?;
        let (volume, echo, doppler) = pool.install(|| {
            let volume = RenderVolume::new(Arc::clone(&atlas.model));
            let echo = Arc::new(EchoTable::of_atlas(&atlas));
            let doppler = settings
                .doppler
                .then(|| Arc::new(FlowField::build(&atlas.model, &echo)));
            (volume, echo, doppler)
        });
        #[cfg(feature = "gpu")]
        let gpu = match settings.backend {
            Backend::Cpu => None,
            backend => GpuViews::open(backend, &volume)?,
        };
        #[cfg(not(feature = "gpu"))]
        if settings.backend == Backend::Gpu {
            return Err(ViewError::Render(stylet_render::RenderError::Draw(
                "this simulator was built without the GPU renderer (cargo feature `gpu`)".into(),
            )));
        }
        Ok(ViewRenderer {
            #[cfg(feature = "gpu")]
            gpu,
            step_mm: views::default_step_mm(&atlas),
            atlas,
            volume,
            echo,
            doppler,
            settings,
            scales: [MAX_SCALE; ViewKind::ALL.len()],
            pool,
        })
    }

    /// What draws: "CPU (n threads)" or the GPU adapter's name.
    pub fn drawn_by(&self) -> String {
        #[cfg(feature = "gpu")]
        if let Some(g) = &self.gpu {
            return format!("GPU: {}", g.ctx.adapter().name);
        }
        format!("CPU ({} threads)", self.pool.current_num_threads())
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
        // The GPU draws the synthetic motion and measured fields it can hold; anything else
        // is drawn on the CPU.
        #[cfg(feature = "gpu")]
        let on_gpu = moment
            .breathing
            .as_ref()
            .is_none_or(|b| stylet_render_gpu::draws_breathing(b.model.as_ref(), b.t_s));
        #[cfg(feature = "gpu")]
        let image = match self.gpu.take() {
            Some(mut gpu) if on_gpu => {
                let image = self.draw_on_gpu(&mut gpu, kind, moment, w, h);
                self.gpu = Some(gpu);
                image?
            }
            kept => {
                self.gpu = kept;
                self.pool.install(|| self.draw_at(kind, moment, w, h))?
            }
        };
        #[cfg(not(feature = "gpu"))]
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
        // Cubic enlargement keeps edges crisp where bilinear would smear them over 3–4 pixels.
        let image = if (w, h) == (width, height) {
            image
        } else {
            self.pool.install(|| image.upscale_sharp(width, height))
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
            ViewKind::Coronal => views::slice_image(atlas, m, &views::plane_spec(atlas, m, Plane::Coronal, w, h)),
            ViewKind::Sagittal => views::slice_image(atlas, m, &views::plane_spec(atlas, m, Plane::Sagittal, w, h)),
            ViewKind::Needle => views::slice_image(atlas, m, &views::needle_spec(atlas, m, w, h)?),
            ViewKind::Ultrasound => {
                let scene = self.ultrasound_scene(moment)?;
                Ok(ultrasound::render(&atlas.model, &scene)?.to_image(w, h))
            }
            ViewKind::Xray => {
                let (scene, window) = self.xray_scene(moment)?;
                let breathing = moment.breathing.as_ref();
                Ok(stylet_render::xray::render_moving(&atlas.model, &scene, breathing, w, h)?.to_image(window))
            }
        }
    }

    /// The ultrasound view's scene (both renderers): the probe in hand, else a convex probe
    /// beside the planned path, with the level's aids.
    fn ultrasound_scene(&self, moment: &Moment) -> Result<stylet_render::ultrasound::UltrasoundScene, ViewError> {
        views::ultrasound_scene(
            &self.atlas,
            Some(moment),
            Some(ProbeKind::Convex),
            moment.difficulty,
            Arc::clone(&self.echo),
            self.doppler.clone(),
        )
    }

    /// The X-ray view's scene and window (both renderers): the scenario's C-arm.
    fn xray_scene(
        &self,
        moment: &Moment,
    ) -> Result<(stylet_render::xray::XrayScene, stylet_render::xray::XrayWindow), ViewError> {
        let scenario = self.atlas.manifest.scenarios.iter().find(|s| s.name == moment.scenario);
        views::xray_scene(&self.atlas, Some(moment), scenario, None, None)
    }

    /// [`Self::draw_at`] on the wgpu renderers: the same scenes, drawn on the GPU.
    #[cfg(feature = "gpu")]
    fn draw_on_gpu(
        &self,
        g: &mut GpuViews,
        kind: ViewKind,
        moment: &Moment,
        w: u32,
        h: u32,
    ) -> Result<Image, ViewError> {
        let atlas = &*self.atlas;
        let m = Some(moment);
        let slice = |g: &mut GpuViews, spec: &stylet_render::mpr::SliceSpec| {
            let field = moment.deformation.as_deref();
            let image = match (moment.breathing.as_ref(), field) {
                (Some(b), _) => g.mpr.render_moving(&g.ctx, &g.volume, spec, Some(b), field),
                (None, Some(field)) => g.mpr.render_deformed(&g.ctx, &g.volume, spec, field),
                (None, None) => g.mpr.render(&g.ctx, &g.volume, spec),
            }
            .map_err(gpu_error)?;
            views::annotated_slice(&image, m)
        };
        match kind {
            ViewKind::ThreeD => {
                let scene = views::scene_3d(atlas, m, self.settings.preset, self.settings.tagging, self.step_mm)?;
                g.raycast.render(&g.ctx, &g.volume, &scene, w, h).map_err(gpu_error)
            }
            ViewKind::Axial => slice(g, &views::plane_spec(atlas, m, Plane::Axial, w, h)),
            ViewKind::Coronal => slice(g, &views::plane_spec(atlas, m, Plane::Coronal, w, h)),
            ViewKind::Sagittal => slice(g, &views::plane_spec(atlas, m, Plane::Sagittal, w, h)),
            ViewKind::Needle => slice(g, &views::needle_spec(atlas, m, w, h)?),
            ViewKind::Ultrasound => {
                let scene = self.ultrasound_scene(moment)?;
                Ok(g.ultrasound
                    .render(&g.ctx, &g.volume, &scene)
                    .map_err(gpu_error)?
                    .to_image(w, h))
            }
            ViewKind::Xray => {
                let (scene, window) = self.xray_scene(moment)?;
                Ok(g.xray
                    .render_moving(&g.ctx, &g.volume, &scene, moment.breathing.as_ref(), w, h)
                    .map_err(gpu_error)?
                    .to_image(window))
            }
        }
    }
}
