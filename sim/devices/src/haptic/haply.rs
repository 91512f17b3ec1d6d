//! Haply Inverse3 through the Inverse Service's WebSocket JSON API (service 3.5; default
//! `ws://localhost:10001`). The service sends its whole inventory when a client connects, then
//! exactly one state message for each message the client sends; a device that stops receiving
//! commands goes idle. So the servo thread runs in lockstep: each tick sends the guarded force
//! (`set_cursor_force`, N, in the service's frame) and reads the state that answers it
//! (`cursor_position`, m). Buttons come from the first handle listed (a wireless VerseGrip's
//! `a`, `b`, `c`, or a wired grip's `button`).
//!
//! Haply publishes no force limits in the API; Stylet keeps the Inverse3 to
//! [`MAX_FORCE_N`] peak and [`MAX_CONTINUOUS_FORCE_N`] continuous (docs/devices.md says why).

use std::net::{TcpStream, ToSocketAddrs};
use std::sync::Arc;
use std::time::Duration;

use serde_json::{Value, json};
use stylet_physics::glam::{DMat3, DVec3};
use tungstenite::client::IntoClientRequest;
use tungstenite::protocol::WebSocketConfig;
use tungstenite::{Message, WebSocket};

use super::safety::{Hold, SafetyLimits};
use super::servo::{ServoCore, Shared};
use super::servo_thread::{ServoIo, ServoThread};
use super::{Backend, DeviceInfo, HapticDevice, HapticError, ServoCounts, ServoReading};

/// The Inverse Service's WebSocket address.
pub const DEFAULT_URL: &str = "ws://localhost:10001";

/// The peak force Stylet sends an Inverse3 (N): the safety limit of Isaac Lab's Haply
/// integration, in the absence of a limit the service reports.
pub const MAX_FORCE_N: f64 = 2.0;
/// The mean force over any second Stylet allows an Inverse3 (N).
pub const MAX_CONTINUOUS_FORCE_N: f64 = 1.0;

/// How long the service may take to answer a message before force output stops.
pub const REPLY_TIMEOUT: Duration = Duration::from_millis(50);
/// How long connecting and the first inventory may take.
const CONNECT_TIMEOUT: Duration = Duration::from_secs(2);
/// The largest message accepted from the service (its inventory is a few kilobytes).
const MAX_MESSAGE_BYTES: usize = 1 << 20;

fn service_error(url: &str, reason: impl std::fmt::Display) -> HapticError {
    HapticError::Service {
        backend: Backend::Haply,
        url: url.to_string(),
        reason: reason.to_string(),
    }
}

/// What one state message says of the Inverse3 and its handle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HaplyState {
    pub position_mm: DVec3,
    pub buttons: u32,
}

/// Why a state message from the Inverse Service cannot be used.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum StateError {
    #[error("no inverse3 list in the service's message")]
    NoDeviceList,
    #[error("Inverse3 {0} is no longer listed")]
    NotListed(String),
    #[error("Inverse3 {0}: no state.cursor_position")]
    NoCursor(String),
    #[error("Inverse3 {device}: cursor_position.{axis} missing or not a position in m")]
    BadAxis { device: String, axis: &'static str },
}

/// Reads the Inverse3 `device_id` from the service's state message, and its cursor and buttons.
pub fn parse_state(message: &Value, device_id: &str) -> Result<HaplyState, StateError> {
    let devices = message
        .get("inverse3")
        .and_then(Value::as_array)
        .ok_or(StateError::NoDeviceList)?;
    let device = devices
        .iter()
        .find(|d| d.get("device_id").and_then(Value::as_str) == Some(device_id))
        .ok_or_else(|| StateError::NotListed(device_id.to_string()))?;
    let p = device
        .pointer("/state/cursor_position")
        .ok_or_else(|| StateError::NoCursor(device_id.to_string()))?;
    let axis = |k: &'static str| {
        p.get(k)
            .and_then(Value::as_f64)
            .filter(|v| v.is_finite() && v.abs() < 10.0)
            .ok_or_else(|| StateError::BadAxis {
                device: device_id.to_string(),
                axis: k,
            })
    };
    let position_mm = DVec3::new(axis("x")?, axis("y")?, axis("z")?) * 1000.0;
    Ok(HaplyState {
        position_mm,
        buttons: handle_buttons(message),
    })
}

/// The first handle's buttons as bits: a, b, c of a wireless VerseGrip (bits 0, 1, 2), or a
/// wired grip's one button (bit 0).
fn handle_buttons(message: &Value) -> u32 {
    let first = |family: &str| {
        message
            .get(family)
            .and_then(Value::as_array)
            .and_then(|a| a.first())
            .and_then(|d| d.get("state"))
    };
    let pressed = |v: Option<&Value>| v.and_then(Value::as_bool).unwrap_or(false);
    if let Some(state) = first("wireless_verse_grip").or_else(|| first("custom_verse_grip")) {
        let b = state.get("buttons");
        return ["a", "b", "c"]
            .iter()
            .enumerate()
            .filter(|(_, k)| pressed(b.and_then(|b| b.get(**k))))
            .fold(0, |bits, (i, _)| bits | 1 << i);
    }
    first("verse_grip").map_or(0, |s| u32::from(pressed(s.get("button"))))
}

/// The command that sets the cursor force (N) of `device_id` for one tick.
pub fn force_command(device_id: &str, force_n: DVec3) -> String {
    json!({
        "inverse3": [{
            "device_id": device_id,
            "commands": {"set_cursor_force": {"vector": {"x": force_n.x, "y": force_n.y, "z": force_n.z}}}
        }]
    })
    .to_string()
}

/// The servo thread's side of the connection: it sends a force and reads the answer.
struct HaplyIo {
    url: String,
    device_id: String,
    socket: WebSocket<TcpStream>,
    /// The state that answered the last message (first: the inventory).
    answer: Option<HaplyState>,
}

impl HaplyIo {
    /// The next text message (pings and pongs are answered by the library and skipped).
    fn receive(&mut self) -> Result<Value, HapticError> {
        loop {
            let m = self.socket.read().map_err(|e| match e {
                tungstenite::Error::Io(e)
                    if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) =>
                {
                    service_error(&self.url, format!("no answer within {} ms", REPLY_TIMEOUT.as_millis()))
                }
                e => service_error(&self.url, e),
            })?;
            match m {
                Message::Text(t) => {
                    return serde_json::from_str(t.as_str())
                        .map_err(|e| service_error(&self.url, format!("a message that is not JSON: {e}")));
                }
                Message::Close(_) => return Err(service_error(&self.url, "the service closed the connection")),
                _ => {}
            }
        }
    }

    fn exchange(&mut self, force_n: DVec3) -> Result<(), HapticError> {
        self.socket
            .send(Message::text(force_command(&self.device_id, force_n)))
            .map_err(|e| service_error(&self.url, e))?;
        let message = self.receive()?;
        self.answer = Some(parse_state(&message, &self.device_id).map_err(|e| service_error(&self.url, e))?);
        Ok(())
    }
}

impl ServoIo for HaplyIo {
    fn read(&mut self) -> Result<(DVec3, Option<DMat3>, u32), HapticError> {
        let s = self
            .answer
            .take()
            .ok_or_else(|| service_error(&self.url, "no state to read"))?;
        Ok((s.position_mm, None, s.buttons))
    }

    fn write(&mut self, force_n: DVec3) -> Result<(), HapticError> {
        self.exchange(force_n)
    }

    fn zero(&mut self) {
        // A failed zero leaves the device to idle: without commands it applies no force.
        let _ = self.exchange(DVec3::ZERO);
    }
}

/// An Inverse3 reached through the Inverse Service, with its servo thread running.
pub struct Haply {
    info: DeviceInfo,
    shared: Arc<Shared>,
    servo: ServoThread<HaplyIo>,
    stopped: bool,
    pub url: String,
    pub device_id: String,
}

impl Haply {
    /// Connects to the Inverse Service at `url` (default [`DEFAULT_URL`]), takes the first
    /// Inverse3 it lists and starts the servo thread (zero force until the guard engages).
    pub fn open(url: Option<&str>) -> Result<Haply, HapticError> {
        let url = url.unwrap_or(DEFAULT_URL).to_string();
        let (socket, inventory) = connect(&url)?;
        let device = inventory
            .get("inverse3")
            .and_then(Value::as_array)
            .and_then(|a| a.first())
            .ok_or_else(|| service_error(&url, "the service lists no Inverse3 (is it plugged in and on?)"))?;
        let device_id = device
            .get("device_id")
            .and_then(Value::as_str)
            .filter(|id| !id.is_empty() && id.len() <= 64)
            .ok_or_else(|| service_error(&url, "the Inverse3 has no device_id"))?
            .to_string();
        let first = parse_state(&inventory, &device_id).map_err(|e| service_error(&url, e))?;
        let info = DeviceInfo {
            backend: Backend::Haply,
            model: format!("Inverse3 {device_id}"),
            max_force_n: MAX_FORCE_N,
            max_continuous_force_n: MAX_CONTINUOUS_FORCE_N,
            senses_orientation: false,
        };
        let shared = Shared::new();
        let core = ServoCore::new(
            SafetyLimits::for_device(info.max_force_n, info.max_continuous_force_n),
            shared.clone(),
        );
        let io = HaplyIo {
            url: url.clone(),
            device_id: device_id.clone(),
            socket,
            answer: Some(first),
        };
        let servo = ServoThread::spawn(io, core, shared.clone(), "haply servo")
            .map_err(|e| service_error(&url, format!("starting the servo thread: {e}")))?;
        Ok(Haply {
            info,
            shared,
            servo,
            stopped: false,
            url,
            device_id,
        })
    }

    /// Zero force for a few ticks, the servo thread stopped, zero sent once more and the
    /// connection closed. Safe to call twice.
    fn stop(&mut self) {
        if self.stopped {
            return;
        }
        self.stopped = true;
        self.shared.set_hold(Hold::Stopping);
        self.shared.wait_ticks(2, Duration::from_millis(50));
        if let Some(mut io) = self.servo.stop() {
            io.zero();
            let _ = io.socket.close(None);
            let _ = io.socket.flush();
        }
    }
}

/// Whether something listens at the service's address (a TCP connection, closed at once; the
/// device is not opened): for `stylet devices`.
pub fn service_listening(url: &str) -> Result<(), HapticError> {
    tcp_connect(url, Duration::from_millis(300)).map(drop)
}

/// A TCP connection to a `ws://` address, with a bounded wait.
fn tcp_connect(url: &str, timeout: Duration) -> Result<TcpStream, HapticError> {
    let request = url.into_client_request().map_err(|e| service_error(url, e))?;
    let uri = request.uri();
    if uri.scheme_str() != Some("ws") {
        return Err(service_error(
            url,
            "only ws:// addresses (the Inverse Service runs on this machine)",
        ));
    }
    let host = uri.host().ok_or_else(|| service_error(url, "no host"))?;
    let port = uri.port_u16().unwrap_or(80);
    let addresses: Vec<_> = (host, port)
        .to_socket_addrs()
        .map_err(|e| service_error(url, e))?
        .collect();
    let mut last = None;
    addresses
        .iter()
        .find_map(|a| TcpStream::connect_timeout(a, timeout).map_err(|e| last = Some(e)).ok())
        .ok_or_else(|| {
            service_error(
                url,
                format!(
                    "cannot connect ({}); is Haply's Inverse Service (Haply Hub) running?",
                    last.map_or("no address".to_string(), |e| e.to_string())
                ),
            )
        })
}

/// Opens the WebSocket (plain `ws://`: the service runs on this machine) with bounded waits and
/// message sizes, and reads the service's inventory.
fn connect(url: &str) -> Result<(WebSocket<TcpStream>, Value), HapticError> {
    let request = url.into_client_request().map_err(|e| service_error(url, e))?;
    let stream = tcp_connect(url, CONNECT_TIMEOUT)?;
    let setup = |e: std::io::Error| service_error(url, e);
    stream.set_nodelay(true).map_err(setup)?;
    stream.set_read_timeout(Some(CONNECT_TIMEOUT)).map_err(setup)?;
    stream.set_write_timeout(Some(CONNECT_TIMEOUT)).map_err(setup)?;
    let config = WebSocketConfig::default()
        .max_message_size(Some(MAX_MESSAGE_BYTES))
        .max_frame_size(Some(MAX_MESSAGE_BYTES));
    let (socket, _) =
        tungstenite::client::client_with_config(request, stream, Some(config)).map_err(|e| service_error(url, e))?;
    let mut io = HaplyIo {
        url: url.to_string(),
        device_id: String::new(),
        socket,
        answer: None,
    };
    let inventory = io.receive()?;
    let stream = io.socket.get_ref();
    stream.set_read_timeout(Some(REPLY_TIMEOUT)).map_err(setup)?;
    stream.set_write_timeout(Some(REPLY_TIMEOUT)).map_err(setup)?;
    Ok((io.socket, inventory))
}

impl HapticDevice for Haply {
    fn info(&self) -> &DeviceInfo {
        &self.info
    }

    fn reading(&self) -> Option<ServoReading> {
        self.shared.readings.latest()
    }

    fn set_force(&self, force_n: DVec3) {
        self.shared.put_force(force_n);
    }

    fn set_hold(&self, hold: Hold) {
        self.shared.set_hold(hold);
    }

    fn counts(&self) -> ServoCounts {
        self.shared.counts()
    }

    fn interval_p99_ms(&self) -> f64 {
        self.shared.interval_percentile_ms(0.99)
    }

    fn fault(&self) -> Option<HapticError> {
        self.shared.fault.get().cloned()
    }

    fn close(mut self: Box<Self>) -> Result<ServoCounts, HapticError> {
        self.stop();
        let counts = self.shared.counts();
        match self.shared.fault.get() {
            Some(e) => Err(e.clone()),
            None => Ok(counts),
        }
    }
}

impl Drop for Haply {
    /// Zero force and the connection closed however the device goes.
    fn drop(&mut self) {
        self.stop();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_state_message_gives_the_cursor_in_mm_and_the_handle_buttons() {
        let m: Value = serde_json::from_str(
            r#"{"session_id": 3,
                "inverse3": [{"device_id": "04C3", "state": {"cursor_position": {"x": 0.1, "y": -0.02, "z": 0.05}}}],
                "wireless_verse_grip": [{"device_id": "1102", "state": {"buttons": {"a": false, "b": true, "c": true}}}]}"#,
        )
        .unwrap();
        let s = parse_state(&m, "04C3").unwrap();
        assert!((s.position_mm - DVec3::new(100.0, -20.0, 50.0)).length() < 1e-9);
        assert_eq!(s.buttons, 0b110);
        let wired: Value =
            serde_json::from_str(r#"{"inverse3": [{"device_id": "A", "state": {"cursor_position": {"x": 0, "y": 0, "z": 0}}}], "verse_grip": [{"state": {"button": true}}]}"#)
                .unwrap();
        assert_eq!(parse_state(&wired, "A").unwrap().buttons, 1);
    }

    #[test]
    fn bad_state_messages_are_named() {
        for (text, want) in [
            (r#"{}"#, "no inverse3 list"),
            (r#"{"inverse3": [{"device_id": "B"}]}"#, "A is no longer listed"),
            (
                r#"{"inverse3": [{"device_id": "A", "state": {}}]}"#,
                "no state.cursor_position",
            ),
            (
                r#"{"inverse3": [{"device_id": "A", "state": {"cursor_position": {"x": 0, "y": "0", "z": 0}}}]}"#,
                "cursor_position.y missing",
            ),
            (
                r#"{"inverse3": [{"device_id": "A", "state": {"cursor_position": {"x": 1e300, "y": 0, "z": 0}}}]}"#,
                "cursor_position.x missing or not a position",
            ),
        ] {
            let e = parse_state(&serde_json::from_str(text).unwrap(), "A")
                .unwrap_err()
                .to_string();
            assert!(e.contains(want), "{text}: {e}");
        }
    }

    #[test]
    fn the_force_command_is_the_services_3_5_wire_format() {
        let v: Value = serde_json::from_str(&force_command("049D", DVec3::new(0.0, 0.5, 1.5))).unwrap();
        assert_eq!(v["inverse3"][0]["device_id"], "049D");
        assert_eq!(v["inverse3"][0]["commands"]["set_cursor_force"]["vector"]["z"], 1.5);
        assert_eq!(v["inverse3"][0]["commands"]["set_cursor_force"]["vector"]["y"], 0.5);
    }

    #[test]
    fn no_service_is_a_message_naming_the_address() {
        // A port nothing listens on: a closed port on this machine refuses at once.
        let free = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let url = format!("ws://127.0.0.1:{}", free.local_addr().unwrap().port());
        drop(free);
        let e = Haply::open(Some(&url)).err().unwrap().to_string();
        assert!(e.starts_with(&format!("haply: {url}: cannot connect")), "{e}");
        assert!(e.contains("Inverse Service"), "{e}");
        let e = Haply::open(Some("wss://localhost:10001")).err().unwrap().to_string();
        assert!(e.contains("only ws://"), "{e}");
    }
}
