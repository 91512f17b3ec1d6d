//! The steps of making an atlas and the time each took (progress on every step that can take more
//! than a second, and the time of each in the report).

use std::time::{Duration, Instant};

/// A step of `atlas import` / `atlas new`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Step {
    ReadCt,
    ReadLabels,
    Biliary,
    Window,
    Write,
    Load,
    Scripts,
    /// `stylet atlas new`'s validation report (stylet-atlas-report), after the smoke test.
    Report,
}

impl Step {
    /// What the step does, for progress lines and reports.
    pub fn describe(self) -> &'static str {
        match self {
            Step::ReadCt => "reading the CT",
            Step::ReadLabels => "reading the labels",
            Step::Biliary => "growing the biliary tree",
            Step::Window => "searching the intercostal window",
            Step::Write => "writing the atlas",
            Step::Load => "loading it back (validation, distance maps)",
            Step::Scripts => "writing the example scripts",
            Step::Report => "drawing the validation report",
        }
    }
}

/// A step starting or finished.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StepEvent {
    Started(Step),
    Finished(Step, Duration),
}

/// Times steps and tells a listener (the command's progress display) when each starts and ends.
pub struct StepTimer<'a> {
    listener: &'a mut dyn FnMut(StepEvent),
    pub timings: Vec<(Step, Duration)>,
}

impl<'a> StepTimer<'a> {
    pub fn new(listener: &'a mut dyn FnMut(StepEvent)) -> StepTimer<'a> {
        StepTimer {
            listener,
            timings: Vec::new(),
        }
    }

    /// Runs `f` as `step`.
    pub fn run<T>(&mut self, step: Step, f: impl FnOnce() -> T) -> T {
        (self.listener)(StepEvent::Started(step));
        let t = Instant::now();
        let out = f();
        let took = t.elapsed();
        self.timings.push((step, took));
        (self.listener)(StepEvent::Finished(step, took));
        out
    }
}

/// "reading the CT 1.2 s, …; 12.5 s in all".
pub fn describe_timings(timings: &[(Step, Duration)]) -> String {
    let total: Duration = timings.iter().map(|(_, d)| *d).sum();
    let parts: Vec<String> = timings
        .iter()
        .map(|(s, d)| format!("{} {:.1} s", s.describe(), d.as_secs_f64()))
        .collect();
    format!("{}; {:.1} s in all", parts.join(", "), total.as_secs_f64())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn steps_are_timed_in_order_and_the_listener_hears_both_ends() {
        let mut heard = Vec::new();
        let mut listen = |e: StepEvent| heard.push(e);
        let mut timer = StepTimer::new(&mut listen);
        let v = timer.run(Step::ReadCt, || 7);
        timer.run(Step::Window, || ());
        let timings = timer.timings.clone();
        assert_eq!(v, 7);
        assert_eq!(
            timings.iter().map(|t| t.0).collect::<Vec<_>>(),
            vec![Step::ReadCt, Step::Window]
        );
        assert_eq!(heard.len(), 4);
        assert_eq!(heard[0], StepEvent::Started(Step::ReadCt));
        assert!(matches!(heard[3], StepEvent::Finished(Step::Window, _)));
        let text = describe_timings(&timings);
        assert!(
            text.starts_with("reading the CT 0.0 s, searching the intercostal window 0.0 s; "),
            "{text}"
        );
    }
}
