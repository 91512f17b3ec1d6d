//! One ray, docs/rendering.md "One ray" steps 1–9, written as plain loops without allocation or
//! recursion so the WGSL port can follow it line by line.

use stylet_physics::glam::{DVec3, Vec3, Vec3A, Vec4};

use std::sync::Arc;

use super::avx2::Avx2;
use super::batch::{Batch, Evaluated};
use super::brick_distance::LeavingRay;
use super::cube_mask::{CubeMask, WindowClasses};
use super::jitter::jitter;
use super::kernel::Kernel;
use super::occupancy::Occupancy;
use super::placer::Placer;
use super::sampler::{At, Sampler};
use super::shading::{MIN_GRADIENT, PhongTerms, half_vector, plane_colour};
use super::window::{Lattice, POINTS, Window, lattice};
use crate::scene::{ClipPlane, Light, MotionHook, Quality, Tagging};
use crate::shadow::Shadows;
use crate::tools::{Primitive, nearest_hit, shade};
use crate::transfer::TransferFunction;
use crate::transfer_table::TransferTable;
use crate::volume::RenderVolume;
use crate::warp::Warp;

/// Everything a ray reads that is the same for every pixel of a frame.
pub struct Frame<'a> {
    pub volume: &'a RenderVolume,
    pub sampler: Sampler<'a>,
    /// c(v) for the plane sample (straight colour, opacity as is).
    pub transfer: &'a TransferFunction,
    /// c(v) for the lattice samples: corrected for the step and premultiplied.
    pub table: TransferTable,
    pub light: Light,
    /// `light`'s Phong terms, prepared once.
    pub phong: PhongTerms,
    pub clip: Option<ClipPlane>,
    pub tagging: Tagging,
    pub quality: Quality,
    /// Present when leaping is on, the motion bounded and some ray may take the general path
    /// (not [`Frame::every_ray_on_bricks`]).
    pub occupancy: Option<Occupancy>,
    /// Per-cube skip bits: with leaping on, no hooks and a CT of ≥ 2 voxels per axis.
    pub cubes: Option<Arc<CubeMask>>,
    /// Whether air (outside the CT) is visible under the transfer function, or a deformed
    /// region may lie outside the CT's box: then leaping never skips samples outside the box.
    pub sample_outside: bool,
    /// Distance from the eye to the farthest corner of the sampling domain (naive extent).
    pub t_far: f32,
    pub background: Vec3,
    pub motion: Option<&'a MotionHook>,
    /// u(·, t) of `motion` at its moment (the signal worked out once per frame).
    pub motion_at: Option<Box<dyn Fn(DVec3) -> DVec3 + Send + Sync + 'a>>,
    /// With a bounded motion: its bound in CT index units per axis; the ray/box extent and the
    /// leaping test are widened by it (a sample reads within it of its world point).
    pub motion_margin: Option<Vec3>,
    /// The tools' primitives (step 4) and the shadows they cast (step 6).
    pub primitives: Vec<Primitive>,
    pub shadows: Shadows,
    /// Whether any tool casts a shadow (else f_shadow = 1 without testing).
    pub has_shadows: bool,
    /// The SIMD lanes for the common frame's points and samples ([`super::avx2`]), when asked
    /// for and the CPU has them (detected once per frame).
    pub(crate) avx2: Option<Avx2>,
    /// Whether the tiles march two pixels' rays in turn ([`march_pair`]); else one after the
    /// other ([`march`], the reference).
    pub pairs: bool,
}

impl Frame<'_> {
    /// Whether every ray's lattice samples take the common frame's brick march (the cube mask,
    /// no motion warp, no deformed region, ray/box clipping, invisible air); else every one
    /// takes the general path (`lattice_general`), the only reader of `occupancy`.
    pub fn every_ray_on_bricks(&self) -> bool {
        self.cubes.is_some()
            && self.motion_at.is_none()
            && self.sampler.deformed.is_none()
            && self.quality.ray_box
            && !self.sample_outside
    }
}

/// "No hit" distance for the tools (no infinities, as in tools.rs and the WGSL port).
const NO_TOOL: f32 = 1.0e30;

/// The ray parameters [t_in, t_out] where the index-space ray `ce` + t·`dc` (t ≥ 0) crosses the
/// sampling domain [−½, n − ½]³ (slabs), or `None` when it misses.
#[inline]
pub fn ray_box(ce: Vec3, dc: Vec3, dims: [u32; 3]) -> Option<(f32, f32)> {
    ray_box_widened(ce, dc, dims, Vec3::ZERO)
}

/// [`ray_box`] on the domain widened by `margin` index units per axis (−½ − 0 and n − ½ + 0 are
/// exact, so a zero margin is [`ray_box`] bit for bit).
#[inline]
fn ray_box_widened(ce: Vec3, dc: Vec3, dims: [u32; 3], margin: Vec3) -> Option<(f32, f32)> {
    let (mut t0, mut t1) = (0.0f32, f32::INFINITY);
    for a in 0..3 {
        let (lo, hi) = (-0.5 - margin[a], dims[a] as f32 - 0.5 + margin[a]);
        if dc[a] == 0.0 {
            if ce[a] < lo || ce[a] > hi {
                return None;
            }
        } else {
            let inv = 1.0 / dc[a];
            let ta = (lo - ce[a]) * inv;
            let tb = (hi - ce[a]) * inv;
            t0 = t0.max(ta.min(tb));
            t1 = t1.min(ta.max(tb));
        }
    }
    if t0 > t1 { None } else { Some((t0, t1)) }
}

/// Whether index `c` lies in the sampling domain (the trilinear inside rule).
#[inline]
fn inside(c: Vec3, dims: [u32; 3]) -> bool {
    (0..3).all(|a| c[a] >= -0.5 && c[a] < dims[a] as f32 - 0.5)
}

/// Whether index `c` lies in the sampling domain widened by `margin` index units per axis.
#[inline]
fn inside_by(c: Vec3, dims: [u32; 3], margin: Vec3) -> bool {
    (0..3).all(|a| c[a] >= -0.5 - margin[a] && c[a] < dims[a] as f32 - 0.5 + margin[a])
}

/// The first k with t_k ≥ `t` (or > `t` when `strict`).
#[inline]
fn first_lattice(t: f32, strict: bool, j: f32, step: f32) -> u32 {
    let ok = |k: u32| {
        let tk = lattice(k, j, step);
        if strict { tk > t } else { tk >= t }
    };
    let mut k = (t / step - j).ceil().max(0.0) as u32;
    while k > 0 && ok(k - 1) {
        k -= 1;
    }
    while !ok(k) {
        k += 1;
    }
    k
}

/// Front-to-back accumulation (C, A) of one ray.
#[derive(Clone, Copy)]
struct Accum {
    /// Accumulated colour C (premultiplied), in one SIMD register: every operation below is
    /// the same per component as on three `f32`.
    c: Vec3A,
    /// Transmittance T = 1 − A: the fraction of light from behind still reaching the eye.
    transmittance: f32,
}

impl Accum {
    /// Nothing accumulated: C = 0, T = 1.
    const CLEAR: Accum = Accum {
        c: Vec3A::ZERO,
        transmittance: 1.0,
    };

    /// Front-to-back emission–absorption (thesis §3.2.1): C += (1 − A)·α·c, A += (1 − A)·α,
    /// written with T = 1 − A as C += T·α·c, T ← T·(1 − α). The same sums; the ray's chain from
    /// sample to sample is then one product.
    #[inline]
    fn add(&mut self, rgb: Vec3, alpha: f32) {
        self.c += self.transmittance * alpha * Vec3A::from(rgb);
        self.transmittance *= 1.0 - alpha;
    }

    /// [`Self::add`] with the colour already multiplied by α.
    #[inline]
    fn add_premultiplied(&mut self, alpha_rgb: Vec3A, alpha: f32) {
        self.c += self.transmittance * alpha_rgb;
        self.transmittance *= 1.0 - alpha;
    }

    /// Whether the accumulated opacity A = 1 − T has reached [`crate::scene::Quality::OPAQUE`]
    /// (early termination).
    #[inline]
    fn is_opaque(&self) -> bool {
        self.transmittance <= 1.0 - crate::scene::Quality::OPAQUE
    }
}

/// One ray's constants for the lattice loop.
struct Ray {
    origin: Vec3,
    dir: Vec3,
    /// The ray in CT index space: c(t) = ce + t·dc.
    ce: Vec3,
    dc: Vec3,
    /// Lattice offset j and the last t to sample (t ≤ t_hi, t < t_tool).
    j: f32,
    t_hi: f32,
    t_tool: f32,
    /// Phong's half vector (the same for every sample of the ray).
    half: Vec3,
}

/// Steps 6–7 for one visible sample: shadow, shading, accumulation. `c` is the table's
/// premultiplied (α·rgb, α). Returns whether the ray is done (early termination).
#[inline(always)]
fn composite(f: &Frame, ray: &Ray, t: f32, c: [f32; 4], g: Vec3, acc: &mut Accum) -> bool {
    let len = g.length();
    let shade = |f_shadow| {
        if len < MIN_GRADIENT {
            1.0
        } else {
            f.phong.shade(g, len, ray.half, f_shadow)
        }
    };
    accumulate(f, ray, t, c, shade, acc)
}

/// Steps 6–7 once f is known as a function of the shadow factor (`shade`): the shadow at the
/// sample's world position, the front-to-back accumulation, and whether the ray is done.
#[inline(always)]
fn accumulate(f: &Frame, ray: &Ray, t: f32, c: [f32; 4], shade: impl FnOnce(f32) -> f32, acc: &mut Accum) -> bool {
    add_shaded(f, c, shade(shadow_factor(f, ray, t)), acc)
}

/// Step 6: the shadow factor at the sample's world position (1 without tools).
#[inline(always)]
fn shadow_factor(f: &Frame, ray: &Ray, t: f32) -> f32 {
    if f.has_shadows {
        f.shadows
            .factor(ray.origin + ray.dir * t, f.light.toward_light, f.light.shadow_in)
    } else {
        1.0
    }
}

/// Step 7 for a sample of table colour `c` (premultiplied) and shading `shade`: the
/// front-to-back accumulation, then whether early termination ends the ray.
#[inline(always)]
fn add_shaded(f: &Frame, c: [f32; 4], shade: f32, acc: &mut Accum) -> bool {
    // The table's (α·r, α·g, α·b, α) in one load; the fourth lane is not read.
    acc.add_premultiplied(Vec3A::from_vec4(Vec4::from_array(c)) * shade, c[3]);
    f.quality.early_termination && acc.is_opaque()
}

/// The first lattice index past a leap to `t_exit`, at least `k_min`:
/// max(k_min, ⌈t_exit/Δ − j − 10⁻³⌉), capped at 2·10⁹ (far past any extent). `inv_step` = 1/Δ
/// (t_exit·(1/Δ) may differ from t_exit/Δ by an ulp: far inside the 10⁻³ margin).
#[inline]
fn lattice_from(t_exit: f32, k_min: u32, j: f32, inv_step: f32) -> u32 {
    let x = t_exit * inv_step - j - 1e-3;
    // NaN and x ≤ k_min fail the test; ⌈x⌉ > k_min exactly when x > k_min.
    if x > k_min as f32 {
        let x = x.min(2.0e9);
        // ⌈x⌉ without a libm call: truncate (x > 0), then round up a fraction.
        // SAFETY: 0 < x ≤ 2·10⁹ fits an i64.
        let c = unsafe { x.to_int_unchecked::<i64>() };
        (if (c as f32) < x { c + 1 } else { c }) as u32
    } else {
        k_min
    }
}

/// Index-space margin by which a brick box is shrunk before a ray passes it: far above the
/// rounding of c(t) = c_e + t·c_r (≈ 10⁻⁴ of a voxel at a few hundred voxels), so no sample
/// outside the box is passed.
const BOX_MARGIN: f32 = 1e-3;

/// Steps 5–8 for the common frame (no motion hook, no deformed region, a ray/box-clipped extent,
/// invisible air, leaping on, a CT of ≥ 2 voxels per axis): every lattice point is located once;
/// when its brick of cubes is at chessboard distance d ≥ 1 from any visible cube
/// ([`super::brick_distance`]), the march passes every lattice point before the ray leaves the
/// box of bricks within d − 1 (k ← max(k + 1, ⌈t_exit/Δ − j − 10⁻³⌉), as step 8); else a point
/// whose own cube is invisible is passed alone ([`CubeMask`]), and the rest are sampled. Only
/// samples that interpolate invisible values are passed: the picture is that of every lattice
/// point sampled. With SIMD lanes (`LANES`, docs/rendering.md "Sample lanes") points are placed
/// and classified eight at a time ([`super::window`], [`CubeMask::classify`]; a window wholly
/// inside the CT leaps only from d ≥ [`LANES_LEAP_FROM`]) and the visible ones read and lit
/// eight at a time ([`super::batch`]), with the numbers of one at a time; without, each point is
/// placed when the march reaches it. A march that would pass lattice index 2·10⁹ (a ray
/// kilometres long) stops there.
///
/// The march goes a window (or a leap) at a time ([`Self::step`]), so that several rays can be
/// marched in turn ([`march_pair`]): their chains of dependent loads and leaps
/// then overlap.
struct BrickMarch {
    ray: Ray,
    leaving: LeavingRay,
    lattice: Lattice,
    /// The next lattice index to visit.
    k: u32,
    /// Whether the next step tests its first point alone before placing a window: after a leap
    /// and at the ray's start (most often in the air around the body), where that point most
    /// often lies in a far brick.
    alone_first: bool,
    /// The classes of the window already placed at `k` (the lanes' look-ahead, see
    /// [`Self::look_ahead`]).
    ahead: Option<WindowClasses>,
    /// Samples counted (air at the box's faces) since the batch's last entry.
    counted: u32,
    samples: u64,
    window: Window,
    batch: Batch,
    evaluated: Evaluated,
}

/// The least brick distance the lanes leap from. A brick at distance 1 is its own empty box:
/// leaping out of it saves a few points at the price of a chain of dependent operations, while
/// a window passes its points (all in invisible cubes) on the lanes without one; it halved the
/// leaps and took 5 % off the chest CT's soft frame. The points sampled are the same: only
/// points of invisible cubes are passed either way.
const LANES_LEAP_FROM: u8 = 2;

/// What a march step reads that is the same for every ray of a frame.
#[derive(Clone, Copy)]
struct BrickContext<'a> {
    cubes: &'a CubeMask,
    kernel: Kernel<'a>,
    placer: Placer,
    inv_step: f32,
}

impl<'a> BrickContext<'a> {
    #[inline(always)]
    fn new(f: &'a Frame, cubes: &'a CubeMask) -> Self {
        BrickContext {
            cubes,
            kernel: Kernel::new(f.sampler.grads, &f.table, &f.phong, f.sampler.half_rows_ct(), f.avx2),
            placer: Placer::new(f.avx2),
            inv_step: 1.0 / f.quality.step_mm,
        }
    }
}

impl BrickMarch {
    #[inline(always)]
    fn new(f: &Frame, ray: Ray, k0: u32) -> Self {
        BrickMarch {
            leaving: LeavingRay::new(ray.ce, ray.dc),
            lattice: Lattice {
                ce: ray.ce,
                dc: ray.dc,
                j: ray.j,
                step: f.quality.step_mm,
            },
            ray,
            k: k0,
            alone_first: true,
            ahead: None,
            counted: 0,
            samples: 0,
            window: Window::default(),
            batch: Batch::default(),
            evaluated: Evaluated::default(),
        }
    }

    /// The march to its end; the samples taken.
    #[inline(always)]
    fn run<const LANES: bool>(mut self, f: &Frame, cx: &BrickContext, acc: &mut Accum) -> u64 {
        while !self.step::<LANES>(f, cx, acc) {}
        self.samples
    }

    /// The leap from lattice index `k`'s point, in brick `b` at distance `d` ≥ 1.
    #[inline(always)]
    fn leap(&mut self, cx: &BrickContext, b: [u32; 3], d: u8, k: u32) {
        let t_exit = cx.cubes.bricks().exit_t(b, d, BOX_MARGIN, &self.leaving);
        self.k = lattice_from(t_exit, k + 1, self.ray.j, cx.inv_step);
        self.alone_first = true;
    }

    /// Evaluates the batch's first [`super::batch::LANES`] samples (or fewer) and composites
    /// them; whether the ray is done.
    #[inline(always)]
    fn composite(&mut self, f: &Frame, cx: &BrickContext, acc: &mut Accum) -> bool {
        cx.kernel
            .take_front(&mut self.batch, self.ray.half, &mut self.evaluated);
        self.flush(f, acc)
    }

    /// Composites the samples evaluated and not yet composited, if any; whether the ray is done.
    #[inline(always)]
    fn flush(&mut self, f: &Frame, acc: &mut Accum) -> bool {
        self.evaluated.len != 0 && composite_evaluated(f, &self.ray, &mut self.evaluated, &mut self.samples, acc)
    }

    /// The march's end past the last point: the batch's rest composited, the air counted.
    #[inline(always)]
    fn end(&mut self, f: &Frame, cx: &BrickContext, acc: &mut Accum) -> bool {
        if self.flush(f, acc) {
            return true;
        }
        while !self.batch.is_empty() {
            if self.composite(f, cx, acc) {
                return true;
            }
        }
        self.samples += u64::from(self.counted);
        true
    }

    /// The classes of the window just placed, when it lies wholly inside the CT and before the
    /// ray's end (its points can then be classified on the lanes); `None` otherwise, and
    /// without the lanes.
    #[inline(always)]
    fn classify(&self, f: &Frame, cx: &BrickContext) -> Option<WindowClasses> {
        let avx2 = f.avx2?;
        // t_k grows with k, so the last point's bounds hold for all eight.
        let last_t = self.window.t[POINTS - 1];
        if self.window.inside == u8::MAX && last_t <= self.ray.t_hi && last_t < self.ray.t_tool && cx.cubes.lanes_fit()
        {
            Some(avx2.classify(cx.cubes, &self.window, LANES_LEAP_FROM))
        } else {
            None
        }
    }

    /// After a window without a leap, the next one (at `k`) placed and classified at once: its
    /// loads (the cube bits' words, the last brick's distance) are then under way while the
    /// other ray of the pair takes its step, and the branch on their answer waits for nothing
    /// when this ray's next step comes. The same windows are
    /// classified as without it.
    #[inline(always)]
    fn look_ahead(&mut self, f: &Frame, cx: &BrickContext) {
        if self.k > LAST_WINDOW_K {
            return;
        }
        cx.placer.place(&f.sampler.ct, &self.lattice, self.k, &mut self.window);
        self.ahead = self.classify(f, cx);
    }

    /// One window of lattice points (k … k + 7, up to a leap), or one leap; whether the ray is
    /// done (its end reached, or opaque).
    #[inline(always)]
    fn step<const LANES: bool>(&mut self, f: &Frame, cx: &BrickContext, acc: &mut Accum) -> bool {
        debug_assert_eq!(cx.placer.uses_lanes(), LANES);
        // A batch the lanes filled is evaluated a step later, and composited a step after that:
        // in between, the other ray's step ran while its records arrived, and then while it
        // was read and lit. The order of compositing is the ray's.
        if LANES {
            if self.flush(f, acc) {
                return true;
            }
            if self.batch.is_full() {
                cx.kernel
                    .take_front(&mut self.batch, self.ray.half, &mut self.evaluated);
            }
        } else if self.batch.is_full() && self.composite(f, cx, acc) {
            return true;
        }
        let k = self.k;
        if k > LAST_WINDOW_K {
            return self.end(f, cx, acc);
        }
        let bricks = cx.cubes.bricks();
        if LANES && self.alone_first {
            // After a leap the next point most often lies in a far brick again (85 % of leaps
            // on the chest CT): tested alone, the chain from leap to leap stays short. So does
            // a ray's first point, which saves most rays a window (the empty frame's set-up
            // and march 6.8 → 6.2 ms).
            self.alone_first = false;
            let t = lattice(k, self.ray.j, self.lattice.step);
            if t <= self.ray.t_hi
                && t < self.ray.t_tool
                && let Some(cell) = f.sampler.ct.locate(self.ray.ce + self.ray.dc * t)
            {
                let d = bricks.at(cell.b);
                if d >= LANES_LEAP_FROM {
                    self.leap(cx, cell.b, d, k);
                    return false;
                }
            }
        }
        // Lattice points k … k + 7 (placed and located together on the lanes), in order,
        // unless the last step placed and classified them already.
        let classes = match self.ahead.take() {
            Some(classes) => Some(classes),
            None => {
                cx.placer.place(&f.sampler.ct, &self.lattice, k, &mut self.window);
                if LANES { self.classify(f, cx) } else { None }
            }
        };
        // A window wholly inside the CT and before the ray's end: its points classified on the
        // lanes and its visible ones before the first leap appended at once.
        if LANES
            && let Some(avx2) = f.avx2
            && let Some(classes) = classes
        {
            let leap_at = (u32::from(classes.far) | 1 << POINTS).trailing_zeros() as usize;
            let take = classes.visible & ((1u32 << leap_at) - 1) as u8;
            if take != 0 {
                cx.kernel.prefetch_window(&self.window);
                avx2.append_window(&mut self.batch, &self.window, take, self.counted);
                self.counted = 0;
            }
            if leap_at < POINTS {
                let b = self.window.cell_at(leap_at).b;
                self.leap(cx, b, classes.far_distance, k + leap_at as u32);
            } else {
                self.k = k + POINTS as u32;
                self.look_ahead(f, cx);
            }
            return false;
        }
        // Point by point: what was evaluated goes first.
        if self.flush(f, acc) {
            return true;
        }
        for i in 0..POINTS {
            let (t, cell) = cx
                .placer
                .point::<LANES>(&f.sampler.ct, &self.lattice, &self.window, k, i);
            if t > self.ray.t_hi || t >= self.ray.t_tool {
                return self.end(f, cx, acc);
            }
            let Some(cell) = cell else {
                // Air outside the CT (rounding at the box's faces), invisible on this path.
                self.counted += 1;
                continue;
            };
            let d = bricks.at(cell.b);
            if d > 0 {
                // The rest of the window is passed: the march resumes past the leap.
                self.leap(cx, cell.b, d, k + i as u32);
                return false;
            }
            if !cx.cubes.visible(cell.b[0], cell.b[1], cell.b[2]) {
                continue;
            }
            cx.kernel.prefetch(&cell);
            self.batch.push(cell, t, self.counted);
            self.counted = 0;
            if self.batch.is_full() && self.composite(f, cx, acc) {
                return true;
            }
        }
        self.k = k + POINTS as u32;
        false
    }
}

/// The last lattice index a window starts at: `lattice_from`'s cap (2·10⁹, far past any
/// extent), below which k … k + 7 fit the lanes' `i32`.
const LAST_WINDOW_K: u32 = 2_000_000_000;

/// Steps 6–7 for the evaluated samples ([`super::batch`], [`Kernel::take_front`]): shadowed
/// and accumulated one after the other in the ray's order, exactly as [`composite`] would have
/// one at a time. Counts the samples up to the last one composited; returns whether the ray is
/// done (early termination). Leaves none held.
#[inline(always)]
fn composite_evaluated(f: &Frame, ray: &Ray, evaluated: &mut Evaluated, samples: &mut u64, acc: &mut Accum) -> bool {
    let n = evaluated.len;
    evaluated.len = 0;
    // 6. The shadow factors first, so that the loop below calls nothing and its chain from
    // sample to sample (T, C and the count) stays in registers.
    let mut f_shadow = [1.0f32; super::batch::LANES];
    if f.has_shadows {
        for (i, s) in f_shadow.iter_mut().enumerate().take(n) {
            *s = shadow_factor(f, ray, evaluated.t[i]);
        }
    }
    let mut done = false;
    let mut local = *acc;
    let mut counted = 0u64;
    for (i, &f_shadow) in f_shadow.iter().enumerate().take(n) {
        counted += u64::from(evaluated.counted_before[i]) + 1;
        let c = evaluated.colour[i];
        // A sample of opacity 0 adds nothing: C += T·0, T·(1 − 0) = T, bit for bit, so it goes
        // through the same operations as the rest (with its shade zeroed, so that no non-finite
        // shade can reach C) rather than a branch, which mispredicted often enough in tissue at
        // the edge of the transfer function's range to cost 3.5 % of the soft-tissue frame.
        let shade = evaluated.shade(i, &f.phong, f_shadow);
        if add_shaded(f, c, if c[3] > 0.0 { shade } else { 0.0 }, &mut local) {
            done = true;
            break;
        }
    }
    *samples += counted;
    *acc = local;
    done
}

/// Steps 5–8 in every other case (motion warp, deformed region, leaping off, no ray/box, visible
/// air): every sample placed and looked up on its own. Returns the number of samples taken.
fn lattice_general(
    f: &Frame,
    ray: &Ray,
    k0: u32,
    mut warp: Option<&mut Warp>,
    at_t: impl Fn(f32) -> At,
    acc: &mut Accum,
) -> u64 {
    let step = f.quality.step_mm;
    let inv_step = 1.0 / step;
    let dims = f.sampler.ct.dims;
    let margin = f.motion_margin.unwrap_or(Vec3::ZERO);
    let mut samples = 0u64;
    let mut k = k0;
    loop {
        let t = lattice(k, ray.j, step);
        if t > ray.t_hi || t >= ray.t_tool {
            break;
        }
        // 8. Empty-space leaping, at the world point (its cells dilated by the motion's bound).
        if let Some(occ) = &f.occupancy {
            let c = ray.ce + ray.dc * t;
            if inside(c, dims) {
                let cell = occ.cell(c);
                if !occ.is_occupied(cell) {
                    k = lattice_from(occ.exit_t(cell, ray.ce, ray.dc), k + 1, ray.j, inv_step);
                    continue;
                }
            } else if !f.sample_outside && !inside_by(c, dims, margin) {
                k += 1;
                continue;
            }
        }
        let at = match warp.as_mut() {
            Some(w) => f.sampler.at_world(w.reference_of(ray.origin + ray.dir * t)),
            None => at_t(t),
        };
        // 5. Sample.
        samples += 1;
        let read = f.sampler.lattice_read(at);
        let c = f.table.lookup(read.value);
        if c[3] > 0.0 && composite(f, ray, t, c, f.sampler.lattice_gradient(at, &read), acc) {
            break;
        }
        k += 1;
    }
    samples
}

/// The colour of pixel (`col`, `row`) for the ray `origin` + t·`dir` (unit `dir`), and the
/// number of volume samples taken.
#[inline(always)]
pub fn march(f: &Frame, col: u32, row: u32, origin: Vec3, dir: Vec3) -> ([u8; 4], u64) {
    let mut pixel = Pixel::begin(f, col, row, origin, dir);
    if let Some(ray) = pixel.bricks.take() {
        pixel.samples += pixel.march_bricks(f, ray);
    }
    pixel.finish(f)
}

/// Two pixels' [`march`]es, bit for bit; when both take the common frame's path their lattice
/// marches go a step of each in turn (`BrickMarch::step`), so the CPU overlaps one ray's
/// dependent loads and leaps with the other's.
#[inline(always)]
pub fn march_pair(f: &Frame, a: (u32, u32, Vec3, Vec3), b: (u32, u32, Vec3, Vec3)) -> [([u8; 4], u64); 2] {
    let mut pa = Pixel::begin(f, a.0, a.1, a.2, a.3);
    let mut pb = Pixel::begin(f, b.0, b.1, b.2, b.3);
    match (pa.bricks.take(), pb.bricks.take(), &f.cubes) {
        (Some(ra), Some(rb), Some(cubes)) => {
            let cx = BrickContext::new(f, cubes);
            if f.avx2.is_some() {
                march_two::<true>(f, &cx, [&mut pa, &mut pb], [ra, rb]);
            } else {
                march_two::<false>(f, &cx, [&mut pa, &mut pb], [ra, rb]);
            }
        }
        (ra, rb, _) => {
            if let Some(ray) = ra {
                pa.samples += pa.march_bricks(f, ray);
            }
            if let Some(ray) = rb {
                pb.samples += pb.march_bricks(f, ray);
            }
        }
    }
    [pa.finish(f), pb.finish(f)]
}

/// Two brick marches a step of each in turn until both are done.
#[inline(always)]
fn march_two<const LANES: bool>(f: &Frame, cx: &BrickContext, pixels: [&mut Pixel; 2], rays: [(Ray, u32); 2]) {
    let [pa, pb] = pixels;
    let [(ra, ka), (rb, kb)] = rays;
    let (mut ma, mut mb) = (BrickMarch::new(f, ra, ka), BrickMarch::new(f, rb, kb));
    let (mut done_a, mut done_b) = (false, false);
    while !(done_a || done_b) {
        done_a = ma.step::<LANES>(f, cx, &mut pa.acc);
        done_b = mb.step::<LANES>(f, cx, &mut pb.acc);
    }
    while !done_a {
        done_a = ma.step::<LANES>(f, cx, &mut pa.acc);
    }
    while !done_b {
        done_b = mb.step::<LANES>(f, cx, &mut pb.acc);
    }
    pa.samples += ma.samples;
    pb.samples += mb.samples;
}

/// One pixel's ray between its set-up (steps 1–4 and the plane sample) and its finish (the tool
/// behind, step 9): what is accumulated so far, and the brick march still to go.
struct Pixel {
    acc: Accum,
    samples: u64,
    dir: Vec3,
    tool: Option<crate::tools::ToolHit>,
    /// The common frame's lattice march, not yet taken (ray, first lattice index).
    bricks: Option<(Ray, u32)>,
}

impl Pixel {
    /// The brick march of `ray` from lattice index `k0`, to its end; the samples taken.
    #[inline(always)]
    fn march_bricks(&mut self, f: &Frame, (ray, k0): (Ray, u32)) -> u64 {
        let Some(cubes) = &f.cubes else {
            unreachable!("a brick march is set up only with the cube mask")
        };
        let cx = BrickContext::new(f, cubes);
        let m = BrickMarch::new(f, ray, k0);
        // With the lanes this runs inside the tile compiled for AVX2 (`draw_tile`), so the
        // lanes' kernels are inlined into the march.
        if f.avx2.is_some() {
            m.run::<true>(f, &cx, &mut self.acc)
        } else {
            m.run::<false>(f, &cx, &mut self.acc)
        }
    }

    /// Steps 1–4, the plane sample, and the lattice samples of every path but the common
    /// frame's (left in `bricks`).
    #[inline(always)]
    fn begin(f: &Frame, col: u32, row: u32, origin: Vec3, dir: Vec3) -> Pixel {
        let q = &f.quality;
        let step = q.step_mm;
        let dims = f.sampler.ct.dims;
        // 1. Sample lattice.
        let j = if q.jitter { jitter(col, row) } else { 0.0 };
        let ce = f.sampler.ct_map.point(origin);
        let dc = f.sampler.ct_map.vector(dir);
        let (je, dj) = match &f.sampler.deformed {
            Some((_, m)) => (m.point(origin), m.vector(dir)),
            None => (Vec3::ZERO, Vec3::ZERO),
        };
        let at_t = |t: f32| At {
            ct: ce + dc * t,
            j: je + dj * t,
        };
        let half = half_vector(dir, &f.light);
        let mut acc = Accum::CLEAR;
        let mut samples = 0u64;

        // 4. Tools: the nearest hit ends the march (tools are never clipped).
        let tool = nearest_hit(&f.primitives, origin, dir, NO_TOOL);
        let t_tool = tool.map_or(NO_TOOL, |h| h.t);

        // 2. Extent: the CT's box, widened by a motion's bound (an unbounded motion: naive).
        let extent = match (q.ray_box, f.motion.is_some(), f.motion_margin) {
            (true, false, _) => ray_box(ce, dc, dims),
            (true, true, Some(m)) => ray_box_widened(ce, dc, dims, m),
            _ => Some((0.0, f.t_far)),
        };
        // 3. Clip plane: the visible part of the extent, and the plane sample where the ray enters it.
        let mut lattice_from: Option<(f32, bool, f32)> = None; // (t_lo, strict, t_hi)
        let mut plane_t: Option<f32> = None;
        if let Some((t0, t1)) = extent {
            match f.clip {
                None => lattice_from = Some((t0, false, t1)),
                Some(p) => {
                    let s0 = (origin - p.point_mm).dot(p.normal);
                    let rn = dir.dot(p.normal);
                    if rn > 0.0 {
                        let tc = -s0 / rn;
                        if tc < t0 {
                            lattice_from = Some((t0, false, t1));
                        } else if tc <= t1 {
                            plane_t = Some(tc);
                            lattice_from = Some((tc, true, t1));
                        }
                    } else if rn < 0.0 {
                        let tc = -s0 / rn;
                        if tc >= t0 {
                            lattice_from = Some((t0, false, t1.min(tc)));
                        }
                    } else if s0 >= 0.0 {
                        lattice_from = Some((t0, false, t1));
                    }
                }
            }
        }

        let mut warp = f.motion_at.as_deref().map(Warp::new);
        let mut bricks = None;
        // The plane sample: no shading, no shadow, opacity as is.
        if let Some(tc) = plane_t
            && tc < t_tool
        {
            let at = match warp.as_mut() {
                Some(w) => f.sampler.at_world(w.reference_of(origin + dir * tc)),
                None => at_t(tc),
            };
            samples += 1;
            let c = f.transfer.eval(f.sampler.s(at));
            let style = match f.tagging {
                Tagging::Off => f.volume.style(0),
                _ => f.volume.style(f.sampler.label(at)),
            };
            let v = plane_colour(f.tagging, c, style);
            if v[3] > 0.0 {
                acc.add(Vec3::new(v[0], v[1], v[2]), v[3].min(1.0));
            }
            if let Some(w) = warp.as_mut() {
                w.restart();
            }
        }

        // 5.–8. The lattice samples.
        if let Some((t_lo, strict, t_hi)) = lattice_from
            && !(q.early_termination && acc.is_opaque())
        {
            let k0 = first_lattice(t_lo, strict, j, step);
            let ray = Ray {
                origin,
                dir,
                ce,
                dc,
                j,
                t_hi,
                t_tool,
                half,
            };
            if f.every_ray_on_bricks() {
                bricks = Some((ray, k0));
            } else {
                samples += lattice_general(f, &ray, k0, warp.as_mut(), at_t, &mut acc);
            }
        }
        Pixel {
            acc,
            samples,
            dir,
            tool,
            bricks,
        }
    }

    /// Step 4's end (the tool behind what was accumulated) and step 9; the pixel and its
    /// samples.
    #[inline(always)]
    fn finish(self, f: &Frame) -> ([u8; 4], u64) {
        debug_assert!(self.bricks.is_none(), "the brick march was taken");
        let Pixel {
            mut acc,
            samples,
            dir,
            tool,
            ..
        } = self;
        // 4. (end) The tool behind what was accumulated.
        if let Some(hit) = tool {
            acc.c += acc.transmittance * Vec3A::from(shade(&hit, &f.light, dir));
            acc.transmittance = 0.0;
        }

        // 9. Finish.
        let rgb = Vec3::from(acc.c) + acc.transmittance * f.background;
        let to8 = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
        ([to8(rgb.x), to8(rgb.y), to8(rgb.z), 255], samples)
    }
}

/// Distance from `eye` to the farthest corner of a grid's sampling domain (index box
/// [−½, n − ½]³ mapped to the world).
pub fn farthest_corner_mm(grid: &stylet_physics::Grid, eye: Vec3) -> f32 {
    let [nx, ny, nz] = grid.dims();
    let mut far = 0.0f32;
    for cx in [-0.5, nx as f64 - 0.5] {
        for cy in [-0.5, ny as f64 - 0.5] {
            for cz in [-0.5, nz as f64 - 0.5] {
                let p = grid.affine().apply(DVec3::new(cx, cy, cz)).as_vec3();
                far = far.max((p - eye).length());
            }
        }
    }
    far
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn first_lattice_respects_strictness() {
        let (j, step) = (0.25, 0.5);
        // t_k = 0.125, 0.625, 1.125, ...
        assert_eq!(first_lattice(0.0, false, j, step), 0);
        assert_eq!(first_lattice(0.625, false, j, step), 1);
        assert_eq!(first_lattice(0.625, true, j, step), 2);
        assert_eq!(first_lattice(0.7, true, j, step), 2);
    }

    #[test]
    fn ray_box_clips_to_the_half_voxel_domain() {
        let (t0, t1) = ray_box(Vec3::new(-10.0, 1.0, 1.0), Vec3::X, [4, 4, 4]).unwrap();
        assert_eq!((t0, t1), (9.5, 13.5));
        assert!(ray_box(Vec3::new(-10.0, 5.0, 1.0), Vec3::X, [4, 4, 4]).is_none());
        assert!(ray_box(Vec3::new(-10.0, 1.0, 1.0), -Vec3::X, [4, 4, 4]).is_none());
        assert_eq!(ray_box(Vec3::new(1.0, 1.0, 1.0), Vec3::X, [4, 4, 4]), Some((0.0, 2.5)));
    }
}
