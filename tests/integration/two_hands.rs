//! Two hands: the ultrasound probe in the second hand while the first advances the needle under
//! live guidance (docs/physics.md "Two hands", docs/metrics.md "Live ultrasound guidance"). The
//! phantom's scripted two-handed success and blind failure, recorded, replayed bit for bit (with
//! deformation and breathing on) and scored.

use std::path::Path;

use crate::common::{default_phantom, phantom_script_text as script, record_script as record, score_session as score};
use stylet_scoring::live_guidance::LiveGuidance;
use stylet_scoring::rubric::Rubric;
use stylet_scoring::score::{ScoreReport, Scorer};

/// The phantom's script `name` recorded at `difficulty`, replayed (verified) and scored, with
/// its live guidance.
fn scored_script(name: &str, difficulty: &str) -> (ScoreReport, LiveGuidance) {
    let atlas = default_phantom();
    let d = tempfile::tempdir().unwrap();
    let path = record(atlas, d.path(), name, difficulty, &script(&format!("{name}.txt")));
    let r = score(atlas, &path);
    assert!(r.replay_verified, "{name}: {:?}", r.divergence);
    let g = r
        .metrics
        .live_guidance
        .expect("the second hand held the probe during the insertion");
    println!("{name}: {g:?}; score {} {:?}", r.grade.score, r.reasons);
    (r, g)
}

#[test]
fn the_scripted_two_handed_success_keeps_the_tip_in_the_live_image_and_passes() {
    let (r, g) = scored_script("two-handed-success", "expert");
    assert!(r.metrics.target_reached && r.metrics.target_confirmed);
    assert!(r.metrics.workflow.ultrasound_before_puncture && r.metrics.workflow.target_scanned_before_puncture);
    assert!(g.needle_tip_visible_share > 0.8, "{g:?}");
    assert!(g.longest_blind_advance_s < 1.0, "{g:?}");
    assert_eq!(g.tip_in_view_at_target_entry, Some(true));
    assert_eq!(r.outcome, stylet_scoring::reasons::Outcome::Passed, "{:?}", r.reasons);
}

#[test]
fn the_scripted_blind_advance_is_out_of_view_hits_the_portal_vein_and_fails() {
    let (r, g) = scored_script("two-handed-blind", "beginner");
    assert!(g.needle_tip_visible_share < 0.2, "{g:?}");
    assert!(g.longest_blind_advance_s > 3.0, "{g:?}");
    assert!(
        r.metrics.risk_hits.iter().any(|h| h.structure.contains("portal")),
        "{:?}",
        r.metrics.risk_hits
    );
    assert_eq!(r.outcome, stylet_scoring::reasons::Outcome::Failed);
    assert!(
        r.grade
            .deductions
            .iter()
            .any(|d| d.metric == "blind_advance_s" && d.points > 0.0),
        "{:?}",
        r.grade.deductions
    );
}

/// A two-tool session with deformation and breathing on replays bit for bit: every recorded
/// force of both hands and every state digest (which covers the deformation field and both
/// tools) is reproduced. The probe's press and the needle's entry share one deformation solve.
#[test]
fn a_two_handed_session_with_deformation_and_breathing_replays_bit_for_bit() {
    let atlas = default_phantom();
    let d = tempfile::tempdir().unwrap();
    let text = "stylet-script 1\ndevice premium\ntool needle gauge 18 length 150 stylet in\ntool2 probe convex\n\
                deformation on\nbreathing on period 4 seed 1\nend 4\n\
                at 0 along intercostal-10-11 -5\n\
                at 0 hand2 pos 172.6 36.6 7.7 dir -0.9985 -0.0538 -0.002 xaxis 0.053 -0.971 0.235\n\
                at 0.3 hand2 press -0.9985 -0.0538 -0.002 1.5\n\
                at 1 along intercostal-10-11 -5\nat 4 along intercostal-10-11 30\n";
    let path = record(atlas, d.path(), "two-handed-success", "beginner", text);
    let session = stylet_recorder::reader::verify(&path).unwrap();
    assert!(session.header.second_hand.is_some() && session.header.deformation.enabled);
    assert!(session.header.breathing.enabled);
    let hands = session
        .ticks
        .iter()
        .filter(|t| t.second_hand.is_some_and(|h| h.force_n != [0.0; 3]));
    assert!(
        hands.count() > 2000,
        "the probe pressed on the skin for most of the run"
    );
    let r = score(atlas, &path);
    assert!(r.replay_verified, "{:?}", r.divergence);
    assert_eq!(r.ticks, 4000);
    assert!(r.digests_checked >= 40, "{}", r.digests_checked);
    assert!(
        r.metrics.max_tissue_displacement_mm > 0.5,
        "{}",
        r.metrics.max_tissue_displacement_mm
    );
}

/// What a two-handed session costs on disk (the goal: under 1.5 MB per minute), for the note.
#[test]
fn a_two_handed_session_is_small() {
    let atlas = default_phantom();
    let d = tempfile::tempdir().unwrap();
    let two = record(
        atlas,
        d.path(),
        "two-handed-success",
        "beginner",
        &script("two-handed-success.txt"),
    );
    let one = record(
        atlas,
        d.path(),
        "success-intercostal",
        "beginner",
        &script("success-intercostal.txt"),
    );
    let per_minute = |p: &Path, seconds: f64| std::fs::metadata(p).unwrap().len() as f64 / seconds * 60.0 / 1e6;
    let (two_mb, one_mb) = (per_minute(&two, 27.0), per_minute(&one, 20.0));
    println!("session size: two hands {two_mb:.3} MB/min, one hand {one_mb:.3} MB/min");
    assert!(two_mb < 1.5, "{two_mb} MB/min");
}

/// The review's timeline marks where the tip was out of the live image: most of the blind
/// insertion, little of the guided one; a one-handed session marks nothing.
#[test]
fn the_review_trace_marks_the_tip_out_of_the_live_image() {
    let atlas = default_phantom();
    let d = tempfile::tempdir().unwrap();
    let scorer = Scorer::new(atlas, Rubric::default_rubric(), None).unwrap();
    let hidden_s = |name: &str| {
        let path = record(atlas, d.path(), name, "beginner", &script(&format!("{name}.txt")));
        let session = stylet_recorder::reader::verify(&path).unwrap();
        let (_, trace) = scorer.score_session_traced(&session).unwrap();
        assert!(trace.tip_hidden.is_empty() || trace.tip_hidden.len() == trace.t_s.len());
        trace.tip_hidden.iter().filter(|h| **h).count() as f64 * trace.bucket_s
    };
    let (guided, blind, one) = (
        hidden_s("two-handed-success"),
        hidden_s("two-handed-blind"),
        hidden_s("success-intercostal"),
    );
    println!("tip out of the live image: guided {guided:.2} s, blind {blind:.2} s");
    assert!(blind > 8.0, "{blind} s");
    assert!(guided < 2.5, "{guided} s");
    assert_eq!(one, 0.0);
}

/// `stylet session inspect` names the second hand; `session export` writes its ticks to
/// `second_hand.csv`, every number giving back its recorded bits.
#[test]
fn session_inspect_and_export_show_the_second_hand() {
    use crate::common::ok;
    let atlas = default_phantom();
    let d = tempfile::tempdir().unwrap();
    let path = record(
        atlas,
        d.path(),
        "two-handed-success",
        "beginner",
        &script("two-handed-success.txt"),
    );
    let p = path.to_str().unwrap();
    let text = ok(&["session", "inspect", p]);
    assert!(
        text.contains("hand 2    premium, starting with convex probe; reported on 27000 ticks"),
        "{text}"
    );
    let json: serde_json::Value = serde_json::from_str(&ok(&["session", "inspect", p, "--json"])).unwrap();
    assert_eq!(json["second_hand"]["device"], "premium");
    let out = d.path().join("csv");
    ok(&["session", "export", p, "--csv", out.to_str().unwrap()]);
    let csv = std::fs::read_to_string(out.join("second_hand.csv")).unwrap();
    let session = stylet_recorder::reader::read(&path).unwrap();
    let mut lines = csv.lines();
    assert!(lines.next().unwrap().starts_with("tick,t_s,x_mm"));
    let rows: Vec<&str> = lines.collect();
    assert_eq!(rows.len(), 27000);
    let row: Vec<f64> = rows[15_000].split(',').map(|v| v.parse().unwrap()).collect();
    let h = session.ticks[15_000].second_hand.unwrap();
    assert_eq!(row[2].to_bits(), h.position_mm[0].to_bits());
    assert_eq!(row[12].to_bits(), h.force_n[2].to_bits());
}
