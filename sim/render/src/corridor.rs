//! The expert corridor (docs/dashboard.md "Expert benchmark"): the tube the expert references'
//! needle paths lie in, drawn as a translucent band on the review's slices and on the 3D overview.
//!
//! Each expert path (its final approach: from the last skin entry to the deepest tip, world mm) is
//! resampled at [`SAMPLES`] points evenly spaced along its length, so that the k-th sample of every
//! path sits the same fraction of the way in. The corridor's centre line is the mean of the k-th
//! samples; its radius there is the largest distance of an expert's k-th sample from that mean, at
//! least [`MIN_RADIUS_MM`] (a needle's width and the spread of a single expert's path).

use stylet_physics::glam::DVec3;

/// Samples along the corridor.
pub const SAMPLES: usize = 24;
/// The narrowest the corridor is drawn (mm).
pub const MIN_RADIUS_MM: f64 = 2.0;
/// The band's colour: white, apart from every label colour, the needle's cyan and the planned
/// path's orange.
pub const CORRIDOR_RGB: [u8; 3] = [255, 255, 255];
/// The band's opacity.
pub const CORRIDOR_ALPHA: f64 = 0.35;
/// The narrowest the band is drawn on either side of its centre line (pixels), so that it shows
/// beside a path drawn on top of it.
pub const MIN_HALF_WIDTH_PX: f64 = 3.0;

/// The corridor of the expert paths.
#[derive(Debug, Clone, PartialEq)]
pub struct Corridor {
    /// Centre line, from the skin entry in (world mm).
    pub centre_mm: Vec<DVec3>,
    /// Radius at each centre point (mm).
    pub radius_mm: Vec<f64>,
    /// The expert paths it was made from.
    pub experts: usize,
}

impl Corridor {
    /// The corridor of `paths` (each at least two points with some length); `None` if none is.
    pub fn from_paths(paths: &[Vec<DVec3>]) -> Option<Corridor> {
        let resampled: Vec<Vec<DVec3>> = paths.iter().filter_map(|p| resample(p, SAMPLES)).collect();
        if resampled.is_empty() {
            return None;
        }
        let n = resampled.len() as f64;
        let centre_mm: Vec<DVec3> = (0..SAMPLES)
            .map(|k| resampled.iter().map(|p| p[k]).sum::<DVec3>() / n)
            .collect();
        let radius_mm = (0..SAMPLES)
            .map(|k| {
                resampled
                    .iter()
                    .map(|p| p[k].distance(centre_mm[k]))
                    .fold(MIN_RADIUS_MM, f64::max)
            })
            .collect();
        Some(Corridor {
            centre_mm,
            radius_mm,
            experts: resampled.len(),
        })
    }
}

/// `count` points evenly spaced along the polyline's length, first and last included; `None` for
/// fewer than two points, no length or a non-finite point.
pub fn resample(path: &[DVec3], count: usize) -> Option<Vec<DVec3>> {
    if path.len() < 2 || count < 2 || !path.iter().all(|p| p.is_finite()) {
        return None;
    }
    let mut along = vec![0.0];
    for w in path.windows(2) {
        along.push(along.last().copied().unwrap_or(0.0) + w[0].distance(w[1]));
    }
    let total = *along.last()?;
    if total <= 1e-9 {
        return None;
    }
    let mut out = Vec::with_capacity(count);
    let mut seg = 0;
    for k in 0..count {
        let s = total * k as f64 / (count - 1) as f64;
        while seg + 2 < along.len() && along[seg + 1] < s {
            seg += 1;
        }
        let len = along[seg + 1] - along[seg];
        let t = if len > 0.0 {
            ((s - along[seg]) / len).clamp(0.0, 1.0)
        } else {
            0.0
        };
        out.push(path[seg].lerp(path[seg + 1], t));
    }
    Some(out)
}

/// The outline of a band of half-width `radius_px[k]` around the pixel polyline `centre_px`
/// (offset along the averaged normals): the left side out, the right side back.
pub fn band_polygon(centre_px: &[(f64, f64)], radius_px: &[f64]) -> Vec<(f64, f64)> {
    let n = centre_px.len().min(radius_px.len());
    if n < 2 {
        return Vec::new();
    }
    let unit = |a: (f64, f64), b: (f64, f64)| {
        let (dx, dy) = (b.0 - a.0, b.1 - a.1);
        let len = (dx * dx + dy * dy).sqrt();
        if len > 1e-9 { (dx / len, dy / len) } else { (0.0, 0.0) }
    };
    let normals: Vec<(f64, f64)> = (0..n)
        .map(|k| {
            let before = if k > 0 {
                unit(centre_px[k - 1], centre_px[k])
            } else {
                (0.0, 0.0)
            };
            let after = if k + 1 < n {
                unit(centre_px[k], centre_px[k + 1])
            } else {
                (0.0, 0.0)
            };
            let (tx, ty) = (before.0 + after.0, before.1 + after.1);
            let len = (tx * tx + ty * ty).sqrt();
            // Seen end-on (no direction on screen) the band is a disc: any normal will do.
            if len > 1e-9 { (-ty / len, tx / len) } else { (1.0, 0.0) }
        })
        .collect();
    let left = (0..n).map(|k| {
        (
            centre_px[k].0 + normals[k].0 * radius_px[k],
            centre_px[k].1 + normals[k].1 * radius_px[k],
        )
    });
    let right = (0..n).rev().map(|k| {
        (
            centre_px[k].0 - normals[k].0 * radius_px[k],
            centre_px[k].1 - normals[k].1 * radius_px[k],
        )
    });
    left.chain(right).collect()
}

/// A polygon clipped to the rectangle [lo, hi] (Sutherland–Hodgman): a band projected from far
/// away stays inside its panel.
pub fn clip_polygon(poly: &[(f64, f64)], lo: (f64, f64), hi: (f64, f64)) -> Vec<(f64, f64)> {
    let mut out: Vec<(f64, f64)> = poly
        .iter()
        .copied()
        .filter(|p| p.0.is_finite() && p.1.is_finite())
        .collect();
    // Each edge: inside test and the intersection of a segment with the edge's line.
    type Inside<'a> = &'a dyn Fn((f64, f64)) -> bool;
    type Cut<'a> = &'a dyn Fn((f64, f64), (f64, f64)) -> (f64, f64);
    let edges: [(Inside, Cut); 4] = [
        (&|p| p.0 >= lo.0, &|a, b| cut_x(a, b, lo.0)),
        (&|p| p.0 <= hi.0, &|a, b| cut_x(a, b, hi.0)),
        (&|p| p.1 >= lo.1, &|a, b| cut_y(a, b, lo.1)),
        (&|p| p.1 <= hi.1, &|a, b| cut_y(a, b, hi.1)),
    ];
    for (inside, cut) in edges {
        let input = std::mem::take(&mut out);
        for (k, &p) in input.iter().enumerate() {
            let prev = input[(k + input.len() - 1) % input.len()];
            match (inside(prev), inside(p)) {
                (true, true) => out.push(p),
                (true, false) => out.push(cut(prev, p)),
                (false, true) => {
                    out.push(cut(prev, p));
                    out.push(p);
                }
                (false, false) => {}
            }
        }
    }
    out
}

fn cut_x(a: (f64, f64), b: (f64, f64), x: f64) -> (f64, f64) {
    let t = (x - a.0) / (b.0 - a.0);
    (x, a.1 + t * (b.1 - a.1))
}

fn cut_y(a: (f64, f64), b: (f64, f64), y: f64) -> (f64, f64) {
    let t = (y - a.1) / (b.1 - a.1);
    (a.0 + t * (b.0 - a.0), y)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resampling_spaces_points_evenly_along_the_length() {
        let path = [DVec3::ZERO, DVec3::new(10.0, 0.0, 0.0), DVec3::new(10.0, 30.0, 0.0)];
        let r = resample(&path, 5).unwrap();
        // 40 mm in all: every 10 mm.
        let want = [(0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (10.0, 20.0), (10.0, 30.0)];
        for (p, w) in r.iter().zip(want) {
            assert!(p.distance(DVec3::new(w.0, w.1, 0.0)) < 1e-12, "{p} vs {w:?}");
        }
        assert_eq!(resample(&[DVec3::ONE, DVec3::ONE], 5), None);
        assert_eq!(resample(&[DVec3::ONE], 5), None);
    }

    #[test]
    fn the_corridor_of_parallel_paths() {
        // Three straight 100 mm paths 3 mm apart: centre on the middle one, radius 3 mm.
        let path = |x: f64| vec![DVec3::new(x, 0.0, 0.0), DVec3::new(x, 0.0, 100.0)];
        let c = Corridor::from_paths(&[path(-3.0), path(0.0), path(3.0)]).unwrap();
        assert_eq!((c.experts, c.centre_mm.len()), (3, SAMPLES));
        assert!(c.centre_mm[0].distance(DVec3::ZERO) < 1e-12);
        assert!(c.centre_mm[SAMPLES - 1].distance(DVec3::new(0.0, 0.0, 100.0)) < 1e-12);
        assert!(c.radius_mm.iter().all(|r| (r - 3.0).abs() < 1e-12), "{:?}", c.radius_mm);
        // One expert: the narrowest corridor along the path.
        let one = Corridor::from_paths(&[path(0.0)]).unwrap();
        assert!(one.radius_mm.iter().all(|r| *r == MIN_RADIUS_MM));
        assert_eq!(Corridor::from_paths(&[]), None);
    }

    #[test]
    fn bands_and_clipping() {
        let band = band_polygon(&[(0.0, 0.0), (10.0, 0.0)], &[2.0, 2.0]);
        assert_eq!(band.len(), 4);
        let ys: Vec<f64> = band.iter().map(|p| p.1.abs()).collect();
        assert!(ys.iter().all(|y| (y - 2.0).abs() < 1e-12), "{band:?}");
        // A square half outside the rectangle keeps its inside half.
        let sq = [(-5.0, 0.0), (5.0, 0.0), (5.0, 4.0), (-5.0, 4.0)];
        let c = clip_polygon(&sq, (0.0, 0.0), (10.0, 10.0));
        assert!(c.iter().all(|p| p.0 >= 0.0 && p.0 <= 5.0), "{c:?}");
        let area: f64 = (0..c.len())
            .map(|k| {
                let (a, b) = (c[k], c[(k + 1) % c.len()]);
                a.0 * b.1 - b.0 * a.1
            })
            .sum::<f64>()
            .abs()
            / 2.0;
        assert!((area - 20.0).abs() < 1e-9, "{area}");
        assert!(clip_polygon(&sq, (20.0, 20.0), (30.0, 30.0)).is_empty());
    }
}
