//! Cohort trends for curriculum staff: pass rate per difficulty per calendar week (weeks start on
//! Monday, UTC upload dates), totals per exercise, and the chart of the weekly pass rates (plotters
//! SVG for pages; the PDF draws the same numbers itself, [`crate::pdf`]).
//!
//! Only puncture sessions make the weekly pass rates: palpation, ultrasound-survey and drainage
//! exercises are counted per exercise, never as failed punctures, and not-gradeable sessions (a
//! recording cut or damaged) are neither passed nor failed: they are counted on their own.

use std::collections::BTreeMap;

use crate::plot::{ChartError, palette};
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use stylet_render::fonts::{SANS, ensure_fonts};
use stylet_scoring::{Difficulty, Exercise};
use stylet_service::store::DayCount;

/// Weeks charted at most (the latest).
pub const WEEKS_MAX: usize = 104;

/// Days since 1970-01-01 of a `YYYY-MM-DD` date (proleptic Gregorian), or `None` if it is not one.
pub fn days_from_date(date: &str) -> Option<i64> {
    let mut parts = date.splitn(3, '-');
    let y: i64 = parts.next()?.parse().ok()?;
    let m: i64 = parts.next()?.parse().ok()?;
    let d: i64 = parts.next()?.parse().ok()?;
    if !(1..=12).contains(&m) || !(1..=31).contains(&d) || date.len() != 10 {
        return None;
    }
    // H. Hinnant's days_from_civil.
    let y = if m <= 2 { y - 1 } else { y };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let doy = (153 * (if m > 2 { m - 3 } else { m + 9 }) + 2) / 5 + d - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    Some(era * 146_097 + doe - 719_468)
}

/// `YYYY-MM-DD` of days since 1970-01-01.
pub fn date_from_days(z: i64) -> String {
    let z = z + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!("{y:04}-{m:02}-{d:02}")
}

/// The Monday that starts the week of a day (days since 1970-01-01, a Thursday).
pub fn week_start(days: i64) -> i64 {
    days - (days + 3).rem_euclid(7)
}

/// Puncture sessions of one difficulty in one calendar week.
#[derive(Debug, Clone, PartialEq)]
pub struct WeekLevel {
    /// The week's Monday, days since 1970-01-01.
    pub week: i64,
    pub difficulty: String,
    /// Scored and gradeable (passed or failed).
    pub graded: i64,
    pub passed: i64,
}

impl WeekLevel {
    pub fn pass_rate_pct(&self) -> Option<f64> {
        (self.graded > 0).then(|| 100.0 * self.passed as f64 / self.graded as f64)
    }
}

/// One exercise's scored sessions over the whole selection.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ExerciseTotal {
    pub exercise: Exercise,
    pub scored: i64,
    pub passed: i64,
    pub not_gradeable: i64,
}

impl ExerciseTotal {
    pub fn failed(&self) -> i64 {
        self.scored - self.passed - self.not_gradeable
    }
    pub fn pass_rate_pct(&self) -> Option<f64> {
        let graded = self.scored - self.not_gradeable;
        (graded > 0).then(|| 100.0 * self.passed as f64 / graded as f64)
    }
}

/// A cohort's trends over a selection.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Trends {
    /// Puncture sessions per week and difficulty, oldest week first, the latest [`WEEKS_MAX`]
    /// weeks; difficulties in level order.
    pub weeks: Vec<WeekLevel>,
    /// Per exercise (puncture first), all weeks.
    pub exercises: Vec<ExerciseTotal>,
}

impl Trends {
    pub fn from_days(days: &[DayCount]) -> Trends {
        let mut weeks: BTreeMap<(i64, usize, String), (i64, i64)> = BTreeMap::new();
        let mut exercises: BTreeMap<Exercise, ExerciseTotal> = BTreeMap::new();
        for d in days {
            let e = exercises.entry(d.exercise).or_insert_with(|| ExerciseTotal {
                exercise: d.exercise,
                ..Default::default()
            });
            e.scored += d.scored;
            e.passed += d.passed;
            e.not_gradeable += d.not_gradeable;
            let Some(day) = days_from_date(&d.day) else { continue };
            if d.exercise == Exercise::Puncture {
                let order = d
                    .difficulty
                    .parse::<Difficulty>()
                    .map_or(Difficulty::ALL.len(), |l| l as usize);
                let w = weeks.entry((week_start(day), order, d.difficulty.clone())).or_default();
                w.0 += d.scored - d.not_gradeable;
                w.1 += d.passed;
            }
        }
        let mut weeks: Vec<WeekLevel> = weeks
            .into_iter()
            .filter(|(_, (graded, _))| *graded > 0)
            .map(|((week, _, difficulty), (graded, passed))| WeekLevel {
                week,
                difficulty,
                graded,
                passed,
            })
            .collect();
        if let Some(last) = weeks.last().map(|w| w.week) {
            let first = last - 7 * (WEEKS_MAX as i64 - 1);
            weeks.retain(|w| w.week >= first);
        }
        Trends {
            weeks,
            exercises: exercises.into_values().collect(),
        }
    }

    /// Not-gradeable sessions of every exercise.
    pub fn not_gradeable(&self) -> i64 {
        self.exercises.iter().map(|e| e.not_gradeable).sum()
    }

    /// The weekly pass-rate points (week Monday in days, %) of each difficulty that has any, in
    /// level order.
    pub fn series(&self) -> Vec<(Difficulty, Vec<(i64, f64)>)> {
        Difficulty::ALL
            .into_iter()
            .filter_map(|level| {
                let pts: Vec<(i64, f64)> = self
                    .weeks
                    .iter()
                    .filter(|w| w.difficulty == level.as_str())
                    .filter_map(|w| Some((w.week, w.pass_rate_pct()?)))
                    .collect();
                (!pts.is_empty()).then_some((level, pts))
            })
            .collect()
    }
}

/// Mondays from `lo` to `hi` (days), every week or every few weeks so that at most 10 are labelled.
pub fn week_ticks(lo: i64, hi: i64) -> Vec<f64> {
    let weeks = (hi - lo) / 7 + 1;
    let step = ((weeks + 9) / 10).max(1) * 7;
    (0..)
        .map(|k| lo + k * step)
        .take_while(|w| *w <= hi)
        .map(|w| w as f64)
        .collect()
}

/// The weekly chart's x range in days, for the page and the PDF alike: half a week before the
/// first Monday, and after the last Monday only room for its date label (5 % of the span, at
/// least half a day), so that the axis ends at the latest week with data.
pub fn week_x_range(lo: i64, hi: i64) -> (f64, f64) {
    let span_days = (hi - lo) as f64 + 7.0;
    (lo as f64 - 3.5, hi as f64 + (0.05 * span_days).max(0.5))
}

/// The colour of a difficulty level on every chart (RGB 0–255).
pub fn level_rgb(level: Difficulty) -> (u8, u8, u8) {
    let c = match level {
        Difficulty::Beginner => palette::BEGINNER,
        Difficulty::Advanced => palette::ADVANCED,
        Difficulty::Expert => palette::EXPERT,
    };
    (c.0, c.1, c.2)
}

pub const TREND_TITLE: &str = "Pass rate per week and difficulty (puncture exercises)";
pub const TREND_X_LABEL: &str = "calendar week (starting Monday, UTC upload date)";
pub const TREND_Y_LABEL: &str = "pass rate (%)";

/// The weekly pass rates as an SVG line chart (one line per difficulty, a dot per week), scaled to
/// the page width like the other charts; `None` when no week has a graded puncture session.
pub fn trend_chart_svg(trends: &Trends) -> Result<Option<String>, ChartError> {
    let series = trends.series();
    if series.is_empty() {
        return Ok(None);
    }
    ensure_fonts();
    let (lo, hi) = series
        .iter()
        .flat_map(|(_, p)| p.iter().map(|(w, _)| *w))
        .fold((i64::MAX, i64::MIN), |(a, b), w| (a.min(w), b.max(w)));
    let (x0, x1) = week_x_range(lo, hi);
    let mut out = String::new();
    {
        let root = SVGBackend::with_string(&mut out, crate::charts::CHART_SIZE).into_drawing_area();
        root.fill(&WHITE)?;
        let mut c = ChartBuilder::on(&root)
            .caption(TREND_TITLE, (SANS, 26))
            .margin(16)
            .x_label_area_size(56)
            .y_label_area_size(72)
            .build_cartesian_2d(x0..x1, 0.0..100.0)?;
        // Plotters would put x ticks anywhere: no labels of its own, the weeks' Mondays drawn
        // below instead.
        c.configure_mesh()
            .x_labels(0)
            .disable_x_mesh()
            .x_desc(TREND_X_LABEL)
            .y_desc(TREND_Y_LABEL)
            .axis_desc_style((SANS, 20))
            .label_style((SANS, 16))
            .light_line_style(RGBColor(235, 235, 235))
            .draw()?;
        let tick_style = TextStyle::from((SANS, 16).into_font()).pos(Pos::new(HPos::Center, VPos::Top));
        for w in week_ticks(lo, hi) {
            let (px, py) = c.backend_coord(&(w, 0.0));
            let (_, top) = c.backend_coord(&(w, 100.0));
            root.draw(&PathElement::new(vec![(px, top), (px, py)], RGBColor(235, 235, 235)))?;
            root.draw(&PathElement::new(vec![(px, py), (px, py + 5)], BLACK))?;
            root.draw(&Text::new(date_from_days(w as i64), (px, py + 8), tick_style.clone()))?;
        }
        let lines: Vec<(Difficulty, Vec<(f64, f64)>)> = series
            .iter()
            .map(|(level, pts)| (*level, pts.iter().map(|(w, p)| (*w as f64, *p)).collect()))
            .collect();
        draw_level_lines(&mut c, &lines)?;
        root.present()?;
    }
    Ok(Some(labelled_svg(&out, TREND_TITLE)))
}

/// One line per difficulty level with a dot per point, in the level's colour, and the legend
/// (the weekly pass rates and a trainee's scores over time draw alike).
pub fn draw_level_lines<'a, 'b: 'a>(
    c: &mut ChartContext<
        'a,
        SVGBackend<'b>,
        Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
    >,
    lines: &[(Difficulty, Vec<(f64, f64)>)],
) -> Result<(), ChartError> {
    for (level, pts) in lines {
        let (r, g, b) = level_rgb(*level);
        let color = RGBColor(r, g, b);
        c.draw_series(
            pts.iter()
                .map(|p| Circle::new(*p, 4, ShapeStyle::from(&color).filled())),
        )?;
        c.draw_series(LineSeries::new(
            pts.iter().copied(),
            ShapeStyle::from(&color).stroke_width(3),
        ))?
        .label(level.as_str())
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], ShapeStyle::from(&color).stroke_width(3)));
    }
    let position = quiet_corner(c, lines);
    c.configure_series_labels()
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK)
        .label_font((SANS, 16))
        .position(position)
        .draw()?;
    Ok(())
}

/// The corner of the plotting area for the legend of `lines`: the one whose legend box would
/// cover the fewest of their dots, the lower right when several tie (the axis ends at the last
/// point, so the latest ones lie at the right edge).
fn quiet_corner<'a, 'b: 'a>(
    c: &ChartContext<
        'a,
        SVGBackend<'b>,
        Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
    >,
    lines: &[(Difficulty, Vec<(f64, f64)>)],
) -> SeriesLabelPosition {
    let longest = lines.iter().map(|(l, _)| l.as_str().chars().count()).max().unwrap_or(0);
    let (w, h) = crate::plot::legend_size_px(longest, lines.len());
    let gap = crate::plot::LEGEND_GAP_PX;
    let (px, py) = c.plotting_area().get_pixel_range();
    let (x0, x1, y0, y1) = (
        f64::from(px.start),
        f64::from(px.end),
        f64::from(py.start),
        f64::from(py.end),
    );
    let dots: Vec<(f64, f64)> = lines
        .iter()
        .flat_map(|(_, pts)| pts.iter())
        .map(|p| {
            let (x, y) = c.backend_coord(p);
            (f64::from(x), f64::from(y))
        })
        .collect();
    // A dot's radius and a pixel: one touching the box counts as covered.
    let r = 5.0;
    let covered = |(bx, by): (f64, f64)| {
        dots.iter()
            .filter(|(x, y)| *x + r > bx && *x - r < bx + w && *y + r > by && *y - r < by + h)
            .count()
    };
    [
        (SeriesLabelPosition::LowerRight, (x1 - gap - w, y1 - gap - h)),
        (SeriesLabelPosition::UpperRight, (x1 - gap - w, y0 + gap)),
        (SeriesLabelPosition::LowerLeft, (x0 + gap, y1 - gap - h)),
        (SeriesLabelPosition::UpperLeft, (x0 + gap, y0 + gap)),
    ]
    .into_iter()
    .min_by_key(|(_, corner)| covered(*corner))
    .map_or(SeriesLabelPosition::LowerRight, |(position, _)| position)
}

/// An inline SVG chart of [`crate::charts::CHART_SIZE`], scalable (its viewBox only, sized by
/// the style sheet), marked as an image with its title as the accessible name.
pub fn labelled_svg(svg: &str, title: &str) -> String {
    let label = title.replace(['"', '<', '>', '&'], " ");
    crate::plot::scalable_svg(svg, crate::charts::CHART_SIZE).replacen(
        "<svg ",
        &format!("<svg class=\"chart\" role=\"img\" aria-label=\"{label}\" "),
        1,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn day(day: &str, exercise: Exercise, difficulty: &str, scored: i64, passed: i64, ng: i64) -> DayCount {
        DayCount {
            day: day.into(),
            exercise,
            difficulty: difficulty.into(),
            scored,
            passed,
            not_gradeable: ng,
        }
    }

    #[test]
    fn dates_round_trip_and_weeks_start_on_monday() {
        for d in ["1970-01-01", "2000-02-29", "2026-11-24", "2024-12-31", "1969-07-20"] {
            assert_eq!(date_from_days(days_from_date(d).unwrap()), d);
        }
        assert_eq!(days_from_date("1970-01-02"), Some(1));
        // 2026-11-24 is a Tuesday; its week starts on Monday 23rd; a Sunday belongs to the
        // week before it.
        assert_eq!(
            date_from_days(week_start(days_from_date("2026-11-24").unwrap())),
            "2026-11-23"
        );
        assert_eq!(
            date_from_days(week_start(days_from_date("2026-11-23").unwrap())),
            "2026-11-23"
        );
        assert_eq!(
            date_from_days(week_start(days_from_date("2026-11-22").unwrap())),
            "2026-11-16"
        );
        assert_eq!(days_from_date("2026-13-01"), None);
        assert_eq!(days_from_date("soon"), None);
    }

    #[test]
    fn weekly_rates_leave_out_other_exercises_and_not_gradeable_sessions() {
        let days = vec![
            // Week of Monday 2026-11-16.
            day("2026-11-16", Exercise::Puncture, "beginner", 3, 2, 0),
            day("2026-11-18", Exercise::Puncture, "beginner", 2, 0, 1),
            day("2026-11-18", Exercise::Palpation, "beginner", 4, 1, 0),
            // Week of Monday 2026-11-23.
            day("2026-11-23", Exercise::Puncture, "advanced", 2, 1, 0),
            day("2026-11-24", Exercise::UltrasoundSurvey, "beginner", 1, 1, 0),
            day("2026-11-25", Exercise::Drainage, "beginner", 1, 1, 0),
        ];
        let t = Trends::from_days(&days);
        let w16 = days_from_date("2026-11-16").unwrap();
        assert_eq!(
            t.weeks,
            vec![
                WeekLevel {
                    week: w16,
                    difficulty: "beginner".into(),
                    graded: 4,
                    passed: 2
                },
                WeekLevel {
                    week: w16 + 7,
                    difficulty: "advanced".into(),
                    graded: 2,
                    passed: 1
                },
            ]
        );
        assert_eq!(t.weeks[0].pass_rate_pct(), Some(50.0));
        assert_eq!(t.not_gradeable(), 1);
        let names: Vec<Exercise> = t.exercises.iter().map(|e| e.exercise).collect();
        assert_eq!(names, Exercise::ALL);
        assert_eq!(
            (t.exercises[0].scored, t.exercises[0].passed, t.exercises[0].failed()),
            (7, 3, 3)
        );
        assert_eq!(t.exercises[1].pass_rate_pct(), Some(25.0));
        let svg = trend_chart_svg(&t).unwrap().unwrap();
        for text in [
            TREND_TITLE,
            TREND_X_LABEL,
            TREND_Y_LABEL,
            "beginner",
            "advanced",
            "2026-11-16",
        ] {
            assert!(svg.contains(text), "{text} missing from the chart");
        }
        assert!(
            !svg.contains(">expert<"),
            "a level without sessions has no legend entry"
        );
        // Sized by the page's style sheet: the viewBox only, no fixed width or height.
        let tag = &svg[..svg.find('>').unwrap()];
        assert!(tag.contains("viewBox=\"0 0 1100 440\""), "{tag}");
        assert!(!tag.contains("width=") && !tag.contains("height="), "{tag}");
        assert_eq!(trend_chart_svg(&Trends::default()).unwrap(), None);
    }

    /// The y of the SVG text that reads `text`.
    fn text_y(svg: &str, text: &str) -> Option<f64> {
        svg.split("<text").skip(1).find_map(|s| {
            let (attrs, rest) = s.split_once('>')?;
            if rest.split_once("</text>")?.0.trim() != text {
                return None;
            }
            attrs.split(" y=\"").nth(1)?.split('"').next()?.parse().ok()
        })
    }

    #[test]
    fn the_weekly_axis_ends_at_the_latest_week() {
        let w = days_from_date("2026-11-23").unwrap();
        // One week: half a week before its Monday, half a day after it.
        assert_eq!(week_x_range(w, w), (w as f64 - 3.5, w as f64 + 0.5));
        // Twenty weeks: 5 % of the span after the last Monday.
        let (x0, x1) = week_x_range(w - 7 * 19, w);
        assert_eq!(x0, (w - 7 * 19) as f64 - 3.5);
        assert!((x1 - w as f64 - 7.0).abs() < 1e-9, "{x1}");
        // The chart of one week (1 of 10 passed): its dot near the right edge, and the legend in
        // a corner where it covers no dot (not the lower right, where the dot is).
        let t = Trends::from_days(&[day("2026-11-24", Exercise::Puncture, "beginner", 10, 1, 0)]);
        let svg = trend_chart_svg(&t).unwrap().unwrap();
        let max_cx = svg
            .split("<circle")
            .skip(1)
            .filter_map(|s| s.split(" cx=\"").nth(1)?.split('"').next()?.parse::<f64>().ok())
            .fold(f64::NEG_INFINITY, f64::max);
        let right_px = crate::charts::CHART_SIZE.0 as f64 - 16.0;
        assert!(
            right_px - max_cx < 150.0,
            "the dot is {} px from the edge",
            right_px - max_cx
        );
        let legend_y = text_y(&svg, "beginner").expect("a legend entry");
        assert!(
            legend_y < crate::charts::CHART_SIZE.1 as f64 / 2.0,
            "legend at y {legend_y}, over the dot"
        );
    }
}
