//! Tools pushed over the guide wire once the needle is out (thesis §2.1): the dilator, which
//! widens the tract, and the drainage catheter (docs/seldinger.md "Over the wire").
//!
//! An over-the-wire tool cannot leave the wire: its tip is a point at an arc length along the
//! wire's path from the skin, moved by the hand's feed. It stops [`TIP_BEHIND_WIRE_MM`] short
//! of the wire's tip (beyond, it would run off the wire). Its resistance is the tissue's along
//! the path, with the needle's parameters scaled by the tool's size:
//!
//! - shaft friction: Σ f_R (N/mm, the tissue's `friction_max_n_per_mm`) over the length inside,
//!   times D_tool / D_needle (friction grows with the circumference in contact);
//! - at the tip, where the tract is narrower than the tool: f_cutthresh × (D_tool − D_tract) /
//!   D_needle (the tissue's puncture force for the circumference the tip must open beyond the
//!   tract, in units of the needle's, whose force the parameters measure).
//!
//! The tract remembers the widest tool that passed each millimetre ([`Tract`]): a dilator
//! pushed first leaves a catheter of its size only the friction.

use glam::DVec3;

use crate::PunctureAtlas;
use crate::properties::Param;

/// Dilator sizes Stylet offers (French: 3 × the outer diameter in mm).
pub const DILATOR_SIZES_FR: [u8; 4] = [6, 8, 10, 12];
/// Drainage catheter sizes (French): the 8–10 F of a first biliary drain.
pub const CATHETER_SIZES_FR: [u8; 2] = [8, 10];
/// French per millimetre of outer diameter.
pub const FR_PER_MM: f64 = 3.0;
/// How far behind the wire's tip an over-the-wire tool stops (mm).
pub const TIP_BEHIND_WIRE_MM: f64 = 10.0;
/// The spacing of the tissue samples along the wire's path (mm).
pub const SAMPLE_MM: f64 = 1.0;

/// Which tool rides the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OverWireKind {
    Dilator,
    Catheter,
}

impl OverWireKind {
    pub fn name(self) -> &'static str {
        match self {
            OverWireKind::Dilator => "dilator",
            OverWireKind::Catheter => "catheter",
        }
    }

    /// Whether `size_fr` is a size this tool comes in.
    pub fn offers(self, size_fr: u8) -> bool {
        match self {
            OverWireKind::Dilator => DILATOR_SIZES_FR.contains(&size_fr),
            OverWireKind::Catheter => CATHETER_SIZES_FR.contains(&size_fr),
        }
    }
}

/// Points along a polyline every `step_mm` from its first node (the first node included), and
/// the polyline's length.
pub fn resample(nodes: &[DVec3], step_mm: f64) -> (Vec<DVec3>, f64) {
    let mut out = Vec::new();
    let Some(&first) = nodes.first() else {
        return (out, 0.0);
    };
    out.push(first);
    let mut next_mm = step_mm;
    let mut walked_mm = 0.0;
    for w in nodes.windows(2) {
        let seg_mm = w[0].distance(w[1]);
        while seg_mm > 0.0 && next_mm <= walked_mm + seg_mm {
            out.push(w[0] + (w[1] - w[0]) * ((next_mm - walked_mm) / seg_mm));
            next_mm += step_mm;
        }
        walked_mm += seg_mm;
    }
    (out, walked_mm)
}

/// The point at `s_mm` along `nodes` (clamped to its ends) and the direction there.
pub fn point_at(nodes: &[DVec3], s_mm: f64) -> (DVec3, DVec3) {
    let mut walked_mm = 0.0;
    let mut last = (nodes.first().copied().unwrap_or(DVec3::ZERO), DVec3::Z);
    for w in nodes.windows(2) {
        let seg_mm = w[0].distance(w[1]);
        if seg_mm <= 0.0 {
            continue;
        }
        let dir = (w[1] - w[0]) / seg_mm;
        if s_mm <= walked_mm + seg_mm {
            let t = ((s_mm - walked_mm) / seg_mm).max(0.0);
            return (w[0] + (w[1] - w[0]) * t, dir);
        }
        walked_mm += seg_mm;
        last = (w[1], dir);
    }
    last
}

/// The widest tool that passed each millimetre of the wire's path from the skin (French).
#[derive(Debug, Clone, PartialEq)]
pub struct Tract {
    /// The needle's size, up to the depth it reached; the wire's beyond.
    needle_fr: f64,
    needle_mm: f64,
    wire_fr: f64,
    widened_fr: Vec<f64>,
}

impl Tract {
    /// The tract a needle of `needle_fr` left to `needle_mm` along the path, and a wire of
    /// `wire_fr` beyond it.
    pub fn new(needle_fr: f64, needle_mm: f64, wire_fr: f64) -> Tract {
        Tract {
            needle_fr,
            needle_mm,
            wire_fr,
            widened_fr: Vec::new(),
        }
    }

    /// The tract's size at `s_mm` along the path (French).
    pub fn size_fr(&self, s_mm: f64) -> f64 {
        let made = if s_mm <= self.needle_mm {
            self.needle_fr
        } else {
            self.wire_fr
        };
        let i = (s_mm.max(0.0) / SAMPLE_MM) as usize;
        made.max(self.widened_fr.get(i).copied().unwrap_or(0.0))
    }

    /// A tool of `size_fr` passed from `from_mm` to `to_mm`.
    pub fn widen(&mut self, from_mm: f64, to_mm: f64, size_fr: f64) {
        let (lo, hi) = (from_mm.min(to_mm).max(0.0), from_mm.max(to_mm).max(0.0));
        let (i0, i1) = ((lo / SAMPLE_MM) as usize, (hi / SAMPLE_MM) as usize);
        if self.widened_fr.len() <= i1 {
            self.widened_fr.resize(i1 + 1, 0.0);
        }
        for w in &mut self.widened_fr[i0..=i1] {
            *w = w.max(size_fr);
        }
    }

    /// The widest size anything opened the tract to between the skin and `s_mm` (French), the
    /// narrowest point of the tract that far.
    pub fn narrowest_fr(&self, s_mm: f64) -> f64 {
        let n = (s_mm.max(0.0) / SAMPLE_MM) as usize;
        (0..=n)
            .map(|i| self.size_fr(i as f64 * SAMPLE_MM))
            .fold(f64::INFINITY, f64::min)
    }

    pub fn digest_into(&self, mut put: impl FnMut(u64)) {
        for v in [self.needle_fr, self.needle_mm, self.wire_fr] {
            put(v.to_bits());
        }
        put(self.widened_fr.len() as u64);
        for v in &self.widened_fr {
            put(v.to_bits());
        }
    }
}

/// The tissue along the wire's path, sampled every [`SAMPLE_MM`] when a tool goes on the wire
/// (the wire cannot move while the hand holds the tool).
#[derive(Debug, Clone, PartialEq)]
struct PathTissue {
    /// Σ f_R from the skin to each sample (N per unit of D_tool / D_needle).
    friction_to_n: Vec<f64>,
    /// f_cutthresh at each sample (N).
    cut_n: Vec<f64>,
}

impl PathTissue {
    fn sample(atlas: &PunctureAtlas, points: &[DVec3]) -> PathTissue {
        let mut friction_to_n = Vec::with_capacity(points.len());
        let mut cut_n = Vec::with_capacity(points.len());
        let mut sum = 0.0;
        for &p in points {
            let depth_mm = f64::from(atlas.skin_distance().sample(p, -1000.0));
            // Outside the skin there is no tissue to rub or open.
            let (f, c) = if depth_mm < 0.0 {
                (0.0, 0.0)
            } else {
                (
                    atlas.param_at(p, depth_mm, Param::FrictionMaxNPerMm),
                    atlas.param_at(p, depth_mm, Param::CutThresholdN),
                )
            };
            friction_to_n.push(sum);
            sum += f * SAMPLE_MM;
            cut_n.push(c);
        }
        PathTissue { friction_to_n, cut_n }
    }

    fn index(&self, s_mm: f64) -> usize {
        ((s_mm.max(0.0) / SAMPLE_MM) as usize).min(self.cut_n.len().saturating_sub(1))
    }
}

/// A dilator or catheter on the wire.
#[derive(Debug, Clone, PartialEq)]
pub struct OverWire {
    pub kind: OverWireKind,
    pub size_fr: u8,
    /// Its tip's arc length along the wire's path from the skin (mm); 0 at the skin.
    inserted_mm: f64,
    /// The farthest its tip may go (mm).
    max_mm: f64,
    tissue: PathTissue,
    /// D_tool / D_needle.
    ratio: f64,
}

/// One tick of an over-the-wire tool.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct OverWireStep {
    /// Axial resistance (N; positive against a push).
    pub force_n: f64,
    /// Tip force opening the tract (N).
    pub opening_n: f64,
}

impl OverWire {
    /// A tool of `size_fr` slid onto the wire at the skin; `path` is the wire from the skin to its
    /// tip, `needle_fr` the size of the needle that made the tract.
    pub fn new(kind: OverWireKind, size_fr: u8, atlas: &PunctureAtlas, path: &[DVec3], needle_fr: f64) -> OverWire {
        let (points, length_mm) = resample(path, SAMPLE_MM);
        OverWire {
            kind,
            size_fr,
            inserted_mm: 0.0,
            max_mm: (length_mm - TIP_BEHIND_WIRE_MM).max(0.0),
            tissue: PathTissue::sample(atlas, &points),
            ratio: f64::from(size_fr) / needle_fr.max(1.0),
        }
    }

    pub fn inserted_mm(&self) -> f64 {
        self.inserted_mm
    }

    /// The tool's outer diameter (mm).
    pub fn diameter_mm(&self) -> f64 {
        f64::from(self.size_fr) / FR_PER_MM
    }

    /// The hand moves the tool by `delta_mm` along the wire (within it), widening `tract` as it
    /// goes forward.
    pub fn step(&mut self, delta_mm: f64, tract: &mut Tract, needle_fr: f64) -> OverWireStep {
        let before = self.inserted_mm;
        self.inserted_mm = (before + delta_mm).clamp(0.0, self.max_mm);
        let moved = self.inserted_mm - before;
        let size = f64::from(self.size_fr);
        let i = self.tissue.index(self.inserted_mm);
        let friction_n = self.tissue.friction_to_n[i] * self.ratio;
        let mut step = OverWireStep::default();
        if moved > 0.0 {
            let opening = (size - tract.size_fr(self.inserted_mm)).max(0.0);
            step.opening_n = self.tissue.cut_n[i] * opening / needle_fr.max(1.0);
            step.force_n = friction_n + step.opening_n;
            tract.widen(before, self.inserted_mm, size);
        } else if moved < 0.0 {
            step.force_n = -friction_n;
        }
        step
    }

    pub fn digest_into(&self, mut put: impl FnMut(u64)) {
        put(u64::from(self.size_fr) | (self.kind as u64) << 8);
        for v in [self.inserted_mm, self.max_mm, self.ratio] {
            put(v.to_bits());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resampling_walks_the_polyline_at_even_steps() {
        let nodes = [DVec3::ZERO, DVec3::new(2.5, 0.0, 0.0), DVec3::new(2.5, 2.0, 0.0)];
        let (points, length) = resample(&nodes, 1.0);
        assert_eq!(length, 4.5);
        assert_eq!(points.len(), 5);
        assert_eq!(points[3], DVec3::new(2.5, 0.5, 0.0));
        let (p, dir) = point_at(&nodes, 3.0);
        assert_eq!((p, dir), (DVec3::new(2.5, 0.5, 0.0), DVec3::Y));
        assert_eq!(point_at(&nodes, 99.0).0, nodes[2]);
    }

    #[test]
    fn a_tract_keeps_the_widest_tool_that_passed() {
        let mut t = Tract::new(3.8, 50.0, 2.7);
        assert_eq!(t.size_fr(10.0), 3.8);
        assert_eq!(t.size_fr(60.0), 2.7);
        t.widen(0.0, 30.0, 8.0);
        t.widen(0.0, 20.0, 6.0);
        assert_eq!(t.size_fr(25.0), 8.0);
        assert_eq!(t.size_fr(40.0), 3.8);
        assert_eq!(t.narrowest_fr(30.0), 8.0);
        assert_eq!(t.narrowest_fr(40.0), 3.8);
    }
}
