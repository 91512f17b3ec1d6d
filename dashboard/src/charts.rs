//! The dashboard's charts as inline SVG (plotters, through `crate::plot`): every chart
//! has a title, axis labels with units and a legend, and each force component keeps its colour
//! everywhere (`palette`). Sparklines are tiny hand-written SVG polylines.

use crate::plot::{ChartColor, LineChart, Series, palette};
use stylet_physics::LabelId;
use stylet_render::RenderError;
use stylet_scoring::ReviewTrace;
use stylet_service::store::ProgressPoint;

/// Chart size in SVG user units (scaled to the page width by CSS).
pub const CHART_SIZE: (u32, u32) = (1100, 440);

fn series(name: &str, color: ChartColor, bold: bool, dashed: bool, points: Vec<(f64, f64)>) -> Series {
    Series {
        name: name.into(),
        color,
        points,
        bold,
        dashed,
        dots: false,
    }
}

fn zip(t: &[f64], v: &[f64]) -> Vec<(f64, f64)> {
    t.iter().copied().zip(v.iter().copied()).collect()
}

/// Event markers worth a line on a force chart.
fn markers(trace: &ReviewTrace) -> Vec<(f64, String)> {
    trace
        .events
        .iter()
        // Redirections are key moments of the player, not lines on the chart (there may be many).
        .filter(|e| e.kind != "tool" && e.kind != "redirection")
        .map(|e| (e.t_s, e.label.clone()))
        .collect()
}

/// The force peaks of the structures the needle cut into, named (`name`: the atlas' label name,
/// `None` for tissue not worth a label, e.g. unlabelled soft tissue): (time of the peak, its
/// force, the structure).
pub fn puncture_peaks(trace: &ReviewTrace, name: &dyn Fn(LabelId) -> Option<String>) -> Vec<(f64, f64, String)> {
    trace
        .punctures
        .iter()
        .filter(|p| p.peak_force_n.is_finite())
        .filter_map(|p| Some((p.peak_t_s, p.peak_force_n, name(p.label)?)))
        .collect()
}

/// Instructors' comments at a moment, as chart notes numbered in the review list's order
/// (`annotations`' comments, oldest first).
pub fn comment_notes(annotations: &serde_json::Value) -> Vec<(f64, String)> {
    annotations["comments"]
        .as_array()
        .map(|cs| {
            cs.iter()
                .enumerate()
                .filter_map(|(n, c)| Some((c["at_s"].as_f64()?, format!("[{}] comment", n + 1))))
                .collect()
        })
        .unwrap_or_default()
}

/// Force along the needle over time: the total and its cutting, friction and base components
/// (eqs. 3.5.1–3.5.6), with the session's events as vertical markers. A session trained on a
/// force-feedback device adds the force the device was sent (its magnitude) and shades where the
/// device's guard zeroed or reduced it; a drainage session shades the steps of the exchange.
pub fn force_chart(trace: &ReviewTrace, title: &str) -> LineChart {
    let t = &trace.t_s;
    let mut series = vec![
        series("total", palette::TOTAL, true, false, zip(t, &trace.force_n)),
        series("cutting", palette::CUTTING, false, false, zip(t, &trace.cutting_n)),
        series("friction", palette::FRICTION, false, false, zip(t, &trace.friction_n)),
        series("base", palette::BASE, false, false, zip(t, &trace.base_n)),
    ];
    if !trace.sent_n.is_empty() {
        series.push(self::series(
            "sent to the device (magnitude)",
            palette::SENT,
            true,
            true,
            zip(t, &trace.sent_n),
        ));
    }
    LineChart {
        title: title.into(),
        x_label: "time (s)".into(),
        y_label: "force along the needle (N)".into(),
        series,
        markers: markers(trace),
        bands: phase_bands(trace).into_iter().chain(guard_bands(trace)).collect(),
        ..Default::default()
    }
}

/// A drainage session's steps after the puncture (the guide wire in, a dilator on it, the
/// catheter on it or placed), each shaded in its colour; the puncture before them is not.
pub fn phase_bands(trace: &ReviewTrace) -> Vec<(f64, f64, ChartColor, String)> {
    use stylet_scoring::drainage::Step;
    trace
        .phases
        .iter()
        .filter_map(|p| {
            let color = match p.step {
                Step::Puncture => return None,
                Step::Wire => palette::WIRE_STEP,
                Step::Dilator => palette::DILATOR_STEP,
                Step::Catheter => palette::CATHETER_STEP,
            };
            Some((p.from_s, p.to_s, color, format!("step: {}", p.step.label())))
        })
        .collect()
}

/// Where a device's force guard zeroed the force (held, watchdog, waiting to engage) or reduced
/// it (ramping in, clamped, continuous limit): consecutive buckets merged into spans.
pub fn guard_bands(trace: &ReviewTrace) -> Vec<(f64, f64, ChartColor, String)> {
    use stylet_recorder::device_forces::guard;
    let zeroed = guard::HELD | guard::WATCHDOG | guard::WAITING | guard::NOT_FINITE;
    let reduced = guard::RAMPING | guard::CLAMPED | guard::CONTINUOUS;
    let kind = |g: u8| {
        if g & zeroed != 0 {
            Some((palette::ZEROED, "force zeroed by the device guard"))
        } else if g & reduced != 0 {
            Some((palette::REDUCED, "force reduced by the device guard"))
        } else {
            None
        }
    };
    let mut bands: Vec<(f64, f64, ChartColor, String)> = Vec::new();
    for (k, &g) in trace.guard.iter().enumerate() {
        let (Some(&t0), Some((color, label))) = (trace.t_s.get(k), kind(g)) else {
            continue;
        };
        let t1 = t0 + trace.bucket_s;
        match bands.last_mut() {
            Some(last) if last.3 == label && (last.1 - t0).abs() < 1e-9 => last.1 = t1,
            _ => bands.push((t0, t1, color, label.to_string())),
        }
    }
    bands
}

/// Insertion depth over time: the needle length inside the body and the tip's depth under the
/// skin surface; in a two-handed session, the spans with the tip out of the live ultrasound
/// image shaded.
pub fn depth_chart(trace: &ReviewTrace, title: &str) -> LineChart {
    let t = &trace.t_s;
    LineChart {
        title: title.into(),
        x_label: "time (s)".into(),
        y_label: "depth (mm)".into(),
        series: vec![
            series(
                "inserted length",
                palette::INSERTED,
                true,
                false,
                zip(t, &trace.inserted_mm),
            ),
            series(
                "tip depth under the skin",
                palette::TIP_DEPTH,
                false,
                false,
                zip(t, &trace.tip_depth_mm),
            ),
        ],
        markers: markers(trace),
        bands: tip_hidden_bands(trace),
        ..Default::default()
    }
}

/// The legend of the spans a two-handed session's needle tip was out of the live image.
pub const TIP_HIDDEN_LABEL: &str = "tip out of the live ultrasound image";

/// Where the needle tip was out of the live ultrasound image (two-handed sessions):
/// consecutive buckets merged into spans.
pub fn tip_hidden_bands(trace: &ReviewTrace) -> Vec<(f64, f64, ChartColor, String)> {
    let mut bands: Vec<(f64, f64, ChartColor, String)> = Vec::new();
    for (k, _) in trace.tip_hidden.iter().enumerate().filter(|(_, h)| **h) {
        let Some(&t0) = trace.t_s.get(k) else { continue };
        let t1 = t0 + trace.bucket_s;
        match bands.last_mut() {
            Some(last) if (last.1 - t0).abs() < 1e-9 => last.1 = t1,
            _ => bands.push((t0, t1, palette::HIDDEN, TIP_HIDDEN_LABEL.to_string())),
        }
    }
    bands
}

/// Two sessions' force curves on one chart: total and cutting force of each, the first solid,
/// the second dashed (colours stay those of the components).
pub fn compare_chart(a: (&ReviewTrace, &str), b: (&ReviewTrace, &str)) -> LineChart {
    let mut s = Vec::new();
    for ((trace, name), dashed) in [(a, false), (b, true)] {
        s.push(series(
            &format!("total — {name}"),
            palette::TOTAL,
            true,
            dashed,
            zip(&trace.t_s, &trace.force_n),
        ));
        s.push(series(
            &format!("cutting — {name}"),
            palette::CUTTING,
            false,
            dashed,
            zip(&trace.t_s, &trace.cutting_n),
        ));
    }
    LineChart {
        title: "Force along the needle, two sessions".into(),
        x_label: "time from the session start (s)".into(),
        y_label: "force along the needle (N)".into(),
        series: s,
        ..Default::default()
    }
}

/// Scores over the trainee's sessions in upload order, one line per difficulty.
pub fn progress_chart(points: &[ProgressPoint], title: &str) -> LineChart {
    let colors = [palette::BEGINNER, palette::ADVANCED, palette::EXPERT];
    let series_list = stylet_scoring::Difficulty::ALL
        .into_iter()
        .zip(colors)
        .filter_map(|(level, color)| {
            let pts: Vec<(f64, f64)> = points
                .iter()
                .enumerate()
                .filter(|(_, p)| p.difficulty == level.as_str())
                .map(|(k, p)| ((k + 1) as f64, p.score))
                .collect();
            (!pts.is_empty()).then(|| Series {
                dots: true,
                ..series(level.as_str(), color, true, false, pts)
            })
        })
        .collect();
    LineChart {
        title: title.into(),
        x_label: "session number (upload order)".into(),
        y_label: "score (0–100)".into(),
        series: series_list,
        y_range: Some((0.0, 100.0)),
        x_whole: true,
        ..Default::default()
    }
}

/// The chart as inline SVG that scales with the page, with `aria-label` for screen readers.
pub fn inline_svg(chart: &LineChart) -> Result<String, RenderError> {
    let (svg, axis) = crate::plot::chart_svg_axis(chart, CHART_SIZE)?;
    let svg = crate::plot::scalable_svg(&svg, CHART_SIZE);
    let label = chart.title.replace(['"', '<', '>', '&'], " ");
    // Where the x axis lies (data and SVG units): the player's cursor and click-to-seek.
    Ok(svg.replacen(
        "<svg ",
        &format!(
            "<svg class=\"chart\" role=\"img\" aria-label=\"{label}\" data-x0=\"{}\" data-x1=\"{}\" data-px0=\"{}\" data-px1=\"{}\" ",
            axis.x0, axis.x1, axis.px0, axis.px1
        ),
        1,
    ))
}

/// A sparkline of scores 0–100 (oldest first): a polyline, the last point as a dot coloured by
/// its result, and a title with the numbers for hover and screen readers.
pub fn sparkline(points: &[(f64, bool)]) -> String {
    const W: f64 = 140.0;
    const H: f64 = 30.0;
    if points.is_empty() {
        return String::from("<span class=\"muted\">no scores</span>");
    }
    let n = points.len();
    let x = |k: usize| {
        if n == 1 {
            W / 2.0
        } else {
            3.0 + (W - 6.0) * k as f64 / (n - 1) as f64
        }
    };
    let y = |s: f64| 3.0 + (H - 6.0) * (1.0 - s.clamp(0.0, 100.0) / 100.0);
    let path: Vec<String> = points
        .iter()
        .enumerate()
        .map(|(k, (s, _))| format!("{:.1},{:.1}", x(k), y(*s)))
        .collect();
    let (last, passed) = points[n - 1];
    let scores: Vec<String> = points.iter().map(|(s, _)| format!("{s:.0}")).collect();
    format!(
        "<svg class=\"spark\" width=\"{W}\" height=\"{H}\" viewBox=\"0 0 {W} {H}\" role=\"img\" \
         aria-label=\"scores {list}\"><title>scores, oldest first: {list}</title>\
         <line x1=\"0\" y1=\"{mid:.1}\" x2=\"{W}\" y2=\"{mid:.1}\" stroke=\"#ddd\"/>\
         <polyline fill=\"none\" stroke=\"#444\" stroke-width=\"1.5\" points=\"{pts}\"/>\
         <circle cx=\"{cx:.1}\" cy=\"{cy:.1}\" r=\"3.5\" fill=\"{fill}\"/></svg>",
        list = scores.join(", "),
        mid = y(50.0),
        pts = path.join(" "),
        cx = x(n - 1),
        cy = y(last),
        fill = if passed { "#1b7a33" } else { "#b3261e" },
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use stylet_scoring::TraceEvent;

    fn trace() -> ReviewTrace {
        let t: Vec<f64> = (0..100).map(|k| k as f64 * 0.02).collect();
        ReviewTrace {
            version: stylet_scoring::trace::TRACE_VERSION,
            physics_version: 2,
            bucket_s: 0.02,
            force_n: t.iter().map(|t| 1.0 + t).collect(),
            cutting_n: t
                .iter()
                .map(|t| if (1.0..1.1).contains(t) { 2.5 } else { 0.0 })
                .collect(),
            friction_n: t.iter().map(|t| 0.3 * t).collect(),
            base_n: t.iter().map(|_| 0.2).collect(),
            inserted_mm: t.iter().map(|t| 40.0 * t).collect(),
            tip_depth_mm: t.iter().map(|t| 30.0 * t - 5.0).collect(),
            tip_mm: t.iter().map(|_| None).collect(),
            t_s: t,
            events: vec![TraceEvent {
                t_s: 1.5,
                kind: "stylet-remove".into(),
                label: "stylet removed".into(),
            }],
            punctures: vec![],
            risk_points: vec![],
            sent_n: Vec::new(),
            guard: Vec::new(),
            tip_hidden: Vec::new(),
            phases: Vec::new(),
        }
    }

    /// The texts of an SVG (plotters writes labels as `<text …>label</text>`).
    fn texts(svg: &str) -> Vec<String> {
        svg.split("<text")
            .skip(1)
            .filter_map(|s| Some(s.split_once('>')?.1.split_once("</text>")?.0.trim().to_string()))
            .collect()
    }

    #[test]
    fn the_force_chart_has_title_axes_with_units_legend_and_events() {
        let svg = inline_svg(&force_chart(&trace(), "Force on the hand — demo")).unwrap();
        let t = texts(&svg);
        for want in [
            "Force on the hand — demo",
            "time (s)",
            "force along the needle (N)",
            "total",
            "cutting",
            "friction",
            "base",
            "stylet removed",
        ] {
            assert!(t.iter().any(|x| x == want), "no text {want:?} in {t:?}");
        }
        // One polyline per series, each in its component's colour.
        for color in ["#1E1E1E", "#D62728", "#1F77B4", "#2CA02C"] {
            assert!(svg.to_uppercase().contains(&format!("STROKE=\"{color}\"")), "{color}");
        }
        assert!(svg.starts_with("<svg class=\"chart\" role=\"img\" aria-label=\"Force on the hand — demo\""));
    }

    #[test]
    fn force_peaks_are_named_and_comments_marked() {
        let mut t = trace();
        t.punctures = vec![
            stylet_scoring::trace::Puncture {
                peak_t_s: 0.5,
                peak_force_n: 2.5,
                t_s: 0.3,
                label: 2,
            },
            stylet_scoring::trace::Puncture {
                peak_t_s: 0.8,
                peak_force_n: 0.4,
                t_s: 0.7,
                label: 3,
            },
        ];
        let name = |l: LabelId| match l {
            2 => Some("skin".to_string()),
            _ => None,
        };
        let peaks = puncture_peaks(&t, &name);
        assert_eq!(peaks, vec![(0.5, 2.5, "skin".to_string())]);
        let notes = comment_notes(&serde_json::json!({"comments": [
            {"author": "ivan", "body": "whole session", "at_s": null},
            {"author": "ivan", "body": "here", "at_s": 1.25},
        ]}));
        assert_eq!(notes, vec![(1.25, "[2] comment".to_string())]);
        let mut chart = force_chart(&t, "F");
        chart.peaks = peaks;
        chart.notes = notes;
        let svg = texts(&inline_svg(&chart).unwrap());
        for want in ["skin", "[2] comment"] {
            assert!(svg.iter().any(|x| x == want), "no {want:?} in {svg:?}");
        }
    }

    /// Boxes of the SVG texts that are one of `labels`, from x, y, dy, text-anchor and font-size
    /// as plotters writes them, with width = characters × 0.6 (bold 0.65) × font-size and
    /// height 1.2 × font-size.
    fn label_boxes(svg: &str, labels: &[&str]) -> Vec<(String, [f64; 4])> {
        svg.split("<text")
            .skip(1)
            .filter_map(|s| {
                let (attrs, rest) = s.split_once('>')?;
                let text = rest.split_once("</text>")?.0.trim().to_string();
                if !labels.contains(&text.as_str()) {
                    return None;
                }
                let attr = |k: &str| Some(attrs.split(&format!(" {k}=\"")).nth(1)?.split('"').next()?.to_string());
                let num = |k: &str| attr(k)?.parse::<f64>().ok();
                let (x, y, fs) = (num("x")?, num("y")?, num("font-size")?);
                let per_char = if attr("font-weight").is_some() { 0.65 } else { 0.6 };
                let w = text.chars().count() as f64 * per_char * fs;
                let x0 = match attr("text-anchor").as_deref() {
                    Some("middle") => x - w / 2.0,
                    Some("end") => x - w,
                    _ => x,
                };
                let y0 = match attr("dy").as_deref() {
                    Some("0.76em") => y,
                    Some("-0.5ex") => y - fs,
                    _ => y - fs / 2.0,
                };
                Some((text, [x0, y0, x0 + w, y0 + 1.2 * fs]))
            })
            .collect()
    }

    #[test]
    fn event_peak_and_comment_labels_never_overlap_and_stay_on_the_chart() {
        let mut t = trace(); // 0 … 1.98 s
        let events = [
            "stylet removed",
            "target reached",
            "risk hit: stomach / oesophagus / duodenum",
            "contrast 2.5 ml",
            "X-ray on",
            "X-ray off",
            "breath release",
            "risk hit: heart and great vessels",
        ];
        t.events = events
            .iter()
            .enumerate()
            .map(|(k, l)| TraceEvent {
                t_s: 1.0 + 0.02 * k as f64,
                kind: "x".into(),
                label: l.to_string(),
            })
            .chain([TraceEvent {
                t_s: 1.98,
                kind: "stylet-remove".into(),
                label: "stylet removed at the end".into(),
            }])
            .collect();
        let mut chart = force_chart(&t, "Force on the hand — success-intercostal (demo-alice)");
        chart.peaks = vec![
            (1.0, 2.5, "stomach / oesophagus / duodenum".into()),
            (1.02, 2.4, "portal and splenic vein".into()),
        ];
        chart.notes = (1..=4)
            .map(|n| (1.0 + 0.01 * n as f64, format!("[{n}] comment")))
            .collect();
        let svg = inline_svg(&chart).unwrap();
        let mut want: Vec<String> = events.iter().map(|s| s.to_string()).collect();
        want.extend(
            [
                "stylet removed at the end",
                "stomach / oesophagus / duodenum",
                "portal and splenic vein",
            ]
            .map(String::from),
        );
        want.extend((1..=4).map(|n| format!("[{n}] comment")));
        let want_refs: Vec<&str> = want.iter().map(String::as_str).collect();
        let boxes = label_boxes(&svg, &want_refs);
        assert_eq!(boxes.len(), want.len(), "every label drawn once: {boxes:?}");
        for (i, (a, p)) in boxes.iter().enumerate() {
            assert!(
                p[0] >= 0.0 && p[2] <= CHART_SIZE.0 as f64,
                "{a} leaves the chart: {p:?}"
            );
            assert!(
                p[1] >= 0.0 && p[3] <= CHART_SIZE.1 as f64,
                "{a} leaves the chart: {p:?}"
            );
            for (b, q) in &boxes[i + 1..] {
                assert!(
                    !(p[0] < q[2] && q[0] < p[2] && p[1] < q[3] && q[1] < p[3]),
                    "{a} {p:?} overlaps {b} {q:?}"
                );
            }
        }
    }

    #[test]
    fn charts_scale_by_their_view_box_not_a_fixed_size() {
        let svg = inline_svg(&force_chart(&trace(), "F")).unwrap();
        let tag = &svg[..svg.find('>').unwrap()];
        assert!(tag.contains("viewBox=\"0 0 1100 440\""), "{tag}");
        assert!(!tag.contains("width=") && !tag.contains("height="), "{tag}");
    }

    #[test]
    fn the_force_chart_keeps_the_cutting_peak() {
        let chart = force_chart(&trace(), "x");
        let cutting = chart.series.iter().find(|s| s.name == "cutting").unwrap();
        let peak = cutting.points.iter().map(|p| p.1).fold(0.0, f64::max);
        assert_eq!(peak, 2.5);
    }

    /// A session trained on a force-feedback device: the force sent beside the computed one, and
    /// the spans the device's guard zeroed or reduced shaded and named in the legend; a session
    /// without a device shows neither.
    #[test]
    fn the_force_sent_to_a_device_and_its_guard_show_beside_the_physics() {
        use stylet_recorder::device_forces::guard;
        let mut t = trace();
        t.sent_n = t.force_n.iter().map(|f| f.min(2.0)).collect();
        // Waiting to engage for the first 10 buckets, then ramping for 5, clamped from bucket 50.
        t.guard = (0..100)
            .map(|k| match k {
                0..10 => guard::WAITING,
                10..15 => guard::RAMPING,
                50.. => guard::CLAMPED,
                _ => 0,
            })
            .collect();
        let chart = force_chart(&t, "Force");
        let sent = chart
            .series
            .iter()
            .find(|s| s.name.starts_with("sent to the device"))
            .unwrap();
        assert_eq!(sent.points.iter().map(|p| p.1).fold(0.0, f64::max), 2.0);
        let spans: Vec<(f64, f64, &str)> = chart
            .bands
            .iter()
            .map(|(a, b, _, l)| ((a * 100.0).round() / 100.0, (b * 100.0).round() / 100.0, l.as_str()))
            .collect();
        assert_eq!(
            spans,
            [
                (0.0, 0.2, "force zeroed by the device guard"),
                (0.2, 0.3, "force reduced by the device guard"),
                (1.0, 2.0, "force reduced by the device guard"),
            ]
        );
        let svg = texts(&inline_svg(&chart).unwrap());
        for want in [
            "sent to the device (magnitude)",
            "force zeroed by the device guard",
            "force reduced by the device guard",
        ] {
            assert_eq!(
                svg.iter().filter(|x| *x == want).count(),
                1,
                "{want} once in the legend"
            );
        }
        let plain = force_chart(&trace(), "Force");
        assert!(plain.bands.is_empty() && plain.series.len() == 4);
    }

    /// A drainage session: the exchange's steps shaded on the force chart in time order, each
    /// named once in the legend; the puncture before them is not shaded.
    #[test]
    fn the_steps_of_a_drainage_are_shaded_on_the_force_chart() {
        use stylet_scoring::drainage::Step;
        use stylet_scoring::trace::TracePhase;
        let mut t = trace();
        let phase = |step, from_s, to_s| TracePhase { step, from_s, to_s };
        t.phases = vec![
            phase(Step::Puncture, 0.0, 0.5),
            phase(Step::Wire, 0.5, 1.0),
            phase(Step::Dilator, 1.0, 1.2),
            phase(Step::Wire, 1.2, 1.4),
            phase(Step::Catheter, 1.4, 2.0),
        ];
        let chart = force_chart(&t, "Force");
        let bands: Vec<(f64, f64, &str)> = chart.bands.iter().map(|(a, b, _, l)| (*a, *b, l.as_str())).collect();
        assert_eq!(
            bands,
            [
                (0.5, 1.0, "step: guide wire"),
                (1.0, 1.2, "step: dilator"),
                (1.2, 1.4, "step: guide wire"),
                (1.4, 2.0, "step: drainage catheter"),
            ]
        );
        let svg = texts(&inline_svg(&chart).unwrap());
        for want in ["step: guide wire", "step: dilator", "step: drainage catheter"] {
            assert_eq!(
                svg.iter().filter(|x| *x == want).count(),
                1,
                "{want} once in the legend"
            );
        }
        assert!(!svg.iter().any(|x| x.contains("puncture")));
    }

    /// A two-handed session: the spans with the tip out of the live image shaded on the depth
    /// chart and named once in its legend; a one-handed session shades nothing.
    #[test]
    fn the_tip_out_of_the_live_image_is_shaded_on_the_depth_chart() {
        let mut t = trace();
        t.tip_hidden = (0..100).map(|k| (20..30).contains(&k) || k >= 90).collect();
        let chart = depth_chart(&t, "Depth");
        let spans: Vec<(f64, f64)> = chart
            .bands
            .iter()
            .map(|(a, b, _, _)| ((a * 100.0).round() / 100.0, (b * 100.0).round() / 100.0))
            .collect();
        assert_eq!(spans, [(0.4, 0.6), (1.8, 2.0)]);
        let svg = texts(&inline_svg(&chart).unwrap());
        assert_eq!(svg.iter().filter(|x| *x == TIP_HIDDEN_LABEL).count(), 1);
        assert!(depth_chart(&trace(), "Depth").bands.is_empty());
    }

    #[test]
    fn depth_progress_and_compare_charts_say_what_they_show() {
        let d = texts(&inline_svg(&depth_chart(&trace(), "Depth")).unwrap());
        for want in ["depth (mm)", "inserted length", "tip depth under the skin"] {
            assert!(d.iter().any(|x| x == want), "{want}");
        }
        let c = texts(&inline_svg(&compare_chart((&trace(), "A"), (&trace(), "B"))).unwrap());
        for want in [
            "total — A",
            "total — B",
            "cutting — A",
            "cutting — B",
            "force along the needle (N)",
        ] {
            assert!(c.iter().any(|x| x == want), "{want}");
        }
        let point = |d: &str, s: f64| ProgressPoint {
            session_id: "x".into(),
            uploaded_at: "t".into(),
            scenario: "s".into(),
            difficulty: d.into(),
            score: s,
            passed: s >= 60.0,
            overridden: false,
        };
        let chart = progress_chart(
            &[
                point("beginner", 50.0),
                point("beginner", 80.0),
                point("advanced", 72.0),
            ],
            "P",
        );
        assert_eq!(chart.series.len(), 2);
        assert_eq!(chart.series[0].points, vec![(1.0, 50.0), (2.0, 80.0)]);
        assert_eq!(chart.series[1].points, vec![(3.0, 72.0)]);
        let p = texts(&inline_svg(&chart).unwrap());
        for want in ["score (0–100)", "session number (upload order)", "beginner", "advanced"] {
            assert!(p.iter().any(|x| x == want), "{want}");
        }
    }

    #[test]
    fn sparklines_show_the_scores() {
        let s = sparkline(&[(40.0, false), (90.0, true)]);
        assert!(s.contains("scores, oldest first: 40, 90"));
        assert!(s.contains("points=\"3.0,17.4 137.0,5.4\""), "{s}");
        assert!(s.contains("#1b7a33"));
        assert!(sparkline(&[]).contains("no scores"));
    }
}
