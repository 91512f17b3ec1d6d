//! The phantom's organs, great vessels and spine as painted parts (signed distances, HU), in
//! painting order; the liver's vessels and ducts come from [`super::liver_trees`].

use libm::sqrt;
use stylet_physics::glam::DVec3;

use super::anatomy::{Anatomy, Part, sq};
use super::noise::Rng;
use super::shapes::{Aabb, Capsule, Ellipsoid, Tube};
use super::structures::{Structure, hu};

impl Anatomy {
    /// All organs, vessels and ducts in painting order (later parts cover earlier ones).
    pub fn parts(&self) -> Vec<Part> {
        let mut parts: Vec<Part> = Vec::new();
        let me = self.clone();
        // Abdominal organs stay inside the cavity and below the diaphragm.
        let abdominal = |shape: Ellipsoid| {
            let a = me.clone();
            move |p: DVec3| {
                shape
                    .sdf(p)
                    .max(a.cavity_sdf(p))
                    .max(p.z - (a.diaphragm_z(p.x, p.y) - 4.0))
            }
        };
        let ell = |s: Structure, v: f64, c: [f64; 3], r: [f64; 3]| {
            let e = Ellipsoid::new(c, r);
            Part {
                structure: s,
                hu: v,
                aabb: e.aabb(),
                sdf: Box::new(abdominal(e)),
            }
        };
        let tube = |s: Structure, v: f64, pts: &[[f64; 3]], r: &[f64]| {
            let t = Tube::new(pts, r);
            Part {
                structure: s,
                hu: v,
                aabb: t.aabb(),
                sdf: Box::new(move |p| t.sdf(p)),
            }
        };

        // Psoas muscles first (organs may press on them); the erector spinae is part of the wall.
        for side in [-1.0, 1.0] {
            let psoas = Tube::new(
                &[[40.0 * side, -22.0, -10.0], [48.0 * side, -20.0, -160.0]],
                &[6.0, 20.0],
            );
            parts.push(Part {
                structure: Structure::Muscle,
                hu: hu::MUSCLE,
                aabb: psoas.aabb(),
                sdf: Box::new(move |p| psoas.sdf(p)),
            });
        }

        // Liver first among the abdominal organs: its neighbours carve into it.
        let a = self.clone();
        parts.push(Part {
            structure: Structure::Liver,
            hu: hu::LIVER,
            aabb: Aabb::new(DVec3::new(-80.0, -65.0, -75.0), DVec3::new(160.0, 120.0, 100.0)),
            sdf: Box::new(move |p| a.liver_sdf(p)),
        });
        // Gallbladder (wall, then bile) on the liver's inferior surface.
        parts.push(ell(
            Structure::Gallbladder,
            hu::GALLBLADDER_WALL,
            [52.0, 55.0, -35.0],
            [15.0, 18.0, 36.0],
        ));
        parts.push(ell(
            Structure::Gallbladder,
            hu::BILE,
            [52.0, 55.0, -35.0],
            [13.0, 16.0, 34.0],
        ));
        // Kidneys with renal sinus fat.
        for (x, z) in [(75.0, -45.0), (-75.0, -32.0)] {
            parts.push(ell(Structure::Kidney, hu::KIDNEY, [x, -42.0, z], [28.0, 24.0, 52.0]));
            parts.push(ell(
                Structure::Fat,
                hu::RENAL_SINUS,
                [x * 0.92, -38.0, z],
                [10.0, 9.0, 22.0],
            ));
        }
        parts.push(ell(
            Structure::Spleen,
            hu::SPLEEN,
            [-105.0, -35.0, 35.0],
            [28.0, 42.0, 50.0],
        ));
        // Stomach: wall, content, gas rising anteriorly in a supine patient.
        parts.push(ell(
            Structure::Stomach,
            hu::STOMACH_WALL,
            [-75.0, 20.0, 28.0],
            [38.0, 42.0, 50.0],
        ));
        parts.push(ell(
            Structure::Stomach,
            hu::STOMACH_CONTENT,
            [-75.0, 20.0, 28.0],
            [34.0, 38.0, 46.0],
        ));
        {
            let inner = Ellipsoid::new([-75.0, 20.0, 28.0], [34.0, 38.0, 46.0]);
            parts.push(Part {
                structure: Structure::Gas,
                hu: hu::AIR,
                aabb: inner.aabb(),
                sdf: Box::new(move |p| inner.sdf(p).max(40.0 - p.y)),
            });
        }
        // Pancreas with the lesion in its head, duodenal C-loop around it.
        parts.push(tube(
            Structure::Pancreas,
            hu::PANCREAS,
            &[[22.0, 34.0, -62.0], [-20.0, 30.0, -45.0], [-85.0, -5.0, -25.0]],
            &[17.0, 12.0, 10.0],
        ));
        parts.push(tube(
            Structure::Duodenum,
            hu::DUODENUM,
            &[
                [5.0, 58.0, -40.0],
                [48.0, 34.0, -52.0],
                [50.0, 28.0, -90.0],
                [5.0, 18.0, -98.0],
                [-22.0, 22.0, -82.0],
            ],
            &[11.0, 12.0, 12.0, 11.0, 10.0],
        ));
        // Colon: ascending, hepatic flexure, transverse, splenic flexure, descending; stool below,
        // gas above (anterior) the centre line.
        let colon_pts = [
            [95.0, -5.0, -160.0],
            [95.0, 5.0, -88.0],
            [70.0, 45.0, -82.0],
            [-70.0, 50.0, -92.0],
            [-100.0, 20.0, -62.0],
            [-100.0, -10.0, -160.0],
        ];
        let colon_r = [20.0, 22.0, 22.0, 21.0, 20.0, 19.0];
        parts.push(tube(Structure::Colon, hu::COLON_WALL, &colon_pts, &colon_r));
        let inner_r: Vec<f64> = colon_r.iter().map(|r| r - 3.0).collect();
        parts.push(tube(Structure::Colon, hu::STOOL, &colon_pts, &inner_r));
        {
            let t = Tube::new(&colon_pts, &inner_r);
            parts.push(Part {
                structure: Structure::Gas,
                hu: hu::AIR,
                aabb: t.aabb(),
                sdf: Box::new(move |p| {
                    let mut best = (f64::INFINITY, 0.0);
                    for c in &t.segments {
                        let (d, tt) = c.sdf_t(p);
                        if d < best.0 {
                            best = (d, c.a.y + tt * (c.b.y - c.a.y));
                        }
                    }
                    best.0.max(best.1 + 4.0 - p.y)
                }),
            });
        }
        // Small bowel loops in the lower abdomen.
        let mut rng = Rng::new(self.seed, 0xB0E1);
        for _ in 0..7 {
            let c = [rng.range(-70.0, 60.0), rng.range(0.0, 60.0), rng.range(-150.0, -105.0)];
            let pts = [
                [
                    c[0] - 30.0,
                    c[1] + rng.range(-10.0, 10.0),
                    c[2] + rng.range(-10.0, 10.0),
                ],
                c,
                [
                    c[0] + 30.0,
                    c[1] + rng.range(-10.0, 10.0),
                    c[2] + rng.range(-10.0, 10.0),
                ],
            ];
            let t = Tube::new(&pts, &[11.0, 11.0, 11.0]);
            let a = self.clone();
            parts.push(Part {
                structure: Structure::Bowel,
                hu: hu::BOWEL,
                aabb: t.aabb(),
                sdf: Box::new(move |p| t.sdf(p).max(a.cavity_sdf(p))),
            });
        }
        // Heart above the diaphragm's central part.
        {
            let e = Ellipsoid::new([-15.0, 35.0, 120.0], [55.0, 45.0, 55.0]);
            let a = self.clone();
            parts.push(Part {
                structure: Structure::Heart,
                hu: hu::HEART,
                aabb: e.aabb(),
                sdf: Box::new(move |p| e.sdf(p).max(a.cavity_sdf(p))),
            });
        }

        // The spine over the posterior organs, the great vessels in front of it.
        parts.extend(self.spine());
        // Great vessels.
        parts.push(tube(
            Structure::Aorta,
            hu::AORTA,
            &[
                [-15.0, 2.0, -160.0],
                [-18.0, 0.0, 40.0],
                [-25.0, -8.0, 80.0],
                [-26.0, -10.0, 160.0],
            ],
            &[11.0, 11.5, 12.0, 12.0],
        ));
        parts.push(tube(
            Structure::VenaCava,
            hu::VENA_CAVA,
            &[
                [22.0, 0.0, -160.0],
                [24.0, 2.0, 40.0],
                [22.0, -2.0, 95.0],
                [5.0, 25.0, 115.0],
            ],
            &[10.0, 10.0, 11.0, 12.0],
        ));
        // Lesion in the pancreatic head, obstructing the distal common bile duct.
        parts.push(ell(
            Structure::Lesion,
            hu::LESION,
            [20.0, 35.0, -60.0],
            [14.0, 13.0, 14.0],
        ));

        // Liver vessels and the dilated biliary tree.
        parts.extend(self.liver_trees());
        parts
    }

    /// Vertebrae (cortex, cancellous bone, processes), discs and the spinal canal.
    fn spine(&self) -> Vec<Part> {
        let mut parts = Vec::new();
        let pitch = 32.0;
        let body_h = 25.0;
        let mut zc = -160.0;
        while zc < 170.0 {
            let (z0, z1) = (zc - body_h / 2.0, zc + body_h / 2.0);
            let body = move |p: DVec3, inset: f64| {
                let radial = sqrt(sq(p.x / (22.0 - inset)) + sq((p.y + 30.0) / (17.0 - inset)));
                let r = (radial - 1.0) * (17.0 - inset);
                r.max(z0 + inset - p.z).max(p.z - z1 + inset)
            };
            let aabb = Aabb::new(DVec3::new(-23.0, -48.0, z0), DVec3::new(23.0, -12.0, z1));
            parts.push(Part {
                structure: Structure::Vertebra,
                hu: hu::VERTEBRA_CORTEX,
                aabb,
                sdf: Box::new(move |p| body(p, 0.0)),
            });
            parts.push(Part {
                structure: Structure::Vertebra,
                hu: hu::CANCELLOUS,
                aabb,
                sdf: Box::new(move |p| body(p, 1.8)),
            });
            let processes = [
                // pedicles, laminae, spinous process, transverse processes
                ([12.0, -40.0, zc], [12.0, -54.0, zc], 5.0),
                ([-12.0, -40.0, zc], [-12.0, -54.0, zc], 5.0),
                ([12.0, -56.0, zc], [0.0, -68.0, zc - 3.0], 4.0),
                ([-12.0, -56.0, zc], [0.0, -68.0, zc - 3.0], 4.0),
                ([0.0, -66.0, zc - 3.0], [0.0, -84.0, zc - 10.0], 5.0),
                ([14.0, -46.0, zc], [44.0, -50.0, zc + 2.0], 4.5),
                ([-14.0, -46.0, zc], [-44.0, -50.0, zc + 2.0], 4.5),
            ];
            for (a, b, r) in processes {
                let c = Capsule::new(DVec3::from_array(a), DVec3::from_array(b), r, r);
                parts.push(Part {
                    structure: Structure::Vertebra,
                    hu: hu::MARROW + 150.0,
                    aabb: c.aabb(),
                    sdf: Box::new(move |p| c.sdf(p)),
                });
            }
            let (d0, d1) = (z1, z1 + pitch - body_h);
            let disc = move |p: DVec3| {
                let radial = sqrt(sq(p.x / 21.0) + sq((p.y + 30.0) / 16.0));
                ((radial - 1.0) * 16.0).max(d0 - p.z).max(p.z - d1)
            };
            parts.push(Part {
                structure: Structure::Disc,
                hu: hu::DISC,
                aabb: Aabb::new(DVec3::new(-22.0, -47.0, d0), DVec3::new(22.0, -13.0, d1)),
                sdf: Box::new(disc),
            });
            zc += pitch;
        }
        let canal = Capsule::new(DVec3::new(0.0, -55.0, -200.0), DVec3::new(0.0, -55.0, 200.0), 9.0, 9.0);
        parts.push(Part {
            structure: Structure::SpinalCord,
            hu: hu::CSF,
            aabb: canal.aabb(),
            sdf: Box::new(move |p| canal.sdf(p)),
        });
        let cord = Capsule::new(DVec3::new(0.0, -55.0, -200.0), DVec3::new(0.0, -55.0, 200.0), 5.5, 5.5);
        parts.push(Part {
            structure: Structure::SpinalCord,
            hu: hu::CORD,
            aabb: cord.aabb(),
            sdf: Box::new(move |p| cord.sdf(p)),
        });
        parts
    }
}
