//! The scripted device: turns a parsed script into one [`TickInput`] per tick.
//!
//! Poses are interpolated between keyframes (position linearly, orientation by slerp). During a
//! `press` the position along the press direction n is force controlled, like a device programmed
//! to push with a constant force (the thesis' 1 N palpation experiment): the depth along n moves by
//! an admittance law, Δs = c (F − F_resist) per tick with F_resist = −f_device · n, limited to
//! 100 mm/s; the script's keyframes set the other components. Events fire on the tick
//! round(t · rate).

use stylet_physics::PlannedPath;
use stylet_physics::glam::{DMat3, DQuat, DVec3};
use stylet_physics::{Event, HandPose, TickInput, TickOutput};

use super::parse::{Action, Hand, PoseSpec, Script, unit};
use crate::Device;

/// Admittance of the force control (mm per N per tick).
const PRESS_ADMITTANCE_MM_PER_N: f64 = 0.02;
/// Fastest motion of the force-controlled axis (mm/s).
const PRESS_MAX_SPEED_MM_PER_S: f64 = 100.0;

/// Why a parsed script cannot be bound to an atlas: a path it names that the atlas lacks or that
/// has no direction, a pose that is not finite, or an end before its last time stamp. The
/// messages name the script line where there is one.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BindError {
    /// `known`: the atlas' insertion paths.
    #[error(
        "line {line}: the atlas has no insertion path '{path}' (it has: {})",
        list_or_none(known)
    )]
    UnknownPath {
        line: usize,
        path: String,
        known: Vec<String>,
    },
    #[error("line {line}: insertion path '{path}' has no direction (its target is its entry)")]
    PathWithoutDirection { line: usize, path: String },
    /// An `aim` whose target is its entry point.
    #[error("line {line}: the target is the entry point")]
    AimWithoutDirection { line: usize },
    #[error("line {line}: the pose is not finite (position {position_mm} mm, orientation {orientation})")]
    PoseNotFinite {
        line: usize,
        position_mm: DVec3,
        orientation: DQuat,
    },
    #[error("the script ends at {end_s} s before its last time stamp {last_s} s")]
    EndsEarly { end_s: f64, last_s: f64 },
}

/// The names joined by ", ", or "none".
fn list_or_none(names: &[String]) -> String {
    if names.is_empty() {
        "none".to_string()
    } else {
        names.join(", ")
    }
}

/// A script bound to an atlas' paths, ready to run.
#[derive(Debug, Clone)]
pub struct ScriptedDevice {
    rate_hz: u32,
    end_tick: u64,
    /// The first hand's track.
    first: Track,
    /// The second hand's track in a two-handed script (none: one hand, or a second hand that
    /// never moves).
    second: Option<Track>,
    events: Vec<(u64, Event)>,
    next_event: usize,
}

/// One device's keyframes and presses.
#[derive(Debug, Clone, Default)]
struct Track {
    /// Pose keyframes (time in s, position, orientation), times never decreasing: looked up by
    /// binary search, about log2(n) comparisons per tick instead of n.
    keys: Vec<(f64, DVec3, DQuat)>,
    /// Press intervals: start tick, end tick (exclusive), direction, force; in order and
    /// disjoint, so the ends never decrease either.
    presses: Vec<(u64, u64, DVec3, f64)>,
    /// A press begun and not yet released while binding: start tick, direction, force.
    open_press: Option<(u64, DVec3, f64)>,
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
    pub fn new(script: &Script, paths: &[PlannedPath]) -> Result<Self, BindError> {
        let rate = script.rate_hz;
        let tick_of = |t: f64| (t * rate as f64).round() as u64;
        let mut tracks = [Track::default(), Track::default()];
        let mut events = Vec::new();
        for item in &script.items {
            let track = &mut tracks[usize::from(item.hand == Hand::Second)];
            match &item.action {
                Action::Pose(p) => {
                    let (pos, dir, xaxis) = match p {
                        PoseSpec::Explicit { pos, dir, xaxis } => (*pos, *dir, *xaxis),
                        PoseSpec::Along { path, depth_mm, xaxis } => {
                            let np = paths
                                .iter()
                                .find(|n| &n.name == path)
                                .ok_or_else(|| BindError::UnknownPath {
                                    line: item.line,
                                    path: path.clone(),
                                    known: paths.iter().map(|n| n.name.clone()).collect(),
                                })?;
                            let d =
                                unit(np.target_mm - np.entry_mm).ok_or_else(|| BindError::PathWithoutDirection {
                                    line: item.line,
                                    path: path.clone(),
                                })?;
                            (np.entry_mm + d * *depth_mm, d, *xaxis)
                        }
                        PoseSpec::Aim {
                            entry,
                            target,
                            depth_mm,
                            xaxis,
                        } => {
                            let d = unit(*target - *entry).ok_or(BindError::AimWithoutDirection { line: item.line })?;
                            (*entry + d * *depth_mm, d, *xaxis)
                        }
                    };
                    let q = orientation(dir, xaxis);
                    // The parser bounds every number; this guards the atlas' paths and the maths.
                    if !(pos.is_finite() && q.is_finite()) {
                        return Err(BindError::PoseNotFinite {
                            line: item.line,
                            position_mm: pos,
                            orientation: q,
                        });
                    }
                    track.keys.push((item.t_s, pos, q));
                }
                Action::Press { dir, force_n } => {
                    if let Some((start, d, f)) = track.open_press.take() {
                        track.presses.push((start, tick_of(item.t_s), d, f));
                    }
                    track.open_press = Some((tick_of(item.t_s), *dir, *force_n));
                }
                Action::Release => {
                    if let Some((start, d, f)) = track.open_press.take() {
                        track.presses.push((start, tick_of(item.t_s), d, f));
                    }
                }
                Action::Event(e) => events.push((tick_of(item.t_s), e.clone())),
            }
        }
        let last = script.items.last().map_or(0.0, |i| i.t_s);
        let end_tick = tick_of(script.end_s.unwrap_or(last)).max(1);
        for track in &mut tracks {
            if let Some((start, d, f)) = track.open_press.take() {
                track.presses.push((start, end_tick, d, f));
            }
        }
        if let Some(e) = script.end_s
            && e < last
        {
            return Err(BindError::EndsEarly { end_s: e, last_s: last });
        }
        let [first, second] = tracks;
        Ok(ScriptedDevice {
            rate_hz: rate,
            end_tick,
            first,
            second: (script.second_hand.is_some() && !second.keys.is_empty()).then_some(second),
            events,
            next_event: 0,
        })
    }

    pub fn rate_hz(&self) -> u32 {
        self.rate_hz
    }

    /// Number of ticks the script runs.
    pub fn ticks(&self) -> u64 {
        self.end_tick
    }

    /// The first hand's scripted pose at time `t` (before force control).
    pub fn pose_at(&self, t: f64) -> (DVec3, DQuat) {
        self.first.pose_at(t)
    }

    /// The first hand's press active at `tick`, if any.
    #[cfg(test)]
    fn press_at(&self, tick: u64) -> Option<(u64, u64, DVec3, f64)> {
        self.first.press_at(tick)
    }
}

impl Track {
    /// The scripted pose at time `t` (before force control).
    fn pose_at(&self, t: f64) -> (DVec3, DQuat) {
        let k = &self.keys;
        if t <= k[0].0 {
            return (k[0].1, k[0].2);
        }
        // The first keyframe at or after t (t is past the first, so j ≥ 1).
        let j = k.partition_point(|key| {
            #[cfg(test)]
            KEY_PROBES.with(|c| c.set(c.get() + 1));
            key.0 < t
        });
        let Some(&b) = k.get(j) else {
            let l = k[k.len() - 1];
            return (l.1, l.2);
        };
        let a = k[j - 1];
        if b.0 <= a.0 {
            return (b.1, b.2);
        }
        let s = (t - a.0) / (b.0 - a.0);
        (a.1 + (b.1 - a.1) * s, a.2.slerp(b.2, s).normalize())
    }

    /// The press active at `tick`, if any.
    fn press_at(&self, tick: u64) -> Option<(u64, u64, DVec3, f64)> {
        let i = self.presses.partition_point(|p| p.1 <= tick);
        self.presses.get(i).filter(|p| p.0 <= tick).copied()
    }

    /// The pose at `tick`: the scripted one, with the position along an active press's direction
    /// force controlled against `force_n`, the force this device was given on the last tick.
    fn pose(&mut self, tick: u64, rate_hz: u32, force_n: Option<DVec3>) -> (DVec3, DQuat) {
        let t = tick as f64 / rate_hz as f64;
        let (mut pos, q) = self.pose_at(t);
        match self.press_at(tick) {
            Some((_, _, n, force)) => {
                let scripted = pos.dot(n);
                let depth = self.press_depth.get_or_insert(scripted);
                if let Some(f) = force_n {
                    let resist = -f.dot(n);
                    let step = PRESS_ADMITTANCE_MM_PER_N * (force - resist);
                    let max = PRESS_MAX_SPEED_MM_PER_S / rate_hz as f64;
                    *depth += step.clamp(-max, max);
                }
                pos += n * (*depth - scripted);
            }
            None => self.press_depth = None,
        }
        (pos, q)
    }
}

impl Device for ScriptedDevice {
    fn next(&mut self, tick: u64, last: Option<&TickOutput>) -> Option<TickInput> {
        if tick >= self.end_tick {
            return None;
        }
        let (pos, q) = self.first.pose(tick, self.rate_hz, last.map(|o| o.force_n));
        let second_force = last.and_then(|o| o.second_hand).map(|h| h.force_n);
        let second_hand = self.second.as_mut().map(|track| {
            let (position_mm, orientation) = track.pose(tick, self.rate_hz, second_force);
            HandPose {
                position_mm,
                orientation,
                buttons: 0,
            }
        });
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
            second_hand,
        })
    }
}

#[cfg(test)]
thread_local! {
    /// Keyframes [`ScriptedDevice::pose_at`] compared with on this thread (tests count the work).
    static KEY_PROBES: std::cell::Cell<u64> = const { std::cell::Cell::new(0) };
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
        let e = ScriptedDevice::new(&s, &[]).unwrap_err().to_string();
        assert!(e.starts_with("line 3:") && e.contains("'nowhere'"), "{e}");
        let paths = [PlannedPath {
            name: "p".into(),
            entry_mm: DVec3::ZERO,
            target_mm: DVec3::new(0.0, 0.0, 100.0),
        }];
        let s = parse("stylet-script 1\nat 0 along p 30\n").unwrap();
        let mut d = ScriptedDevice::new(&s, &paths).unwrap();
        let i = d.next(0, None).unwrap();
        assert_eq!(i.position_mm, DVec3::new(0.0, 0.0, 30.0));
    }

    /// A script of `n` pose keyframes 2 ms apart: keyframe i at x = i mod 1000, y = i, pointing
    /// along z for even i and along x for odd i.
    fn many_keyframes(n: u64) -> ScriptedDevice {
        let mut text = String::with_capacity(n as usize * 40);
        text.push_str("stylet-script 1\n");
        for i in 0..n {
            let dir = if i % 2 == 0 { "0 0 1" } else { "1 0 0" };
            let ms = 2 * i;
            text.push_str(&format!(
                "at {}.{:03} pos {} {i} 0 dir {dir}\n",
                ms / 1000,
                ms % 1000,
                i % 1000
            ));
        }
        ScriptedDevice::new(&parse(&text).unwrap(), &[]).unwrap()
    }

    /// The pose lookup is a binary search (a linear scan every tick took 0.6 s for 40 000
    /// keyframes, minutes for a million): at most ⌈log2 n⌉ + 1 keyframes are looked at per
    /// lookup, wherever t falls.
    #[test]
    fn pose_lookup_looks_at_logarithmically_many_keyframes() {
        let d = many_keyframes(1_000_000);
        for t in [0.0005, 1.0, 999.9991, 1999.997, 1999.998, 5000.0] {
            KEY_PROBES.with(|c| c.set(0));
            d.pose_at(t);
            let probes = KEY_PROBES.with(|c| c.get());
            assert!(probes <= 21, "{probes} keyframes looked at for t = {t} s");
        }
    }

    /// A million keyframes play through: every tick comes, poses interpolate between the right
    /// keyframes (ran for minutes with the linear lookup).
    #[test]
    fn a_million_keyframes_play() {
        let mut d = many_keyframes(1_000_000);
        assert_eq!(d.ticks(), 1_999_998);
        let diagonal = DVec3::new(1.0, 0.0, 1.0).normalize();
        let mut produced = 0u64;
        for tick in 0..d.ticks() {
            let i = d.next(tick, None).unwrap();
            produced += 1;
            let k = tick / 2;
            let (x, y) = if tick % 2 == 0 {
                ((k % 1000) as f64, k as f64)
            } else {
                ((((k % 1000) + ((k + 1) % 1000)) as f64) / 2.0, k as f64 + 0.5)
            };
            if tick % 99_991 == 1 || (tick % 2 == 1 && tick > 1_999_990) {
                let p = i.position_mm;
                assert!((p - DVec3::new(x, y, 0.0)).length() < 1e-6, "tick {tick}: {p}");
                let z = i.orientation * DVec3::Z;
                let want = if tick % 2 == 1 {
                    diagonal
                } else if k % 2 == 0 {
                    DVec3::Z
                } else {
                    DVec3::X
                };
                assert!((z - want).length() < 1e-9, "tick {tick}: axis {z}");
            }
        }
        assert_eq!(produced, 1_999_998);
        assert!(d.next(1_999_998, None).is_none());
    }

    #[test]
    fn presses_are_found_by_tick() {
        let s = parse(
            "stylet-script 1\nat 0 pos 0 0 0 dir 0 0 1\nat 1 press 0 0 1 1\nat 1 press 0 1 0 2\nat 2 release\n\
             at 3 press 1 0 0 3\nend 4\n",
        )
        .unwrap();
        let d = ScriptedDevice::new(&s, &[]).unwrap();
        let force = |tick| d.press_at(tick).map(|p| p.3);
        assert_eq!(
            [0, 999, 1000, 1999, 2000, 2999, 3000, 3999].map(force),
            [None, None, Some(2.0), Some(2.0), None, None, Some(3.0), Some(3.0)]
        );
    }

    #[test]
    fn orientation_puts_z_along_dir_and_x_along_xaxis() {
        let q = orientation(DVec3::new(0.0, -1.0, 0.0), Some(DVec3::new(0.0, 0.0, 1.0)));
        assert!((q * DVec3::Z - DVec3::NEG_Y).length() < 1e-12);
        assert!((q * DVec3::X - DVec3::Z).length() < 1e-12);
    }
}
