//! The drainage catheter's pigtail, formed where its tip lies once the wire is out
//! (docs/seldinger.md "The pigtail").
//!
//! A pigtail catheter is straight on its wire and curls into a loop of [`LOOP_DIAMETER_MM`] when
//! the wire comes out; its drainage holes lie on the loop. The loop takes up the catheter's
//! distal 2π r_nominal of length, so the loop starts that far behind where the tip lay. It curls
//! about the wire's last direction there, toward the lumen (the ducts' inward direction at its
//! start), and is as large as fits: the largest radius r ≤ r_nominal whose centre lies at least r
//! deep in the lumen, down to [`MIN_RADIUS_MM`]; a smaller loop winds more turns of the same
//! length, a helix on the wire's direction with the catheter's diameter as its pitch (a coil
//! stacking along the duct). A loop that starts outside the ducts forms at its nominal
//! size in the tissue (the tissue's resistance to the curl is not modelled).
//!
//! Each drainage hole drains the ducts when it lies in the lumen; one outside leaks bile.

use glam::DVec3;

use super::over_wire::point_at;
use crate::wire::DuctChannel;

/// The loop's diameter (mm): a common small-loop biliary pigtail, an estimate.
pub const LOOP_DIAMETER_MM: f64 = 10.0;
/// The smallest loop a duct lets the catheter curl into (mm).
pub const MIN_RADIUS_MM: f64 = 1.0;
/// Drainage holes, evenly along the loop.
pub const DRAINAGE_HOLES: usize = 6;
/// Points on the loop per turn (the shape drawn in the X-ray).
const POINTS_PER_TURN: usize = 24;

/// The formed catheter.
#[derive(Debug, Clone, PartialEq)]
pub struct Pigtail {
    /// The catheter from the skin to its tip (reference space, mm).
    pub nodes: Vec<DVec3>,
    /// The index of the node where the loop begins.
    pub loop_from: usize,
    pub holes: [DVec3; DRAINAGE_HOLES],
    /// Which holes lie in the ducts' lumen.
    pub holes_in_ducts: [bool; DRAINAGE_HOLES],
    /// The loop's centre and radius (mm).
    pub centre_mm: DVec3,
    pub radius_mm: f64,
}

impl Pigtail {
    /// The pigtail of a catheter of `diameter_mm` on `path` (the wire from the skin) with its
    /// tip `tip_mm` along it; `up` breaks the tie where the lumen gives no direction.
    pub fn form(path: &[DVec3], tip_mm: f64, diameter_mm: f64, channel: &DuctChannel, up: DVec3) -> Pigtail {
        let nominal = 0.5 * LOOP_DIAMETER_MM;
        let loop_mm = std::f64::consts::TAU * nominal;
        let start_mm = (tip_mm - loop_mm).max(0.0);
        let (start, dir) = point_at(path, start_mm);
        // The straight part: the path up to the loop's start.
        let mut nodes = Vec::new();
        let mut walked_mm = 0.0;
        nodes.push(path.first().copied().unwrap_or(start));
        for w in path.windows(2) {
            walked_mm += w[0].distance(w[1]);
            if walked_mm >= start_mm {
                break;
            }
            nodes.push(w[1]);
        }
        nodes.push(start);
        let loop_from = nodes.len() - 1;
        // The side the loop curls to: into the lumen, else `up`.
        let toward = |v: DVec3| (v - dir * v.dot(dir)).try_normalize();
        let side = toward(channel.inward(start))
            .or_else(|| toward(up))
            .unwrap_or_else(|| dir.any_orthonormal_vector());
        let radius_mm = if channel.depth_mm(start) < 0.0 {
            nominal
        } else {
            let mut r = nominal;
            while r > MIN_RADIUS_MM && channel.depth_mm(start + side * r) < r {
                r -= 0.25;
            }
            r.max(MIN_RADIUS_MM)
        };
        let centre_mm = start + side * radius_mm;
        let binormal = dir.cross(side);
        let turns = nominal / radius_mm;
        let total = turns * std::f64::consts::TAU;
        let at = |theta: f64| {
            centre_mm - side * (radius_mm * libm::cos(theta))
                + binormal * (radius_mm * libm::sin(theta))
                + dir * (diameter_mm * theta / std::f64::consts::TAU)
        };
        let n = (turns * POINTS_PER_TURN as f64) as usize + 1;
        nodes.extend((1..=n).map(|i| at(total * i as f64 / n as f64)));
        let holes: [DVec3; DRAINAGE_HOLES] =
            std::array::from_fn(|k| at(total * (k as f64 + 0.5) / DRAINAGE_HOLES as f64));
        let holes_in_ducts = holes.map(|h| channel.depth_mm(h) >= 0.0);
        Pigtail {
            nodes,
            loop_from,
            holes,
            holes_in_ducts,
            centre_mm,
            radius_mm,
        }
    }

    /// Drainage holes in the ducts' lumen.
    pub fn holes_inside(&self) -> usize {
        self.holes_in_ducts.iter().filter(|&&b| b).count()
    }

    /// The catheter's tip (mm).
    pub fn tip_mm(&self) -> DVec3 {
        *self.nodes.last().expect("a pigtail has nodes")
    }

    pub fn digest_into(&self, mut put: impl FnMut(u64)) {
        put(self.nodes.len() as u64);
        for p in self.nodes.iter().chain(&self.holes) {
            p.to_array().iter().for_each(|c| put(c.to_bits()));
        }
        put(self.radius_mm.to_bits());
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::{Affine, Grid};

    /// A straight duct of `radius_mm` along x through a 0.5 mm grid.
    fn duct(radius_mm: f64) -> DuctChannel {
        let grid = Grid::new(
            [160, 60, 60],
            Affine::from_spacing([0.5; 3], DVec3::new(-40.0, -15.0, -15.0)),
        )
        .unwrap();
        let lumen: Vec<bool> = (0..60 * 60 * 160)
            .map(|i| {
                let (y, z) = ((i / 160) % 60, i / (160 * 60));
                let (y, z) = (-15.0 + 0.5 * y as f64, -15.0 + 0.5 * z as f64);
                y * y + z * z <= radius_mm * radius_mm
            })
            .collect();
        DuctChannel::new(&grid, &lumen)
    }

    fn path() -> Vec<DVec3> {
        (0..=120)
            .map(|i| DVec3::new(-40.0 + 0.5 * i as f64, 0.0, 0.0))
            .collect()
    }

    #[test]
    fn in_a_wide_duct_the_loop_forms_whole_and_drains_through_every_hole() {
        let p = Pigtail::form(&path(), 60.0, 2.67, &duct(11.0), DVec3::Y);
        assert_eq!(p.radius_mm, 0.5 * LOOP_DIAMETER_MM);
        assert_eq!(p.holes_inside(), DRAINAGE_HOLES);
        // The loop starts 2π r behind where the tip lay.
        let start_x = -40.0 + 60.0 - std::f64::consts::PI * LOOP_DIAMETER_MM;
        assert!((p.centre_mm.x - start_x).abs() < 1e-9, "{:?}", p.centre_mm);
    }

    #[test]
    fn in_a_narrow_duct_the_loop_winds_smaller_and_stays_inside() {
        let p = Pigtail::form(&path(), 60.0, 2.67, &duct(3.0), DVec3::Y);
        assert!(p.radius_mm < 2.0 && p.radius_mm >= MIN_RADIUS_MM, "{}", p.radius_mm);
        assert!(p.holes_inside() >= DRAINAGE_HOLES - 1, "{}", p.holes_inside());
    }

    #[test]
    fn a_catheter_short_of_the_duct_leaks_through_its_holes() {
        // The duct only from x = 10 mm on: a catheter tip at x = 0 has its loop in the tissue.
        let grid = Grid::new(
            [160, 60, 60],
            Affine::from_spacing([0.5; 3], DVec3::new(-40.0, -15.0, -15.0)),
        )
        .unwrap();
        let lumen: Vec<bool> = (0..60 * 60 * 160)
            .map(|i| {
                let (x, y, z) = (i % 160, (i / 160) % 60, i / (160 * 60));
                let (x, y, z) = (-40.0 + 0.5 * x as f64, -15.0 + 0.5 * y as f64, -15.0 + 0.5 * z as f64);
                x >= 10.0 && y * y + z * z <= 16.0
            })
            .collect();
        let p = Pigtail::form(&path(), 40.0, 2.67, &DuctChannel::new(&grid, &lumen), DVec3::Y);
        assert_eq!(p.holes_inside(), 0);
        assert_eq!(p.radius_mm, 0.5 * LOOP_DIAMETER_MM);
    }
}
