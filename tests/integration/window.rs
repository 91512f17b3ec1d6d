//! The simulator's window, driven headless by egui_kittest and drawn by wgpu on Mesa's software
//! Vulkan (lavapipe): every screen is compared with its snapshot in tests/snapshots/window
//! (`UPDATE_SNAPSHOTS=1` writes them; look at them before committing), and a complete PTCD session
//! driven through the application by the scripted device records a file that `stylet score` replays
//! verified, whose replay in the viewer ends in the same state; sessions by hand move with the
//! keys (a whole drainage among them), and closing the window mid-session loses nothing.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use crate::common::{Auth, Db, Fixture, STYLET, Server, call, login, ok, phantom_atlas, s};
use egui_kittest::kittest::Queryable as _;
use egui_kittest::{Harness, SnapshotOptions};
use stylet_app::views::ViewKind;
use stylet_app::window::egui;
use stylet_app::window::{AppOptions, Layout, Screen, StyletApp};

const SIZE: [f32; 2] = [1024.0, 640.0];

fn phantom(dir: &Path) -> PathBuf {
    let atlas = dir.join("atlases/phantom");
    phantom_atlas(&atlas, "160,160,130", "2.4");
    atlas
}

/// A window on a new phantom with a session by hand started in real time, as a trainee's runs.
fn session_by_hand(dir: &Path) -> Harness<'static, StyletApp> {
    let atlas = phantom(dir);
    let mut h = harness(AppOptions {
        paced: true,
        ..options(dir, &atlas, None)
    });
    h.run_steps(2);
    h.get_by_label("Start session").click();
    h.step();
    assert_eq!(h.state().screen.name(), "session");
    h
}

fn options(dir: &Path, atlas: &Path, script: Option<&str>) -> AppOptions {
    AppOptions {
        atlases: vec![atlas.to_path_buf()],
        sessions_dir: dir.join("sessions"),
        outbox_dir: dir.join("outbox"),
        config_dir: Some(dir.join("config")),
        script: script.map(|n| {
            Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("atlases/phantom/scripts")
                .join(format!("{n}.txt"))
        }),
        // As fast as the CPU allows, and every view at full resolution: the same pictures on
        // every run.
        paced: false,
        view_budget: Duration::from_secs(3600),
        renderer: stylet_app::views::Backend::Cpu,
        replay: None,
        tablet: None,
        hid_profile: None,
        haptic_device: None,
    }
}

fn harness(options: AppOptions) -> Harness<'static, StyletApp> {
    Harness::builder()
        .with_size(SIZE)
        .build_eframe(move |cc| StyletApp::new(&cc.egui_ctx, options))
}

fn snapshot(h: &mut Harness<'_, StyletApp>, name: &str) {
    h.snapshot_options(name, &SnapshotOptions::new().output_path("tests/snapshots/window"));
}

/// Steps the window until `done` holds (the loop and the drawing run on their own threads).
fn step_until(h: &mut Harness<'_, StyletApp>, what: &str, done: impl Fn(&StyletApp) -> bool) {
    let t0 = Instant::now();
    while !done(h.state()) {
        let failed = matches!(&h.state().screen, Screen::Loading(l) if l.problem().is_some());
        if failed || t0.elapsed() > Duration::from_secs(180) {
            let problem = match &h.state().screen {
                Screen::Start(s) => s.problem.clone(),
                Screen::Loading(l) => l.problem().map(str::to_string),
                _ => None,
            };
            panic!(
                "timed out waiting for {what} on the {} screen: {problem:?}",
                h.state().screen.name()
            );
        }
        h.step();
        std::thread::sleep(Duration::from_millis(5));
    }
    // A few more frames so that what was drawn is on screen.
    h.run_steps(3);
}

/// Holds `key` down for `how_long`, frame by frame, then lets the loop take the last of it.
fn hold_key(h: &mut Harness<'_, StyletApp>, key: egui::Key, how_long: Duration) {
    let t0 = Instant::now();
    while t0.elapsed() < how_long {
        h.key_down(key);
        h.step();
        std::thread::sleep(Duration::from_millis(10));
    }
    h.key_up(key);
    h.step();
    std::thread::sleep(Duration::from_millis(100));
    h.step();
}

fn session_settled(app: &StyletApp) -> bool {
    match &app.screen {
        Screen::Session(s) => s.running().is_some_and(|r| r.is_over()) && s.views_current(),
        _ => false,
    }
}

#[test]
fn a_scripted_ptcd_session_through_the_window_is_recorded_scored_and_replayed_to_the_same_state() {
    let dir = tempfile::tempdir().unwrap();
    let atlas = phantom(dir.path());
    let mut h = harness(options(dir.path(), &atlas, Some("complete-ptcd")));
    h.run_steps(3);
    snapshot(&mut h, "start");

    // Palpate, probe, puncture, stylet out, contrast, stylet in, withdraw: the whole script.
    h.get_by_label("Start session (scripted)").click();
    h.step();
    assert_eq!(h.state().screen.name(), "session");
    if let Screen::Session(s) = &mut h.state_mut().screen {
        s.panes.show_timings = false;
    }
    step_until(&mut h, "the session's end", session_settled);
    snapshot(&mut h, "session");

    h.get_by_label("See the results").click();
    h.step();
    wait_for_the_local_score(&mut h);
    let (path, final_digest, report) = match &h.state().screen {
        Screen::Results(r) => {
            let f = r.finished().expect("a finished session");
            (
                f.path.clone(),
                f.report.final_digest,
                r.score().unwrap().as_ref().expect("a score").clone(),
            )
        }
        _ => unreachable!(),
    };
    assert!(report.replay_verified, "{report:?}");
    assert_eq!(report.outcome, stylet_scoring::Outcome::Passed, "{:?}", report.reasons);
    assert_eq!(report.ticks, 46_000);
    snapshot(&mut h, "results");

    // `stylet score` gives the same verdict from the file.
    let cli = ok(&["score", s(&path), "--atlas", s(&atlas), "--json"]);
    let r: serde_json::Value = serde_json::from_str(&cli).unwrap();
    assert_eq!(r["replay_verified"], true, "{r}");
    assert_eq!(r["grade"]["score"].as_f64(), Some(report.grade.score), "{r}");
    assert_eq!(r["metrics"]["target_reached"], true, "{r}");
    assert_eq!(r["metrics"]["workflow"]["palpation_before_puncture"], true, "{r}");
    assert_eq!(r["metrics"]["workflow"]["confirmed_before_withdrawal"], true, "{r}");
    // The session waits in the outbox (offline).
    let outbox = stylet_app::outbox::Outbox::open(&dir.path().join("outbox")).unwrap();
    assert_eq!(outbox.pending().unwrap().len(), 1);

    // The replay viewer: the first tick, then the end, which is the state the session ended in.
    h.get_by_label("Replay this session").click();
    h.step();
    // The file is replayed and scored on a thread of its own first.
    step_until(&mut h, "the replay viewer", |app| app.screen.name() == "replay");
    if let Screen::Replay(r) = &mut h.state_mut().screen {
        r.panes.show_timings = false;
    }
    step_until(&mut h, "the replay's first tick", replay_settled);
    snapshot(&mut h, "replay-start");
    let key_moments = match &h.state().screen {
        Screen::Replay(r) => r.cursor().key_moments().to_vec(),
        _ => unreachable!(),
    };
    let contrast = key_moments
        .iter()
        .find(|m| m.kind == stylet_app::replay_cursor::MomentKind::Contrast)
        .expect("the contrast injection is a key moment");
    h.get_by_label(&format!("{} ({:.1} s)", contrast.label, contrast.time_s))
        .click();
    h.step();
    step_until(&mut h, "the contrast moment", replay_settled);
    snapshot(&mut h, "replay-contrast");
    match &h.state().screen {
        Screen::Replay(r) => assert_eq!(r.cursor().position(), contrast.ticks),
        _ => unreachable!(),
    }
    // Each view on its own, with the needle in the duct and the contrast flowing.
    for kind in ViewKind::ALL {
        if let Screen::Replay(r) = &mut h.state_mut().screen {
            r.panes.layout = Layout::One;
            r.panes.kinds[0] = kind;
        }
        h.step();
        step_until(&mut h, kind.name(), replay_settled);
        snapshot(&mut h, &format!("view-{}", kind.name()));
    }
    if let Screen::Replay(r) = &mut h.state_mut().screen {
        r.jump_to(u64::MAX);
    }
    h.step();
    step_until(&mut h, "the replay's end", replay_settled);
    match &h.state().screen {
        Screen::Replay(r) => {
            assert_eq!(r.cursor().position(), 46_000);
            assert_eq!(
                r.cursor().state_digest(),
                final_digest,
                "the replay viewer ends in another state than the session"
            );
            assert!(r.cursor().report().replay_verified);
        }
        _ => unreachable!(),
    }
}

/// Steps the window until the results screen has the session's local score.
fn wait_for_the_local_score(h: &mut Harness<'_, StyletApp>) {
    step_until(h, "the local score", |app| match &app.screen {
        Screen::Results(r) => r.score().is_some(),
        _ => false,
    });
}

fn replay_settled(app: &StyletApp) -> bool {
    match &app.screen {
        Screen::Replay(r) => r.settled(),
        _ => false,
    }
}

#[test]
fn a_session_by_hand_moves_with_the_keys_and_the_keypad_changes_the_tool() {
    let dir = tempfile::tempdir().unwrap();
    let mut h = session_by_hand(dir.path());
    let start = match &h.state().screen {
        Screen::Session(s) => s.running().unwrap().live().unwrap().pose().unwrap().0,
        _ => panic!("no session"),
    };
    // Keypad 4: the needle, of the gauge chosen in the tools panel (22 G); then W held for a
    // while moves the tool away from the viewer (+y).
    if let Screen::Session(s) = &mut h.state_mut().screen {
        s.gauge = stylet_physics::needle::spec::Gauge::G22;
    }
    h.key_press(egui::Key::Num4);
    hold_key(&mut h, egui::Key::W, Duration::from_millis(600));
    let (moved, needle) = match &h.state().screen {
        Screen::Session(s) => {
            let r = s.running().unwrap();
            let snap = r.snapshot().expect("a snapshot");
            (
                r.live().unwrap().pose().unwrap().0 - start,
                snap.moment.tools.needle.is_some(),
            )
        }
        _ => panic!("no session"),
    };
    assert!(needle, "keypad 4 takes the needle");
    assert!(
        moved.y > 2.0 && moved.x.abs() < 1e-6 && moved.z.abs() < 1e-6,
        "{moved:?}"
    );
    // Enter finishes; the session by hand is recorded and scored like any other.
    h.key_press(egui::Key::Enter);
    wait_for_the_local_score(&mut h);
    match &h.state().screen {
        Screen::Results(r) => {
            let report = r.score().unwrap().as_ref().expect("a score");
            assert!(report.replay_verified, "{report:?}");
            assert!(!report.incomplete, "{report:?}");
            let session = stylet_recorder::read(&r.finished().unwrap().path).unwrap();
            let tools: Vec<_> = session.events.iter().filter_map(|e| e.to_event().ok()).collect();
            assert!(
                tools.iter().any(|e| matches!(
                    e,
                    stylet_physics::Event::SelectTool(stylet_physics::ToolSpec::Needle {
                        gauge: stylet_physics::needle::spec::Gauge::G22,
                        ..
                    })
                )),
                "{tools:?}"
            );
        }
        _ => unreachable!(),
    }
}

/// Turns the mouse wheel over the first picture by `notches` (1 mm each along the tool's axis),
/// two at a time with a frame between, as a hand feeding an instrument would.
fn wheel(h: &mut Harness<'_, StyletApp>, notches: i32) {
    let at = h
        .get_all_by_role(egui::accesskit::Role::Image)
        .next()
        .map(|n| n.rect().center())
        .expect("a picture");
    h.hover_at(at);
    let (sign, mut left) = (notches.signum() as f32, notches.abs());
    while left > 0 {
        let n = left.min(2);
        left -= n;
        h.event(egui::Event::MouseWheel {
            unit: egui::MouseWheelUnit::Line,
            delta: egui::vec2(0.0, sign * n as f32),
            phase: egui::TouchPhase::Move,
            source: egui::MouseWheelSource::Unknown,
            modifiers: egui::Modifiers::NONE,
        });
        h.step();
        std::thread::sleep(Duration::from_millis(15));
    }
    settle(h);
}

/// Waits until the physics has run 100 ticks (0.1 s) past the window's latest snapshot, and the
/// window has seen them: what was pressed or moved before has been taken, and the next press is
/// decided on the state it left (a loaded machine only makes this wait longer).
fn settle(h: &mut Harness<'_, StyletApp>) {
    let tick = |app: &StyletApp| match &app.screen {
        Screen::Session(s) => s.running().and_then(|r| r.snapshot()).map(|snap| snap.output.tick),
        _ => None,
    };
    let before = tick(h.state()).expect("a running session");
    step_until(h, "the physics to take what was sent", |app| {
        tick(app).is_some_and(|t| t >= before + 100)
    });
}

/// A whole drainage by hand through the keys, as the script `full-ptcd.txt` does it: the
/// full-ptcd scenario picked on the start screen; keypad 4 takes the 18 G needle, the wheel brings
/// it in along the planned path to the duct, keypad 5 takes the stylet out; then keypad + takes
/// each step of the exchange in turn (wire in, needle out, dilator in, dilator out, catheter in,
/// wire out) while the wheel feeds what the hand holds. The session is recorded, replays verified
/// and is graded as a drainage whose catheter drains.
#[test]
fn a_whole_drainage_by_hand_through_the_keys() {
    let dir = tempfile::tempdir().unwrap();
    // The default phantom's 1.5 mm voxels: the coarse one of the other tests has ducts too
    // blocky for the catheter's side holes.
    let atlas = dir.path().join("atlases/phantom");
    phantom_atlas(&atlas, "256,256,200", "1.5");
    let mut h = harness(AppOptions {
        paced: true,
        ..options(dir.path(), &atlas, None)
    });
    h.run_steps(2);
    h.get_by_label("Scenario").click();
    h.run_steps(2);
    h.get_by_label("full-ptcd").click();
    h.run_steps(2);
    h.get_by_label("Start session").click();
    h.step();
    assert_eq!(h.state().screen.name(), "session");
    step_until(&mut h, "the first snapshot", |app| match &app.screen {
        Screen::Session(s) => s.running().is_some_and(|r| r.snapshot().is_some()),
        _ => false,
    });
    if let Screen::Session(s) = &mut h.state_mut().screen {
        s.gauge = stylet_physics::needle::spec::Gauge::G18;
    }
    h.key_press(egui::Key::Num4);
    settle(&mut h);
    // 30 mm to the skin, 111 mm on to the duct.
    wheel(&mut h, 141);
    h.key_press(egui::Key::Num5);
    settle(&mut h);
    let next = |h: &mut Harness<'_, StyletApp>| {
        h.key_press(egui::Key::Plus);
        settle(h);
    };
    next(&mut h); // the wire in
    wheel(&mut h, 190);
    next(&mut h); // the needle out
    next(&mut h); // the dilator on
    wheel(&mut h, 140);
    wheel(&mut h, -140);
    next(&mut h); // the dilator out
    next(&mut h); // the catheter on
    wheel(&mut h, 150);
    next(&mut h); // the wire out: the pigtail forms
    h.key_press(egui::Key::Enter);
    wait_for_the_local_score(&mut h);
    let Screen::Results(r) = &h.state().screen else {
        unreachable!()
    };
    let report = r.score().unwrap().as_ref().expect("a score");
    assert!(report.replay_verified, "{report:?}");
    assert_eq!(report.exercise, stylet_scoring::Exercise::Drainage);
    let d = report.metrics.drainage.as_ref().expect("a wire went in");
    println!("{d:?}\n{:?}", report.reasons);
    assert!(d.wire_reached_ducts && !d.access_lost, "{d:?}");
    assert_eq!(
        (
            d.wire_attempts,
            d.dilator_attempts,
            d.catheter_attempts,
            d.refused_steps
        ),
        (1, 1, 1, 0),
        "{d:?}"
    );
    assert!(d.catheter_placed && d.drains() && d.pigtail_in_ducts, "{d:?}");
}

/// A trainee's scenario picker lists the training scenarios, each with its one-line description;
/// the scripted examples and grading fixtures only when asked for.
#[test]
fn the_start_screen_offers_trainees_the_training_scenarios_only() {
    let dir = tempfile::tempdir().unwrap();
    let atlas = phantom(dir.path());
    let mut h = harness(options(dir.path(), &atlas, None));
    h.run_steps(2);
    h.get_by_label("Scenario").click();
    h.run_steps(2);
    for fixture in ["two-attempts", "lung-hit", "vessel-hit", "probe-no-target"] {
        assert!(h.query_by_label(fixture).is_none(), "{fixture} is offered to trainees");
    }
    for training in [
        "success-intercostal",
        "breath-hold",
        "palpation-sweep",
        "probe-parallel",
        "probe-across",
    ] {
        assert!(h.query_by_label(training).is_some(), "{training} is not offered");
    }
    h.get_by_label("breath-hold").click();
    h.run_steps(2);
    assert!(
        h.query_by_label_contains("hold the breath at end-expiration").is_some(),
        "its description"
    );
    h.get_by_label("Also offer the examples and test scenarios").click();
    h.run_steps(2);
    h.get_by_label("Scenario").click();
    h.run_steps(2);
    assert!(h.query_by_label("lung-hit").is_some(), "examples on request");
}

/// A session by hand starts a few centimetres from the skin and the status bar says how far; a
/// few wheel notches over a picture bring the tool closer by as many millimetres.
#[test]
fn a_session_by_hand_starts_near_the_skin_and_says_how_far() {
    let dir = tempfile::tempdir().unwrap();
    let mut h = session_by_hand(dir.path());
    let distance = |h: &Harness<'_, StyletApp>| -> f64 {
        let node = h.get_by_label_contains("mm from the skin");
        // A label's text is its accessibility value.
        let text = node.value().unwrap_or_default();
        text.split(" tip ")
            .nth(1)
            .and_then(|r| r.split(' ').next())
            .and_then(|n| n.parse().ok())
            .unwrap_or_else(|| panic!("{text}"))
    };
    step_until(&mut h, "the first snapshot", |app| match &app.screen {
        Screen::Session(s) => s.running().is_some_and(|r| r.snapshot().is_some()),
        _ => false,
    });
    h.step();
    let before = distance(&h);
    assert!((20.0..=40.0).contains(&before), "starts {before} mm from the skin");
    // 10 notches of the wheel over the first picture: 10 mm closer.
    let at = h
        .get_all_by_role(egui::accesskit::Role::Image)
        .next()
        .map(|n| n.rect().center());
    h.hover_at(at.expect("a picture"));
    h.event(egui::Event::MouseWheel {
        unit: egui::MouseWheelUnit::Line,
        delta: egui::vec2(0.0, 10.0),
        phase: egui::TouchPhase::Move,
        source: egui::MouseWheelSource::Unknown,
        modifiers: egui::Modifiers::NONE,
    });
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_millis(600) {
        h.step();
        std::thread::sleep(Duration::from_millis(20));
    }
    let after = distance(&h);
    assert!(
        (before - after - 10.0).abs() <= 2.0,
        "{before} mm, then {after} mm after 10 notches"
    );
}

/// The keypad by physical key: NumLock off (keypad 4 arrives as ArrowLeft), a release under
/// another logical key (Shift pressed meanwhile), a pedal tap between two frames; none is lost
/// and none tilts the tool.
#[test]
fn the_keypad_works_without_numlock_and_no_press_is_lost() {
    let dir = tempfile::tempdir().unwrap();
    let mut h = session_by_hand(dir.path());
    let send = |h: &Harness<'_, StyletApp>, key, physical, pressed| {
        h.event(egui::Event::Key {
            key,
            physical_key: Some(physical),
            pressed,
            repeat: false,
            modifiers: egui::Modifiers::NONE,
        })
    };
    let aim = |h: &Harness<'_, StyletApp>| match &h.state().screen {
        Screen::Session(s) => s.running().unwrap().live().unwrap().pose().unwrap().1,
        _ => panic!("no session"),
    };
    let before = aim(&h);
    send(&h, egui::Key::ArrowLeft, egui::Key::Num4, true);
    for _ in 0..5 {
        h.step();
        std::thread::sleep(Duration::from_millis(20));
    }
    send(&h, egui::Key::ArrowLeft, egui::Key::Num4, false);
    h.step();
    std::thread::sleep(Duration::from_millis(50));
    h.step();
    assert!(
        aim(&h).angle_between(before) < 1e-9,
        "keypad 4 without NumLock tilted the tool"
    );
    send(&h, egui::Key::Num9, egui::Key::Num9, true);
    h.step();
    send(&h, egui::Key::PageUp, egui::Key::Num9, false);
    h.step();
    send(&h, egui::Key::Num9, egui::Key::Num9, true);
    h.step();
    send(&h, egui::Key::Num9, egui::Key::Num9, false);
    h.step();
    h.key_press(egui::Key::X);
    h.step();
    std::thread::sleep(Duration::from_millis(100));
    h.step();
    h.key_press(egui::Key::Enter);
    wait_for_the_local_score(&mut h);
    let Screen::Results(r) = &h.state().screen else {
        unreachable!()
    };
    let session = stylet_recorder::read(&r.finished().unwrap().path).unwrap();
    let events: Vec<_> = session.events.iter().filter_map(|e| e.to_event().ok()).collect();
    use stylet_physics::{Event, ToolSpec};
    assert!(
        events
            .iter()
            .any(|e| matches!(e, Event::SelectTool(ToolSpec::Needle { .. }))),
        "keypad 4 without NumLock: {events:?}"
    );
    assert!(events.iter().any(|e| matches!(e, Event::BreathHold)), "{events:?}");
    assert!(
        events.iter().any(|e| matches!(e, Event::BreathRelease)),
        "the second press of 9: {events:?}"
    );
    assert!(
        events.iter().any(|e| matches!(e, Event::XrayOn)),
        "the pedal tap: {events:?}"
    );
}

#[test]
fn closing_the_window_during_a_session_finishes_it_and_queues_it_for_upload() {
    let dir = tempfile::tempdir().unwrap();
    let mut h = session_by_hand(dir.path());
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_millis(300) {
        h.step();
        std::thread::sleep(Duration::from_millis(10));
    }
    assert_eq!(h.state().screen.name(), "session");
    h.state_mut().close();
    let outbox = stylet_app::outbox::Outbox::open(&dir.path().join("outbox")).unwrap();
    assert_eq!(outbox.pending().unwrap().len(), 1, "the session is queued");
    let files: Vec<PathBuf> = std::fs::read_dir(dir.path().join("sessions"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    assert_eq!(files.len(), 1);
    // Closed properly: summary and end record written.
    let out = ok(&["session", "verify", s(&files[0])]);
    assert!(out.contains(": good"), "{out}");
}

/// An instructor's replay from the service: the window logged in (an upload-only token kept in its
/// configuration folder) fetches a session by its id and opens it in the replay viewer.
#[test]
fn a_session_fetched_from_the_service_opens_in_the_replay_viewer() {
    use stylet_app::service_client::{ServiceClient, TokenUploader};
    let f = Fixture::new(STYLET);
    let db = Db::Sqlite;
    f.users(&db);
    let server = Server::start(STYLET, &f.data(), &db, &f.atlases(), &[]);
    let client = ServiceClient::new(&server.base).unwrap();
    let token = client.upload_token("tina", "tina-password", "window test").unwrap();
    let up = TokenUploader {
        client: client.clone(),
        token: token.clone(),
    };
    let outbox = stylet_app::outbox::Outbox::open(&f.dir.path().join("upload")).unwrap();
    outbox.add(&f.session("tina-ok")).unwrap();
    let round = outbox.upload_all(&up).unwrap();
    let id = round.uploaded[0].1.clone();
    // The window finds the login the simulator kept.
    let dir = f.dir.path().join("window");
    stylet_app::credentials::Credentials {
        server_url: server.base.clone(),
        username: "tina".into(),
        token,
    }
    .save(&dir.join("config"))
    .unwrap();
    let mut h = harness(options(&dir, &f.atlases().join("phantom"), None));
    h.run_steps(2);
    if let Screen::Start(s) = &mut h.state_mut().screen {
        s.fetch_id = id.clone();
    }
    h.step();
    h.get_by_label("Fetch and replay").click();
    h.step();
    step_until(&mut h, "the fetched replay", |app| app.screen.name() == "replay");
    match &h.state().screen {
        Screen::Replay(r) => {
            assert_eq!(r.cursor().session().header.trainee, "tina");
            assert!(r.cursor().report().replay_verified);
        }
        _ => unreachable!(),
    }
    assert!(dir.join("sessions").join(format!("fetched-{id}.mcap")).is_file());
    drop(server);
}

/// A pairing code made on the service, by `who` for `purpose` (and `cohort`).
fn pairing_code(base: &str, who: &Auth, purpose: &str, cohort: Option<&str>) -> String {
    let body = serde_json::json!({"purpose": purpose, "cohort": cohort}).to_string();
    let (status, json, _) = call(
        "POST",
        &format!("{base}/api/pairing/codes"),
        Some(who),
        Some(body.as_bytes()),
        true,
    );
    assert_eq!(status, 201, "{json}");
    json["code"].as_str().unwrap().to_string()
}

/// Pairing from the start screen (docs/integration.md "Pairing a simulator"): a trainee's code
/// logs the window in (the token kept in its configuration folder); a lab code makes it a lab
/// machine of the cohort, on which a trainee signs in with her own code (her token in memory
/// only) and signs out (her token revoked on the service).
#[test]
fn the_start_screen_pairs_with_a_code_and_a_lab_machine_signs_trainees_in() {
    let f = Fixture::new(STYLET);
    let db = Db::Sqlite;
    f.users(&db);
    let server = Server::start(STYLET, &f.data(), &db, &f.atlases(), &[]);
    let base = server.base.clone();
    let (tina, ivan) = (login(&base, "tina"), login(&base, "ivan"));
    let pair = |h: &mut Harness<'_, StyletApp>, code: String, button: &str| {
        if let Screen::Start(s) = &mut h.state_mut().screen {
            s.server_url = base.clone();
            s.pairing_code = code;
        }
        h.step();
        h.get_by_label(button).click();
        h.step();
    };

    // Tina's own computer.
    let dir = f.dir.path().join("own");
    let mut h = harness(options(&dir, &f.atlases().join("phantom"), None));
    h.run_steps(2);
    pair(&mut h, pairing_code(&base, &tina, "simulator", None), "Pair");
    step_until(&mut h, "the pairing", |app| app.shared.login.is_some());
    let kept = stylet_app::credentials::Credentials::load(&dir.join("config"))
        .unwrap()
        .unwrap();
    assert_eq!(
        (kept.username.as_str(), kept.server_url.as_str()),
        ("tina", base.as_str())
    );
    drop(h);

    // A lab machine of c1, and tina signing in and out on it.
    let dir = f.dir.path().join("lab");
    let mut h = harness(options(&dir, &f.atlases().join("phantom"), None));
    h.run_steps(2);
    pair(&mut h, pairing_code(&base, &ivan, "lab", Some("c1")), "Pair");
    step_until(&mut h, "the lab pairing", |app| app.shared.lab.is_some());
    assert_eq!(h.state().shared.lab.as_ref().unwrap().cohort, "c1");
    assert!(h.state().shared.login.is_none());
    pair(&mut h, pairing_code(&base, &tina, "sign_in", None), "Sign in");
    step_until(&mut h, "the sign-in", |app| app.shared.login.is_some());
    let token = h.state().shared.login.as_ref().unwrap().token.clone();
    assert_eq!(h.state().shared.login.as_ref().unwrap().username, "tina");
    assert_eq!(
        stylet_app::credentials::Credentials::load(&dir.join("config")).unwrap(),
        None,
        "a trainee's token at a lab machine is not written down"
    );
    let signed_in = Auth::Bearer(token);
    assert_eq!(
        call("GET", &format!("{base}/api/sessions/x"), Some(&signed_in), None, false).0,
        404
    );
    h.get_by_label("Sign out").click();
    h.step();
    assert!(h.state().shared.login.is_none());
    assert!(h.state().shared.lab.is_some(), "the machine stays a lab machine");
    let t0 = Instant::now();
    while call("GET", &format!("{base}/api/sessions/x"), Some(&signed_in), None, false).0 != 401 {
        assert!(
            t0.elapsed() < Duration::from_secs(20),
            "the token was not revoked at sign-out"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    drop(h);
    drop(server);
}

/// The devices dialog (docs/simulator.md "Hands and devices"): with a force-feedback device on
/// the command line it moves the needle hand; the trainee gives the probe hand to the keys and
/// mouse, the choice is kept on this machine and offered again by the next window, and a session
/// with two hands starts from it: the keys move the probe, the device the needle; it is recorded
/// with both hands and replays verified.
#[test]
fn the_devices_dialog_gives_each_hand_a_device_and_the_machine_remembers() {
    use stylet_app::hands::{HandAssignment, InputDevice, SecondHandTool};
    let dir = tempfile::tempdir().unwrap();
    let atlas = phantom(dir.path());
    // The device's hand stays where it is.
    let double = stylet_haply_double::HaplyDouble::start(vec![[0.0; 4], [1.0, 0.0, 0.0, 0.0]]).unwrap();
    let choice = stylet_devices::haptic::DeviceChoice {
        backend: stylet_devices::haptic::Backend::Haply,
        library: None,
        url: Some(double.url.clone()),
    };
    let opts = AppOptions {
        paced: true,
        haptic_device: Some((choice, stylet_devices::haptic::pose::Mapping::default())),
        ..options(dir.path(), &atlas, None)
    };
    let mut h = harness(opts.clone());
    h.run_steps(2);
    h.get_by_label("Devices: one hand: force-feedback device");
    // A new dialog is measured in its first frame and drawn from the next.
    h.get_by_label("Devices…").click();
    h.run_steps(3);
    h.get_by_label("Probe hand").click();
    h.run_steps(3);
    h.get_by_label("keys and mouse").click();
    h.run_steps(3);
    snapshot(&mut h, "devices");
    h.get_by_label("Use these devices").click();
    h.run_steps(2);
    let chosen = HandAssignment {
        needle_hand: InputDevice::ForceFeedback,
        probe_hand: Some(InputDevice::KeysAndMouse),
        probe_hand_tool: SecondHandTool::ConvexProbe,
    };
    assert_eq!(HandAssignment::load(&dir.path().join("config")).unwrap(), Some(chosen));

    h.get_by_label("Start session with two hands").click();
    h.step();
    assert_eq!(
        h.state().screen.name(),
        "session",
        "{:?}",
        match &h.state().screen {
            Screen::Start(s) => s.problem.clone(),
            _ => None,
        }
    );
    let poses = |h: &Harness<'_, StyletApp>| match &h.state().screen {
        Screen::Session(s) => {
            let r = s.running().unwrap();
            (
                r.live().unwrap().pose().unwrap().0,
                r.probe_live().unwrap().pose().unwrap().0,
            )
        }
        _ => panic!("no session"),
    };
    h.run_steps(3);
    let (needle0, probe0) = poses(&h);
    hold_key(&mut h, egui::Key::W, Duration::from_millis(600));
    let (needle1, probe1) = poses(&h);
    let moved = probe1 - probe0;
    assert!(
        moved.y > 2.0 && moved.x.abs() < 1e-6,
        "the keys move the probe: {moved:?}"
    );
    assert!(
        (needle1 - needle0).length() < 1e-6,
        "the device holds the needle hand still"
    );
    h.get_by_label("needle hand: Inverse3 0D0B (haply) · probe hand: keys and mouse");
    h.key_press(egui::Key::Enter);
    wait_for_the_local_score(&mut h);
    match &h.state().screen {
        Screen::Results(r) => {
            let report = r.score().unwrap().as_ref().expect("a score");
            assert!(report.replay_verified, "{report:?}");
            let session = stylet_recorder::read(&r.finished().unwrap().path).unwrap();
            assert!(session.header.second_hand.is_some());
            assert!(session.ticks.iter().all(|t| t.second_hand.is_some()));
            assert_eq!(
                session.header.hardware.as_ref().map(|h| h.backend.as_str()),
                Some("haply")
            );
        }
        _ => unreachable!(),
    }
    assert_eq!(double.forces().last().map(|f| [f[1], f[2], f[3]]), Some([0.0; 3]));
    drop(h);
    // The next window on this machine offers the same hands.
    let mut again = harness(opts);
    again.run_steps(2);
    again.get_by_label("Devices: needle hand: force-feedback device; probe hand: keys and mouse (convex probe)");
}

/// The phantom's scripted two-handed session through the window, in a window of the default
/// size: stopped while the needle advances in the probe's live image, both hands' tools and
/// forces on the session screen; run to its end, the results show the live guidance and the bile
/// leak the withdrawal from the duct left behind.
#[test]
fn a_two_handed_session_shows_both_tools_and_its_results_show_the_guidance() {
    let dir = tempfile::tempdir().unwrap();
    let atlas = phantom(dir.path());
    let full = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("atlases/phantom/scripts/two-handed-success.txt"),
    )
    .unwrap();
    assert!(full.contains("\nend 27\n"));
    let part = dir.path().join("two-handed-part.txt");
    // The same script up to 13 s: the probe on the skin, the needle on its way to the duct
    // (two thirds of the way from 15 mm outside the skin at 5 s to 111 mm deep at 17 s).
    let mut until_13_s: String = full
        .replace("\nend 27\n", "\nend 13\n")
        .lines()
        .filter(|l| {
            l.strip_prefix("at ")
                .and_then(|rest| rest.split_whitespace().next())
                .and_then(|t| t.parse::<f64>().ok())
                .is_none_or(|t| t <= 13.0)
        })
        .map(|l| format!("{l}\n"))
        .collect();
    until_13_s.push_str("at 13 along intercostal-10-11 69\n");
    std::fs::write(&part, until_13_s).unwrap();
    std::fs::write(dir.path().join("two-handed-full.txt"), &full).unwrap();
    let window = |script: &Path| {
        let options = AppOptions {
            script: Some(script.to_path_buf()),
            ..options(dir.path(), &atlas, None)
        };
        let mut h = Harness::builder()
            .with_size([1280.0, 800.0])
            .build_eframe(move |cc| StyletApp::new(&cc.egui_ctx, options));
        h.run_steps(3);
        h.get_by_label("Start session (scripted)").click();
        h.step();
        if let Screen::Session(s) = &mut h.state_mut().screen {
            s.panes.show_timings = false;
        }
        step_until(&mut h, "the session's end", session_settled);
        h
    };
    let mut h = window(&part);
    h.get_by_label("Probe hand");
    h.get_by_label("convex probe");
    snapshot(&mut h, "session-two-hands");
    // One test, one set of snapshot results (kittest checks them when they are dropped).
    let mut snapshots = h.take_snapshot_results();
    drop(h);

    let mut h = window(&dir.path().join("two-handed-full.txt"));
    h.get_by_label("See the results").click();
    h.step();
    wait_for_the_local_score(&mut h);
    let report = match &h.state().screen {
        Screen::Results(r) => r.score().unwrap().as_ref().expect("a score").clone(),
        _ => unreachable!(),
    };
    assert!(report.replay_verified, "{report:?}");
    let g = report.metrics.live_guidance.as_ref().expect("live guidance");
    h.get_by_label("Needle tip in the live ultrasound");
    h.get_by_label(&format!("{:.0} % of the insertion", 100.0 * g.needle_tip_visible_share));
    assert!(
        !report.metrics.consequences.is_empty(),
        "withdrawing from the duct leaves a bile leak"
    );
    for c in &report.metrics.consequences {
        h.get_by_label(&format!(
            "{:.1} ml by the end; punctured at {:.1} s, began at {:.1} s",
            c.volume_ml, c.punctured_s, c.began_s
        ));
    }
    snapshot(&mut h, "results-two-hands");
    snapshots.extend(h.take_snapshot_results());
}
