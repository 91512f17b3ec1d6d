//! The procedural phantom: heuristic against ground truth, determinism, anatomy sanity.

use std::collections::BTreeMap;

use stylet_atlas::phantom::structures::Structure;
use stylet_atlas::phantom::{PhantomConfig, generate};
use stylet_physics::HeuristicClass;
use stylet_physics::thresholds::estimate_thresholds;

/// Ground-truth heuristic class of every voxel without a partial label. The thesis' "skin" class
/// (eq. 6.1.1: CT values between air and fat near the surface) is the body's surface voxel layer,
/// where air and tissue share a voxel; dermis deeper than that layer looks like soft tissue on CT
/// and counts as soft tissue / fat, as in Table A.2.
fn truth_classes(p: &stylet_atlas::phantom::Phantom) -> Vec<Option<HeuristicClass>> {
    let grid = *p.truth.grid();
    let [nx, ny, nz] = grid.dims();
    let t = p.truth.data();
    (0..grid.len())
        .map(|idx| {
            let s = Structure::from_u8(t[idx]).unwrap();
            let class = s.truth_class()?;
            if s != Structure::Skin {
                return Some(class);
            }
            let [i, j, k] = grid.unlinear(idx);
            let air = Structure::Air as u8;
            let surface = (i > 0 && t[idx - 1] == air)
                || (i + 1 < nx && t[idx + 1] == air)
                || (j > 0 && t[idx - nx] == air)
                || (j + 1 < ny && t[idx + nx] == air)
                || (k > 0 && t[idx - nx * ny] == air)
                || (k + 1 < nz && t[idx + nx * ny] == air);
            Some(if surface {
                HeuristicClass::Skin
            } else {
                HeuristicClass::Fat
            })
        })
        .collect()
}

/// On the phantom the heuristic h(x, 0), with thresholds estimated from the CT histogram, agrees
/// with the ground truth for skin / fat / bone / air on ≥ 95 % of the voxels that carry no partial
/// label (issue acceptance), and on ≥ 95 % of those inside the body. Per-class agreement is
/// printed for the issue note; air, fat and bone must each reach 95 %. Skin cannot: only the part
/// of the surface layer whose partial volume puts it between the air and fat thresholds is skin
/// (about a fifth of it at 1.5 mm)
/// by eq. 6.1.1 (the threshold stays far below fat so that deep fat never becomes a risk).
#[test]
fn heuristic_agrees_with_ground_truth() {
    let p = generate(&PhantomConfig::default()).unwrap();
    let t = estimate_thresholds(&p.ct, 15.0).unwrap();
    let truth = truth_classes(&p);
    let mut per_class: BTreeMap<HeuristicClass, (u64, u64)> = BTreeMap::new();
    let mut confusion: BTreeMap<(HeuristicClass, HeuristicClass), u64> = BTreeMap::new();
    let (mut body_ok, mut body_all) = (0u64, 0u64);
    for ((&hu, &s), truth) in p.ct.data().iter().zip(p.truth.data()).zip(&truth) {
        let Some(truth) = *truth else { continue };
        let got = t.classify(hu as f64, 0.0);
        let e = per_class.entry(truth).or_default();
        e.1 += 1;
        e.0 += u64::from(got == truth);
        *confusion.entry((truth, got)).or_default() += 1;
        if s != Structure::Air as u8 {
            body_all += 1;
            body_ok += u64::from(got == truth);
        }
    }
    let (ok, all) = per_class.values().fold((0, 0), |(a, b), (c, d)| (a + c, b + d));
    let overall = ok as f64 / all as f64;
    let body = body_ok as f64 / body_all as f64;
    println!("thresholds {t:?}");
    for (c, (o, n)) in &per_class {
        println!(
            "{:>5}: {:6.2} % of {n} voxels",
            c.as_str(),
            100.0 * *o as f64 / *n as f64
        );
    }
    println!("confusion (truth, heuristic) → voxels: {confusion:?}");
    println!(
        "overall {:.2} %, inside the body {:.2} %",
        100.0 * overall,
        100.0 * body
    );
    assert!(overall >= 0.95, "overall agreement {overall}");
    assert!(body >= 0.95, "agreement inside the body {body}");
    for c in [HeuristicClass::Air, HeuristicClass::Fat, HeuristicClass::Bone] {
        let (o, n) = per_class[&c];
        assert!(o as f64 >= 0.95 * n as f64, "{} agreement {o}/{n}", c.as_str());
    }
    let (o, n) = per_class[&HeuristicClass::Skin];
    assert!(o as f64 >= 0.15 * n as f64, "skin agreement {o}/{n}");
}
