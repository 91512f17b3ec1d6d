//! The scripted device: turns a parsed script into one [`TickInput`] per tick.
//!
//! Poses are interpolated between keyframes (position linearly, orientation by slerp). During a
//! `press` the position along the press direction n is force controlled, like a device programmed
//! to push with a constant force (the thesis' 1 N palpation experiment): the depth along n moves by
//! an admittance law, Δs = c (F − F_resist) per tick with F_resist = −f_device · n, limited to
//! 100 mm/s; the script's keyframes set the other components. Events fire on the tick
//! round(t · rate).

use stylet_physics::glam::{DMat3, DQuat, DVec3};
use stylet_physics::{Event, TickInput, TickOutput};

use super::parse::{Action, PoseSpec, Script};
use crate::Device;

/// Admittance of the force control (mm per N per tick).
const PRESS_ADMITTANCE_MM_PER_N: f64 = 0.02;
/// Fastest motion of the force-controlled axis (mm/s).
const PRESS_MAX_SPEED_MM_PER_S: f64 = 100.0;

/// A named insertion path of the atlas, for `along`.
#[derive(Debug, Clone, PartialEq)]
pub struct NamedPath {
    pub name: String,
    pub entry_mm: DVec3,
    pub target_mm: DVec3,
}

/// A script bound to an atlas' paths, ready to run.
#[derive(Debug, Clone)]
pub struct ScriptedDevice {
    rate_hz: u32,
    end_tick: u64,
    keys: Vec<(f64, DVec3, DQuat)>,
    events: Vec<(u64, Event)>,
    /// Press intervals: start tick, end tick (exclusive), direction, force.
    presses: Vec<(u64, u64, DVec3, f64)>,
    next_event: usize,
    /// Depth along the press direction while a press is active.
    press_depth: Option<f64>,
}

/// A tool orientation with z along `dir` and x as close to `xaxis` as possible.
pub fn orientation(dir: DVec3, xaxis: Option<DVec3>) -> DQuat {
    let z = dir.normalize();
    let x = match xaxis.map(|a| a - z * a.dot(z)).filter(|a| a.length() > 1e-6) {
        Some(a) => a.normalize(),
        None => z.any_orthonormal_pair().0,
    };
    let y = z.cross(x);
    DQuat::from_mat3(&DMat3::from_cols(x, y, z)).normalize()
}

impl ScriptedDevice {
    /// Binds the script to the atlas' insertion paths; an unknown path name is an error naming
    /// the script line.
    pub fn new(script: &Script, paths: &[NamedPath]) -> Result<Self, String> {
        let rate = script.rate_hz;
        let tick_of = |t: f64| (t * rate as f64).round() as u64;
        let mut keys = Vec::new();
        let mut events = Vec::new();
        let mut presses = Vec::new();
        let mut open_press: Option<(u64, DVec3, f64)> = None;
        for item in &script.items {
            match &item.action {
                Action::Pose(p) => {
                    let (pos, dir, xaxis) = match p {
                        PoseSpec::Explicit { pos, dir, xaxis } => (*pos, *dir, *xaxis),
                        PoseSpec::Along { path, depth_mm, xaxis } => {
                            let np = paths.iter().find(|n| &n.name == path).ok_or_else(|| {
                                let known: Vec<&str> = paths.iter().map(|n| n.name.as_str()).collect();
                                format!(
                                    "line {}: the atlas has no insertion path '{path}' (it has: {})",
                                    item.line,
                                    if known.is_empty() {
                                        "none".to_string()
                                    } else {
                                        known.join(", ")
                                    }
                                )
                            })?;
                            let d = (np.target_mm - np.entry_mm).normalize();
                            (np.entry_mm + d * *depth_mm, d, *xaxis)
                        }
                        PoseSpec::Aim {
                            entry,
                            target,
                            depth_mm,
                            xaxis,
                        } => {
                            let d = (*target - *entry).normalize();
                            (*entry + d * *depth_mm, d, *xaxis)
                        }
                    };
                    keys.push((item.t_s, pos, orientation(dir, xaxis)));
                }
                Action::Press { dir, force_n } => {
                    if let Some((start, d, f)) = open_press.take() {
                        presses.push((start, tick_of(item.t_s), d, f));
                    }
                    open_press = Some((tick_of(item.t_s), *dir, *force_n));
                }
                Action::Release => {
                    if let Some((start, d, f)) = open_press.take() {
                        presses.push((start, tick_of(item.t_s), d, f));
                    }
                }
                Action::Event(e) => events.push((tick_of(item.t_s), e.clone())),
            }
        }
        let last = script.items.last().map_or(0.0, |i| i.t_s);
        let end_tick = tick_of(script.end_s.unwrap_or(last)).max(1);
        if let Some((start, d, f)) = open_press {
            presses.push((start, end_tick, d, f));
        }
        if let Some(e) = script.end_s
            && e < last
        {
            return Err(format!("the script ends at {e} s before its last time stamp {last} s"));
        }
        Ok(ScriptedDevice {
            rate_hz: rate,
            end_tick,
            keys,
            events,
            presses,
            next_event: 0,
            press_depth: None,
        })
    }

    pub fn rate_hz(&self) -> u32 {
        self.rate_hz
    }

    /// Number of ticks the script runs.
    pub fn ticks(&self) -> u64 {
        self.end_tick
    }

    /// The scripted pose at time `t` (before force control).
    pub fn pose_at(&self, t: f64) -> (DVec3, DQuat) {
        let k = &self.keys;
        if t <= k[0].0 {
            return (k[0].1, k[0].2);
        }
        for w in k.windows(2) {
            let (a, b) = (w[0], w[1]);
            if t <= b.0 {
                if b.0 <= a.0 {
                    return (b.1, b.2);
                }
                let s = (t - a.0) / (b.0 - a.0);
                return (a.1 + (b.1 - a.1) * s, a.2.slerp(b.2, s).normalize());
            }
        }
        let l = k[k.len() - 1];
        (l.1, l.2)
    }
}

impl Device for ScriptedDevice {
    fn next(&mut self, tick: u64, last: Option<&TickOutput>) -> Option<TickInput> {
        if tick >= self.end_tick {
            return None;
        }
        let t = tick as f64 / self.rate_hz as f64;
        let (mut pos, q) = self.pose_at(t);
        let press = self.presses.iter().find(|p| tick >= p.0 && tick < p.1).copied();
        match press {
            Some((_, _, n, force)) => {
                let scripted = pos.dot(n);
                let depth = self.press_depth.get_or_insert(scripted);
                if let Some(out) = last {
                    let resist = -out.force_n.dot(n);
                    let step = PRESS_ADMITTANCE_MM_PER_N * (force - resist);
                    let max = PRESS_MAX_SPEED_MM_PER_S / self.rate_hz as f64;
                    *depth += step.clamp(-max, max);
                }
                pos += n * (*depth - scripted);
            }
            None => self.press_depth = None,
        }
        let mut events = Vec::new();
        while self.next_event < self.events.len() && self.events[self.next_event].0 <= tick {
            events.push(self.events[self.next_event].1.clone());
            self.next_event += 1;
        }
        Some(TickInput {
            position_mm: pos,
            orientation: q,
            buttons: 0,
            events,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::script::parse::parse;

    #[test]
    fn poses_interpolate_and_events_fire_on_their_tick() {
        let s = parse(
            "stylet-script 1\nat 0 pos 0 0 0 dir 0 0 1\nat 1 pos 10 0 0 dir 1 0 0\nat 0.5 event xray-on\nend 2\n",
        );
        // Time stamps must not decrease: the event at 0.5 after the pose at 1 is an error.
        assert!(s.is_err());
        let s = parse(
            "stylet-script 1\nat 0 pos 0 0 0 dir 0 0 1\nat 0.5 event xray-on\nat 1 pos 10 0 0 dir 1 0 0\nend 2\n",
        )
        .unwrap();
        let mut d = ScriptedDevice::new(&s, &[]).unwrap();
        assert_eq!(d.ticks(), 2000);
        let mut fired = Vec::new();
        for tick in 0..2000 {
            let i = d.next(tick, None).unwrap();
            if !i.events.is_empty() {
                fired.push(tick);
            }
            if tick == 500 {
                assert!((i.position_mm.x - 5.0).abs() < 1e-12);
                let z = i.orientation * DVec3::Z;
                assert!((z - DVec3::new(1.0, 0.0, 1.0).normalize()).length() < 1e-9, "{z}");
            }
        }
        assert_eq!(fired, [500]);
        assert!(d.next(2000, None).is_none());
    }

    #[test]
    fn unknown_paths_name_the_line() {
        let s = parse("stylet-script 1\n\nat 0 along nowhere 3\n").unwrap();
        let e = ScriptedDevice::new(&s, &[]).unwrap_err();
        assert!(e.starts_with("line 3:") && e.contains("'nowhere'"), "{e}");
        let paths = [NamedPath {
            name: "p".into(),
            entry_mm: DVec3::ZERO,
            target_mm: DVec3::new(0.0, 0.0, 100.0),
        }];
        let s = parse("stylet-script 1\nat 0 along p 30\n").unwrap();
        let mut d = ScriptedDevice::new(&s, &paths).unwrap();
        let i = d.next(0, None).unwrap();
        assert_eq!(i.position_mm, DVec3::new(0.0, 0.0, 30.0));
    }

    #[test]
    fn orientation_puts_z_along_dir_and_x_along_xaxis() {
        let q = orientation(DVec3::new(0.0, -1.0, 0.0), Some(DVec3::new(0.0, 0.0, 1.0)));
        assert!((q * DVec3::Z - DVec3::NEG_Y).length() < 1e-12);
        assert!((q * DVec3::X - DVec3::Z).length() < 1e-12);
    }
}
