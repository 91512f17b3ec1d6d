//! `stylet score`: replay session files through the physics, measure, grade (docs/metrics.md).

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::Args;
use stylet_scoring::{Rubric, ScoreError, ScoreReport, Scorer};

#[derive(Debug, Args)]
pub struct ScoreArgs {
    /// Session files (.mcap).
    #[arg(required = true)]
    pub files: Vec<PathBuf>,
    /// The atlas the sessions were recorded on (its content hash must match theirs).
    #[arg(long)]
    pub atlas: PathBuf,
    /// Print JSON (one object for one file, an array for several).
    #[arg(long)]
    pub json: bool,
    /// Score on this many threads (default: all cores).
    #[arg(long)]
    pub jobs: Option<usize>,
    /// Write one CSV row per session here.
    #[arg(long)]
    pub csv: Option<PathBuf>,
    /// Rubric TOML (default: the shipped scoring/rubrics/ptcd.toml).
    #[arg(long)]
    pub rubric: Option<PathBuf>,
    /// Guided-mode metrics against this planned path of the atlas (default: the path whose entry
    /// is nearest the trainee's entry).
    #[arg(long)]
    pub path: Option<String>,
}

pub fn run(a: ScoreArgs) -> anyhow::Result<()> {
    let rubric = match &a.rubric {
        Some(p) => {
            let text = std::fs::read_to_string(p).with_context(|| format!("cannot read {}", p.display()))?;
            Rubric::parse(&text).map_err(|e| anyhow::anyhow!("{}: {e}", p.display()))?
        }
        None => Rubric::default_rubric(),
    };
    let atlas = stylet_atlas::load(&a.atlas)?;
    let scorer = Scorer::new(&atlas, rubric, a.path.clone()).map_err(|e| anyhow::anyhow!(e))?;
    if a.files.len() == 1 && a.csv.is_none() {
        let report = scorer.score_file(&a.files[0]).map_err(|e| explain(&a.files[0], e))?;
        if a.json {
            sayf!("{}", serde_json::to_string_pretty(&report)?);
        } else {
            print_report(&a.files[0], &report);
        }
        return Ok(());
    }
    let jobs = a
        .jobs
        .unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
    let bar = indicatif::ProgressBar::new(a.files.len() as u64).with_style(
        indicatif::ProgressStyle::with_template("{bar:40} {pos}/{len} sessions scored ({elapsed}, {eta} left)")
            .expect("a valid template"),
    );
    let results = scorer
        .score_files(&a.files, jobs, &|| bar.inc(1))
        .map_err(|e| anyhow::anyhow!(e))?;
    bar.finish_and_clear();
    if let Some(out) = &a.csv {
        write_csv(out, &results)?;
    }
    if a.json {
        let list: Vec<serde_json::Value> = results
            .iter()
            .map(|(f, r)| match r {
                Ok(s) => serde_json::json!({"file": f, "report": s}),
                Err(e) => serde_json::json!({"file": f, "error": e.to_string()}),
            })
            .collect();
        sayf!("{}", serde_json::to_string_pretty(&list)?);
    } else {
        print_table(&results);
    }
    if let Some(out) = &a.csv {
        eprintln!("{} rows written to {}", results.len(), out.display());
    }
    let failed = results.iter().filter(|r| r.1.is_err()).count();
    if failed > 0 {
        bail!("{failed} of {} sessions could not be scored (see above)", results.len());
    }
    Ok(())
}

fn explain(file: &Path, e: ScoreError) -> anyhow::Error {
    match e {
        ScoreError::Unreadable(m) => anyhow::anyhow!(m),
        e => anyhow::anyhow!("{}: {e}", file.display()),
    }
}

fn yes(b: bool) -> &'static str {
    if b { "yes" } else { "no" }
}

fn opt(v: Option<f64>, unit: &str) -> String {
    v.map_or_else(|| "—".into(), |v| format!("{v:.1} {unit}"))
}

fn print_report(file: &Path, r: &ScoreReport) {
    let m = &r.metrics;
    let g = &r.grade;
    sayf!(
        "{}: {} — {} ({}) at {}",
        file.display(),
        r.trainee,
        r.scenario,
        r.exercise,
        g.difficulty
    );
    match &r.divergence {
        None => sayf!(
            "replay       verified: {} ticks and {} digests reproduced bit for bit",
            r.ticks,
            r.digests_checked
        ),
        Some(d) => sayf!(
            "replay       NOT verified: first difference at tick {} in {} (recorded {}, replayed {})",
            d.tick,
            d.stream,
            d.recorded,
            d.replayed
        ),
    }
    if let Some(why) = &r.incomplete_reason {
        sayf!("incomplete   {why}");
    }
    sayf!("attempts     {} (redirections {})", m.attempts, m.redirections);
    if m.risk_hits.is_empty() {
        sayf!("risk hits    none");
    }
    for h in &m.risk_hits {
        sayf!(
            "risk hit     {} (label {}) at {:.2} s, {:.1} mm deep, {:.2} s inside, {} entr{}",
            h.structure,
            h.label,
            h.t_s,
            h.depth_mm,
            h.duration_s,
            h.entries,
            if h.entries == 1 { "y" } else { "ies" }
        );
        if let Some(c) = &h.consequence {
            sayf!("             risk: {c}");
        }
    }
    sayf!("bone         {} contact(s)", m.bone_contacts);
    sayf!(
        "target       reached {} (after {}), confirmed {} (stylet out {}, contrast {})",
        yes(m.target_reached),
        opt(m.time_to_target_s, "s"),
        yes(m.target_confirmed),
        yes(m.stylet_removed_in_target),
        yes(m.contrast_in_target)
    );
    sayf!(
        "distance     to the target where the last puncture ended {}, closest {}",
        opt(m.target_distance_mm, "mm"),
        opt(m.target_distance_min_mm, "mm")
    );
    sayf!(
        "time         total {:.1} s, X-ray {:.1} s in {} shot(s), ultrasound {:.1} s, palpation {:.1} s",
        m.time_total_s,
        m.fluoro_time_s,
        m.xray_shots,
        m.ultrasound_time_s,
        m.palpation_time_s
    );
    sayf!(
        "needle       path {:.1} mm in the body (inefficiency {}), bending ≤ {:.2} mm, shaft sweep {:.0} mm²",
        m.path_length_mm,
        m.path_inefficiency.map_or_else(|| "—".into(), |v| format!("{v:.2}")),
        m.max_bending_mm,
        m.shaft_sweep_mm2
    );
    if let Some(n) = &m.needle_motion {
        sayf!(
            "hand motion  path {:.1} mm ({:.1} in tissue, {:.1} outside), {:.1} s in tissue, tissue damage {:.0} mm², jerk {:.3e} mm/s^2.5, depth perception {:.1} mm, {} reorientation(s)",
            n.path_length_mm,
            n.path_in_tissue_mm,
            n.path_outside_tissue_mm,
            n.time_in_tissue_s,
            n.tissue_damage_mm2,
            n.jerk_mm_per_s2_5,
            n.depth_perception_mm,
            n.reorientations
        );
    }
    sayf!("force        max {:.2} N, RMS {:.2} N", m.max_force_n, m.rms_force_n);
    sayf!(
        "workflow     palpation first {}, ultrasound first {}, confirmed before withdrawal {}",
        yes(m.workflow.palpation_before_puncture),
        yes(m.workflow.ultrasound_before_puncture),
        yes(m.workflow.confirmed_before_withdrawal)
    );
    if let Some(b) = &m.breathing {
        sayf!(
            "breathing    target reached {} (correct: {}), needle in while breathing {:.1} s, tissue carried past the tip {:.1} mm",
            b.target_reached_phase.map_or("never", |p| p.as_str()),
            b.correct_phase.as_str(),
            b.needle_in_while_breathing_s,
            b.tissue_slide_mm
        );
    }
    if let Some(gm) = &m.guided {
        sayf!(
            "guided       path {}: entry {:.1} mm off, angle {:.1}°, deviation mean {:.1} mm, max {:.1} mm",
            gm.path,
            gm.entry_distance_mm,
            gm.angle_error_deg,
            gm.mean_deviation_mm,
            gm.max_deviation_mm
        );
    }
    if let Some(p) = &m.palpation {
        sayf!(
            "palpation    {} of {} intercostal spaces found ({:.0} %), {} ribs felt",
            p.spaces_found,
            p.spaces_crossed,
            p.coverage * 100.0,
            p.ribs_crossed
        );
    }
    if let Some(u) = &m.ultrasound {
        sayf!(
            "ultrasound   target shown {} (first after {}, {:.1} s in view), good skin contact {:.1} s",
            yes(u.target_scanned),
            opt(u.time_to_target_view_s, "s"),
            u.target_view_time_s,
            u.good_contact_time_s
        );
    }
    if let Some(d) = &m.drainage {
        sayf!(
            "guide wire   reached the ducts {} (at most {:.0} mm in them), through the wall {}, access lost {}, {} put in",
            yes(d.wire_reached_ducts),
            d.wire_in_ducts_max_mm,
            yes(d.wire_left_duct),
            yes(d.access_lost),
            d.wire_attempts
        );
        sayf!(
            "dilator      {} passes (up to {:.1} N); catheter {} put on (up to {:.1} N); {} steps refused",
            d.dilator_attempts,
            d.dilator_peak_force_n,
            d.catheter_attempts,
            d.catheter_peak_force_n,
            d.refused_steps
        );
        if d.catheter_placed {
            sayf!(
                "catheter     placed, pigtail in the ducts {}, {} of {} side holes in the ducts",
                yes(d.pigtail_in_ducts),
                d.catheter_holes_in_ducts,
                d.catheter_holes
            );
        }
        sayf!(
            "fluoroscopy  puncture {:.1} s, wire {:.1} s, dilator {:.1} s, catheter {:.1} s",
            d.fluoroscopy_puncture_s,
            d.fluoroscopy_wire_s,
            d.fluoroscopy_dilator_s,
            d.fluoroscopy_catheter_s
        );
    }
    for d in &g.deductions {
        let words = stylet_scoring::reasons::metric_info(&d.metric).map_or_else(
            || format!("−{:.1}", d.points),
            |i| i.deduction(d.value, d.points, d.free),
        );
        sayf!("deduction    {words}");
    }
    for f in &g.failed {
        sayf!("not met      {f}");
    }
    match r.outcome {
        stylet_scoring::Outcome::NotGradeable => sayf!(
            "grade        NOT GRADEABLE: the recording is incomplete ({} rubric v{}, physics v{})",
            g.rubric,
            g.rubric_version,
            g.physics_version
        ),
        o => sayf!(
            "grade        {:.1} / 100, {} ({} rubric v{}, physics v{})",
            g.score,
            if o == stylet_scoring::Outcome::Passed {
                "PASSED"
            } else {
                "FAILED"
            },
            g.rubric,
            g.rubric_version,
            g.physics_version
        ),
    }
    for reason in &r.reasons {
        sayf!("why          {reason}");
    }
}

pub fn print_table(results: &[(PathBuf, Result<ScoreReport, ScoreError>)]) {
    sayf!(
        "{:<36} {:<12} {:<22} {:<9} {:>8} {:>5} {:>6} {:>4} {:>5} {:<13} {}",
        "session",
        "trainee",
        "scenario",
        "level",
        "verified",
        "tries",
        "risk",
        "bone",
        "score",
        "result",
        "why not passed"
    );
    for (f, r) in results {
        let name = f
            .file_name()
            .map_or_else(|| f.display().to_string(), |n| n.to_string_lossy().into_owned());
        match r {
            Ok(s) => sayf!(
                "{:<36} {:<12} {:<22} {:<9} {:>8} {:>5} {:>6} {:>4} {:>5.1} {:<13} {}",
                name,
                s.trainee,
                s.scenario,
                s.grade.difficulty,
                yes(s.replay_verified),
                s.metrics.attempts,
                s.metrics.risk_hits.len(),
                s.metrics.bone_contacts,
                s.grade.score,
                s.outcome.label(),
                why_not(s)
            ),
            Err(e) => sayf!("{name:<36} not scored: {e}"),
        }
    }
}

/// Why a session did not pass, in words (empty when passed): its reasons, one after another.
fn why_not(s: &ScoreReport) -> String {
    if s.outcome == stylet_scoring::Outcome::Passed {
        return String::new();
    }
    s.reasons.join(" ")
}

/// Columns of `stylet score --csv` (docs/metrics.md "Batch CSV").
pub const SCORE_CSV_HEADER: &str = "file,session_id,trainee,scenario,difficulty,status,replay_verified,incomplete,score,passed,\
rubric,rubric_version,physics_version,attempts,redirections,risk_hits,risk_structures,bone_contacts,target_reached,\
target_confirmed,time_to_target_s,time_total_s,fluoro_time_s,xray_shots,path_length_mm,max_force_n,shaft_sweep_mm2,\
tissue_damage_mm2,time_in_tissue_s,jerk_mm_per_s2_5,target_distance_mm,exercise,outcome,reasons,error";

fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

fn write_csv(out: &Path, results: &[(PathBuf, Result<ScoreReport, ScoreError>)]) -> anyhow::Result<()> {
    let tmp = out.with_extension("csv.partial");
    let mut w = std::io::BufWriter::new(
        std::fs::File::create(&tmp).with_context(|| format!("cannot create {}", tmp.display()))?,
    );
    writeln!(w, "{SCORE_CSV_HEADER}")?;
    let o = |v: Option<f64>| v.map_or_else(String::new, |v| v.to_string());
    for (f, r) in results {
        let file = csv_field(&f.display().to_string());
        match r {
            Ok(s) => {
                let m = &s.metrics;
                let structures: Vec<&str> = m.risk_hits.iter().map(|h| h.structure.as_str()).collect();
                writeln!(
                    w,
                    "{file},{},{},{},{},scored,{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},",
                    csv_field(&s.session_id),
                    csv_field(&s.trainee),
                    csv_field(&s.scenario),
                    csv_field(s.grade.difficulty.as_str()),
                    s.replay_verified,
                    s.incomplete,
                    s.grade.score,
                    s.grade.passed,
                    csv_field(&s.grade.rubric),
                    s.grade.rubric_version,
                    s.physics_version,
                    m.attempts,
                    m.redirections,
                    m.risk_hits.len(),
                    csv_field(&structures.join(";")),
                    m.bone_contacts,
                    m.target_reached,
                    m.target_confirmed,
                    o(m.time_to_target_s),
                    m.time_total_s,
                    m.fluoro_time_s,
                    m.xray_shots,
                    m.path_length_mm,
                    m.max_force_n,
                    m.shaft_sweep_mm2,
                    o(m.needle_motion.map(|n| n.tissue_damage_mm2)),
                    o(m.needle_motion.map(|n| n.time_in_tissue_s)),
                    o(m.needle_motion.map(|n| n.jerk_mm_per_s2_5)),
                    o(m.target_distance_mm),
                    s.exercise.as_str(),
                    s.outcome.as_str(),
                    csv_field(&s.reasons.join(" | ")),
                )?;
            }
            Err(e) => writeln!(
                w,
                "{file},,,,,error,,,,,,,,,,,,,,,,,,,,,,,,,,,,,{}",
                csv_field(&e.to_string())
            )?,
        }
    }
    w.into_inner().map_err(|e| e.into_error())?.sync_all()?;
    std::fs::rename(&tmp, out).with_context(|| format!("cannot write {}", out.display()))?;
    Ok(())
}
