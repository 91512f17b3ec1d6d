//! The dashboard player's frames for a 10-minute session on the default phantom: the replay
//! snapshots built once per session, then frames at arbitrary ticks — the first time (replayed from
//! the nearest snapshot and drawn: 3D, axial, ultrasound, X-ray at 480 × 360) and from the disk
//! cache — with p50 and p99, and the cache's disk use per frame; then the 12 frames of the 3D
//! overview's turntable (tip path, planned path and a corridor drawn). Timed by hand (percentiles,
//! not criterion's means); the ratio is the first frame to the cached one.
//!
//! `cargo bench --bench player`. Rayon gets 2 threads, as on the development machine. Under
//! `cargo test --all-targets` a small phantom and a 20-second session are used once: a smoke test.

use std::path::Path;
use std::process::Command;
use std::sync::Arc;
use std::time::{Duration, Instant};

use stylet_dashboard::player::frames::{AtlasDrawing, FrameCache, FrameView};
use stylet_dashboard::player::states::ReplayStates;

/// A session of `seconds` on the phantom: the needle in and out along the planned path twice a
/// minute; stylet out, fluoroscopy and contrast half-way.
fn script(seconds: u64) -> String {
    let mut s = format!("stylet-script 1\ndevice premium\ntool needle gauge 18 length 150 stylet in\nend {seconds}\n");
    let half = seconds / 2;
    let mut t = 0;
    while t + 20 <= seconds {
        s += &format!(
            "at {t} along intercostal-10-11 -15\nat {} along intercostal-10-11 45\n",
            t + 15
        );
        if (t + 15..t + 20).contains(&half) {
            s +=
                &format!("at {half} event stylet-remove\nat {half} event xray-on\nat {half} event contrast-inject 2\n");
        }
        s += &format!("at {} along intercostal-10-11 45\n", t + 20);
        t += 30;
    }
    s
}

fn run(args: &[&str]) {
    let out = Command::new(env!("CARGO_BIN_EXE_stylet")).args(args).output().unwrap();
    assert!(
        out.status.success(),
        "stylet {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

fn percentile(v: &mut [Duration], p: f64) -> f64 {
    v.sort();
    let i = ((v.len() as f64 - 1.0) * p).round() as usize;
    v[i].as_secs_f64() * 1e3
}

fn main() {
    let measuring = std::env::args().any(|a| a == "--bench");
    // SAFETY: no other thread runs yet.
    unsafe { std::env::set_var("RAYON_NUM_THREADS", "2") };
    let dir = tempfile::tempdir().unwrap();
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let atlas_dir = dir.path().join("atlas");
    let mut phantom = vec!["atlas".to_string(), "phantom".into(), "--out".into(), s(&atlas_dir)];
    if !measuring {
        phantom.extend(["--dims", "64,64,48", "--spacing", "6"].map(String::from));
    }
    run(&phantom.iter().map(String::as_str).collect::<Vec<_>>());
    let seconds = if measuring { 600 } else { 20 };
    let script_path = dir.path().join("long.txt");
    std::fs::write(&script_path, script(seconds)).unwrap();
    let session_path = dir.path().join("long.mcap");
    run(&[
        "script",
        "run",
        "--atlas",
        &s(&atlas_dir),
        "--script",
        &s(&script_path),
        "--scenario",
        "success-intercostal",
        "--out",
        &s(&session_path),
    ]);
    let atlas = Arc::new(stylet_atlas::load(&atlas_dir).unwrap());
    let session = stylet_recorder::reader::read(&session_path).unwrap();
    let scorer = stylet_scoring::Scorer::new(&atlas, stylet_scoring::Rubric::default_rubric(), None).unwrap();
    let (report, trace) = scorer.score_session_traced(&session).unwrap();
    let file_bytes = std::fs::metadata(&session_path).unwrap().len();

    let t = Instant::now();
    let states = ReplayStates::build(session, Arc::clone(&atlas.model)).unwrap().unwrap();
    let build_s = t.elapsed().as_secs_f64();
    let drawing = AtlasDrawing::new(Arc::clone(&atlas));
    let cache = FrameCache::new(dir.path(), 1 << 30);
    let sha = "00".repeat(32);

    // Arbitrary ticks, the same on every run (a small LCG).
    let samples = if measuring { 40 } else { 3 };
    let mut x: u64 = 0x5eed;
    let span = states.last_tick - states.first_tick;
    let ticks: Vec<u64> = (0..samples)
        .map(|_| {
            x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            states.first_tick + (x >> 33) % (span + 1)
        })
        .collect();
    let (w, h) = (480, 360);
    let mut seek = Vec::new();
    let mut first: Vec<Vec<Duration>> = vec![Vec::new(); FrameView::ALL.len()];
    let mut cached = Vec::new();
    let mut png_bytes = 0u64;
    for &tick in &ticks {
        let t = Instant::now();
        let moment = states.moment_at(tick).expect("every tick of the session replays");
        let replayed = t.elapsed();
        seek.push(replayed);
        for (k, view) in FrameView::ALL.into_iter().enumerate() {
            let t = Instant::now();
            let png = drawing.draw(view, &moment, w, h).unwrap().to_png().unwrap();
            let path = cache.path(&sha, view, tick, w, h);
            cache.put(&path, &png);
            // The first frame of a view pays the seek too (each request replays on its own).
            first[k].push(replayed + t.elapsed());
            png_bytes += png.len() as u64;
        }
    }
    for &tick in &ticks {
        for view in FrameView::ALL {
            let path = cache.path(&sha, view, tick, w, h);
            let t = Instant::now();
            let png = cache.get(&path).unwrap();
            cached.push(t.elapsed());
            assert!(!png.is_empty());
        }
    }
    // The overview's turntable, with the session's own final approach as a one-path corridor.
    let corridor = trace
        .final_approach()
        .and_then(|p| stylet_render::corridor::Corridor::from_paths(&[p]));
    let mut overview = Vec::new();
    for frame in 0..stylet_render::overview::FRAMES {
        let t = Instant::now();
        let spec = stylet_dashboard::player::overview::spec(
            scorer.atlas(),
            scorer.paths(),
            &report,
            &trace,
            corridor.as_ref(),
            frame,
        );
        let (ow, oh) = stylet_dashboard::player::overview::OVERVIEW_SIZE;
        let png = stylet_render::overview::render(&atlas, &drawing.volume, &spec, ow, oh)
            .unwrap()
            .to_png()
            .unwrap();
        overview.push(t.elapsed());
        assert!(!png.is_empty());
    }
    if !measuring {
        return;
    }
    let [nx, ny, nz] = atlas.model.ct().grid().dims();
    println!(
        "\nPlayer frames: {seconds} s session ({} ticks, {:.1} MiB file) on the {nx}×{ny}×{nz} phantom, {w}×{h}, CPU on 2 threads",
        states.last_tick - states.first_tick + 1,
        file_bytes as f64 / (1 << 20) as f64
    );
    println!(
        "replay snapshots: {} built in {:.2} s (once per session, on its first frame)",
        states.snapshots(),
        build_s
    );
    let cached_p50 = percentile(&mut cached.clone(), 0.5);
    println!(
        "seek (replay from the nearest snapshot): p50 {:.1} ms, p99 {:.1} ms",
        percentile(&mut seek, 0.5),
        percentile(&mut seek, 0.99)
    );
    println!(
        "{:<12} {:>12} {:>12} {:>14}",
        "view", "first p50 ms", "first p99 ms", "p50 × cached"
    );
    for (k, view) in FrameView::ALL.into_iter().enumerate() {
        let p50 = percentile(&mut first[k], 0.5);
        let p99 = percentile(&mut first[k], 0.99);
        println!("{:<12} {p50:>12.1} {p99:>12.1} {:>14.0}", view.name(), p50 / cached_p50);
    }
    println!(
        "cached frame (disk read): p50 {:.3} ms, p99 {:.3} ms",
        cached_p50,
        percentile(&mut cached, 0.99)
    );
    println!(
        "3D overview frame (tip path of {} stays, drawn and encoded): p50 {:.1} ms, p99 {:.1} ms over the {} turntable angles",
        trace.tip_stays().len(),
        percentile(&mut overview.clone(), 0.5),
        percentile(&mut overview, 0.99),
        stylet_render::overview::FRAMES
    );
    let frames = (samples * FrameView::ALL.len()) as f64;
    println!(
        "disk: {:.1} KiB per frame; a full watch at 1× drawing 5 ticks a second in 4 views ≈ {:.0} MiB per session (cache limit {} MiB)",
        png_bytes as f64 / frames / 1024.0,
        png_bytes as f64 / frames * 4.0 * 5.0 * seconds as f64 / (1 << 20) as f64,
        stylet_dashboard::player::FRAME_CACHE_BYTES >> 20
    );
}
