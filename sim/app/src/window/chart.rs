//! The replay's force chart: the force on the hand along the needle over the session (the
//! thesis' Fig. 3.12 curve), a cursor at the replay's time and the key moments as marks.
//! Clicking or dragging on it asks to jump there.

use eframe::egui;
use stylet_scoring::ReviewTrace;

use crate::replay_cursor::{KeyMoment, MomentKind};

/// The colour of a key moment's mark.
pub fn moment_color(kind: MomentKind) -> egui::Color32 {
    match kind {
        MomentKind::SkinEntry => egui::Color32::from_rgb(230, 200, 90),
        MomentKind::RiskHit => egui::Color32::from_rgb(235, 80, 80),
        MomentKind::TargetReached => egui::Color32::from_rgb(90, 210, 120),
        MomentKind::Contrast => egui::Color32::from_rgb(120, 170, 255),
        MomentKind::StyletOut => egui::Color32::from_rgb(200, 140, 230),
        MomentKind::Redirection => egui::Color32::from_rgb(240, 150, 60),
        MomentKind::Complication => egui::Color32::from_rgb(170, 20, 40),
    }
}

/// Draws the chart in `size`; returns the time (s) the user clicked or dragged to.
pub fn force_chart(
    ui: &mut egui::Ui,
    size: egui::Vec2,
    trace: &ReviewTrace,
    moments: &[KeyMoment],
    cursor_s: f64,
    duration_s: f64,
) -> Option<f64> {
    let (response, painter) = ui.allocate_painter(size, egui::Sense::click_and_drag());
    super::name_widget(&response, egui::Role::Image, "force chart: click to jump there");
    let outer = response.rect;
    painter.rect_filled(outer, 2.0, egui::Color32::from_gray(18));
    let left = 44.0;
    let plot = egui::Rect::from_min_max(outer.min + egui::vec2(left, 8.0), outer.max - egui::vec2(8.0, 18.0));
    let duration_s = duration_s.max(1e-3);
    let max_n = trace
        .force_n
        .iter()
        .copied()
        .filter(|f| f.is_finite())
        .fold(1.0f64, f64::max)
        .ceil();
    let min_n = trace
        .force_n
        .iter()
        .copied()
        .filter(|f| f.is_finite())
        .fold(0.0f64, f64::min)
        .floor();
    let x = |t: f64| plot.left() + (t / duration_s).clamp(0.0, 1.0) as f32 * plot.width();
    let y = |f: f64| plot.bottom() - ((f - min_n) / (max_n - min_n).max(1e-9)) as f32 * plot.height();
    let axis = egui::Stroke::new(1.0, egui::Color32::from_gray(90));
    let text = egui::Color32::from_gray(170);
    let font = egui::FontId::proportional(11.0);
    painter.line_segment(
        [egui::pos2(plot.left(), y(0.0)), egui::pos2(plot.right(), y(0.0))],
        axis,
    );
    painter.line_segment([plot.left_top(), plot.left_bottom()], axis);
    for f in [min_n, 0.0, max_n] {
        painter.text(
            egui::pos2(plot.left() - 4.0, y(f)),
            egui::Align2::RIGHT_CENTER,
            format!("{f:.0} N"),
            font.clone(),
            text,
        );
    }
    let step = nice_step(duration_s);
    let mut t = 0.0;
    while t <= duration_s + 1e-9 {
        painter.text(
            egui::pos2(x(t), plot.bottom() + 2.0),
            egui::Align2::CENTER_TOP,
            format!("{t:.0} s"),
            font.clone(),
            text,
        );
        t += step;
    }
    // A drainage session's steps after the puncture, shaded under the curve and named.
    for p in &trace.phases {
        let Some(rgb) = phase_color(p.step) else { continue };
        let band = egui::Rect::from_x_y_ranges(x(p.from_s)..=x(p.to_s), plot.top()..=plot.bottom());
        painter.rect_filled(band, 0.0, rgb.gamma_multiply(0.18));
        if band.width() > 40.0 {
            painter.text(
                band.left_top() + egui::vec2(3.0, 2.0),
                egui::Align2::LEFT_TOP,
                p.step.label(),
                font.clone(),
                rgb,
            );
        }
    }
    let points: Vec<egui::Pos2> = trace
        .t_s
        .iter()
        .zip(&trace.force_n)
        .filter(|(_, f)| f.is_finite())
        .map(|(&t, &f)| egui::pos2(x(t), y(f)))
        .collect();
    if points.len() > 1 {
        painter.add(egui::Shape::line(
            points,
            egui::Stroke::new(1.5, egui::Color32::from_rgb(240, 160, 60)),
        ));
    }
    for m in moments {
        let px = x(m.time_s);
        painter.line_segment(
            [egui::pos2(px, plot.top()), egui::pos2(px, plot.bottom())],
            egui::Stroke::new(1.0, moment_color(m.kind).gamma_multiply(0.6)),
        );
    }
    let cx = x(cursor_s);
    painter.line_segment(
        [egui::pos2(cx, outer.top()), egui::pos2(cx, outer.bottom())],
        egui::Stroke::new(2.0, egui::Color32::WHITE),
    );
    painter.text(
        plot.right_top() + egui::vec2(-4.0, 2.0),
        egui::Align2::RIGHT_TOP,
        "force along the needle (N, + against insertion)",
        font,
        text,
    );
    if (response.clicked() || response.dragged())
        && let Some(p) = response.interact_pointer_pos()
    {
        return Some((f64::from((p.x - plot.left()) / plot.width())).clamp(0.0, 1.0) * duration_s);
    }
    None
}

/// The shade of a drainage step (the dashboard's colours); none for the puncture.
fn phase_color(step: stylet_scoring::drainage::Step) -> Option<egui::Color32> {
    use stylet_scoring::drainage::Step;
    match step {
        Step::Puncture => None,
        Step::Wire => Some(egui::Color32::from_rgb(140, 165, 190)),
        Step::Dilator => Some(egui::Color32::from_rgb(230, 120, 20)),
        Step::Catheter => Some(egui::Color32::from_rgb(60, 180, 100)),
    }
}

/// A tick spacing of 1, 2 or 5 × 10ⁿ seconds giving about 8 ticks.
fn nice_step(duration_s: f64) -> f64 {
    let raw = duration_s / 8.0;
    let p = 10f64.powf(raw.log10().floor());
    [1.0, 2.0, 5.0, 10.0]
        .into_iter()
        .map(|m| m * p)
        .find(|s| *s >= raw)
        .unwrap_or(p * 10.0)
}
