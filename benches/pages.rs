//! Dashboard page render times with 10 000 sessions in the database (SQLite, the default).
//!
//! Set-up: a small phantom, two real sessions recorded on it and uploaded through the API (so
//! their review pages have files, traces and figures), then 9 998 more session rows written
//! straight into the database: 4 cohorts × 25 trainees × 100 sessions over 100 days, with
//! scores, results, attempts and risk hits; two in three carry an instructor's comment (the
//! review queue lists the rest). Then `stylet serve` (the real server, release
//! build) answers every page `STYLET_BENCH_REQUESTS` times (default 200) in sequence over one
//! keep-alive connection per user; the p50 and p99 of each page are printed, and p50 as a ratio
//! to `GET /healthz` (a database round trip) measured in the same run. Goal here: p99 < 100 ms.
//!
//! `cargo bench --bench pages` (under `scripts/test`, `cargo test --all-targets` runs this with
//! `--bench` absent, i.e. the set-up and one request per page: a smoke test).

use std::io::{BufRead, BufReader, Write};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use stylet_service::Store;

const BIN: &str = env!("CARGO_BIN_EXE_stylet");
const COHORTS: usize = 4;
const TRAINEES_PER_COHORT: usize = 25;
const SESSIONS_PER_TRAINEE: usize = 100;

fn run(args: &[&str]) {
    let out = Command::new(BIN).args(args).output().unwrap();
    assert!(
        out.status.success(),
        "stylet {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

struct Server(Child, String);

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn serve(data: &Path, atlases: &Path) -> Server {
    let mut child = Command::new(BIN)
        .args(["serve", "--bind", "127.0.0.1:0", "--workers", "2", "--data-dir"])
        .arg(data)
        .arg("--atlases")
        .arg(atlases)
        .env("RUST_LOG", "warn")
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let base = line.trim().strip_prefix("listening on ").unwrap().to_string();
    Server(child, base)
}

/// A logged-in HTTP client (cookie) with keep-alive.
struct Browser {
    agent: ureq::Agent,
    cookie: String,
    csrf: String,
}

impl Browser {
    fn login(base: &str, user: &str) -> Browser {
        let agent = ureq::AgentBuilder::new().redirects(0).build();
        let resp = agent
            .post(&format!("{base}/api/login"))
            .set("Content-Type", "application/json")
            .send_string(&format!(r#"{{"username":"{user}","password":"{user}-password"}}"#))
            .unwrap();
        let cookie = resp
            .header("Set-Cookie")
            .unwrap()
            .split(';')
            .next()
            .unwrap()
            .to_string();
        let v: serde_json::Value = serde_json::from_str(&resp.into_string().unwrap()).unwrap();
        let csrf = v["csrf_token"].as_str().unwrap().to_string();
        Browser { agent, cookie, csrf }
    }

    /// Status, body length and time of a GET.
    fn get(&self, url: &str) -> (u16, usize, Duration) {
        let t = Instant::now();
        let resp = self.agent.get(url).set("Cookie", &self.cookie).call();
        let resp = match resp {
            Ok(r) => r,
            Err(ureq::Error::Status(_, r)) => r,
            Err(e) => panic!("{url}: {e}"),
        };
        let status = resp.status();
        let mut body = Vec::new();
        std::io::Read::read_to_end(&mut resp.into_reader(), &mut body).unwrap();
        (status, body.len(), t.elapsed())
    }
}

fn percentile(sorted: &[Duration], q: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * q).round() as usize].as_secs_f64() * 1e3
}

fn main() {
    // `cargo bench` passes --bench; `cargo test --all-targets` does not: then one request a page.
    let measuring = std::env::args().any(|a| a == "--bench");
    let requests: usize = if measuring {
        std::env::var("STYLET_BENCH_REQUESTS")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(200)
    } else {
        1
    };
    let dir = tempfile::tempdir().unwrap();
    let atlases = dir.path().join("atlases");
    let data = dir.path().join("data");
    std::fs::create_dir_all(&data).unwrap();
    run(&[
        "atlas",
        "phantom",
        "--out",
        atlases.join("phantom").to_str().unwrap(),
        "--dims",
        "160,160,130",
        "--spacing",
        "2.4",
    ]);
    let scripts = Path::new(env!("CARGO_MANIFEST_DIR")).join("atlases/phantom/scripts");
    let trainee = |c: usize, t: usize| format!("t{c}-{t:02}");
    let mut real = Vec::new();
    for script in ["success-intercostal", "two-attempts"] {
        let out = dir.path().join(format!("{script}.mcap"));
        run(&[
            "script",
            "run",
            "--atlas",
            atlases.join("phantom").to_str().unwrap(),
            "--script",
            scripts.join(format!("{script}.txt")).to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--trainee",
            &trainee(0, 0),
        ]);
        real.push(out);
    }
    let url = format!("sqlite://{}?mode=rwc", data.join("stylet.db").display());
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .unwrap();
    let t0 = Instant::now();
    rt.block_on(async {
        let store = Store::open(&url).await.unwrap();
        store
            .add_user("root", "admin", "root-password", None, None)
            .await
            .unwrap();
        store
            .add_user("cora", "curriculum", "cora-password", None, None)
            .await
            .unwrap();
        for c in 0..COHORTS {
            let cohort = format!("c{c}");
            store
                .add_user(
                    &format!("i{c}"),
                    "instructor",
                    &format!("i{c}-password"),
                    Some(&cohort),
                    None,
                )
                .await
                .unwrap();
            for t in 0..TRAINEES_PER_COHORT {
                let name = trainee(c, t);
                store
                    .add_user(&name, "trainee", &format!("{name}-password"), Some(&cohort), None)
                    .await
                    .unwrap();
            }
        }
        store.pool.close().await;
    });
    eprintln!("accounts: {:.1} s", t0.elapsed().as_secs_f64());
    let srv = serve(&data, &atlases);
    let base = srv.1.clone();
    // The two real sessions, through the API, scored by the server.
    let owner = Browser::login(&base, &trainee(0, 0));
    let mut real_ids = Vec::new();
    for f in &real {
        let resp = owner
            .agent
            .post(&format!("{base}/api/sessions"))
            .set("Cookie", &owner.cookie)
            .set("X-CSRF-Token", &owner.csrf)
            .set("Content-Type", "application/octet-stream")
            .send_bytes(&std::fs::read(f).unwrap())
            .unwrap();
        let v: serde_json::Value = serde_json::from_str(&resp.into_string().unwrap()).unwrap();
        real_ids.push(v["id"].as_str().unwrap().to_string());
    }
    for id in &real_ids {
        let t = Instant::now();
        loop {
            let r = owner
                .agent
                .get(&format!("{base}/api/sessions/{id}"))
                .set("Cookie", &owner.cookie)
                .call()
                .unwrap();
            let v: serde_json::Value = serde_json::from_str(&r.into_string().unwrap()).unwrap();
            if v["status"] == "scored" {
                break;
            }
            assert!(t.elapsed() < Duration::from_secs(120), "not scored: {v}");
            std::thread::sleep(Duration::from_millis(100));
        }
    }
    // The other 9 998 rows, in one transaction beside the running server (WAL).
    let t1 = Instant::now();
    rt.block_on(async {
        let store = Store::open(&url).await.unwrap();
        let report: String = sqlx::query_scalar("SELECT report_json FROM scores LIMIT 1")
            .fetch_one(&store.pool)
            .await
            .unwrap();
        let atlas_hash: String = sqlx::query_scalar("SELECT content_hash FROM atlases LIMIT 1")
            .fetch_one(&store.pool)
            .await
            .unwrap();
        let mut tx = store.pool.begin().await.unwrap();
        let mut rng: u64 = 0x9E37_79B9_7F4A_7C15;
        let mut next = || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            rng
        };
        let mut k = 0u64;
        let day0 = std::time::SystemTime::now() - Duration::from_secs(100 * 86_400);
        for c in 0..COHORTS {
            for t in 0..TRAINEES_PER_COHORT {
                let name = trainee(c, t);
                let uid: String = sqlx::query_scalar("SELECT id FROM users WHERE username = $1")
                    .bind(name.clone())
                    .fetch_one(&mut *tx)
                    .await
                    .unwrap();
                let instructor: String = sqlx::query_scalar("SELECT id FROM users WHERE username = $1")
                    .bind(format!("i{c}"))
                    .fetch_one(&mut *tx)
                    .await
                    .unwrap();
                let n = if (c, t) == (0, 0) { SESSIONS_PER_TRAINEE - 2 } else { SESSIONS_PER_TRAINEE };
                for s in 0..n {
                    k += 1;
                    let at = humantime::format_rfc3339_micros(day0 + Duration::from_secs(s as u64 * 86_400 + k)).to_string();
                    let level = ["beginner", "advanced", "expert"][(s * 3 / SESSIONS_PER_TRAINEE).min(2)];
                    let scenario = ["success-intercostal", "two-attempts", "lung-hit"][(next() % 3) as usize];
                    let score = (40 + next() % 61) as f64;
                    let passed = i64::from(score >= 60.0);
                    let id = format!("bench-{k:08}");
                    sqlx::query(
                        "INSERT INTO sessions (id, file_sha256, size_bytes, session_uuid, trainee_id, uploaded_by, scenario, difficulty, \
                         atlas_hash, physics_version, duration_s, recorded_at, uploaded_at, status, final_score, final_passed, overridden, \
                         attempts, risk_hits, replay_verified, rubric_version, outcome) \
                         VALUES ($1, $2, 400000, $3, $4, $4, $5, $6, $7, 2, 34.0, $8, $8, 'scored', $9, $10, 0, $11, $12, 1, 1, $13)",
                    )
                    .bind(id.clone())
                    .bind(format!("{k:064x}"))
                    .bind(id.clone())
                    .bind(uid.clone())
                    .bind(scenario)
                    .bind(level)
                    .bind(atlas_hash.clone())
                    .bind(at.clone())
                    .bind(score)
                    .bind(passed)
                    .bind((1 + next() % 3) as i64)
                    .bind(i64::from(next() % 10 == 0))
                    .bind(if passed != 0 { "passed" } else { "failed" })
                    .execute(&mut *tx)
                    .await
                    .unwrap();
                    // Two sessions in three have been commented on (the review queue skips them).
                    if !k.is_multiple_of(3) {
                        sqlx::query(
                            "INSERT INTO comments (id, session_id, author_id, body, created_at) VALUES ($1, $2, $3, $4, $5)",
                        )
                        .bind(format!("comment-{k:08}"))
                        .bind(id.clone())
                        .bind(instructor.clone())
                        .bind("Reviewed.")
                        .bind(at.clone())
                        .execute(&mut *tx)
                        .await
                        .unwrap();
                    }
                    sqlx::query(
                        "INSERT INTO scores (session_id, score, passed, difficulty, rubric, rubric_version, physics_version, \
                         replay_verified, incomplete, report_json, scored_at) VALUES ($1, $2, $3, $4, 'ptcd', 1, 2, TRUE, FALSE, $5, $6)",
                    )
                    .bind(id)
                    .bind(score)
                    .bind(passed != 0)
                    .bind(level)
                    .bind(report.clone())
                    .bind(at)
                    .execute(&mut *tx)
                    .await
                    .unwrap();
                }
            }
        }
        tx.commit().await.unwrap();
        let n: i64 = sqlx::query_scalar("SELECT COUNT(*) FROM sessions").fetch_one(&store.pool).await.unwrap();
        assert_eq!(n, (COHORTS * TRAINEES_PER_COHORT * SESSIONS_PER_TRAINEE) as i64);
        store.pool.close().await;
    });
    eprintln!("10 000 sessions written in {:.1} s", t1.elapsed().as_secs_f64());

    let who = |u: &str| Browser::login(&base, u);
    let (trainee0, instructor, curriculum, admin) = (who(&trainee(0, 0)), who("i0"), who("cora"), who("root"));
    let (a, b) = (&real_ids[0], &real_ids[1]);
    let pages: Vec<(&str, &Browser, String)> = vec![
        ("GET /healthz (baseline)", &curriculum, "/healthz".into()),
        ("trainee home (100 sessions)", &trainee0, "/".into()),
        ("trainee sessions", &trainee0, "/sessions".into()),
        ("session review", &trainee0, format!("/sessions/{a}")),
        (
            "session tip-path PNG (cached)",
            &trainee0,
            format!("/sessions/{a}/slices.png"),
        ),
        ("instructor home", &instructor, "/".into()),
        ("cohort view (2 500 sessions)", &instructor, "/cohorts/c0".into()),
        (
            "cohort view, filtered",
            &instructor,
            "/cohorts/c0?difficulty=advanced&scenario=lung-hit".into(),
        ),
        ("compare two sessions", &instructor, format!("/compare?a={a}&b={b}")),
        ("needs review (instructor, 2 500)", &instructor, "/review-queue".into()),
        (
            "needs review, flagged, page 5",
            &instructor,
            "/review-queue?only=flagged&page=5".into(),
        ),
        ("needs review (admin, 10 000)", &admin, "/review-queue".into()),
        (
            "trainee progress (100 sessions)",
            &instructor,
            format!("/trainees/{}", trainee(0, 1)),
        ),
        (
            "own progress (trainee)",
            &trainee0,
            format!("/trainees/{}", trainee(0, 0)),
        ),
        (
            "compare search (trainee, outcome)",
            &instructor,
            format!("/compare?trainee={}&outcome=failed", trainee(0, 2)),
        ),
        (
            "compare search, page 50 (10 000)",
            &curriculum,
            "/compare?page=50".into(),
        ),
        ("curriculum home (10 000)", &curriculum, "/".into()),
        ("sessions, page 1 of 100", &curriculum, "/sessions".into()),
        ("sessions, page 50", &curriculum, "/sessions?page=50".into()),
        ("reports", &curriculum, "/reports".into()),
        ("cohort report (2 500)", &curriculum, "/reports/cohort?cohort=c1".into()),
        ("accounts", &admin, "/admin/users".into()),
        (
            "CSV export (10 000 rows)",
            &curriculum,
            "/api/export/sessions.csv".into(),
        ),
    ];
    println!(
        "{:<34} {:>7} {:>9} {:>9} {:>9}",
        "page", "KiB", "p50 ms", "p99 ms", "p50/base"
    );
    let mut base_p50 = None;
    for (name, client, path) in &pages {
        let url = format!("{base}{path}");
        // Warm: the first review/figure request builds the cached trace and PNG.
        for _ in 0..3.min(requests) {
            let (status, _, _) = client.get(&url);
            assert_eq!(status, 200, "{name}: {url}");
        }
        let mut times = Vec::with_capacity(requests);
        let mut size = 0;
        for _ in 0..requests {
            let (status, len, t) = client.get(&url);
            assert_eq!(status, 200, "{name}");
            size = len;
            times.push(t);
        }
        times.sort();
        let (p50, p99) = (percentile(&times, 0.5), percentile(&times, 0.99));
        let base_p50 = *base_p50.get_or_insert(p50);
        println!(
            "{name:<34} {:>7.1} {p50:>9.2} {p99:>9.2} {:>9.1}",
            size as f64 / 1024.0,
            p50 / base_p50
        );
    }
    std::io::stdout().flush().unwrap();
}
