//! Colour Doppler over vessels (thesis §3.4; docs/ultrasound.md "Doppler"). The blood's speed
//! follows the thesis from a pressure p(t): |v| = √(2p/ρ_blood), with p pulsatile in arteries
//! (72 beats a minute) and steady in veins; the flow runs along the vessel, whose local axis
//! comes from the labels (the principal axis of the vessel voxels in a 28 mm cube around it); the scanner
//! measures only the part along the beam, |v|·|cos θ|, and shows nothing below its wall filter,
//! so a vessel crossing the beam at right angles stays dark as on a real scanner. Colours by
//! vessel kind as in the thesis: arteries red→yellow, veins blue→cyan with increasing speed.

use std::collections::HashMap;

use stylet_atlas::EchoClass;
use stylet_physics::PunctureAtlas;
use stylet_physics::glam::{DVec3, Vec3};

use super::acoustic::EchoTable;

/// Blood density (kg/m³).
pub const BLOOD_DENSITY_KG_M3: f32 = 1060.0;
/// Arterial dynamic pressure at peak systole and in diastole (Pa): 0.8 and 0.25 m/s, the
/// hepatic artery's range.
pub const ARTERY_SYSTOLE_PA: f32 = 339.0;
pub const ARTERY_DIASTOLE_PA: f32 = 33.0;
/// Venous dynamic pressure (Pa): 0.2 m/s, the portal vein's mean speed.
pub const VEIN_PA: f32 = 21.0;
pub const HEART_RATE_BPM: f32 = 72.0;
/// Share of the cardiac cycle in systole.
const SYSTOLE_SHARE: f32 = 0.35;
/// Speed at the top of the colour scale and the wall filter below which nothing is shown (m/s).
pub const SCALE_M_S: f32 = 0.6;
pub const WALL_FILTER_M_S: f32 = 0.03;
/// Edge of the cells the vessel axis is estimated on (mm), and the neighbourhood's half width
/// in cells (3 → a 28 mm cube).
pub const CELL_MM: f64 = 4.0;
const REACH_CELLS: i64 = 3;

/// The dynamic blood pressure of a vessel kind at time `t_s` (s).
pub fn pressure_pa(kind: EchoClass, t_s: f64) -> f32 {
    match kind {
        EchoClass::Artery => {
            let phase = (t_s * HEART_RATE_BPM as f64 / 60.0).rem_euclid(1.0) as f32;
            let pulse = if phase < SYSTOLE_SHARE {
                (std::f32::consts::PI * phase / SYSTOLE_SHARE).sin().powi(2)
            } else {
                0.0
            };
            ARTERY_DIASTOLE_PA + (ARTERY_SYSTOLE_PA - ARTERY_DIASTOLE_PA) * pulse
        }
        EchoClass::Vein => VEIN_PA,
        EchoClass::Tissue | EchoClass::Fluid => 0.0,
    }
}

/// |v| = √(2p/ρ_blood) (thesis §3.4), m/s.
pub fn speed_m_s(pressure_pa: f32) -> f32 {
    (2.0 * pressure_pa.max(0.0) / BLOOD_DENSITY_KG_M3).sqrt()
}

/// The colour of a measured speed along the beam, or `None` below the wall filter or outside
/// vessels.
pub fn colour(kind: EchoClass, beam_speed_m_s: f32) -> Option<[u8; 3]> {
    if beam_speed_m_s < WALL_FILTER_M_S {
        return None;
    }
    let c = (beam_speed_m_s / SCALE_M_S).min(1.0);
    // ⌊x + ½⌋ as the shader computes it.
    let ramp = (255.0 * c + 0.5).floor() as u8;
    match kind {
        EchoClass::Artery => Some([255, ramp, 0]),
        EchoClass::Vein => Some([0, ramp, 255]),
        EchoClass::Tissue | EchoClass::Fluid => None,
    }
}

/// [`FlowField::dense`]'s grid.
#[derive(Debug, Clone, PartialEq)]
pub struct DenseFlow {
    pub first_cell: [i32; 3],
    pub dims: [u32; 3],
    pub axes: Vec<[f32; 4]>,
}

/// First and second moments of the vessel voxels in one cell.
#[derive(Debug, Clone, Copy, Default)]
struct Moments {
    n: f64,
    s: DVec3,
    /// xx, yy, zz, xy, xz, yz.
    ss: [f64; 6],
}

impl Moments {
    fn add_point(&mut self, p: DVec3) {
        self.n += 1.0;
        self.s += p;
        self.ss[0] += p.x * p.x;
        self.ss[1] += p.y * p.y;
        self.ss[2] += p.z * p.z;
        self.ss[3] += p.x * p.y;
        self.ss[4] += p.x * p.z;
        self.ss[5] += p.y * p.z;
    }
    fn add(&mut self, o: &Moments) {
        self.n += o.n;
        self.s += o.s;
        for k in 0..6 {
            self.ss[k] += o.ss[k];
        }
    }
    /// The covariance's principal axis by power iteration from a fixed start (deterministic).
    fn principal_axis(&self) -> Option<Vec3> {
        if self.n < 2.0 {
            return None;
        }
        let m = self.s / self.n;
        let c = |k: usize, a: f64, b: f64| self.ss[k] / self.n - a * b;
        let (xx, yy, zz) = (c(0, m.x, m.x), c(1, m.y, m.y), c(2, m.z, m.z));
        let (xy, xz, yz) = (c(3, m.x, m.y), c(4, m.x, m.z), c(5, m.y, m.z));
        let mut v = DVec3::new(0.577, 0.578, 0.576);
        for _ in 0..24 {
            let w = DVec3::new(
                xx * v.x + xy * v.y + xz * v.z,
                xy * v.x + yy * v.y + yz * v.z,
                xz * v.x + yz * v.y + zz * v.z,
            );
            let len = w.length();
            if len.is_nan() || len <= 1e-12 {
                return None;
            }
            v = w / len;
        }
        Some(v.as_vec3())
    }
}

/// The flow axis of the vessels, per cell of [`CELL_MM`] (built once per atlas).
#[derive(Debug, Clone, Default)]
pub struct FlowField {
    axes: HashMap<u64, Vec3>,
}

fn cell_of(x_mm: DVec3) -> [i64; 3] {
    (x_mm / CELL_MM).floor().as_i64vec3().to_array()
}

fn key(c: [i64; 3]) -> u64 {
    const M: u64 = (1 << 21) - 1;
    (c[0] as u64 & M) | ((c[1] as u64 & M) << 21) | ((c[2] as u64 & M) << 42)
}

impl FlowField {
    /// Scans the atlas' labels for vessel voxels (veins and arteries of `table`) and estimates
    /// the axis of every cell that holds any.
    pub fn build(atlas: &PunctureAtlas, table: &EchoTable) -> FlowField {
        let labels = atlas.partial_labels();
        let grid = labels.grid();
        let [nx, ny, _] = grid.dims();
        let mut cells: HashMap<u64, ([i64; 3], Moments)> = HashMap::new();
        for (i, &l) in labels.data().iter().enumerate() {
            if !matches!(table.class(l), EchoClass::Vein | EchoClass::Artery) {
                continue;
            }
            let (a, b, c) = (i % nx, (i / nx) % ny, i / (nx * ny));
            let p = grid.voxel_to_world(a, b, c);
            let cell = cell_of(p);
            cells
                .entry(key(cell))
                .or_insert((cell, Moments::default()))
                .1
                .add_point(p);
        }
        let mut axes = HashMap::with_capacity(cells.len());
        for (&k, (cell, _)) in &cells {
            let mut sum = Moments::default();
            for dz in -REACH_CELLS..=REACH_CELLS {
                for dy in -REACH_CELLS..=REACH_CELLS {
                    for dx in -REACH_CELLS..=REACH_CELLS {
                        if let Some((_, m)) = cells.get(&key([cell[0] + dx, cell[1] + dy, cell[2] + dz])) {
                            sum.add(m);
                        }
                    }
                }
            }
            if let Some(axis) = sum.principal_axis() {
                axes.insert(k, axis);
            }
        }
        FlowField { axes }
    }

    /// The vessel axis (unit, sign arbitrary) at a point, if its cell holds vessel voxels.
    pub fn axis_at(&self, x_mm: Vec3) -> Option<Vec3> {
        self.axes.get(&key(cell_of(x_mm.as_dvec3()))).copied()
    }

    /// The axes on a dense grid of cells covering `lo_mm … hi_mm` (what the GPU reads): the first
    /// cell's index, the cells per axis and, x fastest, each cell's axis (zero: no vessel).
    pub fn dense(&self, lo_mm: DVec3, hi_mm: DVec3) -> DenseFlow {
        let lo = cell_of(lo_mm);
        let hi = cell_of(hi_mm);
        let dims = [0, 1, 2].map(|a| (hi[a] - lo[a] + 1).max(1) as u32);
        let mut axes = vec![[0.0f32; 4]; dims.iter().map(|&d| d as usize).product()];
        for z in 0..dims[2] as i64 {
            for y in 0..dims[1] as i64 {
                for x in 0..dims[0] as i64 {
                    if let Some(a) = self.axes.get(&key([lo[0] + x, lo[1] + y, lo[2] + z])) {
                        let i = x as usize + dims[0] as usize * (y as usize + dims[1] as usize * z as usize);
                        axes[i] = [a.x, a.y, a.z, 0.0];
                    }
                }
            }
        }
        DenseFlow {
            first_cell: lo.map(|v| v as i32),
            dims,
            axes,
        }
    }

    /// How many cells carry an axis.
    pub fn cells(&self) -> usize {
        self.axes.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_thesis_speed_law_and_the_cardiac_cycle() {
        assert!((speed_m_s(VEIN_PA) - 0.199).abs() < 0.001);
        assert!((speed_m_s(ARTERY_SYSTOLE_PA) - 0.8).abs() < 0.001);
        let period = 60.0 / HEART_RATE_BPM as f64;
        let peak = pressure_pa(EchoClass::Artery, period * (SYSTOLE_SHARE as f64 / 2.0));
        assert!((peak - ARTERY_SYSTOLE_PA).abs() < 0.01, "{peak}");
        assert_eq!(pressure_pa(EchoClass::Artery, period * 0.6), ARTERY_DIASTOLE_PA);
        assert_eq!(pressure_pa(EchoClass::Vein, 0.3), pressure_pa(EchoClass::Vein, 0.7));
        assert_eq!(pressure_pa(EchoClass::Fluid, 0.3), 0.0);
    }

    #[test]
    fn colours_by_kind_and_nothing_below_the_wall_filter() {
        assert_eq!(colour(EchoClass::Artery, 0.02), None);
        assert_eq!(colour(EchoClass::Artery, 0.05), Some([255, 21, 0]));
        assert_eq!(colour(EchoClass::Artery, 2.0), Some([255, 255, 0]));
        assert_eq!(colour(EchoClass::Vein, 0.6), Some([0, 255, 255]));
        assert_eq!(colour(EchoClass::Fluid, 0.6), None);
    }

    #[test]
    fn the_axis_of_a_tube_is_its_direction() {
        let mut m = Moments::default();
        let dir = DVec3::new(1.0, 2.0, -0.5).normalize();
        let (u, w) = dir.any_orthonormal_pair();
        for s in -20..=20 {
            for a in -3..=3 {
                for b in -3..=3 {
                    m.add_point(dir * s as f64 + u * a as f64 + w * b as f64);
                }
            }
        }
        let axis = m.principal_axis().unwrap().as_dvec3();
        assert!(axis.dot(dir).abs() > 0.9999, "{axis}");
    }
}
