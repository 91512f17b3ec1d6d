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

/// Every 16 G point within 15 %, every 20 G point from 0.1 N on within 20 % (the worst, 0.1 N,
/// −14 %), and the 20 G's 0.05 N point (5 gram-force, the series' outlier) as documented in
/// `needle::spec`: 30–40 % more compliant in the model than measured.
#[test]
fn deflections_match_table_a1() {
    for (g, stylet, len, points) in TABLE_A1 {
        for &(f, measured) in points {
            let e = error(g, stylet, len, f, measured);
            println!(
                "{:>2} G {:<14} {f:.2} N: measured {measured:>4.0} mm, simulated {:>5.1} mm ({:+.1} %)",
                g.number(),
                if stylet { "with stylet" } else { "without stylet" },
                cantilever_tip_deflection_mm(g, stylet, len, f),
                100.0 * e,
            );
            let (low, high) = match (g, f) {
                (Gauge::G16, _) => (-0.15, 0.15),
                (_, f) if f < 0.1 => (0.30, 0.40),
                _ => (-0.20, 0.20),
            };
            assert!(
                (low..=high).contains(&e),
                "{} G, {f} N: {:+.1} %",
                g.number(),
                100.0 * e
            );
        }
    }
}

/// Each series' least-squares compliance, Σ δ F / Σ F², is the model's within 1 %: the fit uses
/// every load point.
#[test]
fn the_model_has_each_series_least_squares_compliance() {
    for (g, stylet, len, points) in TABLE_A1 {
        let (fd, ff) = points.iter().fold((0.0, 0.0), |(a, b), &(f, d)| (a + f * d, b + f * f));
        let measured = fd / ff;
        let model = cantilever_tip_deflection_mm(g, stylet, len, 1.0);
        println!(
            "{} G stylet {stylet}: {measured:.1} mm/N measured, {model:.1} simulated",
            g.number()
        );
        assert!(
            (model / measured - 1.0).abs() < 0.01,
            "{} G: {model} vs {measured}",
            g.number()
        );
    }
}

/// The thin PTCD needles with their stylets, 150 mm free, 0.1 N at the tip: the simulated
/// deflection beside a steel tube of the nominal gauge (E = 200 000 N/mm², δ = F L³ / (3 EI))
/// and a solid rod of its outer diameter (a stylet filling the lumen).
#[test]
fn thin_needles_bend_like_steel() {
    let theory = |ei: f64| 0.1 * 150f64.powi(3) / (3.0 * ei);
    let steel = |d: f64, inner: f64| 200_000.0 * std::f64::consts::PI * (d.powi(4) - inner.powi(4)) / 64.0;
    for (g, inner_mm) in [(Gauge::G20, 0.603), (Gauge::G22, 0.413)] {
        let d = g.outer_diameter_mm();
        let sim = cantilever_tip_deflection_mm(g, true, 150.0, 0.1);
        let (tube, rod) = (theory(steel(d, inner_mm)), theory(steel(d, 0.0)));
        println!(
            "{} G, 150 mm, 0.1 N: simulated {sim:.1} mm; steel tube {tube:.1} mm, solid rod {rod:.1} mm",
            g.number()
        );
        // Stiffer than the bare tube, at most 15 % stiffer than the rod.
        assert!(
            sim < tube && sim > rod / 1.15,
            "{} G: {sim} vs tube {tube}, rod {rod}",
            g.number()
        );
    }
}
