//! The liver's vessel trees and the dilated biliary tree: fixed main trunks (portal vein, hepatic
//! veins, common bile duct, left and right hepatic ducts) and peripheral branches grown from the
//! seed inside the liver, clear of the planned insertion path. Each peripheral portal branch has a
//! companion bile duct (portal triad) that starts where its parent's companion ends, so the biliary
//! tree is one connected piece.

use std::f64::consts::PI;

use libm::{cos, sin};
use stylet_physics::glam::DVec3;

use super::anatomy::{Anatomy, Part, RHD};
use super::noise::Rng;
use super::shapes::Capsule;
use super::structures::{Structure, hu};

impl Anatomy {
    /// Portal and hepatic veins and the dilated biliary tree. Main trunks are fixed; peripheral
    /// branches are grown from the seed, inside the liver and clear of the planned insertion path.
    pub(super) fn liver_trees(&self) -> Vec<Part> {
        let lm = self.landmarks();
        let path = Capsule::new(lm.target, lm.intercostal_10_11, 0.0, 0.0);
        let mut parts = Vec::new();
        let seg = |s: Structure, v: f64, c: Capsule| Part {
            structure: s,
            hu: v,
            aabb: c.aabb(),
            sdf: Box::new(move |p| c.sdf(p)),
        };
        let cap = |a: [f64; 3], b: [f64; 3], ra: f64, rb: f64| {
            Capsule::new(DVec3::from_array(a), DVec3::from_array(b), ra, rb)
        };

        // Portal vein: main trunk to the hilum, right and left branches, right anterior/posterior.
        let pv_main = [
            cap([0.0, 28.0, -52.0], [14.0, 26.0, -25.0], 7.5, 7.2),
            cap([14.0, 26.0, -25.0], [24.0, 20.0, -5.0], 7.2, 7.0),
        ];
        let rpv = cap([24.0, 20.0, -5.0], [68.0, 6.0, 4.0], 6.0, 5.5);
        let rpv_ant = cap([68.0, 6.0, 4.0], [92.0, 30.0, 0.0], 4.5, 4.0);
        let rpv_post = cap([68.0, 6.0, 4.0], [98.0, -20.0, 12.0], 4.5, 4.0);
        let lpv = [
            cap([24.0, 20.0, -5.0], [-5.0, 28.0, 5.0], 5.5, 5.0),
            cap([-5.0, 28.0, 5.0], [-30.0, 36.0, 12.0], 5.0, 4.5),
        ];
        let mut pv: Vec<Capsule> = pv_main.iter().chain(&lpv).copied().collect();
        pv.extend([rpv, rpv_ant, rpv_post]);

        // Bile duct trunks: common bile duct from the lesion up to the hilum, left hepatic duct and
        // the right hepatic duct's anterior and posterior segmental ducts (the target comes last).
        let cbd = [
            cap([20.0, 35.0, -47.0], [26.0, 36.0, -25.0], 6.0, 6.0),
            cap([26.0, 36.0, -25.0], [30.0, 35.0, -2.0], 6.0, 5.5),
        ];
        let lhd = [
            cap([29.0, 35.0, 1.0], [-2.0, 42.0, 9.0], 4.2, 4.0),
            cap([-2.0, 42.0, 9.0], [-28.0, 48.0, 15.0], 4.0, 3.2),
        ];
        let seg_ducts = [
            cap(RHD.1.to_array(), [93.0, 46.0, 8.0], 3.4, 3.0),
            cap(RHD.1.to_array(), [99.0, -4.0, 18.0], 3.4, 3.0),
        ];

        // Peripheral portal branches, each with a companion bile duct (portal triads) that starts
        // where its parent's companion ends, so the biliary tree stays one connected piece.
        let mut rng = Rng::new(self.seed, 0x7EE5);
        let inside = |p: DVec3| self.liver_sdf(p);
        let mut duct_branches = Vec::new();
        let mut pv_branches = Vec::new();
        for (root, duct_root) in [(rpv_ant, seg_ducts[0]), (rpv_post, seg_ducts[1]), (lpv[1], lhd[1])] {
            let dir = (root.b - root.a).normalize();
            let mut tree = Vec::new();
            grow(
                &mut rng,
                root.b,
                dir,
                28.0,
                root.rb * 0.8,
                2,
                &inside,
                &path,
                None,
                &mut tree,
            );
            let mut duct_end: Vec<Option<(DVec3, f64)>> = Vec::with_capacity(tree.len());
            for b in &tree {
                let c = b.capsule;
                let start = match b.parent {
                    None => Some((duct_root.b, duct_root.rb)),
                    Some(p) => duct_end[p],
                };
                let companion = start.and_then(|(a, ra)| {
                    let axis = (c.b - c.a).normalize();
                    let anterior = (DVec3::Y - axis * axis.y).normalize_or_zero();
                    let rb = (c.rb * 0.6).max(1.0);
                    let d = Capsule::new(a, c.b + anterior * (c.rb + rb + 1.5), ra.min((c.ra * 0.6).max(1.2)), rb);
                    let ok = inside(d.b) < -(d.rb + 1.0) && segment_distance(&d, &path) > 6.0;
                    ok.then_some(d)
                });
                duct_end.push(companion.map(|d| (d.b, d.rb)));
                duct_branches.extend(companion);
            }
            pv_branches.extend(tree.iter().map(|b| b.capsule));
        }
        pv.extend(pv_branches);

        // Hepatic veins into the IVC below the heart, with grown branches.
        let hv_trunks = [
            [
                cap([26.0, 0.0, 80.0], [70.0, -15.0, 55.0], 6.5, 5.5),
                cap([70.0, -15.0, 55.0], [112.0, -20.0, 25.0], 5.5, 4.0),
            ],
            [
                cap([20.0, 8.0, 82.0], [35.0, 40.0, 50.0], 6.0, 5.0),
                cap([35.0, 40.0, 50.0], [45.0, 65.0, 12.0], 5.0, 3.5),
            ],
            [
                cap([12.0, 8.0, 82.0], [-10.0, 30.0, 65.0], 5.5, 4.5),
                cap([-10.0, 30.0, 65.0], [-35.0, 45.0, 45.0], 4.5, 3.5),
            ],
        ];
        let mut hv: Vec<Capsule> = hv_trunks.iter().flatten().copied().collect();
        let mut hv_branches = Vec::new();
        for t in &hv_trunks {
            let root = t[1];
            grow(
                &mut rng,
                root.b,
                (root.b - root.a).normalize(),
                24.0,
                root.rb * 0.8,
                2,
                &inside,
                &path,
                None,
                &mut hv_branches,
            );
            let mid = (t[0].a + t[0].b) * 0.5;
            let side = (t[0].b - t[0].a).normalize().cross(DVec3::Z).normalize_or_zero();
            grow(
                &mut rng,
                mid,
                (side - DVec3::Z * 0.5).normalize(),
                22.0,
                3.0,
                1,
                &inside,
                &path,
                None,
                &mut hv_branches,
            );
        }
        hv.extend(hv_branches.iter().map(|b| b.capsule));

        let target = Capsule::new(RHD.0, RHD.1, 4.5, 4.5);

        for c in pv {
            parts.push(seg(Structure::PortalVein, hu::PORTAL_VEIN, c));
        }
        for c in hv {
            parts.push(seg(Structure::HepaticVein, hu::HEPATIC_VEIN, c));
        }
        for c in cbd.into_iter().chain(lhd).chain(seg_ducts).chain(duct_branches) {
            parts.push(seg(Structure::BileDuct, hu::BILE, c));
        }
        parts.push(seg(Structure::TargetDuct, hu::BILE, target));
        parts
    }
}

/// Smallest distance between a capsule's axis and a segment (sampled, good to 0.5 mm).
fn segment_distance(c: &Capsule, path: &Capsule) -> f64 {
    let n = 24;
    (0..=n)
        .map(|i| {
            let p = c.a + (c.b - c.a) * (i as f64 / n as f64);
            path.sdf(p) - c.ra.max(c.rb)
        })
        .fold(f64::INFINITY, f64::min)
}

/// One grown vessel segment and the segment it branches from (`None` for a root).
#[derive(Debug, Clone, Copy)]
struct Branch {
    capsule: Capsule,
    parent: Option<usize>,
}

/// Grows a binary branching tree from `start` along `dir` inside the region where `inside` < 0,
/// keeping every branch at least 6 mm from the planned insertion path.
#[allow(clippy::too_many_arguments)]
fn grow(
    rng: &mut Rng,
    start: DVec3,
    dir: DVec3,
    len: f64,
    radius: f64,
    depth: u32,
    inside: &dyn Fn(DVec3) -> f64,
    path: &Capsule,
    parent: Option<usize>,
    out: &mut Vec<Branch>,
) {
    if radius < 1.2 {
        return;
    }
    let mut l = len;
    for _ in 0..3 {
        let end = start + dir * l;
        let c = Capsule::new(start, end, radius, radius * 0.85);
        if inside(end) < -(radius + 2.0) && segment_distance(&c, path) > 6.0 {
            out.push(Branch { capsule: c, parent });
            let me = Some(out.len() - 1);
            if depth > 0 {
                for k in 0..2 {
                    let angle = rng.range(0.4, 0.75) * if k == 0 { 1.0 } else { -1.0 };
                    let child = rotate_about_random_axis(rng, dir, angle);
                    let child_len = len * rng.range(0.6, 0.8);
                    grow(
                        rng,
                        end,
                        child,
                        child_len,
                        radius * 0.72,
                        depth - 1,
                        inside,
                        path,
                        me,
                        out,
                    );
                }
            }
            return;
        }
        l *= 0.6;
    }
}

/// Rotates `dir` by `angle` about an axis perpendicular to it, the axis chosen at random.
fn rotate_about_random_axis(rng: &mut Rng, dir: DVec3, angle: f64) -> DVec3 {
    let helper = if dir.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
    let u = dir.cross(helper).normalize();
    let w = dir.cross(u);
    let spin = rng.range(0.0, 2.0 * PI);
    let axis = u * cos(spin) + w * sin(spin);
    // Rodrigues' rotation of dir about an axis perpendicular to it.
    (dir * cos(angle) + axis.cross(dir) * sin(angle)).normalize()
}
