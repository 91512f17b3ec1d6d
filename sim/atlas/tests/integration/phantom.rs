//! The procedural phantom: heuristic against ground truth, determinism, anatomy sanity.

use std::collections::BTreeMap;
use std::sync::OnceLock;

use stylet_atlas::import::biliary::count_components;
use stylet_atlas::phantom::structures::Structure;
use stylet_atlas::phantom::{Phantom, PhantomConfig, generate};
use stylet_physics::HeuristicClass;
use stylet_physics::glam::DVec3;
use stylet_physics::thresholds::estimate_thresholds;

/// The default phantom, generated once for all tests of this file.
fn phantom() -> &'static Phantom {
    static P: OnceLock<Phantom> = OnceLock::new();
    P.get_or_init(|| generate(&PhantomConfig::default()).unwrap())
}

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
/// label, and on ≥ 95 % of those inside the body. Per-class agreement is printed; air, fat and bone
/// must each reach 95 %. Skin cannot: only the part of the surface layer whose partial volume puts
/// it between the air and fat thresholds is skin (about a fifth of it at 1.5 mm) by eq. 6.1.1 (the
/// threshold stays far below fat so that deep fat never becomes a risk).
#[test]
fn heuristic_agrees_with_ground_truth() {
    let p = phantom();
    let t = estimate_thresholds(&p.ct, 15.0).unwrap();
    let truth = truth_classes(p);
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

/// Same config, same bits, whatever the thread count; another seed changes noise and branches.
#[test]
fn generation_is_deterministic() {
    let config = PhantomConfig {
        dims: [64, 64, 50],
        spacing_mm: [6.0; 3],
        ..PhantomConfig::default()
    };
    let run = |threads: usize, config: PhantomConfig| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| generate(&config).unwrap())
    };
    let a = run(1, config);
    let b = run(2, config);
    let bits = |p: &Phantom| p.ct.data().iter().map(|v| v.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&a), bits(&b));
    assert_eq!(a.partial.data(), b.partial.data());
    assert_eq!(a.truth.data(), b.truth.data());
    let c = run(2, PhantomConfig { seed: 2, ..config });
    assert_ne!(bits(&a), bits(&c));
}

/// The atlas ships only the partial labels of Table A.2; skin, fat, bone and air are not labelled.
#[test]
fn only_table_a2_structures_are_labelled() {
    let p = phantom();
    let mut ids: Vec<u16> = p.partial.data().to_vec();
    ids.sort_unstable();
    ids.dedup();
    assert_eq!(ids, [0, 10, 11, 12, 13, 14, 20, 21, 30, 40, 41]);
    for (&l, &t) in p.partial.data().iter().zip(p.truth.data()) {
        let s = Structure::from_u8(t).unwrap();
        if matches!(
            s,
            Structure::Skin | Structure::Fat | Structure::Rib | Structure::Vertebra | Structure::Air
        ) {
            assert_eq!(l, 0, "{s:?} carries label {l}");
        }
    }
}

/// Realistic HU per tissue (mean over the ground truth): within the ranges radiology books give.
#[test]
fn tissue_values_are_realistic() {
    let p = phantom();
    let mut sums: BTreeMap<u8, (f64, u64)> = BTreeMap::new();
    for (&v, &t) in p.ct.data().iter().zip(p.truth.data()) {
        let e = sums.entry(t).or_default();
        e.0 += v as f64;
        e.1 += 1;
    }
    let mean = |s: Structure| {
        let (a, n) = sums[&(s as u8)];
        a / n as f64
    };
    let expect = [
        (Structure::Air, -1010.0, -980.0),
        (Structure::Fat, -120.0, -60.0),
        (Structure::Muscle, 30.0, 70.0),
        (Structure::Liver, 80.0, 120.0),
        (Structure::PortalVein, 110.0, 170.0),
        (Structure::TargetDuct, -10.0, 50.0),
        (Structure::LungRight, -900.0, -700.0),
        (Structure::Rib, 200.0, 900.0),
        (Structure::Vertebra, 200.0, 900.0),
    ];
    for (s, lo, hi) in expect {
        let m = mean(s);
        assert!(m > lo && m < hi, "{s:?}: mean {m:.0} HU outside {lo} … {hi}");
    }
}

/// The biliary tree is one connected piece, dilated (the target duct is at least 8 mm wide), and
/// the target lies inside the liver.
#[test]
fn biliary_tree_is_connected_and_inside_the_liver() {
    let p = phantom();
    let g = *p.partial.grid();
    let tree: Vec<bool> = p.partial.data().iter().map(|&l| l == 20 || l == 21).collect();
    assert_eq!(count_components(&g, &tree), 1);
    let target = p.partial.data().iter().filter(|&&l| l == 21).count() as f64;
    let ml = target * 1.5f64.powi(3) / 1000.0;
    assert!(ml > 1.5, "target volume {ml} ml");
    // Every target voxel has liver or duct tissue around it within 6 mm (it is embedded in liver).
    let centre = p.manifest.paths[0].target_mm;
    let c = DVec3::from_array(centre);
    let [i, j, k] = g.nearest_voxel(c).unwrap();
    assert_eq!(
        p.partial.get(i, j, k),
        21,
        "the path's target point lies in the target label"
    );
    let mut liver_around = 0;
    for d in [DVec3::X, DVec3::NEG_X, DVec3::Y, DVec3::NEG_Y, DVec3::Z, DVec3::NEG_Z] {
        if p.partial.nearest(c + d * 9.0, 0) == 10 {
            liver_around += 1;
        }
    }
    assert!(
        liver_around >= 4,
        "liver around the target in {liver_around} of 6 directions"
    );
}

/// The predefined path runs from the skin, through the intercostal fascia (between two ribs),
/// through the liver to the target without touching bone or any risk structure.
#[test]
fn intercostal_path_avoids_bone_and_risk_structures() {
    let p = phantom();
    let path = &p.manifest.paths[0];
    assert_eq!(path.name, "intercostal-10-11");
    let (a, b) = (DVec3::from_array(path.entry_mm), DVec3::from_array(path.target_mm));
    let risk = [11u16, 12, 13, 14, 40, 41];
    let mut seen = Vec::new();
    let n = (a.distance(b) / 0.25) as usize;
    for s in 0..=n {
        let x = a + (b - a) * (s as f64 / n as f64);
        let truth = Structure::from_u8(p.truth.nearest(x, 0)).unwrap();
        assert!(
            !matches!(truth, Structure::Rib | Structure::Vertebra | Structure::Cartilage),
            "bone at {x}"
        );
        let l = p.partial.nearest(x, 0);
        assert!(!risk.contains(&l), "risk label {l} at {x}");
        if seen.last() != Some(&truth) {
            seen.push(truth);
        }
    }
    assert!(
        matches!(seen[0], Structure::Air | Structure::Skin),
        "starts on the skin: {seen:?}"
    );
    for s in [
        Structure::Skin,
        Structure::Fat,
        Structure::Muscle,
        Structure::Fascia,
        Structure::Liver,
    ] {
        assert!(seen.contains(&s), "crosses {s:?}: {seen:?}");
    }
    assert_eq!(*seen.last().unwrap(), Structure::TargetDuct, "{seen:?}");
    // Ribs lie above and below the crossing of the rib layer (just outside the fascia, within
    // 30 mm cranially and caudally): the path goes through an intercostal space.
    let points: Vec<DVec3> = (0..=n).map(|s| a + (b - a) * (s as f64 / n as f64)).collect();
    let fascia = points
        .iter()
        .position(|x| p.truth.nearest(*x, 0) == Structure::Fascia as u8)
        .unwrap();
    let rib_layer = points[fascia.saturating_sub((5.0 / 0.25) as usize)];
    let rib_at = |dz: f64| {
        (1..=60).any(|m| p.truth.nearest(rib_layer + DVec3::Z * dz * m as f64 * 0.5, 0) == Structure::Rib as u8)
    };
    assert!(rib_at(1.0) && rib_at(-1.0), "ribs above and below {rib_layer}");
}

/// Golden digest of a small phantom's voxels. Sessions record the atlas content hash, and the
/// embedded phantom is regenerated on every machine, so its bytes must not drift between builds,
/// compilers or CPUs (libm for transcendentals, counter-based noise, fixed summation orders). Change
/// the constant only on purpose, when the anatomy changes, and say so in the commit.
#[test]
fn small_phantom_matches_its_golden_digest() {
    use sha2::{Digest, Sha256};
    let p = generate(&PhantomConfig {
        dims: [64, 64, 50],
        spacing_mm: [6.0; 3],
        ..PhantomConfig::default()
    })
    .unwrap();
    let mut h = Sha256::new();
    for v in p.ct.data() {
        h.update(v.to_le_bytes());
    }
    for l in p.partial.data() {
        h.update(l.to_le_bytes());
    }
    let digest: String = h.finalize().iter().map(|b| format!("{b:02x}")).collect();
    assert_eq!(digest, GOLDEN_SMALL_PHANTOM, "the phantom's voxels changed");
}

const GOLDEN_SMALL_PHANTOM: &str = "f04b7521497825f79816a6f47e96edbea79d88aea48531303c9507bdd14e4c2a";
