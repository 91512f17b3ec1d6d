//! The whole simulator with a force-feedback device: the haptic loop ticking the phantom at
//! 1 kHz, the tool moved by a device through its backend and the force sent back, against each
//! backend's device double (the OpenHaptics and DHD shared libraries, the Haply Inverse Service
//! on a loopback WebSocket), whose simulated arm follows a scripted hand and records every force
//! it is sent.

use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crate::common::default_phantom;
use stylet_app::haptic::{HapticLoop, LoopOptions};
use stylet_app::session::physics_profile_for;
use stylet_devices::Device;
use stylet_devices::haptic::dhd::Dhd;
use stylet_devices::haptic::haply::Haply;
use stylet_devices::haptic::openhaptics::OpenHaptics;
use stylet_devices::haptic::pose::{HapticPose, Mapping, vendor_axes};
use stylet_devices::haptic::{Backend, HapticDevice};
use stylet_devices::live::live_device;
use stylet_haply_double::HaplyDouble;
use stylet_physics::glam::{DQuat, DVec3};
use stylet_physics::{Gauge, SimConfig, Simulation, TickInput, TickOutput, ToolSpec};
use stylet_render::views::SessionLabels;

/// The live device, with the simulation's tick stalled once (as a machine that stops the loop
/// would), and every tick's computed force kept.
struct Stalling<D> {
    inner: D,
    stall_at_tick: u64,
    stall: Duration,
    computed: Arc<Mutex<Vec<(Instant, DVec3, f64)>>>,
    stalled_at: Arc<Mutex<Option<Instant>>>,
}

impl<D: Device> Device for Stalling<D> {
    fn next(&mut self, tick: u64, last: Option<&TickOutput>) -> Option<TickInput> {
        if let Some(out) = last {
            self.computed
                .lock()
                .unwrap()
                .push((Instant::now(), out.force_n, out.tip_depth_mm));
        }
        if tick == self.stall_at_tick {
            *self.stalled_at.lock().unwrap() = Some(Instant::now());
            std::thread::sleep(self.stall);
        }
        self.inner.next(tick, last)
    }
}

/// A double's record of every force it accepted, on its own clock.
trait Felt {
    /// (s since the device opened, force N in the vendor's frame).
    fn felt(&self) -> Vec<(f64, DVec3)>;
    /// Broken API rules.
    fn broken_rules(&self) -> u64;
    /// The zero of [`Felt::felt`]'s clock.
    fn clock_start(&self) -> Instant;
}

impl Felt for HaplyDouble {
    fn felt(&self) -> Vec<(f64, DVec3)> {
        self.forces()
            .iter()
            .map(|f| (f[0], DVec3::new(f[1], f[2], f[3])))
            .collect()
    }
    fn broken_rules(&self) -> u64 {
        self.violations()
    }
    fn clock_start(&self) -> Instant {
        HaplyDouble::clock_start(self)
    }
}

/// A device double built as a shared library beside the test binary (a dev-dependency), read
/// through its test entry points.
struct LibraryDouble {
    library: libloading::Library,
    path: std::path::PathBuf,
}

impl LibraryDouble {
    fn open(crate_name: &str) -> LibraryDouble {
        let exe = std::env::current_exe().unwrap();
        let path = exe.parent().unwrap().join(format!(
            "{}{crate_name}{}",
            std::env::consts::DLL_PREFIX,
            std::env::consts::DLL_SUFFIX
        ));
        // SAFETY: the test's own double.
        let library = unsafe { libloading::Library::new(&path) }.unwrap();
        LibraryDouble { library, path }
    }

    fn set_hand(&self, hand: &[[f64; 4]]) {
        // SAFETY: the double's function with its declared signature; 4 doubles per keyframe.
        unsafe {
            let f: libloading::Symbol<unsafe extern "C" fn(*const f64, usize)> =
                self.library.get(b"stylet_double_set_hand\0").unwrap();
            f(hand.as_ptr().cast(), hand.len());
        }
    }
}

impl Felt for LibraryDouble {
    fn felt(&self) -> Vec<(f64, DVec3)> {
        // SAFETY: the double's function with its declared signature; room for 4·n doubles.
        unsafe {
            let f: libloading::Symbol<unsafe extern "C" fn(*mut f64, usize) -> usize> =
                self.library.get(b"stylet_double_forces\0").unwrap();
            let n = f(std::ptr::null_mut(), 0);
            let mut buf = vec![0.0f64; 4 * n];
            let n = f(buf.as_mut_ptr(), n).min(n);
            buf.chunks(4)
                .take(n)
                .map(|c| (c[0], DVec3::new(c[1], c[2], c[3])))
                .collect()
        }
    }
    fn broken_rules(&self) -> u64 {
        // SAFETY: the double's function with its declared signature.
        unsafe {
            let f: libloading::Symbol<unsafe extern "C" fn() -> u64> =
                self.library.get(b"stylet_double_frame_violations\0").unwrap();
            f()
        }
    }
    fn clock_start(&self) -> Instant {
        // SAFETY: the double's function with its declared signature, called while the library
        // stays loaded (borrowed from `self`).
        let time_s: libloading::Symbol<unsafe extern "C" fn() -> f64> =
            unsafe { self.library.get(b"stylet_double_time_s\0") }.unwrap();
        // Read the double's clock between two instants; the narrowest of a few reads (a loaded
        // machine may hold the thread up between them) gives the zero to well within a millisecond.
        (0..8)
            .map(|_| {
                let before = Instant::now();
                // SAFETY: as above.
                let t = Duration::from_secs_f64(unsafe { time_s() });
                let after = Instant::now();
                (after - before, before + (after - before) / 2 - t)
            })
            .min_by_key(|(width, _)| *width)
            .unwrap()
            .1
    }
}

/// The hand of the whole-simulator test (Stylet's device frame: +y away from the user, which the
/// view turns along the planned path): still for 1.5 s (forces engage and ramp in), then
/// `standoff + 15` mm forward in 3 s (through the skin), held.
fn pushing_hand(backend: Backend, standoff_mm: f64) -> Vec<[f64; 4]> {
    let to_vendor = vendor_axes(backend).transpose();
    let at = |t: f64, mm: f64| {
        let p = to_vendor * (DVec3::Y * mm);
        [t, p.x, p.y, p.z]
    };
    vec![
        at(0.0, 0.0),
        at(1.5, 0.0),
        at(4.5, standoff_mm + 15.0),
        at(10.0, standoff_mm + 15.0),
    ]
}

/// The whole simulator against one backend's double: a scripted hand pushes a 22 G needle through
/// the phantom's skin along the planned path; the double feels the skin's resistance, clamped to
/// the device's limit; a stalled tick zeroes the force within the watchdog's 10 ms; the last force
/// at shutdown is zero. Prints the servo rate and jitter the double saw and the tick-to-force
/// latency.
fn whole_simulator(device: Box<dyn HapticDevice>, standoff_mm: f64, double: &dyn Felt) {
    let atlas = default_phantom();
    let path = atlas.guided_path().unwrap();
    let (entry, target) = (DVec3::from_array(path.entry_mm), DVec3::from_array(path.target_mm));
    let dir = (target - entry).normalize();
    let start = entry - dir * standoff_mm;
    let backend = device.info().backend;
    let max_n = device.info().max_force_n;
    let profile = physics_profile_for(device.info());
    let needle = ToolSpec::Needle {
        gauge: Gauge::G22,
        length_mm: 150.0,
        stylet_in: true,
    };
    let sim = Simulation::new(Arc::clone(&atlas.model), SimConfig::new(profile, needle)).unwrap();
    let (live, handle) = live_device(start, stylet_devices::script::device::orientation(dir, None), 1000);
    // The view turns the hand's "away from the user" along the path (a stylus held level and
    // pointing away then points the needle along it too).
    handle.set_view(DQuat::from_rotation_arc(DVec3::Y, dir));
    let live = live.with_pose_source(Box::new(HapticPose::new(device, Mapping::default())));
    let computed = Arc::new(Mutex::new(Vec::new()));
    let stalled_at = Arc::new(Mutex::new(None));
    let haptic = HapticLoop::spawn(
        sim,
        Box::new(Stalling {
            inner: live,
            stall_at_tick: 5200,
            stall: Duration::from_millis(60),
            computed: computed.clone(),
            stalled_at: stalled_at.clone(),
        }),
        None,
        SessionLabels {
            scenario: "force feedback".into(),
            difficulty: stylet_scoring::Difficulty::Beginner,
            seed: 0,
        },
        LoopOptions::default(),
    )
    .unwrap();
    let began = Instant::now();
    while haptic.stats().ticks < 6000 && began.elapsed() < Duration::from_secs(30) {
        std::thread::sleep(Duration::from_millis(20));
    }
    handle.finish();
    let report = haptic.join().unwrap();
    let forces = double.felt();
    let computed = computed.lock().unwrap();
    // The double's clock starts when the device opened (within the open call).
    let zero = double.clock_start();
    let on_double_clock = |t: Instant| t.duration_since(zero).as_secs_f64();
    let computed_peak = computed.iter().map(|c| c.1.length()).fold(0.0, f64::max);
    let felt_peak = forces.iter().map(|f| f.1.length()).fold(0.0, f64::max);
    let deepest_mm = computed.iter().map(|c| c.2).fold(f64::NEG_INFINITY, f64::max);
    // Tick to force: from the tick that first computed 0.3 N (the skin touched) to the first
    // force of 0.3 N the double was sent.
    let computed_at = on_double_clock(computed.iter().find(|c| c.1.length() >= 0.3).unwrap().0);
    let felt_at = forces.iter().find(|f| f.1.length() >= 0.3).unwrap().0;
    let latency_ms = (felt_at - computed_at) * 1000.0;
    // The servo loop as the double saw it: one force per servo tick.
    let mut intervals_ms: Vec<f64> = forces.windows(2).map(|w| (w[1].0 - w[0].0) * 1000.0).collect();
    intervals_ms.sort_by(f64::total_cmp);
    let p99_ms = intervals_ms[(intervals_ms.len() * 99 / 100).min(intervals_ms.len() - 1)];
    let rate_hz = (forces.len() - 1) as f64 / (forces.last().unwrap().0 - forces[0].0);
    eprintln!(
        "{backend}: {} ticks, servo {rate_hz:.0} Hz, 99 % of intervals within {p99_ms:.2} ms; computed peak \
         {computed_peak:.3} N, felt peak {felt_peak:.3} N of {max_n} N; tip {deepest_mm:.1} mm under the skin; \
         tick to force {latency_ms:.2} ms",
        report.stats.ticks,
    );
    assert!(forces.len() > 4000, "{backend}: {} forces", forces.len());
    assert_eq!(double.broken_rules(), 0, "{backend}");
    // The needle went through the skin, and the hand felt the resistance, up to the limit.
    assert!(
        deepest_mm > 5.0,
        "{backend}: the tip reached {deepest_mm} mm under the skin"
    );
    assert!(
        computed_peak > 1.0,
        "{backend}: the skin resisted with {computed_peak} N"
    );
    assert!(felt_peak <= max_n + 1e-9, "{backend}: felt {felt_peak} N");
    // The hand felt the skin. How much of its peak depends on the machine: every hold-up of the
    // loop longer than the watchdog's 10 ms zeroes the force and ramps it in again over a second
    // (on an idle machine the hand gets all of it up to the device's maximum, less where a
    // Touch's continuous limit of 0.88 N over a second holds it back; the wall scenarios check
    // the clamp exactly). The latency is reported, not asserted: a figure, not a gate.
    assert!(felt_peak > 0.1, "{backend}: felt {felt_peak} N of {computed_peak} N");
    // The stalled tick: zero within the watchdog's 10 ms (and a servo tick), held until the loop
    // ran again.
    let stalled = on_double_clock(stalled_at.lock().unwrap().unwrap());
    let during: Vec<_> = forces
        .iter()
        .filter(|f| f.0 > stalled + 0.015 && f.0 < stalled + 0.055)
        .collect();
    assert!(
        during.len() >= 10,
        "{backend}: {} servo ticks in the stall",
        during.len()
    );
    assert!(
        during.iter().all(|f| f.1 == DVec3::ZERO),
        "{backend}: a force while the tick was stalled"
    );
    // The hand felt the needle in the half second before the stall (a loaded machine may have
    // held the loop up just before it, and the force then ramps in again).
    let before = forces
        .iter()
        .filter(|f| f.0 < stalled && f.0 > stalled - 0.5)
        .map(|f| f.1.length())
        .fold(0.0, f64::max);
    assert!(before > 0.01, "{backend}: a force before the stall: {before} N");
    assert_eq!(
        forces.last().unwrap().1,
        DVec3::ZERO,
        "{backend}: the last force at shutdown"
    );
}

#[test]
fn a_hand_on_the_haply_double_feels_the_skin_and_is_safe_when_the_tick_stalls() {
    // The patient first: the hand's script runs from the moment the device opens.
    default_phantom();
    let double = HaplyDouble::start(pushing_hand(Backend::Haply, 20.0)).unwrap();
    let device = Haply::open(Some(&double.url)).unwrap();
    whole_simulator(Box::new(device), 20.0, &double);
}

#[test]
fn a_hand_on_the_openhaptics_double_feels_the_skin_and_is_safe_when_the_tick_stalls() {
    // The patient first: the hand's script runs from the moment the device opens.
    default_phantom();
    let double = LibraryDouble::open("stylet_openhaptics_double");
    double.set_hand(&pushing_hand(Backend::OpenHaptics, 20.0));
    let device = OpenHaptics::open(Some(&double.path)).unwrap();
    whole_simulator(Box::new(device), 20.0, &double);
}

#[test]
fn a_hand_on_the_dhd_double_feels_the_skin_and_is_safe_when_the_tick_stalls() {
    // The patient first: the hand's script runs from the moment the device opens.
    default_phantom();
    let double = LibraryDouble::open("stylet_dhd_double");
    double.set_hand(&pushing_hand(Backend::Dhd, 20.0));
    let device = Dhd::open(Some(&double.path)).unwrap();
    whole_simulator(Box::new(device), 20.0, &double);
}

/// A coarse phantom (64 × 64 × 50 voxels of 6 mm) in `dir` and a beginner's plan on it whose
/// sessions are written to `dir/sessions`.
fn small_phantom_plan(dir: &Path) -> (Arc<stylet_atlas::Atlas>, stylet_app::session::SessionPlan) {
    let p = stylet_atlas::phantom::generate(&stylet_atlas::phantom::PhantomConfig {
        dims: [64, 64, 50],
        spacing_mm: [6.0; 3],
        ..Default::default()
    })
    .unwrap();
    stylet_atlas::write(dir, &p.manifest, &p.ct, &p.partial).unwrap();
    let atlas = Arc::new(stylet_atlas::load(dir).unwrap());
    let plan = stylet_app::session::SessionPlan {
        atlas: Arc::clone(&atlas),
        scenario: atlas.manifest.scenarios[0].name.clone(),
        difficulty: stylet_scoring::Difficulty::Beginner,
        trainee: "tina".into(),
        seed: 1,
        sessions_dir: dir.join("sessions"),
    };
    (atlas, plan)
}

/// A session by hand with a force-feedback device (`stylet sim --device haply`): the device
/// opened when the session starts, its model and limits in the session header, the clutch
/// recorded in the notes, and the file replays and scores like any other.
#[test]
fn a_session_with_the_haply_double_records_the_device_and_its_clutch() {
    use stylet_app::session::{Driver, HandDevice, LiveHands, RunningSession};
    use stylet_devices::haptic::DeviceChoice;

    let dir = tempfile::tempdir().unwrap();
    let (atlas, plan) = small_phantom_plan(dir.path());
    let double = HaplyDouble::start(vec![[0.0, 0.0, 0.0, 0.0], [2.0, 0.0, 0.0, 0.0]]).unwrap();
    let choice = DeviceChoice {
        backend: Backend::Haply,
        library: None,
        url: Some(double.url.clone()),
    };
    let hands = LiveHands {
        needle: HandDevice::ForceFeedback(choice, Mapping::default()),
        probe: None,
    };
    let run = RunningSession::start(plan, Driver::Live(hands), true).unwrap();
    assert_eq!(run.moved_by(), Some("Inverse3 0D0B (haply)"));
    let wait_ticks = |n: u64| {
        let began = Instant::now();
        let from = run.stats().ticks;
        while run.stats().ticks < from + n && began.elapsed() < Duration::from_secs(20) {
            std::thread::sleep(Duration::from_millis(5));
        }
    };
    wait_ticks(300);
    // The grip's b button is the clutch.
    double.set_buttons(0b10);
    wait_ticks(300);
    double.set_buttons(0);
    wait_ticks(300);
    let finished = run.finish().unwrap();
    assert!(
        double.forces().len() > 500,
        "the servo loop ran: {}",
        double.forces().len()
    );
    assert_eq!(double.forces().last().map(|f| [f[1], f[2], f[3]]), Some([0.0; 3]));
    let session = stylet_recorder::reader::read(&finished.path).unwrap();
    let hardware = session.header.hardware.clone().expect("the device in the header");
    assert_eq!(
        (hardware.backend.as_str(), hardware.model.as_str()),
        ("haply", "Inverse3 0D0B")
    );
    assert_eq!((hardware.max_force_n, hardware.max_continuous_force_n), (2.0, 1.0));
    let notes: Vec<&str> = session.annotations.iter().map(|a| a.text.as_str()).collect();
    let held = notes.iter().position(|n| n.starts_with("clutch held"));
    let flow = notes.iter().rposition(|n| n.starts_with("forces flow again"));
    assert!(held.is_some() && flow > held, "{notes:?}");
    // The clutch's button reached the recorded ticks too.
    assert!(session.ticks.iter().any(|t| t.buttons & 0b10 != 0));
    // The force sent, tick by tick beside the ticks: zero at the start (no force computed yet),
    // held while the clutch was.
    use stylet_recorder::device_forces::guard;
    let sent = &session.device_forces;
    assert!(
        sent.len() + 5 >= session.ticks.len(),
        "{} of {} ticks",
        sent.len(),
        session.ticks.len()
    );
    assert!(sent[0].zeroed(), "{:?}", sent[0]);
    let held = sent.iter().filter(|f| f.guard & guard::HELD != 0).count();
    assert!((200..=400).contains(&held), "{held} ticks held");
    assert!(sent.iter().filter(|f| f.zeroed()).all(|f| f.sent_n == [0.0; 3]));
    // The Python reader reads the same.
    let py = std::process::Command::new(crate::common::python())
        .arg("-c")
        .arg(
            "import sys; sys.path.insert(0, sys.argv[1]); import stylet_session as s; \
             d = s.read_session(sys.argv[2]).device_forces; print(len(d['tick']), sum(d['held']), d['sent_magnitude_n'][0])",
        )
        .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("recorder/python"))
        .arg(&finished.path)
        .output()
        .unwrap();
    assert!(py.status.success(), "{}", String::from_utf8_lossy(&py.stderr));
    assert_eq!(
        String::from_utf8_lossy(&py.stdout).trim(),
        format!("{} {held} 0.0", sent.len())
    );
    let inspect = crate::common::ok(&["session", "inspect", finished.path.to_str().unwrap()]);
    assert!(
        inspect.contains(&format!(
            "hardware  Inverse3 0D0B (haply), 2.00 N peak, 1.00 N continuous; force sent on {} ticks",
            sent.len()
        )),
        "{inspect}"
    );
    finished.score().unwrap();
    // The review's force chart: the force sent beside the replayed one, the clutch shaded.
    let scorer = stylet_scoring::Scorer::new(&atlas, stylet_scoring::Rubric::default_rubric(), None).unwrap();
    let (_, trace) = scorer.score_session_traced(&session).unwrap();
    assert_eq!(trace.sent_n.len(), trace.t_s.len());
    assert!(trace.guard.iter().any(|g| g & guard::HELD != 0));
    let chart = stylet_dashboard::charts::force_chart(&trace, "Force");
    assert!(chart.series.iter().any(|s| s.name.starts_with("sent to the device")));
    assert!(chart.bands.iter().any(|b| b.3 == "force zeroed by the device guard"));
}

/// Two hands by hand (docs/simulator.md "Hands and devices"): the keys and mouse hold the first
/// hand's tool out of reach, the Haply double holds the convex probe in the second hand and
/// presses it into the skin. The double feels the probe's force (the first hand's is zero all
/// along), clamped to its limit and zero at the end; the file records both hands and replays
/// verified.
#[test]
fn a_force_feedback_device_in_the_probe_hand_feels_the_probe() {
    use stylet_app::session::{Driver, HandDevice, LiveHands, RunningSession, probe_start_pose};
    use stylet_devices::haptic::DeviceChoice;
    use stylet_physics::{HandTool, ProbeKind};

    let dir = tempfile::tempdir().unwrap();
    let (_, plan) = small_phantom_plan(dir.path());
    let double = HaplyDouble::start(pushing_hand(Backend::Haply, 30.0)).unwrap();
    let choice = DeviceChoice {
        backend: Backend::Haply,
        library: None,
        url: Some(double.url.clone()),
    };
    let (_, probe_q) = probe_start_pose(&plan);
    let hands = LiveHands {
        needle: HandDevice::KeysAndMouse,
        probe: Some((
            HandDevice::ForceFeedback(choice, Mapping::default()),
            HandTool::Probe(ProbeKind::Convex),
        )),
    };
    let run = RunningSession::start(plan, Driver::Live(hands), true).unwrap();
    assert_eq!(
        (run.moved_by(), run.probe_moved_by()),
        (None, Some("Inverse3 0D0B (haply)"))
    );
    // The keys steer the first hand; the hand moving away from the user pushes the probe in.
    let keys = run.steered_by_keys().unwrap().pose().unwrap();
    assert_eq!(Some(keys), run.live().unwrap().pose());
    run.probe_live()
        .unwrap()
        .set_view(DQuat::from_rotation_arc(DVec3::Y, probe_q * DVec3::Z));
    let began = Instant::now();
    while run.stats().ticks < 5500 && began.elapsed() < Duration::from_secs(30) {
        std::thread::sleep(Duration::from_millis(20));
    }
    let finished = run.finish().unwrap();
    let felt = double.forces();
    let felt_peak = felt
        .iter()
        .map(|f| DVec3::new(f[1], f[2], f[3]).length())
        .fold(0.0, f64::max);
    // How much of the probe's force the hand gets depends on the machine (a hold-up of the loop
    // past the watchdog zeroes it and ramps it in again), as in the one-handed test above.
    assert!(felt_peak > 0.1 && felt_peak <= 2.0 + 1e-9, "felt {felt_peak} N");
    assert_eq!(felt.last().map(|f| [f[1], f[2], f[3]]), Some([0.0; 3]));
    let session = stylet_recorder::reader::read(&finished.path).unwrap();
    let hand2 = session.header.second_hand.clone().expect("a two-handed header");
    assert_eq!(
        (hand2.device.as_str(), hand2.initial_tool),
        ("touch", Some(HandTool::Probe(ProbeKind::Convex)))
    );
    // The first hand never touched; the second pressed on the skin.
    assert!(session.ticks.iter().all(|t| t.force_n == [0.0; 3]));
    let pressed = session
        .ticks
        .iter()
        .filter_map(|t| t.second_hand.map(|h| DVec3::from_array(h.force_n).length()))
        .fold(0.0, f64::max);
    assert!(pressed > 0.3, "the probe pressed with {pressed} N");
    // The device forces the file records are the needle hand's device's: none here.
    assert!(session.header.hardware.is_none() && session.device_forces.is_empty());
    let report = finished.score().unwrap();
    assert!(report.replay_verified, "{:?}", report.divergence);
}

/// A second hand's device that cannot be opened stops the session before it starts, by name, and
/// the first hand's force-feedback device, already opened, is closed again at zero force.
#[test]
fn a_missing_probe_hand_device_closes_the_needle_hands_device() {
    use stylet_app::session::{Driver, HandDevice, LiveHands, RunningSession};
    use stylet_devices::haptic::DeviceChoice;
    use stylet_physics::{HandTool, ProbeKind};

    let dir = tempfile::tempdir().unwrap();
    let (_, plan) = small_phantom_plan(dir.path());
    let double = HaplyDouble::start(vec![[0.0; 4], [1.0, 0.0, 0.0, 0.0]]).unwrap();
    let hands = LiveHands {
        needle: HandDevice::ForceFeedback(
            DeviceChoice {
                backend: Backend::Haply,
                library: None,
                url: Some(double.url.clone()),
            },
            Mapping::default(),
        ),
        // No SpaceMouse is connected to a test machine.
        probe: Some((HandDevice::SpaceMouse, HandTool::Probe(ProbeKind::Convex))),
    };
    let e = RunningSession::start(plan, Driver::Live(hands), true)
        .err()
        .expect("refused");
    let e = e.to_string();
    assert!(
        e.starts_with("the device cannot be used: ")
            && (e.contains("no SpaceMouse found") || e.contains("HID devices")),
        "{e}"
    );
    let began = Instant::now();
    while double.connected() && began.elapsed() < Duration::from_secs(5) {
        std::thread::sleep(Duration::from_millis(10));
    }
    assert_eq!(double.connections(), 1, "the device was opened");
    assert!(!double.connected(), "and closed again");
    assert!(double.forces().iter().all(|f| [f[1], f[2], f[3]] == [0.0; 3]));
    assert!(!dir.path().join("sessions").exists(), "no session file was begun");
}
