//! A servo loop of Stylet's own, for APIs without a scheduler (Force Dimension's DHD, Haply's
//! WebSocket service): a thread that reads the device, runs the [`ServoCore`] tick and writes the
//! force once a millisecond, and on any device error stops force output with the error kept.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use stylet_physics::glam::{DMat3, DVec3};

use super::HapticError;
use super::servo::{ServoCore, Shared};

/// The servo period: 1 kHz.
pub(crate) const PERIOD: Duration = Duration::from_millis(1);

/// One device's reads and writes, as the servo thread calls them.
pub(crate) trait ServoIo: Send + 'static {
    /// The stylus now: tip (mm, device frame), orientation when sensed, button bits.
    fn read(&mut self) -> Result<(DVec3, Option<DMat3>, u32), HapticError>;
    /// Commands `force_n` (N, device frame).
    fn write(&mut self, force_n: DVec3) -> Result<(), HapticError>;
    /// Commands zero force, as well as the device still can (after an error, at the end).
    fn zero(&mut self);
}

/// A running servo thread; [`ServoThread::stop`] hands the device's I/O back.
pub(crate) struct ServoThread<Io: ServoIo> {
    run: Arc<AtomicBool>,
    handle: Option<JoinHandle<Io>>,
}

impl<Io: ServoIo> ServoThread<Io> {
    /// Starts ticking `io` through `core` at [`PERIOD`].
    pub fn spawn(mut io: Io, mut core: ServoCore, shared: Arc<Shared>, name: &str) -> std::io::Result<Self> {
        let run = Arc::new(AtomicBool::new(true));
        let running = run.clone();
        let handle = std::thread::Builder::new().name(name.into()).spawn(move || {
            let mut next = Instant::now();
            while running.load(Ordering::Acquire) {
                let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                    let (position_mm, rotation, buttons) = io.read()?;
                    let force_n = core.tick(position_mm, rotation, buttons);
                    io.write(force_n)
                }));
                match outcome {
                    Ok(Ok(())) => {}
                    Ok(Err(e)) => {
                        let _ = shared.fault.set(e);
                        io.zero();
                        break;
                    }
                    // A panic in the tick: zero force, and the loop ends (the device reports the
                    // servo loop stopped through its tick count).
                    Err(_) => {
                        io.zero();
                        break;
                    }
                }
                next += PERIOD;
                let now = Instant::now();
                if next > now {
                    std::thread::sleep(next - now);
                } else if now - next > 10 * PERIOD {
                    // Far behind (the machine stalled us): start afresh rather than burst.
                    next = now;
                }
            }
            io
        })?;
        Ok(ServoThread {
            run,
            handle: Some(handle),
        })
    }

    /// Stops the thread and returns the device's I/O (`None` if the thread panicked outside a
    /// tick, which it does not); zero force was the last command when the loop ran under a
    /// stopping hold.
    pub fn stop(&mut self) -> Option<Io> {
        self.run.store(false, Ordering::Release);
        self.handle.take().and_then(|h| h.join().ok())
    }
}
