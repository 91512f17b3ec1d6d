//! Table A.1 of the thesis: tip deflection of cantilevered needles under a tip force, measured
//! with a bench vise and a spring scale, against the simulator's needle model.

use stylet_physics::needle::spec::Gauge;
use stylet_physics::needle::tool::cantilever_tip_deflection_mm;

/// (gauge, stylet in, free length mm, [(force N, measured deflection mm)]).
type Series = (Gauge, bool, f64, &'static [(f64, f64)]);
const TABLE_A1: [Series; 3] = [
    (
        Gauge::G16,
        true,
        165.0,
        &[(0.25, 6.0), (0.5, 13.0), (0.75, 20.0), (1.0, 26.0), (1.25, 33.0)],
    ),
    (Gauge::G16, false, 165.0, &[(0.25, 13.0), (0.5, 26.0), (0.75, 38.0)]),
    (
        Gauge::G20,
        true,
        200.0,
        &[(0.05, 13.0), (0.1, 41.0), (0.15, 53.0), (0.2, 69.0)],
    ),
];

fn error(g: Gauge, stylet: bool, len: f64, f: f64, measured: f64) -> f64 {
    (cantilever_tip_deflection_mm(g, stylet, len, f) - measured) / measured
}

/// Every 16 G point and the 20 G small-load point within 15 %.
#[test]
fn small_load_deflections_within_15_percent() {
    for (g, stylet, len, points) in TABLE_A1 {
        for &(f, measured) in points {
            let e = error(g, stylet, len, f, measured);
            let small = g == Gauge::G16 || f <= 0.05;
            println!(
                "{:>2} G {:<14} {f:.2} N: measured {measured:>4.0} mm, simulated {:>5.1} mm ({:+.1} %){}",
                g.number(),
                if stylet { "with stylet" } else { "without stylet" },
                cantilever_tip_deflection_mm(g, stylet, len, f),
                100.0 * e,
                if small {
                    ""
                } else {
                    "  (large load, outside the linear regime of the data)"
                }
            );
            if small {
                assert!(e.abs() <= 0.15, "{} G, {f} N: {:+.1} %", g.number(), 100.0 * e);
            }
        }
    }
}

/// The 20 G needle's larger loads are 25–37 % more compliant than the model (documented in
/// `needle::spec`): keeps that statement true.
#[test]
fn large_load_deviation_of_the_20g_needle_is_as_documented() {
    for &(f, measured) in &TABLE_A1[2].3[1..] {
        let e = error(Gauge::G20, true, 200.0, f, measured);
        assert!((-0.40..=-0.20).contains(&e), "{f} N: {:+.1} %", 100.0 * e);
    }
}
