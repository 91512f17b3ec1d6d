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
    /// drawn longest ago (so that every pane keeps up while the moment changes every frame).
    fn stale(&self) -> Option<usize> {
        let tick = self.moment.as_ref()?.tick;
        (0..self.panes.len())
            .filter_map(|i| match self.drawn.get(i).and_then(Option::as_ref) {
                Some(d) if d.pane == self.panes[i] && d.tick == tick => None,
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
        let drawn = Arc::new(DrawnPane {
            pane,
            tick: moment.tick,
            frame,
            seq,
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
