//! Simulated ultrasound with colour Doppler (thesis §3.4; docs/ultrasound.md): B-mode from the
//! CT along the scan lines of a linear or convex probe, after Wein et al. 2008 and Reichl et
//! al. 2009. Per sample: CT value and label → acoustic impedance, attenuation and scatter
//! ([`acoustic`]); the echo is the amplitude still travelling times the reflection at the
//! interface with the previous sample plus the tissue's speckle ([`speckle`], fixed to the
//! patient); the amplitude then loses the reflected part and the round-trip attenuation, so bone
//! and air cast shadows. The needle adds its specular echo, reverberation and shadow
//! ([`needle`]). Time-gain compensation, log compression to the dynamic range, then scan
//! conversion to the fan with the training aids ([`display`]); Doppler colour over veins and
//! arteries ([`doppler`]). The CPU reference: rayon over scan lines, every line a pure function
//! of the inputs, so the image is bit-identical on any number of threads. A breathing patient
//! (`UltrasoundScene::breathing`): each sample reads the CT, the labels, the speckle and the flow
//! at its reference point, found along the scan line as the ray caster finds it ([`crate::warp`]);
//! the probe, the needle and the aids are in the world.

pub mod acoustic;
pub mod display;
pub mod doppler;
pub mod needle;
pub mod probe;
pub mod speckle;

use std::sync::Arc;

use rayon::prelude::*;
pub use stylet_atlas::EchoClass;
use stylet_physics::atlas::AIR_HU;
use stylet_physics::glam::Vec3;
use stylet_physics::{ProbeKind, PunctureAtlas};

pub use acoustic::EchoTable;
pub use display::Sonogram;
pub use doppler::FlowField;
pub use probe::ScanGeometry;

use crate::RenderError;
use crate::consequences::{COLLECTION_MAX_HU, COLLECTION_MIN_HU, ConsequenceScene, FluidCollection};
use crate::raycast::sampler::{Grid3, nearest_voxel};
use crate::tools::{LineShape, NeedleShape, ProbeShape};
use crate::volume::IndexMap;

/// The most scan lines and samples per line a frame may have.
pub const MAX_LINES: u32 = 2048;
pub const MAX_SAMPLES: u32 = 4096;
/// Gain of the specular reflection and of the diffuse scatter (liver speckle about −34 dB
/// under a perfect reflector at the face).
pub const SPECULAR_GAIN: f32 = 1.0;
pub const SCATTER_GAIN: f32 = 0.02;
/// The attenuation time-gain compensation makes up for (dB/cm/MHz, one way; applied to the
/// round trip): an average
/// soft tissue, so deep liver stays visible and tissue behind fluid looks brighter
/// (enhancement), as on a scanner with its TGC sliders in the middle.
pub const TGC_DB_PER_CM_MHZ: f32 = 0.55;
/// Impedance of the coupling gel under the face (MRayl), and the thickest layer of it that
/// fills the gap between face and skin (mm; a curved face on a curved flank): air within this
/// depth before the first tissue counts as gel, so a probe lifted farther off shows black.
pub const GEL_MRAYL: f32 = 1.52;
pub const GEL_MAX_MM: f32 = 8.0;
/// The weakest signal Doppler still measures, relative to the transmitted amplitude after
/// time-gain compensation: in an acoustic shadow there is no colour.
pub const DOPPLER_MIN_SIGNAL: f32 = 0.01;
/// CT values below this are air and the partial-volume voxels of the skin's surface; the gel
/// replaces them at the face.
pub const AIR_BELOW_HU: f32 = -200.0;

/// An ultrasound frame neither renderer draws: settings out of range, or a scene that is not
/// finite or whose labels do not lie on the CT's grid.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum UltrasoundError {
    #[error("{lines} lines × {samples} samples: at most {max_lines} lines and 2 … {max_samples} samples", max_lines = MAX_LINES, max_samples = MAX_SAMPLES)]
    Resolution { lines: u32, samples: u32 },
    #[error("depth {0} mm must be 10 … 300")]
    Depth(f32),
    #[error("frequency {0} MHz must be 1 … 20")]
    Frequency(f32),
    #[error("gain {gain_db} dB must be −60 … 60 and dynamic range {dynamic_range_db} dB 20 … 120")]
    Gain { gain_db: f32, dynamic_range_db: f32 },
    #[error("the probe's pose must be finite with a unit orientation")]
    ProbePose,
    #[error("the needle's nodes and diameter must be finite")]
    Needle,
    #[error("the guide wire's, dilator's and catheter's nodes and diameters must be finite, at most {max} nodes each and {max_lines} lines", max = crate::tools::MAX_LINE_NODES, max_lines = MAX_INSTRUMENT_LINES)]
    Line,
    #[error("the session time must be finite")]
    Time,
    #[error("the labels and the CT have different grids")]
    LabelGrid,
}

/// What a frame depends on besides the atlas.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UltrasoundSettings {
    pub lines: u32,
    pub samples: u32,
    pub depth_mm: f32,
    pub frequency_mhz: f32,
    /// Overall gain added after compression (dB).
    pub gain_db: f32,
    /// Echo range mapped from black to white (dB).
    pub dynamic_range_db: f32,
}

impl UltrasoundSettings {
    /// 256 lines × 512 samples; a convex abdominal probe at 3.5 MHz to 150 mm, a linear one at
    /// 7.5 MHz to 60 mm.
    pub fn for_probe(kind: ProbeKind) -> UltrasoundSettings {
        let frequency_mhz = match kind {
            ProbeKind::Convex => 3.5,
            ProbeKind::Linear => 7.5,
        };
        let depth_mm = kind.default_depth_mm() as f32;
        UltrasoundSettings {
            lines: 256,
            samples: 512,
            depth_mm,
            frequency_mhz,
            gain_db: 0.0,
            dynamic_range_db: 60.0,
        }
    }

    /// Names the first value outside what both renderers draw.
    pub fn validate(&self) -> Result<(), UltrasoundError> {
        if !(1..=MAX_LINES).contains(&self.lines) || !(2..=MAX_SAMPLES).contains(&self.samples) {
            return Err(UltrasoundError::Resolution {
                lines: self.lines,
                samples: self.samples,
            });
        }
        let ok = |v: f32, lo: f32, hi: f32| v.is_finite() && (lo..=hi).contains(&v);
        if !ok(self.depth_mm, 10.0, 300.0) {
            return Err(UltrasoundError::Depth(self.depth_mm));
        }
        if !ok(self.frequency_mhz, 1.0, 20.0) {
            return Err(UltrasoundError::Frequency(self.frequency_mhz));
        }
        if !ok(self.gain_db, -60.0, 60.0) || !ok(self.dynamic_range_db, 20.0, 120.0) {
            return Err(UltrasoundError::Gain {
                gain_db: self.gain_db,
                dynamic_range_db: self.dynamic_range_db,
            });
        }
        Ok(())
    }
}

/// Everything one ultrasound frame depends on besides the CT and its labels.
#[derive(Debug, Clone)]
pub struct UltrasoundScene {
    pub probe: ProbeShape,
    pub settings: UltrasoundSettings,
    /// The session seed: the speckle pattern (fixed to the patient).
    pub seed: u64,
    /// Session time (s): the arterial pulse of the Doppler view.
    pub time_s: f64,
    pub needle: Option<NeedleShape>,
    /// The guide wire, dilator and catheter (world space, [`crate::tools::lines_of`]).
    pub lines: Vec<LineShape>,
    pub echo: Arc<EchoTable>,
    /// Colour Doppler over the vessels, with their flow axes; `None`: B-mode only.
    pub doppler: Option<Arc<FlowField>>,
    /// Training aids: a guide line (two world points: the needle's expected course, drawn
    /// projected into the image) and the target's outline.
    pub guide_mm: Option<[Vec3; 2]>,
    pub outline_target: bool,
    /// The breathing motion at the frame's moment (eqs. 5.4.1–5.4.2); `None`: a still patient.
    pub breathing: Option<crate::scene::MotionHook>,
    /// What wrong punctures did (reference space, [`crate::consequences`]): fluid collections,
    /// lungs with air in their pleural space.
    pub consequences: ConsequenceScene,
}

/// The most instrument lines a frame takes: the exchange has at most a wire and the tool on it,
/// or a placed catheter.
pub const MAX_INSTRUMENT_LINES: usize = 4;

/// Per-sample flags of a [`Sonogram`].
pub const FLAG_TARGET: u8 = 1;
pub const FLAG_DOPPLER: u8 = 2;

/// Renders one frame (before scan conversion) of `atlas` seen by the scene's probe.
pub fn render(atlas: &PunctureAtlas, scene: &UltrasoundScene) -> Result<Sonogram, RenderError> {
    check_scene(scene, atlas)?;
    let s = scene.settings;
    let p = &scene.probe;
    let geometry = ScanGeometry::new(p, s.lines, s.samples, s.depth_mm);
    let u_at = scene.breathing.as_ref().map(|b| b.model.at_time(b.t_s));
    let frame = Frame::new(atlas, scene, geometry, u_at.as_deref());
    let n = s.samples as usize;
    let mut envelope = vec![0.0f32; s.lines as usize * n];
    let mut colour = vec![[0u8; 3]; s.lines as usize * n];
    let mut flags = vec![0u8; s.lines as usize * n];
    envelope
        .par_chunks_mut(n)
        .zip(colour.par_chunks_mut(n))
        .zip(flags.par_chunks_mut(n))
        .enumerate()
        .for_each(|(i, ((b, c), f))| frame.scan_line(i as u32, b, c, f));
    let bmode = compress(&envelope, &s);
    Ok(Sonogram {
        geometry,
        bmode,
        colour,
        flags,
        guide_mm: scene.guide_mm,
        outline_target: scene.outline_target,
    })
}

/// What both renderers check before drawing: settings, a finite pose with a unit orientation,
/// a finite needle and time, labels on the CT's grid.
pub fn check_scene(scene: &UltrasoundScene, atlas: &PunctureAtlas) -> Result<(), UltrasoundError> {
    scene.settings.validate()?;
    let p = &scene.probe;
    let q = p.orientation;
    if !(p.position_mm.is_finite() && q.is_finite() && q.length() > 0.5) {
        return Err(UltrasoundError::ProbePose);
    }
    if let Some(n) = &scene.needle
        && !(n.diameter_mm.is_finite() && n.diameter_mm > 0.0 && n.nodes_mm.iter().all(|p| p.is_finite()))
    {
        return Err(UltrasoundError::Needle);
    }
    if scene.lines.len() > MAX_INSTRUMENT_LINES
        || !scene.lines.iter().all(|l| {
            l.diameter_mm.is_finite()
                && l.diameter_mm > 0.0
                && l.nodes_mm.len() <= crate::tools::MAX_LINE_NODES
                && l.nodes_mm.iter().all(|p| p.is_finite())
        })
    {
        return Err(UltrasoundError::Line);
    }
    if !scene.time_s.is_finite() {
        return Err(UltrasoundError::Time);
    }
    if atlas.partial_labels().grid().dims() != atlas.ct().grid().dims() {
        return Err(UltrasoundError::LabelGrid);
    }
    Ok(())
}

/// Each scan line's first meeting with an instrument — the needle, the guide wire, a dilator or
/// catheter — (`None`: none in the line) and the sample it lands on: what both renderers add to
/// the line's echoes.
pub fn needle_hits(scene: &UltrasoundScene, geometry: &ScanGeometry) -> Vec<Option<(needle::InstrumentHit, u32)>> {
    let dz = geometry.sample_mm();
    let needle = scene
        .needle
        .iter()
        .map(|n| (&n.nodes_mm, n.diameter_mm, needle::Echogenicity::needle(n.diameter_mm)));
    let lines = scene
        .lines
        .iter()
        .map(|l| (&l.nodes_mm, l.diameter_mm, needle::Echogenicity::of_line(l.kind)));
    let instruments: Vec<_> = needle.chain(lines).collect();
    (0..geometry.lines)
        .map(|i| {
            let (origin, dir) = geometry.line(i);
            let mut first: Option<needle::InstrumentHit> = None;
            for &(nodes, diameter_mm, echo) in &instruments {
                let length_mm = first.map_or(geometry.depth_mm, |f| f.hit.depth_mm);
                if let Some(hit) = needle::first_hit(origin, dir, length_mm, nodes, diameter_mm / 2.0) {
                    first = Some(needle::InstrumentHit { hit, echo });
                }
            }
            first.map(|h| (h, ((h.hit.depth_mm / dz) as u32).min(geometry.samples - 1)))
        })
        .collect()
}

/// One tissue's per-sample constants: impedance, the round-trip amplitude factor of one
/// sample's depth, scatter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SampleProps {
    pub z: f32,
    pub loss: f32,
    pub scatter: f32,
}

/// The lookup of solid tissue by whole HU, from this value up.
pub const LUT_LOW_HU: i32 = -1024;
pub const LUT_LEN: usize = 4096;

/// The per-frame tables both renderers read: solid tissue by whole HU from [`LUT_LOW_HU`],
/// fluid, blood, and the time-gain compensation per sample.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameTables {
    pub tissue: Vec<SampleProps>,
    pub fluid: SampleProps,
    pub blood: SampleProps,
    pub haematoma: SampleProps,
    pub tgc: Vec<f32>,
}

impl FrameTables {
    pub fn new(settings: &UltrasoundSettings) -> FrameTables {
        let s = settings;
        let dz_cm = s.depth_mm / s.samples as f32 / 10.0;
        let props = |a: acoustic::Acoustic| SampleProps {
            z: a.impedance_mrayl,
            loss: 10f32.powf(-a.attenuation_db_per_cm_mhz * s.frequency_mhz * 2.0 * dz_cm / 20.0),
            scatter: a.scatter,
        };
        FrameTables {
            tissue: (0..LUT_LEN)
                .map(|k| props(acoustic::tissue((LUT_LOW_HU + k as i32) as f32)))
                .collect(),
            fluid: props(acoustic::FLUID),
            blood: props(acoustic::BLOOD),
            haematoma: props(acoustic::HAEMATOMA),
            tgc: (0..s.samples)
                .map(|j| {
                    let z_cm = (j as f32 + 0.5) * dz_cm;
                    10f32.powf((TGC_DB_PER_CM_MHZ * s.frequency_mhz * 2.0 * z_cm) / 20.0)
                })
                .collect(),
        }
    }

    /// What a fluid collection echoes like: a fresh haematoma, or clear fluid for bile.
    #[inline]
    pub fn collection(&self, c: &FluidCollection) -> SampleProps {
        match c.kind {
            stylet_physics::Consequence::BileLeak => self.fluid,
            _ => self.haematoma,
        }
    }

    /// The tissue entry of a CT value.
    #[inline]
    pub fn tissue_at(&self, hu: f32) -> SampleProps {
        // ⌊hu + ½⌋, not `round` (halves away from zero): WGSL's round takes halves to even.
        let k = ((hu + 0.5).floor() as i32 - LUT_LOW_HU).clamp(0, LUT_LEN as i32 - 1);
        self.tissue[k as usize]
    }
}

/// What every scan line of one frame shares.
struct Frame<'a> {
    scene: &'a UltrasoundScene,
    geometry: ScanGeometry,
    grid: Grid3<'a>,
    map: IndexMap,
    /// The last voxel index per axis: samples beyond the CT's box read the voxel on its face.
    box_hi: Vec3,
    labels: &'a [u16],
    tables: FrameTables,
    hits: Vec<Option<(needle::InstrumentHit, u32)>>,
    speckle_seed: u32,
    /// Blood speed per vessel kind now (m/s).
    vein_m_s: f32,
    artery_m_s: f32,
    /// u(·, t) of a breathing patient.
    u_at: Option<&'a (dyn Fn(stylet_physics::glam::DVec3) -> stylet_physics::glam::DVec3 + Send + Sync)>,
}

impl<'a> Frame<'a> {
    fn new(
        atlas: &'a PunctureAtlas,
        scene: &'a UltrasoundScene,
        geometry: ScanGeometry,
        u_at: Option<&'a (dyn Fn(stylet_physics::glam::DVec3) -> stylet_physics::glam::DVec3 + Send + Sync)>,
    ) -> Frame<'a> {
        let ct = atlas.ct();
        let dims = IndexMap::of(ct.grid()).dims;
        Frame {
            scene,
            geometry,
            grid: Grid3::new(ct.data(), dims),
            map: IndexMap::of(ct.grid()),
            box_hi: Vec3::new(dims[0] as f32, dims[1] as f32, dims[2] as f32) - Vec3::ONE,
            labels: atlas.partial_labels().data(),
            tables: FrameTables::new(&scene.settings),
            hits: needle_hits(scene, &geometry),
            speckle_seed: speckle::lattice_seed(scene.seed),
            vein_m_s: doppler::speed_m_s(doppler::pressure_pa(EchoClass::Vein, scene.time_s)),
            artery_m_s: doppler::speed_m_s(doppler::pressure_pa(EchoClass::Artery, scene.time_s)),
            u_at,
        }
    }

    /// The fluid collection that replaces soft tissue of CT value `hu` at reference point `x`.
    #[inline]
    fn collection_at(&self, x: Vec3, hu: f32) -> Option<&FluidCollection> {
        if !(COLLECTION_MIN_HU..COLLECTION_MAX_HU).contains(&hu) {
            return None;
        }
        self.scene.consequences.collections.iter().find(|c| c.contains(x))
    }

    /// Whether `label` is a lung whose surface slides under the chest wall: an aerated lung with
    /// no air in its pleural space.
    #[inline]
    fn slides(&self, label: stylet_physics::LabelId) -> bool {
        self.scene.echo.is_pleural(label) && !self.scene.consequences.air_in_pleura_of(label)
    }

    /// One scan line: B-mode display values (0 … 1), Doppler colours and flags per sample.
    fn scan_line(&self, i: u32, bmode: &mut [f32], colour: &mut [[u8; 3]], flags: &mut [u8]) {
        let g = &self.geometry;
        let (origin, dir) = g.line(i);
        let dz = g.sample_mm();
        let instrument = self.hits[i as usize];
        let hit_sample = instrument.map(|(_, j)| j as usize);
        let mut travelling = 1.0f32;
        let mut z_prev = GEL_MRAYL;
        // The comet tail's first echo, where it starts and its spacing.
        let mut ring: Option<(f32, f32, f32)> = None;
        let mut in_gel = true;
        let gel_max_mm = g.gel_allowance_mm(i);
        let mut warp = self.u_at.map(crate::warp::Warp::new);
        for j in 0..bmode.len() {
            let depth_mm = (j as f32 + 0.5) * dz;
            // The tissue seen: the world point, or its reference point in a breathing patient.
            let x = match warp.as_mut() {
                Some(w) => w.reference_of(origin + dir * depth_mm),
                None => origin + dir * depth_mm,
            };
            // Beyond the CT's box the patient goes on (a CT ends in tissue at its first and last
            // slices, and where its field of view cuts the body): reading air there put an
            // interface of 1 − r² ≈ 10⁻³ into every line leaving the box, a black wedge with a
            // straight edge. The voxel on the box's face is read instead; air there stays air.
            let c = self.map.point(x).clamp(Vec3::ZERO, self.box_hi);
            let hu = self.grid.trilinear(c).unwrap_or(AIR_HU);
            let label = nearest_voxel(c, self.map.dims).map_or(0, |v| self.labels[v]);
            let class = self.scene.echo.class(label);
            let gel = in_gel && hu < AIR_BELOW_HU && depth_mm <= gel_max_mm;
            if in_gel && !gel && hu < AIR_BELOW_HU {
                // The gap is wider than the gel bridges: the probe is off the skin, and sound
                // does not pass from the face into air.
                travelling = 0.0;
            }
            in_gel = gel;
            if in_gel {
                bmode[j] = 0.0;
                continue;
            }
            let p = match class {
                EchoClass::Tissue => match self.collection_at(x, hu) {
                    Some(c) => self.tables.collection(c),
                    None if self.slides(label) => SampleProps {
                        scatter: acoustic::PLEURA_SCATTER,
                        ..self.tables.tissue_at(hu)
                    },
                    None => self.tables.tissue_at(hu),
                },
                EchoClass::Fluid => self.tables.fluid,
                EchoClass::Vein | EchoClass::Artery => self.tables.blood,
            };
            let r = acoustic::reflection(z_prev, p.z);
            let scatter = if p.scatter > 0.0 {
                SCATTER_GAIN * p.scatter * speckle::amplitude(x, self.speckle_seed)
            } else {
                0.0
            };
            let mut echo = travelling * (SPECULAR_GAIN * r.abs() + scatter);
            travelling *= (1.0 - r * r) * p.loss;
            z_prev = p.z;
            if hit_sample == Some(j)
                && let Some((h, _)) = instrument
            {
                let e = travelling * h.echo.reflection * h.hit.specular;
                echo += e;
                travelling *= h.echo.transmission;
                if h.echo.ring_mm > 0.0 {
                    ring = Some((e, h.hit.depth_mm, h.echo.ring_mm));
                }
            }
            bmode[j] = echo;
            if self.scene.echo.is_target(label) {
                flags[j] |= FLAG_TARGET;
            }
            if let Some(flow) = &self.scene.doppler
                && matches!(class, EchoClass::Vein | EchoClass::Artery)
                && travelling * self.tables.tgc[j] >= DOPPLER_MIN_SIGNAL
                && let Some(axis) = flow.axis_at(x)
            {
                let speed = if class == EchoClass::Artery {
                    self.artery_m_s
                } else {
                    self.vein_m_s
                };
                if let Some(rgb) = doppler::colour(class, speed * axis.dot(dir).abs()) {
                    colour[j] = rgb;
                    flags[j] |= FLAG_DOPPLER;
                }
            }
        }
        // The comet tail: echoes one shaft diameter apart below the first, each weaker.
        if let Some((e, depth, spacing_mm)) = ring {
            let mut a = e;
            for k in 1..=needle::REVERB_ECHOES {
                a *= needle::REVERB_DECAY;
                let j = ((depth + k as f32 * spacing_mm) / dz) as usize;
                if let Some(b) = bmode.get_mut(j) {
                    *b += a;
                }
            }
        }
        for (b, t) in bmode.iter_mut().zip(&self.tables.tgc) {
            *b *= t;
        }
    }
}

/// The beam's lateral profile over neighbouring lines (weights of lines i − 2 … i + 2): a real
/// beam is 1–2 mm wide, so neighbouring lines share echoes and a rib's edge shades gradually.
const LATERAL_PSF: [f32; 5] = [1.0 / 9.0, 2.0 / 9.0, 3.0 / 9.0, 2.0 / 9.0, 1.0 / 9.0];

/// The display values (0 … 1) of a frame's time-gain-compensated envelopes (line-major), line by
/// line in parallel (`compress_line`).
pub fn compress(envelope: &[f32], s: &UltrasoundSettings) -> Vec<f32> {
    let n = s.samples as usize;
    let mut bmode = vec![0.0f32; envelope.len()];
    bmode
        .par_chunks_mut(n)
        .enumerate()
        .for_each(|(i, out)| compress_line(envelope, n, i, s, out));
    bmode
}

/// Line `i` of the display: the time-gain-compensated envelopes averaged over the beam's width
/// ([`LATERAL_PSF`], lines beyond the array's ends clamped), log-compressed to the dynamic range
/// with the gain.
fn compress_line(envelope: &[f32], samples: usize, i: usize, s: &UltrasoundSettings, out: &mut [f32]) {
    let last = envelope.len() / samples - 1;
    let rows: [&[f32]; 5] = std::array::from_fn(|k| {
        let line = (i + k).saturating_sub(2).min(last);
        &envelope[line * samples..(line + 1) * samples]
    });
    for (j, o) in out.iter_mut().enumerate() {
        let mut e = 0.0;
        for (w, r) in LATERAL_PSF.iter().zip(&rows) {
            e += w * r[j];
        }
        let db = 20.0 * e.max(1e-12).log10() + s.gain_db;
        *o = ((db + s.dynamic_range_db) / s.dynamic_range_db).clamp(0.0, 1.0);
    }
}
