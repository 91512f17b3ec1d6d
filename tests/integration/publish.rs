//! Publishing atlases (docs/api.md "Atlases"): `stylet atlas validate`, then `stylet atlas publish`
//! with an instructor's token; the service checks the atlas again, keeps it by content hash, lists
//! it in the catalogue (API and page), audits it, and accepts and scores sessions on it, also after
//! a restart. Every kind of bad publication is refused with its reason and leaves nothing behind.

use std::path::{Path, PathBuf};
use std::time::Duration;

use crate::common::*;
use serde_json::Value;

on_both_databases!(publishing_an_atlas, "publish");

/// `stylet atlas publish DIR --server BASE` with `token` in STYLET_TOKEN: (success, stdout, stderr).
fn publish_cli(dir: &Path, base: &str, token: &str) -> (bool, String, String) {
    let out = STYLET
        .command()
        .args(["atlas", "publish", s(dir), "--server", base])
        .env("STYLET_TOKEN", token)
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// A `full` API token of `user`.
fn full_token(base: &str, user: &str) -> String {
    let who = login(base, user);
    let (status, made, _) = call(
        "POST",
        &format!("{base}/api/tokens"),
        Some(&who),
        Some(br#"{"label":"publishing","scope":"full"}"#),
        true,
    );
    assert_eq!(status, 201, "{made}");
    made["token"].as_str().unwrap().to_string()
}

/// The audit rows of `action`: (actor username, target, detail).
fn audits(db: &Db, data: &Path, action: &str) -> Vec<(String, String, String)> {
    on_database(db, data, async |store| {
        let rows = sqlx::query(
            "SELECT u.username, a.target, a.detail FROM audit_log a JOIN users u ON u.id = a.actor_id \
             WHERE a.action = $1 ORDER BY a.at, a.id",
        )
        .bind(action.to_string())
        .fetch_all(&store.pool)
        .await
        .unwrap();
        use sqlx::Row;
        rows.iter()
            .map(|r| {
                (
                    r.get::<String, _>("username"),
                    r.get::<String, _>("target"),
                    r.get::<String, _>("detail"),
                )
            })
            .collect()
    })
}

/// What `DATA/atlases` holds: the published atlases' folders, and nothing else.
fn published_entries(data: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(data.join("atlases"))
        .map(|rd| {
            rd.flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .collect()
        })
        .unwrap_or_default();
    names.sort();
    names
}

fn catalogue(base: &str, who: &Auth) -> Vec<Value> {
    let (status, json, _) = call("GET", &format!("{base}/api/atlases"), Some(who), None, false);
    assert_eq!(status, 200, "{json}");
    json["atlases"].as_array().unwrap().clone()
}

/// An upload's files: (name inside the archive, bytes).
type Files = Vec<(String, Vec<u8>)>;

fn publishing_an_atlas(db: Db) {
    let f = Fixture::new(STYLET);
    f.users(&db);
    let data = f.data();
    let other = f.dir.path().join("other-atlas");
    let session = std::fs::read(f.session("tina-other-atlas")).unwrap();

    // Not validated yet: the command refuses before sending anything.
    let srv = Server::start(STYLET, &data, &db, &f.atlases(), &["--workers", "1"]);
    let b = srv.base.clone();
    let ivan_token = full_token(&b, "ivan");
    let (ok_, _, err) = publish_cli(&other, &b, &ivan_token);
    assert!(
        !ok_ && err.contains("not validated") && err.contains("stylet atlas validate"),
        "{err}"
    );

    // A session on the unpublished atlas is refused.
    let tina = login(&b, "tina");
    let (status, json, _) = call("POST", &format!("{b}/api/sessions"), Some(&tina), Some(&session), false);
    assert_eq!(status, 422, "{json}");
    assert!(json["error"].as_str().unwrap().contains("does not know"), "{json}");

    let out = ok(&["atlas", "validate", s(&other)]);
    assert!(out.contains("is validated"), "{out}");
    assert!(other.join("validation.toml").is_file());

    // Trainees and curriculum staff may not publish, whatever their token.
    for user in ["tina", "cora"] {
        let token = full_token(&b, user);
        let (ok_, _, err) = publish_cli(&other, &b, &token);
        assert!(
            !ok_ && err.contains("403") && err.contains("only admins and instructors may publish"),
            "{user}: {err}"
        );
    }
    // No token at all.
    let out = STYLET
        .command()
        .args(["atlas", "publish", s(&other), "--server", &b])
        .env_remove("STYLET_TOKEN")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("set STYLET_TOKEN"), "{err}");
    assert!(published_entries(&data).is_empty(), "{:?}", published_entries(&data));

    // The instructor publishes it.
    let (ok_, out, err) = publish_cli(&other, &b, &ivan_token);
    assert!(ok_, "{out}{err}");
    assert!(out.contains("published on"), "{out}");
    assert!(out.contains("success.txt ok"), "{out}");
    let list = catalogue(&b, &tina);
    let item = list
        .iter()
        .find(|a| a["origin"] == "published")
        .unwrap_or_else(|| panic!("{list:?}"));
    let hash = item["content_hash"].as_str().unwrap().to_string();
    assert_eq!(item["published_by"], "ivan", "{item}");
    assert_eq!(published_entries(&data), vec![hash.clone()]);
    let audit = audits(&db, &data, "atlas.publish");
    assert_eq!(audit.len(), 1, "{audit:?}");
    assert_eq!((audit[0].0.as_str(), audit[0].1.as_str()), ("ivan", hash.as_str()));
    assert!(audit[0].2.contains("success.txt ok"), "{audit:?}");

    // Sessions on it are now accepted and scored.
    let (status, json, _) = call("POST", &format!("{b}/api/sessions"), Some(&tina), Some(&session), false);
    assert_eq!(status, 201, "{json}");
    let id = json["id"].as_str().unwrap().to_string();
    let scored = wait_scored(&b, &tina, &id);
    assert_eq!(scored["status"], "scored", "{scored}");
    assert_eq!(scored["atlas_hash"].as_str(), Some(hash.as_str()), "{scored}");

    // Publishing it again changes nothing.
    let (ok_, out, err) = publish_cli(&other, &b, &ivan_token);
    assert!(ok_ && out.contains("was already published"), "{out}{err}");
    assert_eq!(published_entries(&data), vec![hash.clone()]);

    // The catalogue page lists it, with its publisher and its session.
    let page = dashboard_page(&b, &tina, "/atlases");
    assert!(
        page.contains("Scenario catalogue") && page.contains(&format!("data-hash=\"{hash}\"")),
        "{page}"
    );
    assert!(page.contains("published by ivan"), "{page}");

    // After a restart the published atlas is still known, and its session still scored.
    drop(srv);
    let srv = Server::start(STYLET, &data, &db, &f.atlases(), &["--workers", "1"]);
    let b = srv.base.clone();
    let tina = login(&b, "tina");
    let list = catalogue(&b, &tina);
    let item = list
        .iter()
        .find(|a| a["content_hash"] == hash.as_str())
        .expect("still listed");
    assert_eq!(
        (item["origin"].as_str(), item["sessions"].as_i64()),
        (Some("published"), Some(1)),
        "{item}"
    );
    let (status, json, _) = call("GET", &format!("{b}/api/sessions/{id}"), Some(&tina), None, false);
    assert_eq!((status, json["status"].as_str()), (200, Some("scored")), "{json}");
}

/// The HTML of a dashboard page seen by `who` (its login cookie).
fn dashboard_page(base: &str, who: &Auth, path: &str) -> String {
    let Auth::Cookie { token, .. } = who else {
        panic!("a login")
    };
    ureq::get(&format!("{base}{path}"))
        .set("Cookie", &format!("stylet_session={token}"))
        .call()
        .unwrap()
        .into_string()
        .unwrap()
}

/// A tar archive of `files` (name, bytes), as regular files.
fn tar_of(files: &[(&str, Vec<u8>)]) -> Vec<u8> {
    let mut b = tar::Builder::new(Vec::new());
    for (name, bytes) in files {
        let mut h = tar::Header::new_gnu();
        h.set_size(bytes.len() as u64);
        h.set_mode(0o644);
        h.set_entry_type(tar::EntryType::Regular);
        // Names set raw: the builder's own checks would refuse the hostile ones.
        let field = &mut h.as_old_mut().name;
        field[..name.len()].copy_from_slice(name.as_bytes());
        h.set_cksum();
        b.append(&h, bytes.as_slice()).unwrap();
    }
    b.into_inner().unwrap()
}

/// The files of the atlas in `dir` as an upload holds them.
fn atlas_files(dir: &Path) -> Files {
    let mut files: Files = ["atlas.toml", "validation.toml", "ct.nii.gz", "labels.nii.gz"]
        .iter()
        .map(|n| (n.to_string(), std::fs::read(dir.join(n)).unwrap()))
        .collect();
    for e in std::fs::read_dir(dir.join("scripts")).unwrap().flatten() {
        let name = format!("scripts/{}", e.file_name().to_string_lossy());
        files.push((name, std::fs::read(e.path()).unwrap()));
    }
    files
}

/// A POST of an archive (over a raw socket: the server may answer and close before the whole
/// body is sent, as it does for refusals decided from the headers): status and its error.
fn post_tar(base: &str, token: &str, body: &[u8], content_type: &str) -> (u16, String) {
    let auth = Auth::Bearer(token.to_string());
    let (status, json) = raw_post_as(base, "/api/atlases", Some(&auth), content_type, body);
    let error = json["error"].as_str().map_or_else(|| json.to_string(), str::to_string);
    (status, error)
}

#[test]
fn bad_publications_are_refused_with_the_reason_and_leave_nothing() {
    let db = Db::Sqlite;
    let f = Fixture::new(STYLET);
    f.users(&db);
    let data = f.data();
    let good = f.dir.path().join("other-atlas");
    ok(&["atlas", "validate", s(&good)]);
    let srv = Server::start(
        STYLET,
        &data,
        &db,
        &f.atlases(),
        &["--workers", "1", "--max-atlas-bytes", "8000000"],
    );
    let b = srv.base.clone();
    let token = full_token(&b, "root");
    let files = atlas_files(&good);
    let with = |edit: &dyn Fn(&mut Files)| {
        let mut f = files.clone();
        edit(&mut f);
        let refs: Vec<(&str, Vec<u8>)> = f.iter().map(|(n, b)| (n.as_str(), b.clone())).collect();
        tar_of(&refs)
    };
    let replace = |name: &'static str, bytes: Vec<u8>| {
        move |f: &mut Files| {
            for e in f.iter_mut().filter(|e| e.0 == name) {
                e.1 = bytes.clone();
            }
        }
    };
    let text = |name: &str| String::from_utf8(files.iter().find(|f| f.0 == name).unwrap().1.clone()).unwrap();
    let ct = files.iter().find(|f| f.0 == "ct.nii.gz").unwrap().1.clone();

    // The guided path's target moved 40 mm off the duct, and the record rewritten for the new
    // content: the record vouches, but the scripts the server generates fail.
    let moved_target = {
        let manifest = text("atlas.toml");
        let at = manifest.find("target_mm = [\n").unwrap() + "target_mm = [\n".len();
        let end = at + manifest[at..].find(',').unwrap();
        let x: f64 = manifest[at..end].trim().parse().unwrap();
        let moved = format!("{}    {:.1}{}", &manifest[..at], x - 40.0, &manifest[end..]);
        let tmp = tempfile::tempdir().unwrap();
        std::fs::write(tmp.path().join("atlas.toml"), &moved).unwrap();
        for v in ["ct.nii.gz", "labels.nii.gz"] {
            std::fs::copy(good.join(v), tmp.path().join(v)).unwrap();
        }
        let parsed = stylet_atlas::store::parse_manifest(&moved).unwrap();
        let hash = stylet_atlas::store::content_hash(tmp.path(), &parsed).unwrap();
        let old = stylet_atlas::store::parse_manifest(&text("atlas.toml")).unwrap();
        let old_hash = stylet_atlas::store::content_hash(&good, &old).unwrap();
        let record = text("validation.toml").replace(&old_hash, &hash);
        with(&|f: &mut Files| {
            replace("atlas.toml", moved.clone().into_bytes())(f);
            replace("validation.toml", record.clone().into_bytes())(f);
        })
    };
    // The record rewritten to vouch for the content of `files` (its hash computed as the server
    // does).
    let vouched = |edit: &dyn Fn(&mut Files)| {
        let mut edited = files.clone();
        edit(&mut edited);
        let tmp = tempfile::tempdir().unwrap();
        for (name, bytes) in &edited {
            if !name.contains('/') {
                std::fs::write(tmp.path().join(name), bytes).unwrap();
            }
        }
        let parsed = stylet_atlas::store::read_manifest(tmp.path()).unwrap();
        let hash = stylet_atlas::store::content_hash(tmp.path(), &parsed).unwrap();
        let old = stylet_atlas::store::parse_manifest(&text("atlas.toml")).unwrap();
        let old_hash = stylet_atlas::store::content_hash(&good, &old).unwrap();
        let record = text("validation.toml").replace(&old_hash, &hash);
        with(&|f: &mut Files| {
            edit(f);
            replace("validation.toml", record.clone().into_bytes())(f);
        })
    };
    let damaged_vouched = vouched(&replace("ct.nii.gz", ct[..ct.len() / 2].to_vec()));
    let cases: Vec<(&str, Vec<u8>, &str, u16, &str)> = vec![
        (
            "not a tar",
            b"hello, this is not an archive".to_vec(),
            "application/x-tar",
            422,
            "the archive is not valid",
        ),
        (
            "wrong media type",
            with(&|_| {}),
            "application/zip",
            415,
            "Content-Type application/x-tar",
        ),
        (
            "no validation record",
            with(&|f| f.retain(|e| e.0 != "validation.toml")),
            "application/x-tar",
            422,
            "not validated: it has no validation.toml",
        ),
        (
            "changed after validation",
            with(&replace(
                "atlas.toml",
                text("atlas.toml")
                    .replacen("description = \"", "description = \"Edited. ", 1)
                    .into_bytes(),
            )),
            "application/x-tar",
            422,
            "changed after it was validated",
        ),
        (
            // The record is checked first, before a volume is read: it vouches for other content.
            "a damaged CT",
            with(&replace("ct.nii.gz", ct[..ct.len() / 2].to_vec())),
            "application/x-tar",
            422,
            "changed after it was validated",
        ),
        (
            "a damaged CT with a record written for it",
            damaged_vouched.clone(),
            "application/x-tar",
            422,
            "the atlas is damaged: ct.nii.gz",
        ),
        (
            "a record whose script failed",
            with(&replace(
                "validation.toml",
                text("validation.toml")
                    .replacen("passed = true", "passed = false", 1)
                    .into_bytes(),
            )),
            "application/x-tar",
            422,
            "not validated: its smoke test failed: scripts/success.txt should: reaches and confirms the target",
        ),
        (
            "a script the record names is missing",
            with(&|f| f.retain(|e| e.0 != "scripts/success.txt")),
            "application/x-tar",
            422,
            "scripts/success.txt",
        ),
        (
            "a target moved off the duct, the record rewritten for it",
            moved_target.clone(),
            "application/x-tar",
            422,
            "the server's own smoke test of the atlas failed: scripts/success.txt should: reaches and confirms the target",
        ),
        (
            "a long name beyond the extended-header limit",
            {
                let mut b = tar::Builder::new(Vec::new());
                let mut h = tar::Header::new_gnu();
                h.set_size(1);
                h.set_mode(0o644);
                let long = format!("scripts/{}.txt", "a".repeat(5000));
                b.append_data(&mut h, long, &b"x"[..]).unwrap();
                b.into_inner().unwrap()
            },
            "application/x-tar",
            422,
            "an extended header (long name or PAX record) of 5013 bytes",
        ),
        (
            "a path that climbs out",
            with(&|f| f.push(("../escape.nii".into(), b"x".to_vec()))),
            "application/x-tar",
            422,
            "unexpected entry \"../escape.nii\"",
        ),
        (
            "an unknown file",
            with(&|f| f.push(("report/index.html".into(), b"<script>".to_vec()))),
            "application/x-tar",
            422,
            "unexpected entry \"report/index.html\"",
        ),
        (
            "a third volume",
            with(&|f| f.push(("extra.nii.gz".into(), b"x".to_vec()))),
            "application/x-tar",
            422,
            "more than two NIfTI volumes",
        ),
        (
            "a name twice",
            with(&|f| f.push(("atlas.toml".into(), b"x".to_vec()))),
            "application/x-tar",
            422,
            "appears twice",
        ),
    ];
    for (what, body, media, status, reason) in cases {
        let (got, error) = post_tar(&b, &token, &body, media);
        eprintln!("{what}: {got} {error}");
        assert_eq!(got, status, "{what}: {error}");
        assert!(error.contains(reason), "{what}: {error}");
        assert!(
            published_entries(&data).is_empty(),
            "{what} left {:?}",
            published_entries(&data)
        );
    }

    // A symbolic link in the archive.
    let mut tb = tar::Builder::new(Vec::new());
    let mut h = tar::Header::new_gnu();
    h.set_entry_type(tar::EntryType::Symlink);
    h.set_size(0);
    h.set_link_name("/etc/passwd").unwrap();
    tb.append_data(&mut h, "atlas.toml", std::io::empty()).unwrap();
    let (got, error) = post_tar(&b, &token, &tb.into_inner().unwrap(), "application/x-tar");
    assert_eq!(got, 422, "{error}");
    assert!(error.contains("not a regular file"), "{error}");

    // No Content-Length (a chunked body): its time limit could not follow from its size.
    {
        use std::io::{Read, Write};
        let addr = b.strip_prefix("http://").unwrap();
        let mut sock = std::net::TcpStream::connect(addr).unwrap();
        let head = format!(
            "POST /api/atlases HTTP/1.1\r\nHost: {addr}\r\nAuthorization: Bearer {token}\r\n\
             Content-Type: application/x-tar\r\nTransfer-Encoding: chunked\r\nConnection: close\r\n\r\n5\r\nhello\r\n0\r\n\r\n"
        );
        sock.write_all(head.as_bytes()).unwrap();
        let mut resp = String::new();
        let _ = sock.read_to_string(&mut resp);
        assert!(
            resp.starts_with("HTTP/1.1 411") && resp.contains("Content-Length"),
            "{resp}"
        );
    }

    // Larger than the server's limit: refused before the body is read.
    let (got, error) = post_tar(
        &b,
        &token,
        &with(&replace("ct.nii.gz", vec![0u8; 9_000_000])),
        "application/x-tar",
    );
    assert_eq!(got, 413, "{error}");
    assert!(error.contains("limit of 8000000 bytes"), "{error}");
    assert!(published_entries(&data).is_empty(), "{:?}", published_entries(&data));

    // The good archive still publishes.
    let (got, error) = post_tar(&b, &token, &with(&|_| {}), "application/x-tar");
    assert_eq!(got, 201, "{error}");
    assert_eq!(published_entries(&data).len(), 1);
}

#[test]
fn a_stale_atlas_is_refused_before_anything_is_sent() {
    let dir = tempfile::tempdir().unwrap();
    let atlas: PathBuf = dir.path().join("a");
    phantom_atlas(&atlas, "96,96,80", "4");
    ok(&["atlas", "validate", s(&atlas)]);
    let manifest = std::fs::read_to_string(atlas.join("atlas.toml")).unwrap();
    std::fs::write(
        atlas.join("atlas.toml"),
        manifest.replacen("description = \"", "description = \"Edited. ", 1),
    )
    .unwrap();
    // No server listens there: the refusal comes before any connection.
    let (ok_, _, err) = publish_cli(&atlas, "http://127.0.0.1:9", "token");
    assert!(!ok_ && err.contains("changed after it was validated"), "{err}");
}

/// An atlas with measured breathing motion (`stylet atlas attach-motion`) is published with its
/// fields and signal under `motion/`, and a breathing session on it is accepted and scored; a
/// motion file atlas.toml does not name, one missing, or too many are refused.
#[test]
fn an_atlas_with_measured_breathing_is_published_with_its_motion() {
    use stylet_atlas::nifti_io::write_displacement_field;
    use stylet_physics::Grid;
    use stylet_physics::glam::DVec3;
    use stylet_physics::motion::GridField;

    let db = Db::Sqlite;
    let f = Fixture::new(STYLET);
    f.users(&db);
    let data = f.data();
    let work = f.dir.path().join("work");
    std::fs::create_dir_all(&work).unwrap();
    let dir = f.dir.path().join("breathing-atlas");
    phantom_atlas(&dir, "96,96,80", "4");
    let bounds = stylet_atlas::load(&dir).unwrap().model.ct().grid().world_bounds();
    let centre = (bounds.0 + bounds.1) * 0.5;
    let grid = Grid::new([24, 24, 20], stylet_physics::Affine::from_spacing([16.0; 3], bounds.0)).unwrap();
    let field = GridField::sample(grid, move |x| {
        DVec3::new(0.0, 2.0, -8.0) * (-(x - centre).length_squared() / (2.0 * 80.0 * 80.0)).exp()
    });
    let a1 = work.join("a1.nii.gz");
    write_displacement_field(&a1, &field, "publish test").unwrap();
    let signal = work.join("signal.csv");
    let rows: String = (0..=80)
        .map(|k| {
            format!(
                "{:.2},{:.6}\n",
                k as f64 * 0.25,
                (std::f64::consts::PI * k as f64 * 0.25 / 4.0).sin().powi(2)
            )
        })
        .collect();
    std::fs::write(&signal, format!("time_s,g\n{rows}")).unwrap();
    ok(&[
        "atlas",
        "attach-motion",
        s(&dir),
        "--a1",
        s(&a1),
        "--signal",
        s(&signal),
    ]);
    ok(&["atlas", "validate", s(&dir)]);

    // A server whose voxel limit the CT (96 × 96 × 80 = 737 280 voxels) fits but not the CT and
    // the field (24 × 24 × 20 = 11 520) together: refused from the headers, with the count.
    {
        let small = Server::start(
            STYLET,
            &data,
            &db,
            &f.atlases(),
            &["--workers", "1", "--max-atlas-voxels", "740000"],
        );
        let token = full_token(&small.base, "ivan");
        let (ok_, out, err) = publish_cli(&dir, &small.base, &token);
        assert!(!ok_, "{out}{err}");
        assert!(err.contains("413") || err.contains("too large"), "{err}");
        assert!(
            err.contains("748800 voxels") && err.contains("limit of 740000"),
            "{err}"
        );
        assert!(published_entries(&data).is_empty(), "{:?}", published_entries(&data));
    }

    let srv = Server::start(STYLET, &data, &db, &f.atlases(), &["--workers", "1"]);
    let b = srv.base.clone();
    let token = full_token(&b, "ivan");

    // Hand-made archives first: each refused with its reason, nothing kept.
    let mut files = atlas_files(&dir);
    let mut motion: Vec<String> = std::fs::read_dir(dir.join("motion"))
        .unwrap()
        .map(|e| format!("motion/{}", e.unwrap().file_name().to_string_lossy()))
        .collect();
    motion.sort();
    assert_eq!(motion.len(), 2, "{motion:?}");
    for m in &motion {
        files.push((m.clone(), std::fs::read(dir.join(m)).unwrap()));
    }
    let with = |edit: &dyn Fn(&mut Files)| {
        let mut f = files.clone();
        edit(&mut f);
        let refs: Vec<(&str, Vec<u8>)> = f.iter().map(|(n, b)| (n.as_str(), b.clone())).collect();
        tar_of(&refs)
    };
    let field_bytes = std::fs::read(&a1).unwrap();
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        (
            "a field atlas.toml does not name",
            with(&|f| f.push(("motion/a2.nii.gz".into(), field_bytes.clone()))),
            "\"motion/a2.nii.gz\" is not a breathing file atlas.toml names",
        ),
        (
            "the signal left out",
            with(&|f| f.retain(|e| !e.0.ends_with(".csv"))),
            "the atlas is damaged",
        ),
        (
            "five motion files",
            with(&|f| {
                for k in 0..3 {
                    f.push((format!("motion/x{k}.nii.gz"), b"x".to_vec()));
                }
            }),
            "more than 4 files of breathing motion",
        ),
        (
            "a motion file in a folder of its own",
            with(&|f| f.push(("motion/deep/a.nii.gz".into(), b"x".to_vec()))),
            "unexpected entry \"motion/deep/a.nii.gz\"",
        ),
    ];
    for (what, body, reason) in cases {
        let (got, error) = post_tar(&b, &token, &body, "application/x-tar");
        eprintln!("{what}: {got} {error}");
        assert_eq!(got, 422, "{what}: {error}");
        assert!(error.contains(reason), "{what}: {error}");
        assert!(
            published_entries(&data).is_empty(),
            "{what} left {:?}",
            published_entries(&data)
        );
    }

    // The command packs the motion with the atlas; the service keeps it.
    let (ok_, out, err) = publish_cli(&dir, &b, &token);
    assert!(ok_, "{out}{err}");
    let hash = stylet_atlas::load(&dir).unwrap().content_hash;
    assert_eq!(published_entries(&data), vec![hash.clone()]);
    for m in &motion {
        assert_eq!(
            std::fs::read(data.join("atlases").join(&hash).join(m)).unwrap(),
            std::fs::read(dir.join(m)).unwrap(),
            "{m}"
        );
    }

    // A breathing session on it is accepted, replayed with the measured motion and scored.
    // (The script's name is the scenario's: one the atlas declares.)
    let script = work.join("success-intercostal.txt");
    std::fs::write(
        &script,
        "stylet-script 1\nbreathing on\nend 5\nat 0 along intercostal-10-11 -15\nat 4 along intercostal-10-11 40\n",
    )
    .unwrap();
    let session = work.join("breathe.mcap");
    ok(&[
        "script",
        "run",
        "--atlas",
        s(&dir),
        "--script",
        s(&script),
        "--out",
        s(&session),
        "--trainee",
        "tina",
    ]);
    let tina = login(&b, "tina");
    let (_, scored) = upload_scored(&b, &tina, &session);
    assert_eq!(scored["atlas_hash"].as_str(), Some(hash.as_str()), "{scored}");
}

/// A 512-byte tar header of `kind` for `name` declaring `size` bytes, its checksum set.
fn raw_header(name: &str, kind: tar::EntryType, size: u64) -> Vec<u8> {
    let mut h = tar::Header::new_ustar();
    h.set_entry_type(kind);
    h.set_size(size);
    h.set_mode(0o644);
    h.as_old_mut().name[..name.len()].copy_from_slice(name.as_bytes());
    h.set_cksum();
    h.as_bytes().to_vec()
}

/// `data` padded to whole 512-byte blocks.
fn blocks(data: &[u8]) -> Vec<u8> {
    let mut out = data.to_vec();
    out.resize(data.len().div_ceil(512) * 512, 0);
    out
}

/// Archives built to make the server read much, or to tell files apart, are refused before anything
/// large is read; refusals are short and never echo what was sent. A PAX `size` that disagrees with
/// its entry's header (a folder: PAX 512, header 0) in front of a 64 MiB GNU long name; an entry
/// running past the end of the archive; breathing files outside the atlas (`/etc/passwd` and a path
/// that does not exist answer alike).
#[test]
fn hostile_archives_are_refused_before_they_are_read() {
    let db = Db::Sqlite;
    let f = Fixture::new(STYLET);
    let srv = f.serve(&db, 1);
    let b = srv.base.clone();
    let token = full_token(&b, "root");
    let pid = srv.child.id();
    std::fs::write(format!("/proc/{pid}/clear_refs"), "5").unwrap();
    let (_, rss0) = memory_mib(pid);

    // The PAX record says the folder has 512 bytes; its header says 0. After it, a block of
    // zeros: a reader believing the header takes it for the end of the archive, one believing the
    // PAX record for the folder's data, and reads on: a GNU long name of 64 MiB.
    let long: u64 = 64 << 20;
    let mut pax_then_long = Vec::new();
    let record = b"12 size=512\n";
    pax_then_long.extend(raw_header(
        "PaxHeaders/scripts",
        tar::EntryType::XHeader,
        record.len() as u64,
    ));
    pax_then_long.extend(blocks(record));
    pax_then_long.extend(raw_header("scripts/", tar::EntryType::Directory, 0));
    pax_then_long.extend([0u8; 512]);
    pax_then_long.extend(raw_header("././@LongLink", tar::EntryType::GNULongName, long));
    pax_then_long.extend(std::iter::repeat_n(b'a', long as usize));
    pax_then_long.extend(raw_header("atlas.toml", tar::EntryType::Regular, 0));
    pax_then_long.extend([0u8; 1024]);

    let mut past_end = raw_header("ct.nii.gz", tar::EntryType::Regular, 1 << 30);
    past_end.extend([7u8; 4096]);

    let good = f.dir.path().join("other-atlas");
    ok(&["atlas", "validate", s(&good)]);
    let with_breathing = |a1: &str| {
        let mut files = atlas_files(&good);
        for (name, bytes) in files.iter_mut() {
            if name == "atlas.toml" {
                let text = String::from_utf8(bytes.clone()).unwrap();
                assert!(text.contains("motion = \"synthetic\"\n"), "the atlas breathes");
                *bytes = text
                    .replacen(
                        "motion = \"synthetic\"\n",
                        &format!("motion = \"measured\"\na1 = {a1:?}\n"),
                        1,
                    )
                    .into_bytes();
            }
        }
        let refs: Vec<(&str, Vec<u8>)> = files.iter().map(|(n, b)| (n.as_str(), b.clone())).collect();
        tar_of(&refs)
    };

    for (what, body, reason) in [
        (
            "a PAX size that disagrees, before a 64 MiB long name",
            pax_then_long,
            "a PAX record gives an entry 512 bytes, its header 0",
        ),
        ("an entry past the end", past_end, "runs past the end of the archive"),
    ] {
        let (status, json) = raw_post_as(
            &b,
            "/api/atlases",
            Some(&Auth::Bearer(token.clone())),
            "application/x-tar",
            &body,
        );
        let text = json.to_string();
        assert_eq!(status, 422, "{what}: {}", &text[..text.len().min(300)]);
        assert!(text.len() < 4096, "{what}: a {}-byte refusal", text.len());
        assert!(!text.contains("aaaaaaaaaaaaaaaa"), "{what}: the name was echoed");
        assert!(text.contains(reason), "{what}: {text}");
    }
    let (peak, _) = memory_mib(pid);
    println!("hostile archives: server RSS {rss0:.0} MiB, peak {peak:.0} MiB");
    // The 64 MiB name was never read into memory.
    assert!(peak - rss0 < 32.0, "{rss0:.0} -> {peak:.0} MiB");

    // Files outside the atlas: the same answer whether or not something is there.
    let answers: Vec<(u16, String)> = [
        "/etc/passwd",
        "/no/such/file.nii.gz",
        "../../stylet.db",
        "../../nothing",
    ]
    .iter()
    .map(|p| post_tar(&b, &token, &with_breathing(p), "application/x-tar"))
    .collect();
    for (status, error) in &answers {
        assert_eq!(*status, 422, "{error}");
        assert!(
            error.contains("breathing.a1") && error.contains("inside the atlas directory"),
            "{error}"
        );
    }
    assert!(answers.windows(2).all(|w| w[0] == w[1]), "{answers:#?}");
    assert!(
        published_entries(&f.data()).is_empty(),
        "{:?}",
        published_entries(&f.data())
    );
}

/// `stylet atlas unpublish HASH --server BASE` with `token` in STYLET_TOKEN.
fn unpublish_cli(hash: &str, base: &str, token: &str) -> (bool, String, String) {
    let out = STYLET
        .command()
        .args(["atlas", "unpublish", hash, "--server", base])
        .env("STYLET_TOKEN", token)
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Two publications whose archives arrive slowly do not hold up a third. An atlas published before
/// is not checked again (a server whose voxel limit it no longer meets takes it back at once).
/// Withdrawing (`DELETE /api/atlases/{hash}`, admins only, and `stylet atlas unpublish`): the atlas
/// leaves the catalogue and takes no new sessions, the sessions on it stay readable and replayable,
/// every step audited; publishing it again reinstates it. The server runs with a one-byte atlas
/// cache, so every atlas it needs is loaded again from disk: scores and player frames still come.
#[test]
fn publications_arrive_side_by_side_and_atlases_are_withdrawn() {
    let db = Db::Sqlite;
    let f = Fixture::new(STYLET);
    f.users(&db);
    let data = f.data();
    let good = f.dir.path().join("other-atlas");
    ok(&["atlas", "validate", s(&good)]);
    let archive = {
        let files = atlas_files(&good);
        let refs: Vec<(&str, Vec<u8>)> = files.iter().map(|(n, b)| (n.as_str(), b.clone())).collect();
        tar_of(&refs)
    };
    let extra = [
        "--workers",
        "1",
        "--min-upload-rate",
        "1024",
        "--atlas-cache-bytes",
        "1",
    ];
    let srv = Server::start(STYLET, &data, &db, &f.atlases(), &extra);
    let b = srv.base.clone();
    let addr = b.strip_prefix("http://").unwrap().to_string();
    let (root_token, ivan_token) = (full_token(&b, "root"), full_token(&b, "ivan"));
    let configured = catalogue(&b, &login(&b, "tina"))[0]["content_hash"].clone();

    // Two slow publications (a few KB/s of a 1 MB archive), then a third, whole.
    let slow: Vec<std::net::TcpStream> = [&root_token, &ivan_token]
        .iter()
        .map(|t| {
            use std::io::Write;
            let mut sock = std::net::TcpStream::connect(&addr).unwrap();
            let head = format!(
                "POST /api/atlases HTTP/1.1\r\nHost: {addr}\r\nAuthorization: Bearer {t}\r\n\
                 Content-Type: application/x-tar\r\nContent-Length: 1000000\r\n\r\n"
            );
            sock.write_all(head.as_bytes()).unwrap();
            sock.write_all(&[0u8; 4096]).unwrap();
            sock
        })
        .collect();
    let feeding = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(true));
    let feeder = {
        let feeding = feeding.clone();
        std::thread::spawn(move || {
            use std::io::Write;
            let mut slow = slow;
            while feeding.load(std::sync::atomic::Ordering::Relaxed) {
                for sock in &mut slow {
                    let _ = sock.write_all(&[0u8; 2048]);
                }
                std::thread::sleep(Duration::from_secs(1));
            }
        })
    };
    std::thread::sleep(Duration::from_secs(2));
    let (status, error) = post_tar(&b, &root_token, &archive, "application/x-tar");
    feeding.store(false, std::sync::atomic::Ordering::Relaxed);
    feeder.join().unwrap();
    assert_eq!(status, 201, "a publication beside two slow ones: {error}");
    let hash = catalogue(&b, &login(&b, "tina"))
        .iter()
        .find(|a| a["content_hash"] != configured)
        .map(|a| a["content_hash"].as_str().unwrap().to_string())
        .unwrap();

    // A session on it, scored; then withdrawn by an admin (not by an instructor).
    let tina = login(&b, "tina");
    let session = std::fs::read(f.session("tina-other-atlas")).unwrap();
    let (status, up) = raw_post(&b, "/api/sessions", Some(&tina), &session);
    assert_eq!(status, 201, "{up}");
    let id = up["id"].as_str().unwrap().to_string();
    assert_eq!(wait_scored(&b, &tina, &id)["status"], "scored");
    let url = format!("{b}/api/atlases/{hash}");
    let ivan = Auth::Bearer(ivan_token.clone());
    let (status, body, _) = call("DELETE", &url, Some(&ivan), None, false);
    assert_eq!(status, 403, "{body}");
    let root = Auth::Bearer(root_token.clone());
    let (status, body, _) = call("DELETE", &url, Some(&root), None, false);
    assert_eq!(status, 200, "{body}");
    assert_eq!(body["status"], "withdrawn");
    let (status, _, _) = call("DELETE", &url, Some(&root), None, false);
    assert_eq!(status, 409, "withdrawn twice");
    let (status, _, _) = call(
        "DELETE",
        &format!("{b}/api/atlases/{}", "0".repeat(64)),
        Some(&root),
        None,
        false,
    );
    assert_eq!(status, 404);
    assert!(catalogue(&b, &tina).iter().all(|a| a["content_hash"] != hash.as_str()));
    // No new sessions on it; the old one stays readable and replayable.
    let mut again =
        stylet_recorder::reader::read_bytes(&session, stylet_recorder::Mode::Strict, &Default::default()).unwrap();
    again.header.session_id = stylet_recorder::new_session_id();
    let other = f.dir.path().join("again.mcap");
    let w = stylet_recorder::SessionWriter::create(&other, &again.header, Default::default()).unwrap();
    for e in &again.events {
        w.event_record_blocking(e.clone()).unwrap();
    }
    for d in &again.digests {
        w.digest_blocking(d.tick, d.digest).unwrap();
    }
    w.record_read_blocking(&again.ticks, &again.output_checks).unwrap();
    w.finish().unwrap();
    let (status, refused) = raw_post(&b, "/api/sessions", Some(&tina), &std::fs::read(&other).unwrap());
    assert_eq!(status, 422, "{refused}");
    assert!(refused["error"].as_str().unwrap().contains("withdrawn"), "{refused}");
    let (status, row, _) = call("GET", &format!("{b}/api/sessions/{id}"), Some(&tina), None, false);
    assert_eq!((status, row["status"].as_str()), (200, Some("scored")), "{row}");
    let frame = format!("{b}/sessions/{id}/frame?view=axial&tick=100");
    let (status, png) = get_bytes(&frame, &tina);
    assert_eq!(status, 200, "{}", String::from_utf8_lossy(&png));
    assert!(png.starts_with(b"\x89PNG"));
    assert_eq!(audits(&db, &data, "atlas.withdraw").len(), 1);

    // Published again: reinstated, at once (the checks ran when it was first published).
    let (status, error) = post_tar(&b, &ivan_token, &archive, "application/x-tar");
    assert_eq!(status, 201, "{error}");
    assert!(catalogue(&b, &tina).iter().any(|a| a["content_hash"] == hash.as_str()));
    // And withdrawn again from the command line.
    let (ok_, out, err) = unpublish_cli(&hash, &b, &root_token);
    assert!(ok_ && out.contains("withdrawn"), "{out}{err}");
    let (ok_, _, err) = unpublish_cli(&hash, &b, &ivan_token);
    assert!(!ok_ && err.contains("403"), "{err}");
    assert_eq!(audits(&db, &data, "atlas.withdraw").len(), 2);
    drop(srv);

    // After a restart it is still withdrawn, and its session still replays.
    let srv = Server::start(
        STYLET,
        &data,
        &db,
        &f.atlases(),
        &["--workers", "1", "--max-atlas-voxels", "1"],
    );
    let b = srv.base.clone();
    let tina = login(&b, "tina");
    assert!(catalogue(&b, &tina).iter().all(|a| a["content_hash"] != hash.as_str()));
    let (status, _) = get_bytes(&format!("{b}/sessions/{id}/frame?view=3d&tick=200"), &tina);
    assert_eq!(status, 200);
    // This server's voxel limit (1) refuses any new atlas; one it has checked before is taken
    // back without checking it again.
    let root_token = full_token(&b, "root");
    let (status, error) = post_tar(&b, &root_token, &archive, "application/x-tar");
    assert_eq!(status, 201, "{error}");
    let (status, error) = post_tar(&b, &root_token, &archive, "application/x-tar");
    assert_eq!(status, 200, "{error}");
}

/// A folder in the atlas store without its publication record in the database (copied there by
/// hand, or left by a crash between the rename and the row) is not served: it is not in the
/// catalogue, sessions on it are refused, and the log says why.
#[test]
fn an_atlas_folder_without_its_publication_record_is_not_served() {
    let db = Db::Sqlite;
    let f = Fixture::new(STYLET);
    f.users(&db);
    let data = f.data();
    let other = f.dir.path().join("other-atlas");
    let manifest = stylet_atlas::store::read_manifest(&other).unwrap();
    let hash = stylet_atlas::store::content_hash(&other, &manifest).unwrap();
    let planted = data.join("atlases").join(&hash);
    std::fs::create_dir_all(&planted).unwrap();
    for name in ["atlas.toml", "ct.nii.gz", "labels.nii.gz"] {
        std::fs::copy(other.join(name), planted.join(name)).unwrap();
    }
    let srv = Server::start(STYLET, &data, &db, &f.atlases(), &["--workers", "1"]);
    let b = srv.base.clone();
    let tina = login(&b, "tina");
    let listed = catalogue(&b, &tina);
    assert_eq!(listed.len(), 1, "{listed:?}");
    assert!(listed.iter().all(|a| a["content_hash"] != hash.as_str()), "{listed:?}");
    let (status, body) = raw_post(
        &b,
        "/api/sessions",
        Some(&tina),
        &std::fs::read(f.session("tina-other-atlas")).unwrap(),
    );
    assert_eq!(status, 422, "{body}");
    assert!(body["error"].as_str().unwrap().contains("does not know"), "{body}");
    let log = std::fs::read_to_string(data.join("server.log")).unwrap();
    assert!(log.contains("no publication record"), "{log}");
    assert!(audits(&db, &data, "atlas.publish").is_empty());
}
