//! Attacks on the service as the hardening and load tests run them: uploads of junk behind a
//! valid header, slow uploads, slow headers, and a probe of `/healthz` on new connections.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

use super::Auth;

/// The first bytes of a session file, through its header record: what the server needs to
/// authorise an upload.
pub fn header_prefix(file: &[u8]) -> Vec<u8> {
    let n = (8..=file.len())
        .find(|&n| matches!(stylet_recorder::reader::read_header_prefix(&file[..n]), Ok(Some(_))))
        .unwrap();
    file[..n].to_vec()
}

/// The request head of an upload of `len` bytes by `auth`.
pub fn upload_head(addr: &str, auth: &Auth, len: u64) -> String {
    let credentials = match auth {
        Auth::Cookie { token, csrf } => format!("Cookie: stylet_session={token}\r\nX-CSRF-Token: {csrf}\r\n"),
        Auth::Bearer(t) => format!("Authorization: Bearer {t}\r\n"),
    };
    format!(
        "POST /api/sessions HTTP/1.1\r\nHost: {addr}\r\n{credentials}Content-Type: application/octet-stream\r\n\
         Content-Length: {len}\r\nConnection: close\r\n\r\n"
    )
}

/// The status and headers of a raw HTTP answer.
pub fn status_of(answer: &[u8]) -> (u16, String) {
    let text = String::from_utf8_lossy(answer).to_string();
    let status = text.split_whitespace().nth(1).and_then(|c| c.parse().ok()).unwrap_or(0);
    (status, text)
}

/// An upload of `len` bytes: `head` (a real session's first bytes), then zeros, written as fast
/// as the server takes them until it answers or the body is sent; returns the answer.
pub fn junk_upload(addr: &str, auth: &Auth, head: &[u8], len: u64) -> (u16, String) {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(120))).unwrap();
    s.write_all(upload_head(addr, auth, len).as_bytes()).unwrap();
    let mut sent = 0u64;
    let zeros = vec![0u8; 256 << 10];
    if s.write_all(head).is_ok() {
        sent += head.len() as u64;
        while sent < len {
            let n = (len - sent).min(zeros.len() as u64) as usize;
            if s.write_all(&zeros[..n]).is_err() {
                break; // answered and closed early
            }
            sent += n as u64;
        }
    }
    let mut answer = Vec::new();
    let _ = s.read_to_end(&mut answer);
    status_of(&answer)
}

/// Latency of `/healthz` on a new connection each time (ms; 5000 when there was no answer in
/// 5 s): what a load balancer sees.
pub fn healthz_ms(addr: &str) -> f64 {
    let t0 = Instant::now();
    let answered = (|| -> std::io::Result<bool> {
        let mut s = TcpStream::connect_timeout(&addr.parse().unwrap(), Duration::from_secs(5))?;
        s.set_read_timeout(Some(Duration::from_secs(5)))?;
        s.write_all(b"GET /healthz HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")?;
        let mut answer = Vec::new();
        s.read_to_end(&mut answer)?;
        Ok(status_of(&answer).0 == 200)
    })();
    match answered {
        Ok(true) => t0.elapsed().as_secs_f64() * 1e3,
        _ => 5000.0,
    }
}

/// Probes `/healthz` every 50 ms on a thread until `stop`; returns the latencies, sorted.
pub fn probe_healthz(
    addr: String,
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
) -> std::thread::JoinHandle<Vec<f64>> {
    std::thread::spawn(move || {
        let mut ms = Vec::new();
        while !stop.load(std::sync::atomic::Ordering::Relaxed) {
            ms.push(healthz_ms(&addr));
            std::thread::sleep(Duration::from_millis(50));
        }
        ms.sort_by(f64::total_cmp);
        ms
    })
}

pub fn p99(sorted: &[f64]) -> f64 {
    sorted[((sorted.len() as f64 - 1.0) * 0.99).round() as usize]
}

/// Raises this process's open-file limit to its hard limit (the attacks open hundreds of sockets).
pub fn more_files() {
    use rustix::process::{Resource, getrlimit, setrlimit};
    let mut l = getrlimit(Resource::Nofile);
    l.current = l.maximum;
    let _ = setrlimit(Resource::Nofile, l);
}
