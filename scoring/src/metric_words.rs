//! The one table of rubric metrics for people: each metric's identifier, its name in plain words,
//! its unit, and how a failed requirement or a deduction on it reads. The CLI, the API (the
//! `reasons` of a report), the dashboard and the CSV all phrase results from here, so no metric
//! identifier reaches text meant for people.

/// The unit of a rubric metric, which decides how its values are written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Unit {
    /// A whole number of things ("2 attempts").
    Count,
    /// Seconds.
    Seconds,
    Millimetres,
    SquareMillimetres,
    Newtons,
    Millilitres,
    /// Gy·cm² (dose-area product).
    GrayCm2,
    Degrees,
    /// A plain ratio (1 = ideal).
    Ratio,
    /// √(∫‖jerk‖² dt): mm·s^-2.5.
    RootIntegralJerk,
    /// 0 … 1, written as a percentage.
    Fraction,
    /// 0 or 1: something that did or did not happen; phrased by [`MetricInfo::flag_text`].
    Flag,
}

/// One rubric metric for people.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MetricInfo {
    /// The identifier rubrics and JSON use (`fluoro_time_s`).
    pub id: &'static str,
    /// Its name in plain words ("time under X-ray").
    pub label: &'static str,
    pub unit: Unit,
    /// Flags: what happened when the flag is 1, as the end of a sentence ("the target was not
    /// reached").
    pub flag_text: &'static str,
}

const fn m(id: &'static str, label: &'static str, unit: Unit) -> MetricInfo {
    MetricInfo {
        id,
        label,
        unit,
        flag_text: "",
    }
}

const fn flag(id: &'static str, label: &'static str, text: &'static str) -> MetricInfo {
    MetricInfo {
        id,
        label,
        unit: Unit::Flag,
        flag_text: text,
    }
}

/// Every metric a rubric may name (rubric_metrics::rubric_metrics() is checked against it by a test).
pub const METRICS: &[MetricInfo] = &[
    m("attempts", "attempts", Unit::Count),
    m("redirections", "redirections", Unit::Count),
    m("risk_hits", "risk structures hit", Unit::Count),
    m("risk_time_s", "time inside risk structures", Unit::Seconds),
    m("bone_contacts", "bone contacts", Unit::Count),
    flag(
        "target_not_reached",
        "target not reached",
        "the needle never reached the target",
    ),
    flag(
        "target_not_confirmed",
        "target not confirmed",
        "the position in the target was not confirmed (stylet out in the target, and contrast filling the ducts)",
    ),
    m("extravasated_ml", "contrast outside the ducts", Unit::Millilitres),
    m("risk_displacement_mm", "risk structure pushed aside", Unit::Millimetres),
    m("time_total_s", "total time", Unit::Seconds),
    m("fluoro_time_s", "time under X-ray", Unit::Seconds),
    m("xray_shots", "X-ray shots", Unit::Count),
    m("dose_area_product_gy_cm2", "dose-area product", Unit::GrayCm2),
    m("max_force_n", "peak force", Unit::Newtons),
    m(
        "shaft_sweep_mm2",
        "tissue swept by the bending shaft",
        Unit::SquareMillimetres,
    ),
    m(
        "tissue_damage_mm2",
        "tissue damage (area swept by the needle line)",
        Unit::SquareMillimetres,
    ),
    m("time_in_tissue_s", "time with the needle in tissue", Unit::Seconds),
    m("needle_path_length_mm", "needle path length", Unit::Millimetres),
    m("path_in_tissue_mm", "needle path in tissue", Unit::Millimetres),
    m(
        "path_outside_tissue_mm",
        "needle path outside tissue",
        Unit::Millimetres,
    ),
    m(
        "jerk_mm_per_s2_5",
        "needle jerk (motion smoothness)",
        Unit::RootIntegralJerk,
    ),
    m("depth_perception_mm", "needle motion along its axis", Unit::Millimetres),
    m("reorientations", "needle reorientations in tissue", Unit::Count),
    flag(
        "target_reached_while_breathing",
        "target reached without a breath hold at end-expiration",
        "the needle reached the target while the patient breathed or held their breath in another phase than end-expiration",
    ),
    m(
        "breathing_tissue_slide_mm",
        "tissue moved past the needle by breathing",
        Unit::Millimetres,
    ),
    m(
        "tip_out_of_view_share",
        "share of the insertion with the needle tip out of the live ultrasound image",
        Unit::Ratio,
    ),
    m(
        "blind_advance_s",
        "longest needle advance with the tip out of the ultrasound image",
        Unit::Seconds,
    ),
    flag(
        "tip_out_of_view_at_target",
        "needle tip out of the ultrasound image when it entered the target",
        "the needle tip was not in the live ultrasound image when it entered the target",
    ),
    m("path_inefficiency", "path inefficiency", Unit::Ratio),
    m("target_distance_mm", "distance from the target", Unit::Millimetres),
    flag(
        "missing_palpation",
        "no palpation before the puncture",
        "there was no palpation before the puncture",
    ),
    flag(
        "missing_ultrasound",
        "no ultrasound before the puncture",
        "there was no ultrasound before the puncture",
    ),
    flag(
        "missing_target_scan",
        "target not scanned before the puncture",
        "the target was not seen in the ultrasound image before the puncture",
    ),
    m(
        "guided_entry_distance_mm",
        "entry off the planned entry",
        Unit::Millimetres,
    ),
    m("guided_angle_error_deg", "angle off the planned path", Unit::Degrees),
    m(
        "guided_mean_deviation_mm",
        "mean deviation from the planned path",
        Unit::Millimetres,
    ),
    // Palpation.
    m("intercostal_spaces_found", "intercostal spaces found", Unit::Count),
    m("intercostal_spaces_missed", "intercostal spaces missed", Unit::Count),
    m(
        "palpation_coverage",
        "share of the intercostal spaces found",
        Unit::Fraction,
    ),
    m("palpation_time_s", "palpation time", Unit::Seconds),
    // Ultrasound survey.
    flag(
        "target_not_scanned",
        "target never shown",
        "the target never came within 5 mm of the ultrasound image",
    ),
    m(
        "time_to_target_view_s",
        "time to the first view of the target",
        Unit::Seconds,
    ),
    m("good_contact_time_s", "time in good skin contact", Unit::Seconds),
    m(
        "poor_contact_share",
        "share of probe time in poor skin contact",
        Unit::Fraction,
    ),
    // The Seldinger exchange (drainage).
    flag(
        "wire_not_in_ducts",
        "guide wire never in the ducts",
        "the guide wire never lay in the bile ducts",
    ),
    flag(
        "wire_through_wall",
        "guide wire through a duct wall",
        "the guide wire went through a duct wall into the liver",
    ),
    m("wire_folded_mm", "guide wire pushed into a loop", Unit::Millimetres),
    m(
        "wrong_branch_entries",
        "guide wire runs into a wrong branch",
        Unit::Count,
    ),
    flag(
        "access_lost",
        "access lost",
        "the guide wire was drawn out of the ducts after the needle came out",
    ),
    m("wire_attempts", "guide wires put in", Unit::Count),
    m("dilator_attempts", "dilators put on the wire", Unit::Count),
    m("catheter_attempts", "catheters put on the wire", Unit::Count),
    m("refused_steps", "refused steps", Unit::Count),
    m("fluoro_wire_s", "time under X-ray with the guide wire", Unit::Seconds),
    m("fluoro_dilator_s", "time under X-ray with the dilator", Unit::Seconds),
    m("fluoro_catheter_s", "time under X-ray with the catheter", Unit::Seconds),
    m("dilator_max_force_n", "largest push on the dilator", Unit::Newtons),
    m("catheter_max_force_n", "largest push on the catheter", Unit::Newtons),
    flag(
        "catheter_not_placed",
        "drainage catheter not placed",
        "no drainage catheter was placed",
    ),
    m(
        "catheter_holes_outside_ducts",
        "catheter side holes outside the ducts",
        Unit::Count,
    ),
    flag(
        "pigtail_outside_ducts",
        "pigtail outside the ducts",
        "the catheter's pigtail formed outside the ducts",
    ),
];

/// The table entry of a metric identifier.
pub fn metric_info(id: &str) -> Option<&'static MetricInfo> {
    METRICS.iter().find(|m| m.id == id)
}

/// The plain-words name of a metric identifier ("fluoro_time_s" → "time under X-ray").
pub fn metric_label(id: &str) -> Option<&'static str> {
    metric_info(id).map(|m| m.label)
}

/// A number without needless decimals: 2 → "2", 2.5 → "2.5", 40.04 → "40.04".
pub(crate) fn num(v: f64) -> String {
    let r = (v * 100.0).round() / 100.0;
    if r == r.trunc() {
        format!("{}", r as i64)
    } else {
        let s = format!("{r:.2}");
        s.trim_end_matches('0').to_string()
    }
}

impl MetricInfo {
    /// A value with its unit: "2 attempts", "40.5 s", "9.5 mm", "75 %".
    pub fn value(&self, v: f64) -> String {
        match self.unit {
            Unit::Count => format!(
                "{} {}",
                num(v),
                if v == 1.0 {
                    singular(self.label)
                } else {
                    self.label.into()
                }
            ),
            Unit::Seconds => format!("{} s", num(v)),
            Unit::Millimetres => format!("{} mm", num(v)),
            Unit::SquareMillimetres => format!("{} mm²", num(v)),
            Unit::Newtons => format!("{} N", num(v)),
            Unit::Millilitres => format!("{} ml", num(v)),
            Unit::GrayCm2 => format!("{} Gy·cm²", num(v)),
            Unit::Degrees => format!("{}°", num(v)),
            Unit::RootIntegralJerk => format!("{} mm/s^2.5", num(v)),
            Unit::Ratio => num(v),
            Unit::Fraction => format!("{} %", num(v * 100.0)),
            Unit::Flag => {
                if v > 0.0 {
                    "yes".into()
                } else {
                    "no".into()
                }
            }
        }
    }

    /// An amount of this metric with its unit: "40 s", "2", "1.5 ml" (flags and counts bare).
    pub fn amount(&self, v: f64) -> String {
        self.bound(v)
    }

    /// A bound alone: "1", "30 s", "75 %".
    fn bound(&self, v: f64) -> String {
        match self.unit {
            Unit::Count | Unit::Ratio | Unit::Flag => num(v),
            _ => self.value(v),
        }
    }

    /// The measured value as a phrase with its name: "2 attempts", "40 s of time under X-ray".
    pub fn phrase(&self, v: f64) -> String {
        match self.unit {
            Unit::Count => self.value(v),
            Unit::Flag => self.label.to_string(),
            Unit::Ratio => format!("{} of {}", self.label, num(v)),
            // "share of the spaces found" → "50 % of the spaces found".
            Unit::Fraction => format!("{} {}", self.value(v), self.label.trim_start_matches("share ")),
            _ => format!("{} of {}", self.value(v), self.label),
        }
    }

    /// A requirement `min ≤ v ≤ max` that `v` misses, as a sentence.
    pub fn unmet(&self, v: f64, min: Option<f64>, max: Option<f64>) -> String {
        if self.unit == Unit::Flag {
            return capitalise(&format!("{}.", self.flag_text));
        }
        let s = match (min, max) {
            (Some(lo), _) if v < lo => format!("{}: at least {} required", self.phrase(v), self.bound(lo)),
            (_, Some(0.0)) => format!("{}: none allowed", self.phrase(v)),
            (_, Some(hi)) => format!("{}: at most {} allowed", self.phrase(v), self.bound(hi)),
            _ => format!("{} is out of range", self.phrase(v)),
        };
        capitalise(&format!("{s}."))
    }

    /// A deduction as a phrase: "−15 for 2 attempts (1 free)", "−40 because the needle never
    /// reached the target".
    pub fn deduction(&self, v: f64, points: f64, free: Option<f64>) -> String {
        let pts = format!("−{}", num(points));
        if self.unit == Unit::Flag {
            return format!("{pts} because {}", self.flag_text);
        }
        match free.filter(|f| *f > 0.0) {
            Some(f) => format!("{pts} for {} ({} free)", self.phrase(v), self.bound(f)),
            None => format!("{pts} for {}", self.phrase(v)),
        }
    }
}

/// "risk structures hit" → "risk structure hit": the first plural word loses its s.
fn singular(label: &str) -> String {
    let mut done = false;
    label
        .split(' ')
        .map(|w| match w.strip_suffix('s') {
            Some(one) if !done => {
                done = true;
                one
            }
            _ => w,
        })
        .collect::<Vec<_>>()
        .join(" ")
}

fn capitalise(s: &str) -> String {
    let mut c = s.chars();
    match c.next() {
        Some(f) => f.to_uppercase().collect::<String>() + c.as_str(),
        None => String::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_rubric_metric_has_words_and_no_identifier_leaks() {
        for id in crate::rubric_metrics::rubric_metrics() {
            let info = metric_info(id).unwrap_or_else(|| panic!("{id} lacks a table entry"));
            for text in [
                info.label.to_string(),
                info.unmet(3.0, None, Some(1.0)),
                info.unmet(0.0, Some(1.0), None),
                info.deduction(3.0, 10.0, Some(1.0)),
            ] {
                assert!(!text.contains('_'), "{id}: {text}");
            }
        }
        assert_eq!(metric_label("fluoro_time_s"), Some("time under X-ray"));
        assert_eq!(metric_label("nonsense"), None);
    }

    #[test]
    fn phrases_read_as_words() {
        let a = metric_info("attempts").unwrap();
        assert_eq!(a.deduction(2.0, 15.0, Some(1.0)), "−15 for 2 attempts (1 free)");
        assert_eq!(a.unmet(2.0, None, Some(1.0)), "2 attempts: at most 1 allowed.");
        let r = metric_info("risk_hits").unwrap();
        assert_eq!(r.unmet(1.0, None, Some(0.0)), "1 risk structure hit: none allowed.");
        let c = metric_info("palpation_coverage").unwrap();
        assert_eq!(
            c.unmet(0.25, Some(0.5), None),
            "25 % of the intercostal spaces found: at least 50 % required."
        );
        let f = metric_info("fluoro_time_s").unwrap();
        assert_eq!(
            f.unmet(40.0, None, Some(30.0)),
            "40 s of time under X-ray: at most 30 s allowed."
        );
        let t = metric_info("target_not_reached").unwrap();
        assert_eq!(
            t.deduction(1.0, 40.0, Some(0.0)),
            "−40 because the needle never reached the target"
        );
        assert_eq!(t.unmet(1.0, None, Some(0.0)), "The needle never reached the target.");
    }
}
