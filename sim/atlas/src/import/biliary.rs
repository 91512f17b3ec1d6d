//! Synthesis of a dilated biliary tree inside a real liver label, as the thesis did for its 4D
//! patient (§5.6): real CTs rarely show the ducts, and the available segmentations have none.
//!
//! Ducts grow from the hilum (where the portal vein meets the liver) along geodesic paths that
//! keep to the liver's interior: to the right lobe (its first stretch is the right hepatic duct,
//! the target), to the left lobe, downward (common hepatic duct) and a few seeded side branches.
//! The label map gets the duct and target labels; the CT gets bile values (with the liver's own
//! noise) blended with partial volume, so the ducts appear hypodense as dilated ducts do.

use std::cmp::Reverse;
use std::collections::{BinaryHeap, VecDeque};

use stylet_physics::distance::squared_edt;
use stylet_physics::glam::DVec3;
use stylet_physics::{Grid, LabelId, Volume};

use super::recipe::Biliary;
use crate::phantom::noise::{Rng, gaussian};
use crate::phantom::shapes::Capsule;

/// What was synthesised, for the import report and the tests.
#[derive(Debug, Clone)]
pub struct BiliaryReport {
    pub hilum_mm: DVec3,
    /// How the hilum was found: "portal vein" or "deepest liver point".
    pub hilum_source: &'static str,
    pub target_center_mm: DVec3,
    pub target_voxels: usize,
    pub duct_voxels: usize,
    /// 26-connected components of ducts ∪ target (1 = one connected tree).
    pub components: usize,
    /// Liver noise estimate used for the bile values (HU).
    pub liver_noise_hu: f64,
}

/// Why no biliary tree can be grown in this liver with these parameters (the recipe's
/// `[biliary]` table): the liver label is too small, too thin or not connected enough.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BiliaryError {
    #[error("the liver label {label} covers only {ml:.0} ml; a biliary tree needs at least 100 ml")]
    LiverTooSmall { label: LabelId, ml: f64 },
    /// No liver voxel lies `margin_mm` inside the liver, as the target duct needs.
    #[error("the liver has no voxel {margin_mm:.1} mm away from its surface")]
    TooThin { margin_mm: f64 },
    #[error("no deep liver voxel to the right of the hilum")]
    NoRightLobe,
    #[error("the right lobe is not reachable from the hilum inside the liver")]
    RightLobeUnreachable,
}

/// A duct centre line with its radius at each point.
struct Duct {
    points: Vec<DVec3>,
    radius_start: f64,
    radius_end: f64,
    label: LabelId,
}

/// Errors do not name the recipe; the caller does.
pub fn synthesize(
    params: &Biliary,
    ct: &mut Volume<f32>,
    labels: &mut Volume<LabelId>,
    source: &Volume<LabelId>,
) -> Result<BiliaryReport, BiliaryError> {
    let grid = *ct.grid();
    let liver: Vec<bool> = labels.data().iter().map(|&l| l == params.liver_label).collect();
    let liver_count = liver.iter().filter(|&&b| b).count();
    let voxel_mm3: f64 = grid.spacing_mm().iter().product();
    if (liver_count as f64 * voxel_mm3) < 100_000.0 {
        return Err(BiliaryError::LiverTooSmall {
            label: params.liver_label,
            ml: liver_count as f64 * voxel_mm3 / 1000.0,
        });
    }
    let not_liver: Vec<bool> = liver.iter().map(|&b| !b).collect();
    let depth: Vec<f64> = squared_edt(&grid, &not_liver)
        .into_iter()
        .map(|d| (d as f64).sqrt())
        .collect();
    let world = |idx: usize| grid.linear_to_world(idx);
    let margin = params.target_radius_mm + 3.0;

    // Hilum: portal-vein voxels in or next to the liver, snapped to a deep liver voxel.
    let near_liver: Vec<f64> = squared_edt(&grid, &liver)
        .into_iter()
        .map(|d| (d as f64).sqrt())
        .collect();
    let (mut sum, mut n) = (DVec3::ZERO, 0usize);
    for (idx, &s) in source.data().iter().enumerate() {
        if s != 0 && params.hilum_from.contains(&s) && near_liver[idx] <= 6.0 {
            sum += world(idx);
            n += 1;
        }
    }
    let deep: Vec<usize> = (0..grid.len()).filter(|&i| depth[i] >= margin).collect();
    if deep.is_empty() {
        return Err(BiliaryError::TooThin { margin_mm: margin });
    }
    let (hilum, hilum_source) = if n > 0 {
        let c = sum / n as f64;
        let best = *deep
            .iter()
            .min_by(|&&a, &&b| world(a).distance_squared(c).total_cmp(&world(b).distance_squared(c)))
            .expect("non-empty");
        (best, "portal vein")
    } else {
        let best = *deep
            .iter()
            .max_by(|&&a, &&b| depth[a].total_cmp(&depth[b]).then(b.cmp(&a)))
            .expect("non-empty");
        (best, "deepest liver point")
    };
    let h = world(hilum);
    let pick = |score: &dyn Fn(DVec3) -> f64, min_depth: f64| -> Option<usize> {
        (0..grid.len())
            .filter(|&i| depth[i] >= min_depth)
            .max_by(|&a, &b| score(world(a)).total_cmp(&score(world(b))).then(b.cmp(&a)))
    };
    let right_end = pick(
        &|p: DVec3| (p.x - h.x) - 0.7 * (p.z - h.z).abs() - 0.3 * (p.y - h.y).abs(),
        margin,
    )
    .ok_or(BiliaryError::NoRightLobe)?;
    let left_end = pick(
        &|p: DVec3| (h.x - p.x) - 0.7 * (p.z - h.z).abs() - 0.3 * (p.y - h.y).abs(),
        params.duct_radius_mm + 3.0,
    );
    let down_end = pick(
        &|p: DVec3| (h.z - p.z) - 0.7 * ((p.x - h.x).abs() + (p.y - h.y).abs()),
        params.duct_radius_mm + 2.0,
    );

    let allowed = |min: f64| -> Vec<bool> { depth.iter().map(|&d| d >= min).collect() };
    let right =
        geodesic(&grid, &allowed(margin), &depth, hilum, right_end).ok_or(BiliaryError::RightLobeUnreachable)?;
    let right_pts = smooth(&right.iter().map(|&i| world(i)).collect::<Vec<_>>());
    let (target_pts, rest_pts) = split_at_length(&right_pts, params.target_length_mm);

    let mut ducts = vec![Duct {
        points: rest_pts.clone(),
        radius_start: params.duct_radius_mm,
        radius_end: params.branch_radius_mm,
        label: params.duct_label,
    }];
    let duct_allowed = allowed(params.duct_radius_mm + 2.0);
    for end in [left_end, down_end].into_iter().flatten() {
        if let Some(p) = geodesic(&grid, &duct_allowed, &depth, hilum, end) {
            let pts = smooth(&p.iter().map(|&i| world(i)).collect::<Vec<_>>());
            if polyline_length(&pts) > 10.0 {
                ducts.push(Duct {
                    points: pts,
                    radius_start: params.duct_radius_mm + 0.5,
                    radius_end: params.branch_radius_mm,
                    label: params.duct_label,
                });
            }
        }
    }
    // Seeded side branches from the right segmental and left ducts.
    let mut rng = Rng::new(params.seed, 0xD0C7);
    let branch_allowed = allowed(params.branch_radius_mm + 1.5);
    let anchors: Vec<DVec3> = ducts.iter().flat_map(|d| d.points.iter().copied()).collect();
    for _ in 0..params.branches {
        if anchors.is_empty() {
            break;
        }
        let a = anchors[(rng.next_f64() * anchors.len() as f64) as usize % anchors.len()];
        let dir = DVec3::new(rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), rng.range(-1.0, 1.0)).normalize_or_zero();
        let goal = a + dir * rng.range(25.0, 45.0);
        let start = nearest_allowed(&grid, &branch_allowed, a);
        let end = nearest_allowed(&grid, &branch_allowed, goal);
        if let (Some(s), Some(e)) = (start, end)
            && let Some(p) = geodesic(&grid, &branch_allowed, &depth, s, e)
        {
            let pts = smooth(&p.iter().map(|&i| world(i)).collect::<Vec<_>>());
            if polyline_length(&pts) > 8.0 {
                ducts.push(Duct {
                    points: pts,
                    radius_start: params.branch_radius_mm,
                    radius_end: params.branch_radius_mm * 0.8,
                    label: params.duct_label,
                });
            }
        }
    }
    // The target last, so the confluence at the hilum belongs to it.
    ducts.push(Duct {
        points: target_pts.clone(),
        radius_start: params.target_radius_mm,
        radius_end: params.target_radius_mm,
        label: params.target_label,
    });

    // Liver noise (robust: MAD of the deep liver) for the bile values.
    let mut liver_hu: Vec<f32> = deep.iter().map(|&i| ct.data()[i]).collect();
    let median = median_f32(&mut liver_hu);
    let mut dev: Vec<f32> = liver_hu.iter().map(|v| (v - median).abs()).collect();
    let noise = 1.4826 * median_f32(&mut dev) as f64;

    let h_mm = libm::cbrt(voxel_mm3);
    for d in &ducts {
        paint_duct(&grid, d, &liver, h_mm, params.bile_hu, noise, params.seed, ct, labels);
    }

    let target_voxels = labels.data().iter().filter(|&&l| l == params.target_label).count();
    let duct_voxels = labels.data().iter().filter(|&&l| l == params.duct_label).count();
    let tree: Vec<bool> = labels
        .data()
        .iter()
        .map(|&l| l == params.target_label || l == params.duct_label)
        .collect();
    let components = count_components(&grid, &tree);
    let target_center_mm = target_pts.iter().copied().sum::<DVec3>() / target_pts.len().max(1) as f64;
    Ok(BiliaryReport {
        hilum_mm: h,
        hilum_source,
        target_center_mm,
        target_voxels,
        duct_voxels,
        components,
        liver_noise_hu: noise,
    })
}

fn median_f32(v: &mut [f32]) -> f32 {
    if v.is_empty() {
        return 0.0;
    }
    let mid = v.len() / 2;
    *v.select_nth_unstable_by(mid, |a, b| a.total_cmp(b)).1
}

/// Shortest path through allowed voxels (26-neighbourhood), preferring the liver's interior:
/// each step costs its length × (1 + 10 mm / depth). Ties break on voxel index: deterministic.
fn geodesic(grid: &Grid, allowed: &[bool], depth: &[f64], start: usize, goal: usize) -> Option<Vec<usize>> {
    if !allowed[start] || !allowed[goal] {
        return None;
    }
    let [nx, ny, nz] = grid.dims();
    let s = grid.spacing_mm();
    let mut dist = vec![f64::INFINITY; grid.len()];
    let mut prev = vec![usize::MAX; grid.len()];
    let mut heap = BinaryHeap::new();
    dist[start] = 0.0;
    heap.push(Reverse((0u64, start)));
    while let Some(Reverse((bits, idx))) = heap.pop() {
        let d = f64::from_bits(bits);
        if d > dist[idx] {
            continue;
        }
        if idx == goal {
            break;
        }
        let [i, j, k] = grid.unlinear(idx);
        for dk in -1i64..=1 {
            for dj in -1i64..=1 {
                for di in -1i64..=1 {
                    if di == 0 && dj == 0 && dk == 0 {
                        continue;
                    }
                    let (a, b, c) = (i as i64 + di, j as i64 + dj, k as i64 + dk);
                    if a < 0 || b < 0 || c < 0 || a >= nx as i64 || b >= ny as i64 || c >= nz as i64 {
                        continue;
                    }
                    let n = grid.linear(a as usize, b as usize, c as usize);
                    if !allowed[n] {
                        continue;
                    }
                    let len =
                        ((di as f64 * s[0]).powi(2) + (dj as f64 * s[1]).powi(2) + (dk as f64 * s[2]).powi(2)).sqrt();
                    let nd = d + len * (1.0 + 10.0 / depth[n].max(0.1));
                    if nd < dist[n] {
                        dist[n] = nd;
                        prev[n] = idx;
                        heap.push(Reverse((nd.to_bits(), n)));
                    }
                }
            }
        }
    }
    if !dist[goal].is_finite() {
        return None;
    }
    let mut path = vec![goal];
    while *path.last().expect("non-empty") != start {
        path.push(prev[*path.last().expect("non-empty")]);
    }
    path.reverse();
    Some(path)
}

fn nearest_allowed(grid: &Grid, allowed: &[bool], p: DVec3) -> Option<usize> {
    (0..grid.len()).filter(|&i| allowed[i]).min_by(|&a, &b| {
        let pa = grid.unlinear(a);
        let pb = grid.unlinear(b);
        let da = grid.voxel_to_world(pa[0], pa[1], pa[2]).distance_squared(p);
        let db = grid.voxel_to_world(pb[0], pb[1], pb[2]).distance_squared(p);
        da.total_cmp(&db).then(a.cmp(&b))
    })
}

/// Moving average over five points (end points kept), removing the voxel staircase.
fn smooth(points: &[DVec3]) -> Vec<DVec3> {
    if points.len() < 5 {
        return points.to_vec();
    }
    let mut out = points.to_vec();
    for _ in 0..2 {
        let src = out.clone();
        for i in 2..src.len() - 2 {
            out[i] = (src[i - 2] + src[i - 1] + src[i] + src[i + 1] + src[i + 2]) / 5.0;
        }
    }
    out
}

fn polyline_length(p: &[DVec3]) -> f64 {
    p.windows(2).map(|w| w[0].distance(w[1])).sum()
}

/// Splits a polyline after `length` mm: (first part, rest starting where the first ends).
fn split_at_length(p: &[DVec3], length: f64) -> (Vec<DVec3>, Vec<DVec3>) {
    let mut acc = 0.0;
    for i in 1..p.len() {
        acc += p[i - 1].distance(p[i]);
        if acc >= length {
            return (p[..=i].to_vec(), p[i..].to_vec());
        }
    }
    (p.to_vec(), p[p.len().saturating_sub(1)..].to_vec())
}

/// Paints one duct into the label map and the CT, only inside the liver.
#[allow(clippy::too_many_arguments)]
fn paint_duct(
    grid: &Grid,
    duct: &Duct,
    liver: &[bool],
    h_mm: f64,
    bile_hu: f64,
    noise_hu: f64,
    seed: u64,
    ct: &mut Volume<f32>,
    labels: &mut Volume<LabelId>,
) {
    let total = polyline_length(&duct.points).max(1e-9);
    let mut along = 0.0;
    for w in duct.points.windows(2) {
        let seg_len = w[0].distance(w[1]);
        let r0 = duct.radius_start + (duct.radius_end - duct.radius_start) * (along / total);
        along += seg_len;
        let r1 = duct.radius_start + (duct.radius_end - duct.radius_start) * (along / total);
        let cap = Capsule::new(w[0], w[1], r0, r1);
        let bb = cap.aabb().grow(h_mm);
        let lo = grid.world_to_index(bb.min);
        let hi = grid.world_to_index(bb.max);
        let d = grid.dims();
        let range = |a: usize| {
            let (l, u) = (
                lo[a].min(hi[a]).floor().max(0.0),
                lo[a].max(hi[a]).ceil().min(d[a] as f64 - 1.0),
            );
            (l as usize, u as usize)
        };
        let ((i0, i1), (j0, j1), (k0, k1)) = (range(0), range(1), range(2));
        for k in k0..=k1 {
            for j in j0..=j1 {
                for i in i0..=i1 {
                    let idx = grid.linear(i, j, k);
                    if !liver[idx] {
                        continue;
                    }
                    let sd = cap.sdf(grid.voxel_to_world(i, j, k));
                    let alpha = (0.5 - sd / h_mm).clamp(0.0, 1.0);
                    if alpha <= 0.0 {
                        continue;
                    }
                    let bile = bile_hu + noise_hu * gaussian(seed, 0xB11E, idx as u64);
                    let v = &mut ct.data_mut()[idx];
                    *v = (*v as f64 + alpha * (bile - *v as f64)) as f32;
                    if sd < 0.0 {
                        labels.data_mut()[idx] = duct.label;
                    }
                }
            }
        }
    }
}

/// Number of 26-connected components of a mask.
pub fn count_components(grid: &Grid, mask: &[bool]) -> usize {
    let [nx, ny, nz] = grid.dims();
    let mut seen = vec![false; mask.len()];
    let mut count = 0;
    let mut queue = VecDeque::new();
    for start in 0..mask.len() {
        if !mask[start] || seen[start] {
            continue;
        }
        count += 1;
        seen[start] = true;
        queue.push_back(start);
        while let Some(idx) = queue.pop_front() {
            let [i, j, k] = grid.unlinear(idx);
            for dk in -1i64..=1 {
                for dj in -1i64..=1 {
                    for di in -1i64..=1 {
                        let (a, b, c) = (i as i64 + di, j as i64 + dj, k as i64 + dk);
                        if a < 0 || b < 0 || c < 0 || a >= nx as i64 || b >= ny as i64 || c >= nz as i64 {
                            continue;
                        }
                        let n = grid.linear(a as usize, b as usize, c as usize);
                        if mask[n] && !seen[n] {
                            seen[n] = true;
                            queue.push_back(n);
                        }
                    }
                }
            }
        }
    }
    count
}
