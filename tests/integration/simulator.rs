//! The desktop simulator's machinery end to end: a complete PTCD session driven through the haptic
//! loop by the scripted device records a file that `stylet score` replays verified; a paced loop
//! records its timing as notes; the outbox uploads a session recorded while the server was down
//! once when it comes back, and loses nothing on the way.

use crate::common::{Db, Fixture, STYLET, Server, call, login, ok, phantom_script, s};
use stylet_app::outbox::Outbox;
use stylet_app::service_client::{ServiceClient, TokenUploader};

#[test]
fn a_complete_session_through_the_haptic_loop_is_graded_by_the_same_replay() {
    let f = Fixture::new(STYLET);
    let atlas = f.atlases().join("phantom");
    let through_app = f.dir.path().join("app.mcap");
    let out = ok(&[
        "sim",
        "--headless",
        "--unpaced",
        "--atlas",
        s(&atlas),
        "--script",
        s(&phantom_script("complete-ptcd")),
        "--out",
        s(&through_app),
        "--trainee",
        "tina",
    ]);
    assert!(out.contains("haptic loop unpaced: 46000 ticks"), "{out}");
    assert!(out.contains("complete"), "{out}");
    let report = ok(&["score", s(&through_app), "--atlas", s(&atlas), "--json"]);
    let r: serde_json::Value = serde_json::from_str(&report).unwrap();
    assert_eq!(r["replay_verified"], true, "{r}");
    let m = &r["metrics"];
    // Palpate, scan, puncture, stylet out, contrast, finish: the whole workflow, graded.
    assert_eq!(m["workflow"]["palpation_before_puncture"], true, "{m}");
    assert_eq!(m["workflow"]["ultrasound_before_puncture"], true, "{m}");
    assert_eq!(m["workflow"]["target_scanned_before_puncture"], true, "{m}");
    assert_eq!(m["workflow"]["confirmed_before_withdrawal"], true, "{m}");
    assert_eq!(m["target_reached"], true, "{m}");
    assert_eq!(m["target_confirmed"], true, "{m}");
    assert_eq!(m["attempts"], 1, "{m}");
    assert_eq!(m["risk_hits"].as_array().map(Vec::len), Some(0), "{m}");
    assert!(m["contrast_in_ducts_ml"].as_f64().unwrap() > 0.0, "{m}");
    assert_eq!(r["grade"]["passed"], true, "{r}");
    // The loop computes exactly what the scripted runner does: the same ticks, bit for bit.
    let direct = f.dir.path().join("direct.mcap");
    ok(&[
        "script",
        "run",
        "--atlas",
        s(&atlas),
        "--script",
        s(&phantom_script("complete-ptcd")),
        "--out",
        s(&direct),
        "--trainee",
        "tina",
    ]);
    let a = stylet_recorder::read(&through_app).unwrap();
    let b = stylet_recorder::read(&direct).unwrap();
    assert_eq!(a.ticks.len(), 46_000);
    assert!(
        a.ticks == b.ticks,
        "the haptic loop's ticks differ from the script runner's"
    );
    assert_eq!(a.events, b.events);
}

#[test]
fn a_paced_loop_runs_in_real_time_and_notes_its_timing() {
    let f = Fixture::new(STYLET);
    let atlas = f.atlases().join("phantom");
    let text = "stylet-script 1\ndevice premium\ntool needle gauge 18 length 150 stylet in\nend 1.5\n\
                at 0 along intercostal-10-11 -15\nat 1.5 along intercostal-10-11 5\n";
    let sc = f.dir.path().join("short.txt");
    std::fs::write(&sc, text).unwrap();
    let out_file = f.dir.path().join("paced.mcap");
    let out = ok(&[
        "sim",
        "--headless",
        "--atlas",
        s(&atlas),
        "--script",
        s(&sc),
        "--out",
        s(&out_file),
    ]);
    assert!(out.contains("haptic loop paced: 1500 ticks"), "{out}");
    // Pacing never runs a tick early: the loop's own clock, from its first tick to its last,
    // shows at least the 1.499 s between the starts of tick 0 and tick 1499.
    let wall_s: f64 = out
        .split("simulated in ")
        .nth(1)
        .and_then(|r| r.split(' ').next())
        .and_then(|v| v.parse().ok())
        .expect("the loop's wall time");
    assert!(wall_s >= 1.499, "{out}");
    let session = stylet_recorder::read(&out_file).unwrap();
    let notes: Vec<&str> = session.annotations.iter().map(|a| a.text.as_str()).collect();
    assert!(
        notes.iter().any(|n| n.starts_with("haptic loop: 1500 ticks in")),
        "{notes:?}"
    );
    let report = ok(&["score", s(&out_file), "--atlas", s(&atlas), "--json"]);
    let v: serde_json::Value = serde_json::from_str(&report).unwrap();
    assert_eq!(v["replay_verified"], true, "{v}");
}

#[test]
fn the_window_needs_a_patient_and_a_display_and_says_so() {
    let run = |args: &[&str], display: bool| {
        let mut c = STYLET.command();
        c.args(args);
        if !display {
            c.env_remove("DISPLAY")
                .env_remove("WAYLAND_DISPLAY")
                .env_remove("WAYLAND_SOCKET");
        }
        let out = c.output().unwrap();
        assert!(!out.status.success());
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let err = run(&["sim", "--atlas", "/nonexistent"], true);
    assert!(err.contains("/nonexistent is not an atlas"), "{err}");
    let f = tempfile::tempdir().unwrap();
    let atlas = f.path().join("phantom");
    crate::common::phantom_atlas(&atlas, "64,64,48", "6");
    let data = f.path().join("data");
    let err = run(&["sim", "--atlas", s(&atlas), "--data-dir", s(&data)], false);
    assert!(err.contains("cannot open the window"), "{err}");
    assert!(err.contains("--headless --script"), "{err}");
}

/// The fixture with its accounts (SQLite), and a loopback address with nothing listening yet, where
/// the server starts later: (fixture, database, address, base URL).
fn accounts_and_a_free_address() -> (Fixture, Db, std::net::SocketAddr, String) {
    let f = Fixture::new(STYLET);
    let db = Db::Sqlite;
    f.users(&db);
    let addr = {
        let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        l.local_addr().unwrap()
    };
    let base = format!("http://{addr}");
    (f, db, addr, base)
}

#[test]
fn a_session_recorded_while_the_server_is_down_is_uploaded_once_when_it_is_back() {
    let (f, db, addr, base) = accounts_and_a_free_address();
    let outbox = Outbox::open(&f.dir.path().join("outbox")).unwrap();
    let name = outbox.add(&f.session("tina-ok")).unwrap();
    // A damaged file never enters: the outbox holds sessions only.
    let damaged = f.dir.path().join("damaged.mcap");
    let mut bytes = std::fs::read(f.session("tina-ok")).unwrap();
    bytes.truncate(bytes.len() / 2);
    std::fs::write(&damaged, &bytes).unwrap();
    assert!(outbox.add(&damaged).is_err());

    // Server down: the login fails with a clear reason, the upload waits, nothing is lost.
    let client = ServiceClient::new(&base).unwrap();
    let e = client.upload_token("tina", "tina-password", "test").unwrap_err();
    assert!(e.to_string().contains("cannot be reached"), "{e}");
    let down = TokenUploader {
        client: client.clone(),
        token: "0".repeat(64),
    };
    let round = outbox.upload_all(&down).unwrap();
    assert!(round.uploaded.is_empty() && round.refused.is_empty(), "{round:?}");
    assert_eq!(round.waiting.len(), 1);
    assert!(round.waiting[0].1.contains("unavailable"), "{round:?}");
    assert_eq!(outbox.pending().unwrap(), vec![name.clone()]);

    // The server comes back at the same address.
    let server = Server::start_at(STYLET, &addr.to_string(), &f.data(), &db, &f.atlases(), &[]);
    assert_eq!(server.base, base);
    // The server refuses an unknown token before it reads the body and closes while a large
    // file is still being sent: the client still reads that as "log in again", not as a network
    // failure.
    let big = vec![0u8; 16 << 20];
    let reply = client.upload(&down.token, &big);
    assert!(
        matches!(reply, stylet_app::service_client::UploadReply::Unauthorized { .. }),
        "{reply:?}"
    );
    // A token the server does not know: kept, and the round says to log in again.
    let round = outbox.upload_all(&down).unwrap();
    assert!(round.needs_login, "{round:?}");
    assert_eq!(outbox.pending().unwrap(), vec![name.clone()]);
    // Log in once: an upload-only token.
    let token = client.upload_token("tina", "tina-password", "stylet sim test").unwrap();
    let up = TokenUploader { client, token };
    let round = outbox.upload_all(&up).unwrap();
    assert_eq!(round.uploaded.len(), 1, "{round:?}");
    let id = round.uploaded[0].1.clone();
    assert!(outbox.pending().unwrap().is_empty());
    // Nothing left: the next round uploads nothing.
    assert_eq!(outbox.upload_all(&up).unwrap(), Default::default());
    // A crash between the upload and the removal leaves the file: sent again, the service
    // recognises the bytes (200, same id) and the outbox lets it go. One session on the server.
    outbox.add(&f.session("tina-ok")).unwrap();
    let round = outbox.upload_all(&up).unwrap();
    assert_eq!(round.uploaded[0].1, id);
    let tina = login(&base, "tina");
    let (status, list, _) = call("GET", &format!("{base}/api/sessions"), Some(&tina), None, false);
    assert_eq!(status, 200, "{list}");
    assert_eq!(list["total"], 1, "{list}");
    assert_eq!(list["sessions"][0]["id"], id.as_str());
    // A session the service refuses (recorded on an atlas it does not have) moves aside with
    // the service's reason; the token is upload-only and cannot list sessions.
    outbox.add(&f.session("tina-other-atlas")).unwrap();
    let round = outbox.upload_all(&up).unwrap();
    assert_eq!(round.refused.len(), 1, "{round:?}");
    let refused = outbox.refused().unwrap();
    assert!(refused[0].1.contains("(422)"), "{refused:?}");
    assert!(outbox.pending().unwrap().is_empty());
    let (status, _, _) = call(
        "GET",
        &format!("{base}/api/sessions"),
        Some(&crate::common::Auth::Bearer(up.token.clone())),
        None,
        false,
    );
    assert_eq!(status, 403);
    // The replay viewer fetches a session with the same upload-only token: the very bytes.
    let fetched_dir = f.dir.path().join("fetched");
    let fetched = up.client.fetch_session(&up.token, &id, &fetched_dir).unwrap();
    assert_eq!(
        std::fs::read(&fetched).unwrap(),
        std::fs::read(f.session("tina-ok")).unwrap()
    );
    // Not another trainee's (404, as if it did not exist), not a made-up id, nothing half-written.
    let tom = up
        .client
        .upload_token("tom", "tom-password", "tom's simulator")
        .unwrap();
    let e = up.client.fetch_session(&tom, &id, &fetched_dir).unwrap_err();
    assert!(matches!(e, stylet_app::service_client::FetchError::NotFound(_)), "{e}");
    let e = up
        .client
        .fetch_session(&up.token, "../../etc/passwd", &fetched_dir)
        .unwrap_err();
    assert!(matches!(e, stylet_app::service_client::FetchError::BadId(_)), "{e}");
    let names: Vec<_> = std::fs::read_dir(&fetched_dir)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names.len(), 1, "{names:?}");
    drop(server);
}

/// The window shows what `stylet render` shows for the same tick: the loop's snapshot at 13.008 s of
/// the example puncture (needle in the duct, fluoroscopy on, contrast flowing), drawn by the
/// simulator's view renderer, equals the CLI's picture of the recorded session at the same tick, pixel for
/// pixel, in every view.
#[test]
fn the_simulator_draws_what_stylet_render_draws_for_the_same_tick() {
    use std::sync::Arc;
    use stylet_app::haptic::{HapticLoop, LoopOptions};
    use stylet_app::views::{ViewKind, ViewRenderer, ViewSettings};
    use stylet_devices::Device;
    use stylet_devices::script::{ScriptedDevice, parse, scripted_simulation};
    use stylet_physics::{TickInput, TickOutput};
    use stylet_render::views::SessionLabels;

    /// The script's device, ending after `last`.
    struct Until {
        inner: ScriptedDevice,
        last: u64,
    }
    impl Device for Until {
        fn next(&mut self, tick: u64, last: Option<&TickOutput>) -> Option<TickInput> {
            if tick > self.last {
                None
            } else {
                self.inner.next(tick, last)
            }
        }
    }

    let f = Fixture::new(STYLET);
    let dir = f.atlases().join("phantom");
    let atlas = Arc::new(stylet_atlas::load(&dir).unwrap());
    let text = std::fs::read_to_string(phantom_script("success-intercostal")).unwrap();
    let (sim, device) =
        scripted_simulation(Arc::clone(&atlas.model), &atlas.planned_paths(), &parse(&text).unwrap()).unwrap();
    let labels = SessionLabels {
        scenario: "success-intercostal".into(),
        difficulty: stylet_scoring::Difficulty::Beginner,
        seed: 0,
    };
    let haptic = HapticLoop::spawn(
        sim,
        Box::new(Until {
            inner: device,
            last: 13_008,
        }),
        None,
        labels,
        LoopOptions {
            paced: false,
            publish_every: 16,
        },
    )
    .unwrap();
    while !haptic.is_finished() {
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    let snap = haptic.snapshot().expect("the loop published");
    haptic.join().unwrap();
    // Published every 16th tick: 13 008 = 16 · 813.
    assert_eq!(snap.moment.tick, 13_008);
    assert!(snap.moment.tools.needle.is_some());
    assert!(snap.moment.xray_on);
    assert!(snap.moment.contrast.is_some(), "contrast is flowing at 13 s");
    let mut views = ViewRenderer::new(
        Arc::clone(&atlas),
        ViewSettings {
            doppler: false,
            ..Default::default()
        },
    )
    .unwrap();
    // `stylet render`'s picture of the recorded session at the same tick (`--gpu` on the GPU).
    let session = f.session("tina-ok");
    let cli_view = |kind: ViewKind, gpu: bool| {
        let png = f
            .dir
            .path()
            .join(format!("{}{}.png", kind.name(), if gpu { "-gpu" } else { "" }));
        let mut args = vec![
            "render",
            "--atlas",
            s(&dir),
            "--session",
            s(&session),
            "--at",
            "13.008",
            "--view",
            kind.name(),
            "--size",
            "240x160",
            "--out",
            s(&png),
        ];
        if gpu {
            args.push("--gpu");
        }
        ok(&args);
        stylet_render::image::Image::read_png(&png).unwrap()
    };
    let mut cpu_frames = Vec::new();
    for kind in ViewKind::ALL {
        let frame = views.draw(kind, &snap.moment, 240, 160).unwrap();
        assert_eq!(frame.scale, 1.0, "the first frame is at full resolution");
        let cli = cli_view(kind, false);
        assert!(
            cli == frame.image,
            "{}: the simulator's view differs from stylet render's",
            kind.name()
        );
        cpu_frames.push(frame.image);
    }
    // The same on the GPU renderers (lavapipe here): the window's views drawn by wgpu equal
    // `stylet render --gpu`'s pictures, and stay close to the CPU's.
    let mut gpu_views = ViewRenderer::new(
        Arc::clone(&atlas),
        ViewSettings {
            doppler: false,
            backend: stylet_app::views::Backend::Gpu,
            ..Default::default()
        },
    )
    .unwrap();
    assert!(gpu_views.drawn_by().starts_with("GPU: "), "{}", gpu_views.drawn_by());
    for (kind, cpu) in ViewKind::ALL.into_iter().zip(&cpu_frames) {
        let frame = gpu_views.draw(kind, &snap.moment, 240, 160).unwrap();
        let cli = cli_view(kind, true);
        assert!(
            cli == frame.image,
            "{}: the simulator's GPU view differs from stylet render --gpu's",
            kind.name()
        );
        let mean_abs = cpu
            .rgba
            .iter()
            .zip(&frame.image.rgba)
            .map(|(a, b)| (0..3).map(|c| f64::from(a[c].abs_diff(b[c]))).sum::<f64>() / 3.0)
            .sum::<f64>()
            / cpu.rgba.len() as f64;
        assert!(
            mean_abs < 4.0,
            "{}: GPU and CPU differ by {mean_abs:.2} grey levels on average",
            kind.name()
        );
    }
}

/// The outbox's retrier uploads by itself once the server is back, with no one pressing a
/// button.
#[test]
fn the_retrier_uploads_when_the_server_comes_back() {
    use stylet_app::outbox::{Backoff, Retrier};
    let (f, db, addr, base) = accounts_and_a_free_address();
    // A token made on a first run of the server, which then goes down.
    let token = {
        let server = Server::start_at(STYLET, &addr.to_string(), &f.data(), &db, &f.atlases(), &[]);
        let t = ServiceClient::new(&server.base)
            .unwrap()
            .upload_token("tina", "tina-password", "retrier test")
            .unwrap();
        drop(server);
        t
    };
    let outbox = Outbox::open(&f.dir.path().join("outbox")).unwrap();
    outbox.add(&f.session("tina-ok")).unwrap();
    let retrier = Retrier::start(
        outbox.clone(),
        std::sync::Arc::new(TokenUploader {
            client: ServiceClient::new(&base).unwrap(),
            token,
        }),
        Backoff {
            first: std::time::Duration::from_millis(100),
            max: std::time::Duration::from_millis(400),
        },
    )
    .unwrap();
    std::thread::sleep(std::time::Duration::from_millis(500));
    assert_eq!(
        outbox.pending().unwrap().len(),
        1,
        "nothing can be uploaded while the server is down"
    );
    let last = retrier.last_round().unwrap().unwrap();
    assert!(last.waiting[0].1.contains("unavailable"), "{last:?}");
    let server = Server::start_at(STYLET, &addr.to_string(), &f.data(), &db, &f.atlases(), &[]);
    // The round that uploads records itself after the file has left: wait for the record.
    let t0 = std::time::Instant::now();
    while retrier.uploaded().is_empty() {
        assert!(
            t0.elapsed().as_secs() < 60,
            "not uploaded a minute after the server came back: {:?}",
            retrier.last_round()
        );
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    assert_eq!(retrier.uploaded().len(), 1);
    assert!(outbox.pending().unwrap().is_empty());
    drop(retrier);
    let tina = login(&server.base, "tina");
    let (_, list, _) = call(
        "GET",
        &format!("{}/api/sessions", server.base),
        Some(&tina),
        None,
        false,
    );
    assert_eq!(list["total"], 1, "{list}");
}
