//! Tissue deformation speed (the thesis' Table 4.1 analogue), on the default phantom with an 18 G
//! needle 10 cm into the liver along the intercostal path, 2-thread rayon pool:
//!
//! - one warm-started solve of the default schedule on 32 and 64 cells (33³ and 65³ nodes), and
//!   one explicit step on 64 cells as the unit of work (ratios in the same run);
//! - the haptic tick's median, p99 and p99.9 over 30 s at 1 kHz with deformation off, and on with
//!   the solves on their own thread (the live simulator's set-up), same trembling needle; then
//!   with the convex probe pressed on in the second hand as well (two tools, one solve); with
//!   deformation on, the ticks that launch and enter solves apart from the others;
//! - replay speed of a 1-minute needle session recorded with and without deformation.
//!
//! `STYLET_BENCH_EXPORT=DIR` also writes the 64-cell system and the Stylet solution of one
//! cold-started frame (`fixed.u8`, `u_bc.f64`, `u_stylet.f64`, `meta.json`) for
//! `benches/deformation/scipy_cg.py DIR`, which solves the same discretised system with
//! `scipy.sparse.linalg.cg` to the residual Stylet reached. Under `cargo test --all-targets` each
//! part runs once on a small case: a smoke test.

mod common;

use std::hint::black_box;
use std::path::Path;
use std::time::Instant;

use criterion::Criterion;
use stylet_devices::script::parse;
use stylet_physics::deform::{self, DeformSettings};
use stylet_physics::glam::DVec3;
use stylet_physics::{Simulation, TickInput};

const NEEDLE_IN: &str = "stylet-script 1\ntool needle gauge 18 length 200\nend 11\nat 0 along intercostal-10-11 -10\nat 10 along intercostal-10-11 100\nat 11 along intercostal-10-11 100\n";
/// The same needle with the convex probe in the second hand, pressed on with 1.5 N beside the
/// entry point in the plane of the path (as `atlases/phantom/scripts/two-handed-success.txt`).
const NEEDLE_AND_PROBE_IN: &str = "stylet-script 1\ntool needle gauge 18 length 200\ntool2 probe convex\nend 11\n\
    at 0 along intercostal-10-11 -10\n\
    at 0 hand2 pos 172.6 36.6 7.7 dir -0.9985 -0.0538 -0.002 xaxis 0.053 -0.971 0.235\n\
    at 0.5 hand2 press -0.9985 -0.0538 -0.002 1.5\n\
    at 10 along intercostal-10-11 100\nat 11 along intercostal-10-11 100\n";

fn main() {
    let measuring = std::env::args().any(|a| a == "--bench");
    // SAFETY: no other thread runs yet.
    unsafe { std::env::set_var("RAYON_NUM_THREADS", "2") };
    let (dir, atlas) = common::phantom();

    let (sim, _) = prepared(&atlas, NEEDLE_IN, DeformSettings::on(), false);
    let needle = sim.needle().expect("a needle");
    let tip = needle.path().tip().expect("inserted").pos;
    let points = deform::tool_points::needle_points(needle, 0.5);
    println!(
        "needle {:.0} mm inserted, {} tool points",
        needle.inserted_mm(),
        points.len()
    );
    let mut c = Criterion::default().configure_from_args();
    if !measuring {
        c = c
            .sample_size(10)
            .warm_up_time(std::time::Duration::from_millis(1))
            .measurement_time(std::time::Duration::from_millis(1));
    }
    let mut g = c.benchmark_group("deformation");
    g.sample_size(if measuring { 30 } else { 10 });
    for cells in [32u32, 64] {
        let s = DeformSettings {
            cells,
            ..DeformSettings::default()
        };
        let mut field = deform::solve(&atlas.model, &s, None, tip, &points);
        g.bench_function(format!("solve {cells} cells"), |b| {
            b.iter(|| {
                field = deform::solve(&atlas.model, &s, Some(&field), tip, &points);
                black_box(field.max_displacement_mm())
            })
        });
        if !measuring {
            break;
        }
    }
    // The unit of work: the same solve with one explicit step and no coarse levels.
    let one_step = DeformSettings {
        schedule: deform::Schedule {
            levels: 1,
            coarsest_steps: 1,
            ..DeformSettings::default().schedule
        },
        ..DeformSettings::default()
    };
    let mut field = deform::solve(&atlas.model, &one_step, None, tip, &points);
    g.bench_function("one explicit step, 64 cells (with the solve's fixed costs)", |b| {
        b.iter(|| {
            field = deform::solve(&atlas.model, &one_step, Some(&field), tip, &points);
            black_box(field.max_displacement_mm())
        })
    });
    g.finish();

    if let Ok(out) = std::env::var("STYLET_BENCH_EXPORT") {
        export(&atlas, tip, &points, Path::new(&out));
    }

    // The haptic tick with deformation off and on (solves on their own thread).
    let ticks = if measuring { 30_000 } else { 300 };
    for (name, script, settings, background) in [
        ("needle tick, deformation off", NEEDLE_IN, DeformSettings::off(), false),
        (
            "needle tick, deformation on, solves on their own thread",
            NEEDLE_IN,
            DeformSettings::on(),
            true,
        ),
        (
            "needle + convex probe tick (two hands), deformation on, solves on their own thread",
            NEEDLE_AND_PROBE_IN,
            DeformSettings::on(),
            true,
        ),
    ] {
        let (mut sim, input) = prepared(&atlas, script, settings, background);
        let (m, p99, p999) = percentiles(&mut sim, &input, ticks);
        println!("{name}: median {m:.2} µs, p99 {p99:.2} µs, p99.9 {p999:.1} µs");
    }

    // Replay speed of a one-minute needle session.
    let seconds = if measuring { 60 } else { 2 };
    let script = common::needle_session_script(seconds);
    let mut base = None;
    for (name, settings) in [("off", DeformSettings::off()), ("on", DeformSettings::on())] {
        let file = dir.path().join(format!("{name}.mcap"));
        let s = common::replay_time_s(&atlas, &with_deformation(&script, settings), &file);
        let rt = seconds as f64 / s;
        let ratio = base.map_or(String::new(), |b: f64| format!(", {:.3} of the time without", s / b));
        base.get_or_insert(s);
        println!("replay of a {seconds} s needle session, deformation {name}: {s:.3} s = {rt:.1}× real time{ratio}");
    }
}

/// Runs a script to its end with the given deformation and returns the simulation and last input.
fn prepared(atlas: &stylet_atlas::Atlas, text: &str, d: DeformSettings, background: bool) -> (Simulation, TickInput) {
    let (mut sim, last) = common::prepared(atlas, &with_deformation(text, d));
    if background {
        sim.set_deform_in_background(true);
    }
    (sim, last)
}

/// The script with the given deformation.
fn with_deformation(text: &str, d: DeformSettings) -> stylet_devices::script::Script {
    let mut script = parse(text).unwrap();
    script.deformation = d;
    script
}

/// Median, 99th and 99.9th percentile of single ticks (µs), paced as in the haptic loop (so a
/// solve on its own thread has the latency's time to finish before the tick that needs its
/// result); with deformation on, the ticks that launch and enter solves reported apart.
fn percentiles(sim: &mut Simulation, input: &TickInput, n: usize) -> (f64, f64, f64) {
    let times = common::tick_times(sim, input, n);
    // The ticks that launch a solve and enter the last one (every 100th) apart from the rest:
    // what the haptic thread does itself, and what the solve on the other core costs it.
    let every = sim.config().deformation.every_ticks as usize;
    if sim.config().deformation.enabled && n > every {
        // Step i runs from tick t0 + i and launches (and enters) when the tick it ends on,
        // t0 + i + 1, is a multiple of `every_ticks`.
        let t0 = sim.tick() as usize - n;
        let launches = |i: usize| (t0 + i + 1).is_multiple_of(every);
        let split = |want: bool| -> Vec<f64> {
            let mut v: Vec<f64> = times
                .iter()
                .enumerate()
                .filter(|(i, _)| launches(*i) == want)
                .map(|(_, t)| *t)
                .collect();
            v.sort_by(f64::total_cmp);
            v
        };
        let (launch, rest) = (split(true), split(false));
        let q = |v: &[f64], p: f64| v[((v.len() as f64 * p) as usize).min(v.len() - 1)];
        println!(
            "  ticks that launch and enter solves: median {:.2} µs, max {:.1} µs; the other ticks: median {:.2} µs, p99 {:.2} µs, p99.9 {:.1} µs",
            q(&launch, 0.5),
            q(&launch, 1.0),
            q(&rest, 0.5),
            q(&rest, 0.99),
            q(&rest, 0.999)
        );
    }
    common::quantiles(times)
}

/// The 64-cell system of one cold-started frame and Stylet's solution, for scipy_cg.py.
fn export(atlas: &stylet_atlas::Atlas, tip: DVec3, points: &[deform::ToolPoint], out: &Path) {
    std::fs::create_dir_all(out).unwrap();
    let s = DeformSettings::default();
    let t = Instant::now();
    let f = deform::solve(&atlas.model, &s, None, tip, points);
    let ms = t.elapsed().as_secs_f64() * 1e3;
    let (fixed, u_bc) = deform::field::dirichlet(&atlas.model, &s, f.lattice(), points);
    let bytes = |v: &[DVec3]| {
        v.iter()
            .flat_map(|d| d.to_array())
            .flat_map(f64::to_le_bytes)
            .collect::<Vec<u8>>()
    };
    std::fs::write(
        out.join("fixed.u8"),
        fixed.iter().map(|&b| u8::from(b)).collect::<Vec<u8>>(),
    )
    .unwrap();
    std::fs::write(out.join("u_bc.f64"), bytes(&u_bc)).unwrap();
    std::fs::write(out.join("u_stylet.f64"), bytes(&f.displacements())).unwrap();
    let (mu, lm) = s.regulariser.lame();
    std::fs::write(
        out.join("meta.json"),
        format!(
            "{{\"n\": {}, \"h_mm\": {}, \"mu\": {mu}, \"lambda_plus_mu\": {lm}, \"stylet_cold_solve_ms\": {ms:.3}}}\n",
            f.lattice().n,
            f.lattice().h_mm
        ),
    )
    .unwrap();
    println!(
        "exported the 64-cell system to {} (cold solve {ms:.1} ms)",
        out.display()
    );
}
