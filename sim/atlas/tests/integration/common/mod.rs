//! Helpers shared by the atlas tests: a tiny valid atlas to break in many ways, and the shared data.

use std::path::{Path, PathBuf};

use stylet_atlas::manifest::{Manifest, Provenance, ScenarioFile};
use stylet_physics::glam::DVec3;
use stylet_physics::{Affine, Grid, LabelId, Volume};

/// A 24 × 20 × 16 grid of 4 mm voxels.
pub fn tiny_grid() -> Grid {
    Grid::new(
        [24, 20, 16],
        Affine::from_spacing([4.0; 3], DVec3::new(-46.0, -38.0, -30.0)),
    )
    .unwrap()
}

/// An ellipsoidal "body" of soft tissue with fat, a bone rod and a liver block with a target duct.
pub fn tiny_volumes() -> (Volume<f32>, Volume<LabelId>) {
    let g = tiny_grid();
    let mut ct = Volume::filled(g, -1000.0f32);
    let mut labels = Volume::filled(g, 0 as LabelId);
    for k in 0..16 {
        for j in 0..20 {
            for i in 0..24 {
                let p = g.voxel_to_world(i, j, k);
                let r = (p.x / 44.0).powi(2) + (p.y / 34.0).powi(2);
                if r <= 1.0 {
                    ct.set(i, j, k, if r > 0.7 { -100.0 } else { 45.0 });
                }
                if (p.x + 20.0).abs() < 5.0 && (p.y + 10.0).abs() < 5.0 {
                    ct.set(i, j, k, 700.0);
                }
                if p.x > 0.0 && p.x < 30.0 && p.y.abs() < 16.0 {
                    ct.set(i, j, k, 60.0);
                    labels.set(i, j, k, 10);
                    if (p.x - 14.0).abs() < 4.0 && p.y.abs() < 4.0 {
                        ct.set(i, j, k, 10.0);
                        labels.set(i, j, k, 21);
                    }
                }
            }
        }
    }
    (ct, labels)
}

pub fn tiny_manifest() -> Manifest {
    let mut scenario = ScenarioFile::ptcd();
    scenario.labels.retain(|l| l.id <= 5 || l.id == 10 || l.id == 21);
    Manifest::new(
        "tiny",
        "a tiny test atlas",
        Provenance {
            source: "test".into(),
            generator: "test".into(),
            ..Default::default()
        },
        scenario,
    )
}

/// Writes the tiny atlas into `dir`.
pub fn write_tiny(dir: &Path) {
    let (ct, labels) = tiny_volumes();
    stylet_atlas::write(dir, &tiny_manifest(), &ct, &labels).unwrap();
}

/// The real CT data (`scripts/fetch-data`). Tests that need it fail, not skip, when it is missing.
pub fn shared_data() -> PathBuf {
    stylet_testkit::real_ct_data()
}

pub fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}
