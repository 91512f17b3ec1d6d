//! Draws the window's views on a thread of its own, so that neither the haptic loop nor the
//! window's frame waits for a ray cast. The window asks for panes (a view and its size on
//! screen) at a moment; the worker draws whichever pane is out of date, newest moment first,
//! and tells the window when a frame is ready.

use std::sync::{Arc, Condvar, Mutex};
use std::thread::JoinHandle;

use stylet_atlas::Atlas;
use stylet_render::views::{Moment, ViewError};

use crate::views::{Frame, ViewKind, ViewRenderer, ViewSettings};

/// One pane of the layout: a view and its size on screen (pixels).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Pane {
    pub kind: ViewKind,
    pub width: u32,
    pub height: u32,
}

/// A drawn pane, or why it could not be drawn.
#[derive(Debug)]
pub struct DrawnPane {
    pub pane: Pane,
    /// The tick of the moment it shows.
    pub tick: u64,
    pub frame: Result<Frame, ViewError>,
    /// Order of drawing (1 for the worker's first frame).
    pub seq: u64,
    /// The moment drawn.
    pub moment: Arc<Moment>,
    /// Drawing it again would give the same picture: the view's resolution scale stays as it
    /// was drawn (at full resolution, or as fine as its time budget allows).
    pub settled: bool,
}

/// Whether `kind` shows the same picture at moments `a` and `b`: the tools, the device, the
/// X-ray switch, the contrast and the deformation are the same and the patient does not breathe;
/// the ultrasound also at the same time (its Doppler colours pulse with the heart). Only the
/// tick differs, so the view need not be drawn again: on a machine without a GPU the CPU then
/// draws the views that change, at a finer scale, instead of redrawing the still ones.
pub fn same_picture(kind: ViewKind, a: &Moment, b: &Moment) -> bool {
    let same_deformation = match (&a.deformation, &b.deformation) {
        (None, None) => true,
        (Some(x), Some(y)) => Arc::ptr_eq(x, y),
        _ => false,
    };
    // The haptic loop shares one overlay until the contrast changes; a replay builds its own.
    let same_contrast = match (&a.contrast, &b.contrast) {
        (None, None) => true,
        (Some(x), Some(y)) => Arc::ptr_eq(x, y) || x == y,
        _ => false,
    };
    a.breathing.is_none()
        && b.breathing.is_none()
        && same_deformation
        && a.tools == b.tools
        && a.device_mm == b.device_mm
        && a.axis == b.axis
        && a.xray_on == b.xray_on
        && a.scenario == b.scenario
        && a.difficulty == b.difficulty
        && a.seed == b.seed
        && same_contrast
        && a.consequences == b.consequences
        && (kind != ViewKind::Ultrasound || a.time_s == b.time_s)
}

#[derive(Default)]
struct State {
    moment: Option<Arc<Moment>>,
    panes: Vec<Pane>,
    drawn: Vec<Option<Arc<DrawnPane>>>,
    /// The renderer could not be built (the atlas cannot be drawn).
    failed: Option<String>,
    /// What draws ([`ViewRenderer::drawn_by`]), once ready.
    drawn_by: Option<String>,
    ready: bool,
    stop: bool,
}

impl State {
    /// The pane to draw next: of those not showing the current moment at their size, the one
    /// drawn longest ago (so that every pane keeps up while the moment changes every frame). A
    /// settled pane whose picture the new moment does not change is current.
    fn stale(&self) -> Option<usize> {
        let moment = self.moment.as_ref()?;
        let tick = moment.tick;
        (0..self.panes.len())
            .filter_map(|i| match self.drawn.get(i).and_then(Option::as_ref) {
                Some(d)
                    if d.pane == self.panes[i]
                        && (d.tick == tick || (d.settled && same_picture(d.pane.kind, &d.moment, moment))) =>
                {
                    None
                }
                Some(d) => Some((d.seq, i)),
                None => Some((0, i)),
            })
            .min()
            .map(|(_, i)| i)
    }
}

/// The drawing thread of one atlas.
pub struct ViewWorker {
    shared: Arc<(Mutex<State>, Condvar)>,
    thread: Option<JoinHandle<()>>,
}

impl ViewWorker {
    /// Starts the thread; it prepares the atlas for drawing first (`ViewRenderer::new`), then
    /// calls `on_frame` after each pane it draws.
    pub fn start(
        atlas: Arc<Atlas>,
        settings: ViewSettings,
        on_frame: Box<dyn Fn() + Send>,
    ) -> Result<ViewWorker, std::io::Error> {
        let shared = Arc::new((Mutex::new(State::default()), Condvar::new()));
        let inner = Arc::clone(&shared);
        let thread = std::thread::Builder::new()
            .name("stylet-views".into())
            .spawn(move || run(atlas, settings, &inner, on_frame.as_ref()))?;
        Ok(ViewWorker {
            shared,
            thread: Some(thread),
        })
    }

    /// Asks for `panes` drawn at `moment` (drawn frames of other moments stay shown meanwhile).
    pub fn request(&self, moment: &Moment, panes: &[Pane]) {
        let (lock, wake) = &*self.shared;
        let Ok(mut s) = lock.lock() else { return };
        let same_moment = s.moment.as_ref().is_some_and(|m| m.tick == moment.tick);
        if same_moment && s.panes == panes {
            return;
        }
        if !same_moment {
            s.moment = Some(Arc::new(moment.clone()));
        }
        if s.panes != panes {
            s.panes = panes.to_vec();
            s.drawn.resize(panes.len(), None);
        }
        wake.notify_one();
    }

    /// The latest drawing of each requested pane (`None`: not drawn yet).
    pub fn drawn(&self) -> Vec<Option<Arc<DrawnPane>>> {
        self.shared.0.lock().map(|s| s.drawn.clone()).unwrap_or_default()
    }

    /// The atlas is prepared and the worker draws.
    pub fn is_ready(&self) -> bool {
        self.shared.0.lock().is_ok_and(|s| s.ready)
    }

    /// What draws the views (the CPU and its threads, or the GPU adapter), once ready.
    pub fn drawn_by(&self) -> Option<String> {
        self.shared.0.lock().ok().and_then(|s| s.drawn_by.clone())
    }

    /// Why the worker cannot draw at all, if it cannot.
    pub fn failure(&self) -> Option<String> {
        self.shared.0.lock().ok().and_then(|s| s.failed.clone())
    }

    /// Every requested pane shows the requested moment.
    pub fn is_current(&self) -> bool {
        self.shared.0.lock().is_ok_and(|s| s.ready && s.stale().is_none())
    }
}

impl Drop for ViewWorker {
    /// Asks the thread to stop and does not wait: it may be preparing the atlas for seconds, and
    /// it holds nothing but shared references.
    fn drop(&mut self) {
        let (lock, wake) = &*self.shared;
        if let Ok(mut s) = lock.lock() {
            s.stop = true;
        }
        wake.notify_all();
        drop(self.thread.take());
    }
}

fn run(atlas: Arc<Atlas>, settings: ViewSettings, shared: &(Mutex<State>, Condvar), on_frame: &dyn Fn()) {
    let (lock, wake) = shared;
    crate::priority::lower_this_thread(crate::priority::DRAWING_NICENESS);
    let mut renderer = match ViewRenderer::new(atlas, settings) {
        _ if lock.lock().is_ok_and(|s| s.stop) => return,
        Ok(r) => r,
        Err(e) => {
            if let Ok(mut s) = lock.lock() {
                s.failed = Some(e.to_string());
            }
            on_frame();
            return;
        }
    };
    if let Ok(mut s) = lock.lock() {
        s.ready = true;
        s.drawn_by = Some(renderer.drawn_by());
    }
    on_frame();
    let mut seq = 0u64;
    loop {
        let (index, pane, moment) = {
            let Ok(mut s) = lock.lock() else { return };
            loop {
                if s.stop {
                    return;
                }
                if let Some(i) = s.stale() {
                    let moment = Arc::clone(s.moment.as_ref().expect("a stale pane has a moment"));
                    break (i, s.panes[i], moment);
                }
                s = match wake.wait(s) {
                    Ok(s) => s,
                    Err(_) => return,
                };
            }
        };
        let frame = renderer.draw(pane.kind, &moment, pane.width, pane.height);
        seq += 1;
        let settled = frame.as_ref().is_ok_and(|f| f.scale == renderer.scale(pane.kind));
        let drawn = Arc::new(DrawnPane {
            pane,
            tick: moment.tick,
            frame,
            seq,
            moment: Arc::clone(&moment),
            settled,
        });
        if let Ok(mut s) = lock.lock() {
            // The layout may have changed while drawing: keep the frame only where it still fits.
            if s.panes.get(index) == Some(&pane) {
                s.drawn[index] = Some(drawn);
            }
        }
        on_frame();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use stylet_physics::glam::DVec3;
    use stylet_render::tools::ToolState;

    fn moment(tick: u64) -> Moment {
        Moment {
            tools: ToolState::default(),
            contrast: None,
            consequences: Vec::new(),
            scenario: "s".into(),
            xray_on: false,
            seed: 1,
            time_s: tick as f64 / 1000.0,
            difficulty: stylet_atlas::Difficulty::Beginner,
            device_mm: DVec3::new(1.0, 2.0, 3.0),
            axis: DVec3::Z,
            tick,
            deformation: None,
            breathing: None,
        }
    }

    /// A still tool: only the tick moves, so no view but the pulsing ultrasound changes; a
    /// moved tool or the X-ray switched on changes them.
    #[test]
    fn a_still_scene_is_the_same_picture_and_a_moved_tool_is_not() {
        let (a, b) = (moment(100), moment(116));
        for kind in [ViewKind::ThreeD, ViewKind::Axial, ViewKind::Needle, ViewKind::Xray] {
            assert!(same_picture(kind, &a, &b), "{kind:?}");
        }
        assert!(
            !same_picture(ViewKind::Ultrasound, &a, &b),
            "the Doppler pulses with time"
        );
        let moved = Moment {
            device_mm: DVec3::new(1.0, 2.0, 3.5),
            ..moment(116)
        };
        assert!(!same_picture(ViewKind::ThreeD, &a, &moved));
        let xray = Moment {
            xray_on: true,
            ..moment(116)
        };
        assert!(!same_picture(ViewKind::Xray, &a, &xray));
    }
}
