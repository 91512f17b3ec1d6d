//! The consequences of a wrong puncture (docs/complications.md), end to end: the phantom's
//! scripts recorded, replayed (verified) and scored; what the physics let out is reported with
//! the metrics and marked on the review's timeline, and the views draw it where a clinician
//! looks: a haematoma on the live ultrasound, a pneumothorax on the X-ray.

use stylet_physics::complications::{ComplicationKind, Site};
use stylet_physics::glam::DVec3;
use stylet_recorder::reader;
use stylet_render::consequences::{fluid_collections, xray_voxels};
use stylet_render::xray::attenuation::{MU_WATER_PER_MM, water_relative};
use stylet_scoring::consequences::{ConsequenceKind, ConsequenceRecord};
use stylet_scoring::rubric::Rubric;
use stylet_scoring::score::{ScoreReport, Scorer};
use stylet_scoring::trace::ReviewTrace;

use crate::common::{default_phantom, phantom_script_text, record_script};

/// The phantom's script `name` (its text changed by `edit`) recorded, replayed and scored with
/// its review trace.
fn scored(name: &str, edit: impl Fn(String) -> String) -> (ScoreReport, ReviewTrace) {
    let atlas = default_phantom();
    let d = tempfile::tempdir().unwrap();
    let path = record_script(
        atlas,
        d.path(),
        name,
        "beginner",
        &edit(phantom_script_text(&format!("{name}.txt"))),
    );
    let session = reader::verify(&path).unwrap();
    let (r, trace) = Scorer::new(atlas, Rubric::default_rubric(), None)
        .unwrap()
        .score_session_traced(&session)
        .unwrap();
    assert!(r.replay_verified, "{name}: {:?}", r.divergence);
    println!("{name}: {:?}", r.metrics.consequences);
    (r, trace)
}

fn only(r: &ScoreReport) -> &ConsequenceRecord {
    assert_eq!(r.metrics.consequences.len(), 1, "{:?}", r.metrics.consequences);
    &r.metrics.consequences[0]
}

#[test]
fn an_18_gauge_needle_through_the_portal_vein_grows_a_haematoma_and_a_22_gauge_one_does_not() {
    let (r, trace) = scored("vessel-hit", |t| t);
    let c = only(&r);
    assert_eq!(
        (c.kind, c.structure.as_str()),
        (ConsequenceKind::Haematoma, "portal vein")
    );
    // The hole bleeds from the tick it is made (the first leak update, ≤ 10 ms later) …
    let hit = r
        .metrics
        .risk_hits
        .iter()
        .find(|h| h.structure == "portal vein")
        .unwrap();
    assert!((c.punctured_s - hit.t_s).abs() < 0.01, "{c:?} {hit:?}");
    assert!(c.began_s - c.punctured_s <= 0.01, "{c:?}");
    // … about a millilitre a second, slowing as it clots: 8 s later, 5 to 9 ml.
    assert!((5.0..9.0).contains(&c.volume_ml), "{c:?}");
    let marked = trace
        .events
        .iter()
        .find(|e| e.kind == "complication")
        .expect("a timeline mark");
    assert_eq!(marked.t_s, c.began_s);
    assert_eq!(marked.label, "haematoma began: portal vein");
    // A fine (22 G) needle crosses the same vein with impunity: the hit counts, nothing bleeds.
    let (fine, trace) = scored("vessel-hit", |t| t.replace("gauge 18", "gauge 22"));
    assert!(fine.metrics.risk_hits.iter().any(|h| h.structure == "portal vein"));
    assert!(fine.metrics.consequences.is_empty(), "{:?}", fine.metrics.consequences);
    assert!(!trace.events.iter().any(|e| e.kind == "complication"));
}

#[test]
fn a_lung_hit_lets_air_into_the_pleural_space_once_and_a_duct_leaks_bile_once_the_needle_is_out() {
    let (r, _) = scored("lung-hit", |t| t);
    let c = only(&r);
    assert_eq!(
        (c.kind, c.structure.as_str()),
        (ConsequenceKind::Pneumothorax, "right lung")
    );
    // One hole: withdrawing back through the lung cuts no second one. Air comes fast, then
    // the hole closes (10 s): tens of millilitres to a few hundred.
    assert!((30.0..400.0).contains(&c.volume_ml), "{c:?}");
    let (r, _) = scored("success-intercostal", |t| t);
    let c = only(&r);
    assert_eq!(c.kind, ConsequenceKind::BileLeak);
    // The needle in the duct plugs its hole: bile leaks only after the withdrawal (from 14 s).
    assert!(c.punctured_s < 11.0 && c.began_s > 14.0, "{c:?}");
    assert!(c.volume_ml > 0.0);
}

/// A pneumothorax of 100 ml in the phantom's right lung: its outer layers turn to air (the
/// X-ray's μ falls by exactly the air's volume of lung), the lung they held lies on the layers
/// beneath (nothing is lost), and nothing changes outside the lung.
#[test]
fn a_pneumothorax_on_the_xray_is_air_at_the_lungs_surface_and_the_lung_it_pushed_in() {
    let atlas = default_phantom();
    let lung = atlas
        .model
        .label_table()
        .labels()
        .iter()
        .find(|l| l.name == "right lung")
        .unwrap()
        .id;
    let site = Site {
        kind: ComplicationKind::Pneumothorax,
        label: lung,
        began_tick: 0,
        site_mm: DVec3::ZERO,
        hole_mm: 1.27,
        open_s: 10.0,
        volume_ml: 100.0,
    };
    let changes = xray_voxels(&atlas.model, &[site]);
    let grid = atlas.model.ct().grid();
    let voxel_mm3: f64 = grid.spacing_mm().iter().product();
    let labels = atlas.model.partial_labels().data();
    assert!(
        changes
            .iter()
            .all(|(v, _)| labels[grid.linear(v[0], v[1], v[2])] == lung)
    );
    let air: Vec<_> = changes.iter().filter(|(_, mu)| *mu < 0.0).collect();
    let line: f64 = changes
        .iter()
        .filter(|(_, mu)| *mu > 0.0)
        .map(|(_, mu)| f64::from(*mu))
        .sum();
    let removed: f64 = air.iter().map(|(_, mu)| -f64::from(*mu)).sum();
    assert!((line - removed).abs() < 1e-3 * removed, "{line} {removed}");
    // The air's volume: each voxel's share of its μ taken away.
    let ct = atlas.model.ct().data();
    let air_ml: f64 = air
        .iter()
        .map(|(v, mu)| {
            let lung_mu = f64::from(MU_WATER_PER_MM / 1000.0 * water_relative(ct[grid.linear(v[0], v[1], v[2])]));
            -f64::from(*mu) / lung_mu * voxel_mm3 / 1000.0
        })
        .sum();
    assert!((air_ml - 100.0).abs() < 0.5, "{air_ml} ml of air");
    // No fluid collection for air.
    assert!(fluid_collections(&[site]).is_empty());
}
