//! A double of Haply's Inverse Service for tests (docs/devices.md "Device doubles"): a WebSocket
//! server on a loopback port that speaks the service's 3.5 JSON protocol over the simulated arm of
//! `stylet-device-double-arm`, playing one Inverse3 with a wireless VerseGrip.
//!
//! As the service does, it sends its whole inventory (config, state, status) when a client
//! connects, then exactly one state message per message received; a message without a
//! `set_cursor_force` for the Inverse3 leaves the device idle (no force). Positions go out in
//! metres, forces come in newtons. Messages that break the protocol (not JSON, another device's
//! id, the pre-3.5 `values` field) are counted as violations and answered with the state, as the
//! service would ignore them.

use std::net::{TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;

use serde_json::{Value, json};
use stylet_device_double_arm::Arm;
use tungstenite::Message;

/// The double's Inverse3.
pub const DEVICE_ID: &str = "0D0B";

#[derive(Debug)]
struct State {
    arm: Arm,
    connected: bool,
    connections: u64,
    violations: u64,
}

/// A running Inverse Service double; dropping it stops the server.
pub struct HaplyDouble {
    pub url: String,
    state: Arc<Mutex<State>>,
    run: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl HaplyDouble {
    /// Starts a server on a free loopback port, its arm following `hand` ((t s, x, y, z mm)
    /// keyframes, in the service's frame) from the moment a client connects.
    pub fn start(hand: Vec<[f64; 4]>) -> std::io::Result<HaplyDouble> {
        let listener = TcpListener::bind("127.0.0.1:0")?;
        listener.set_nonblocking(true)?;
        let url = format!("ws://{}", listener.local_addr()?);
        let state = Arc::new(Mutex::new(State {
            arm: Arm::new(hand),
            connected: false,
            connections: 0,
            violations: 0,
        }));
        let run = Arc::new(AtomicBool::new(true));
        let thread = {
            let (state, run) = (state.clone(), run.clone());
            std::thread::Builder::new()
                .name("haply double".into())
                .spawn(move || serve(&listener, &state, &run))?
        };
        Ok(HaplyDouble {
            url,
            state,
            run,
            thread: Some(thread),
        })
    }

    fn state(&self) -> MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Every force the Inverse3 was commanded: (t s since the client connected, fx, fy, fz N).
    pub fn forces(&self) -> Vec<[f64; 4]> {
        self.state().arm.forces().to_vec()
    }

    /// The zero of [`Self::forces`]' clock (the latest client's connection).
    pub fn clock_start(&self) -> std::time::Instant {
        self.state().arm.started_at()
    }

    /// Messages that broke the protocol.
    pub fn violations(&self) -> u64 {
        self.state().violations
    }

    /// Whether a client is connected now.
    pub fn connected(&self) -> bool {
        self.state().connected
    }

    /// How many clients have connected.
    pub fn connections(&self) -> u64 {
        self.state().connections
    }

    /// The VerseGrip's buttons (bit 0: a, 1: b, 2: c).
    pub fn set_buttons(&self, buttons: u32) {
        self.state().arm.buttons = buttons;
    }
}

impl Drop for HaplyDouble {
    fn drop(&mut self) {
        self.run.store(false, Ordering::Release);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Serves one client at a time until stopped.
fn serve(listener: &TcpListener, state: &Mutex<State>, run: &AtomicBool) {
    while run.load(Ordering::Acquire) {
        match listener.accept() {
            Ok((stream, _)) => {
                let _ = client(stream, state, run);
                let mut s = state.lock().unwrap_or_else(|e| e.into_inner());
                s.connected = false;
                s.arm.cut_force();
            }
            Err(_) => std::thread::sleep(Duration::from_millis(2)),
        }
    }
}

fn client(stream: TcpStream, state: &Mutex<State>, run: &AtomicBool) -> Result<(), Box<dyn std::error::Error>> {
    stream.set_nonblocking(false)?;
    stream.set_nodelay(true)?;
    stream.set_read_timeout(Some(Duration::from_millis(20)))?;
    let mut ws = tungstenite::accept(stream)?;
    {
        let mut s = state.lock().unwrap_or_else(|e| e.into_inner());
        let buttons = s.arm.buttons;
        s.arm = s.arm.restarted();
        s.arm.buttons = buttons;
        s.connected = true;
        s.connections += 1;
        s.arm.step();
        let inventory = message(&s.arm, true);
        drop(s);
        ws.send(Message::text(inventory))?;
    }
    while run.load(Ordering::Acquire) {
        let text = match ws.read() {
            Ok(Message::Text(t)) => t,
            Ok(Message::Close(_)) => return Ok(()),
            Ok(_) => continue,
            Err(tungstenite::Error::Io(e))
                if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) =>
            {
                // No message for 20 ms: the device idles.
                state.lock().unwrap_or_else(|e| e.into_inner()).arm.cut_force();
                continue;
            }
            Err(e) => return Err(e.into()),
        };
        let mut s = state.lock().unwrap_or_else(|e| e.into_inner());
        s.arm.step();
        match force_commanded(text.as_str()) {
            Ok(Some(f)) => s.arm.accept_force(f),
            Ok(None) => s.arm.cut_force(),
            Err(()) => {
                s.violations += 1;
                s.arm.cut_force();
            }
        }
        let reply = message(&s.arm, false);
        drop(s);
        ws.send(Message::text(reply))?;
    }
    let _ = ws.close(None);
    Ok(())
}

/// The force a client message commands the Inverse3 (`None`: no force command, the device
/// idles); `Err` for a message that breaks the protocol.
fn force_commanded(text: &str) -> Result<Option<[f64; 3]>, ()> {
    let v: Value = serde_json::from_str(text).map_err(|_| ())?;
    let Some(devices) = v.get("inverse3") else {
        return Ok(None);
    };
    let mut force = None;
    for d in devices.as_array().ok_or(())? {
        if d.get("device_id").and_then(Value::as_str) != Some(DEVICE_ID) {
            return Err(());
        }
        if let Some(cmd) = d.pointer("/commands/set_cursor_force") {
            let vector = cmd.get("vector").ok_or(())?;
            let axis = |k: &str| {
                vector
                    .get(k)
                    .and_then(Value::as_f64)
                    .filter(|x| x.is_finite())
                    .ok_or(())
            };
            force = Some([axis("x")?, axis("y")?, axis("z")?]);
        }
    }
    Ok(force)
}

/// The service's message: the inventory (with config and status) or a state update.
fn message(arm: &Arm, inventory: bool) -> String {
    let [x, y, z] = arm.position_mm().map(|c| c / 1000.0);
    let pressed = |bit: u32| arm.buttons & (1 << bit) != 0;
    let mut inverse3 = json!({
        "device_id": DEVICE_ID,
        "state": {
            "cursor_position": {"x": x, "y": y, "z": z},
            "cursor_velocity": {"x": 0.0, "y": 0.0, "z": 0.0},
            "control_mode": "force"
        },
        "status": {"calibrated": true, "in_use": true, "power_supply": true, "ready": true, "started": true}
    });
    let mut grip = json!({
        "device_id": "1102",
        "state": {"buttons": {"a": pressed(0), "b": pressed(1), "c": pressed(2)},
                  "orientation": {"w": 1.0, "x": 0.0, "y": 0.0, "z": 0.0}},
        "status": {"connected": true, "awake": true, "ready": true}
    });
    if inventory {
        inverse3["config"] = json!({"type": "inverse3", "handedness": "right", "basis": {"permutation": "XYZ"}});
        grip["config"] = json!({"type": "wireless_verse_grip"});
    }
    json!({"session_id": 1, "inverse3": [inverse3], "verse_grip": [], "wireless_verse_grip": [grip]}).to_string()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn force_commands_are_read_and_protocol_breaks_are_caught() {
        let cmd = |id: &str, field: &str| {
            format!(
                r#"{{"inverse3":[{{"device_id":"{id}","commands":{{"set_cursor_force":{{"{field}":{{"x":1,"y":2,"z":3}}}}}}}}]}}"#
            )
        };
        assert_eq!(force_commanded(&cmd(DEVICE_ID, "vector")), Ok(Some([1.0, 2.0, 3.0])));
        assert_eq!(force_commanded("{}"), Ok(None));
        assert_eq!(force_commanded(&cmd("FFFF", "vector")), Err(()));
        assert_eq!(force_commanded(&cmd(DEVICE_ID, "values")), Err(()));
        assert_eq!(force_commanded("not json"), Err(()));
    }
}
