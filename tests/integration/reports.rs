//! The cohort report as a PDF: made on the server, read back with `pdftotext` (poppler-utils,
//! installed by scripts/test), it holds the cohort's numbers as the API reports them session by
//! session; palpation sessions are counted per exercise, not as punctures; the same authorization
//! as the printable page.

use std::io::Read;
use std::path::Path;
use std::process::Command;

use crate::common::*;
use serde_json::Value;

/// The body of a GET as bytes, with its status and content type.
fn get_bytes(base: &str, path: &str, auth: Option<&Auth>) -> (u16, String, Vec<u8>) {
    let agent = ureq::AgentBuilder::new().redirects(0).build();
    let mut req = agent.get(&format!("{base}{path}"));
    if let Some(Auth::Cookie { token, .. }) = auth {
        req = req.set("Cookie", &format!("stylet_session={token}"));
    }
    let resp = match req.call() {
        Ok(r) => r,
        Err(ureq::Error::Status(_, r)) => r,
        Err(e) => panic!("GET {path}: {e}"),
    };
    let status = resp.status();
    let ctype = resp.content_type().to_string();
    let mut body = Vec::new();
    resp.into_reader().take(50 << 20).read_to_end(&mut body).unwrap();
    (status, ctype, body)
}

/// The PDF's text, laid out as on the page (`pdftotext -layout`).
fn pdf_text(pdf: &[u8], dir: &Path) -> String {
    assert!(
        Path::new("/usr/bin/pdftotext").is_file(),
        "pdftotext is missing: scripts/test installs the Debian package poppler-utils"
    );
    let file = dir.join("report.pdf");
    std::fs::write(&file, pdf).unwrap();
    let out = Command::new("pdftotext")
        .args(["-layout", "-enc", "UTF-8", s(&file), "-"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "pdftotext: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

/// The words of the first line after the one that contains every one of `header`.
fn row_after(text: &str, header: &[&str]) -> Vec<String> {
    let lines: Vec<&str> = text.lines().collect();
    let k = lines
        .iter()
        .position(|l| header.iter().all(|h| l.contains(h)))
        .unwrap_or_else(|| panic!("no line with {header:?} in:\n{text}"));
    lines[k + 1..]
        .iter()
        .find(|l| !l.trim().is_empty())
        .unwrap()
        .split_whitespace()
        .map(str::to_string)
        .collect()
}

fn pct(a: i64, b: i64) -> String {
    format!("{:.0}", 100.0 * a as f64 / b as f64)
}

on_both_databases!(the_cohort_report_pdf_holds_the_cohorts_numbers => cohort_report_pdf, "reports");

fn cohort_report_pdf(db: Db) {
    let f = Fixture::new(STYLET);
    f.users(&db);
    // A palpation exercise of tina's: reported as palpation, never as a failed puncture.
    let palpation = f.session("tina-palpation");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("atlases/phantom/scripts/palpation-sweep.txt");
    ok(&[
        "script",
        "run",
        "--atlas",
        s(&f.atlases().join("phantom")),
        "--script",
        s(&script),
        "--out",
        s(&palpation),
        "--trainee",
        "tina",
    ]);
    let srv = Server::start(STYLET, &f.data(), &db, &f.atlases(), &["--workers", "2"]);
    let base = srv.base.clone();
    let tina = login(&base, "tina");
    let mut reports: Vec<Value> = Vec::new();
    for name in ["tina-ok", "tina-lung", "tina-two", "tina-palpation"] {
        let (_, scored) = upload_scored(&base, &tina, &f.session(name));
        reports.push(scored);
    }
    // The palpation exercise is not a puncture: tina's progress (scores over time, the suggested
    // difficulty) holds her three punctures only.
    let (status, progress, _) = call(
        "GET",
        &format!("{base}/api/trainees/tina/progress"),
        Some(&tina),
        None,
        false,
    );
    assert_eq!(status, 200, "{progress}");
    let points: Vec<&Value> = progress["progress"]
        .as_object()
        .unwrap()
        .values()
        .flat_map(|v| v.as_array().unwrap())
        .collect();
    let palpation_id = reports[3]["id"].as_str().unwrap();
    assert_eq!(points.len(), 3, "{progress}");
    assert!(points.iter().all(|p| p["session_id"] != palpation_id), "{progress}");
    // tom (cohort c2) has a session that cohort c1's report must not count.
    let tom = login(&base, "tom");
    wait_scored(&base, &tom, &upload(&base, &tom, &f.session("tom-ok")));

    // The numbers, independently: from each session's report through the API.
    let report_of = |v: &Value| -> Value { v.get("score").cloned().unwrap_or(Value::Null) };
    let exercise = |v: &Value| report_of(v)["exercise"].as_str().unwrap_or("puncture").to_string();
    let passed = |v: &Value| report_of(v)["grade"]["passed"].as_bool().unwrap();
    let punctures: Vec<&Value> = reports.iter().filter(|r| exercise(r) == "puncture").collect();
    assert_eq!(punctures.len(), 3, "three punctures: {reports:?}");
    assert_eq!(exercise(&reports[3]), "palpation", "{}", reports[3]);
    let punct_passed = punctures.iter().filter(|r| passed(r)).count() as i64;
    let all_passed = reports.iter().filter(|r| passed(r)).count() as i64;
    let risk: i64 = reports
        .iter()
        .map(|r| {
            report_of(r)["metrics"]["risk_hits"]
                .as_array()
                .map_or(0, |a| a.len() as i64)
        })
        .sum();
    let mean = reports
        .iter()
        .map(|r| report_of(r)["grade"]["score"].as_f64().unwrap())
        .sum::<f64>()
        / 4.0;
    assert!(
        (1..3).contains(&punct_passed),
        "the fixture has passed and failed punctures"
    );
    let lung = &reports[1];
    assert!(!passed(lung));
    let unmet: Vec<String> = report_of(lung)["grade"]["unmet"]
        .as_array()
        .unwrap()
        .iter()
        .map(|u| u["metric"].as_str().unwrap().to_string())
        .collect();
    assert!(!unmet.is_empty(), "the lung hit misses requirements: {lung}");

    let cora = login(&base, "cora");
    let (status, ctype, pdf) = get_bytes(&base, "/reports/cohort.pdf?cohort=c1", Some(&cora));
    assert_eq!(status, 200, "{}", String::from_utf8_lossy(&pdf));
    assert_eq!(ctype, "application/pdf");
    assert!(pdf.starts_with(b"%PDF-"));
    let dir = tempfile::tempdir().unwrap();
    let text = pdf_text(&pdf, dir.path());
    assert!(text.contains("Cohort c1 — training report, all dates"), "{text}");
    assert!(text.contains("Generated") && text.contains("by cora"), "{text}");

    // Totals: trainees, sessions, scored, pass rate, not gradeable, mean score, risk hits.
    let totals = row_after(&text, &["Trainees", "Sessions", "Pass rate", "Risk-structure hits"]);
    let all_graded = 4;
    assert_eq!(
        totals,
        [
            "1".to_string(),
            "4".into(),
            "4".into(),
            pct(all_passed, all_graded),
            "%".into(),
            "0".into(),
            format!("{mean:.1}"),
            risk.to_string()
        ],
        "{text}"
    );
    // The weekly pass rate counts the three punctures only.
    let today = humantime::format_rfc3339_seconds(std::time::SystemTime::now()).to_string();
    let week_row = row_after(&text, &["Week of (Monday)", "Difficulty", "Passed / graded"]);
    assert_eq!(week_row[1], "beginner", "{text}");
    // pdftotext may close up "2 / 3" into "2/3".
    let joined = |w: &[String]| w.join(" ").replace(" / ", "/");
    assert_eq!(
        joined(&week_row[2..]),
        format!("{punct_passed}/3 {} %", pct(punct_passed, 3)),
        "{text}"
    );
    assert!(week_row[0].as_str() <= &today[..10], "{week_row:?}");
    assert!(
        text.contains("Pass rate per week and difficulty (puncture exercises)"),
        "{text}"
    );
    assert!(
        text.contains("pass rate (%)") && text.contains("calendar week"),
        "chart axes: {text}"
    );
    // Per exercise.
    let palp = text
        .lines()
        .find(|l| l.trim_start().starts_with("palpation"))
        .unwrap_or_else(|| panic!("no palpation row: {text}"));
    let p_passed = i64::from(passed(&reports[3]));
    assert_eq!(
        palp.split_whitespace().take(5).collect::<Vec<_>>(),
        [
            "palpation",
            "1",
            &p_passed.to_string(),
            &(1 - p_passed).to_string(),
            "0"
        ],
        "{text}"
    );
    // Why the lung hit failed, in words: its unmet requirements' names from the one table.
    for m in &unmet {
        let label = stylet_scoring::metric_label(m).unwrap();
        assert!(
            text.contains(&format!("requirement not met: {label}")),
            "{label}: {text}"
        );
        assert!(!text.contains(m.as_str()), "a metric identifier in the PDF: {m}");
    }
    // Per trainee: tina's sessions and pass rate.
    let tina_row = text
        .lines()
        .find(|l| l.trim_start().starts_with("tina") && l.contains('/'))
        .unwrap();
    let words: Vec<String> = tina_row.split_whitespace().map(str::to_string).collect();
    assert!(
        joined(&words).starts_with(&format!("tina 4 {all_passed}/4 {} %", pct(all_passed, 4))),
        "{tina_row}"
    );
    assert!(!text.contains("tom"), "another cohort's trainee in the report: {text}");

    // The page shows the same pass rate, and links to the PDF.
    let (status, _, html) = get_bytes(&base, "/reports/cohort?cohort=c1", Some(&cora));
    assert_eq!(status, 200);
    let html = String::from_utf8(html).unwrap();
    assert!(
        html.contains(&format!("id=\"report-pass-rate\">{} %", pct(all_passed, all_graded))),
        "{html}"
    );
    assert!(html.contains("/reports/cohort.pdf?"), "{html}");
    assert!(html.contains("id=\"trend-chart\""), "{html}");

    // Authorization as the page: the cohort's instructor yes; trainees and other cohorts no;
    // not logged in: to the login page; no cohort: 400.
    let ivan = login(&base, "ivan");
    assert_eq!(get_bytes(&base, "/reports/cohort.pdf?cohort=c1", Some(&ivan)).0, 200);
    assert_eq!(get_bytes(&base, "/reports/cohort.pdf?cohort=c2", Some(&ivan)).0, 404);
    assert_eq!(get_bytes(&base, "/reports/cohort.pdf?cohort=c1", Some(&tina)).0, 404);
    assert_eq!(get_bytes(&base, "/reports/cohort.pdf?cohort=c1", None).0, 303);
    assert_eq!(get_bytes(&base, "/reports/cohort.pdf", Some(&cora)).0, 400);
    // A date range with nothing in it.
    let (status, _, pdf) = get_bytes(&base, "/reports/cohort.pdf?cohort=c1&to=2000-01-01", Some(&cora));
    assert_eq!(status, 200);
    let text = pdf_text(&pdf, dir.path());
    assert!(
        text.contains("until 2000-01-01") && text.contains("No graded puncture sessions"),
        "{text}"
    );
}
