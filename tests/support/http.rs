//! A minimal HTTP/1.0 client over std's TcpStream for the daemon's tests: HTTP/1.0 so every
//! response (also the event stream) is plain bytes to the end of the connection, no chunking.

#![allow(dead_code)]

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::process::{Child, Stdio};
use std::time::{Duration, Instant};

pub struct Response {
    pub status: u16,
    pub headers: Vec<(String, String)>,
    pub body: Vec<u8>,
}

impl Response {
    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers.iter().find(|(k, _)| k.eq_ignore_ascii_case(name)).map(|(_, v)| v.as_str())
    }
    pub fn json(&self) -> serde_json::Value {
        serde_json::from_slice(&self.body)
            .unwrap_or_else(|e| panic!("not JSON ({e}): {}", String::from_utf8_lossy(&self.body)))
    }
    pub fn text(&self) -> String {
        String::from_utf8_lossy(&self.body).into_owned()
    }
}

fn connect(port: u16) -> TcpStream {
    let s = TcpStream::connect(("127.0.0.1", port)).expect("connect to the daemon");
    s.set_read_timeout(Some(Duration::from_secs(120))).unwrap();
    s
}

fn write_request(s: &mut TcpStream, method: &str, path: &str, token: Option<&str>, body: Option<&str>) {
    let mut req = format!("{method} {path} HTTP/1.0\r\nHost: 127.0.0.1\r\n");
    if let Some(t) = token {
        req.push_str(&format!("Authorization: Bearer {t}\r\n"));
    }
    if let Some(b) = body {
        req.push_str(&format!("Content-Type: application/json\r\nContent-Length: {}\r\n\r\n{b}", b.len()));
    } else {
        req.push_str("\r\n");
    }
    s.write_all(req.as_bytes()).unwrap();
}

fn read_head(r: &mut BufReader<TcpStream>) -> (u16, Vec<(String, String)>) {
    let mut line = String::new();
    r.read_line(&mut line).unwrap();
    let status: u16 =
        line.split_whitespace().nth(1).and_then(|s| s.parse().ok()).unwrap_or_else(|| panic!("status line {line:?}"));
    let mut headers = Vec::new();
    loop {
        line.clear();
        r.read_line(&mut line).unwrap();
        let l = line.trim_end();
        if l.is_empty() {
            break;
        }
        if let Some((k, v)) = l.split_once(':') {
            headers.push((k.trim().to_string(), v.trim().to_string()));
        }
    }
    (status, headers)
}

pub fn request(port: u16, method: &str, path: &str, token: Option<&str>, body: Option<&str>) -> Response {
    let mut s = connect(port);
    write_request(&mut s, method, path, token, body);
    let mut r = BufReader::new(s);
    let (status, headers) = read_head(&mut r);
    let mut body = Vec::new();
    r.read_to_end(&mut body).unwrap();
    Response { status, headers, body }
}

/// An open event stream: (event name, data) pairs as they arrive.
pub struct EventStream {
    reader: BufReader<TcpStream>,
    pub status: u16,
}

impl EventStream {
    pub fn open(port: u16, path: &str, token: &str) -> EventStream {
        let mut s = connect(port);
        write_request(&mut s, "GET", path, Some(token), None);
        let mut reader = BufReader::new(s);
        let (status, _) = read_head(&mut reader);
        EventStream { reader, status }
    }

    /// The next event, or `None` at the end of the stream.
    pub fn next_event(&mut self) -> Option<(String, String)> {
        let (mut name, mut data) = (String::new(), String::new());
        let mut line = String::new();
        loop {
            line.clear();
            if self.reader.read_line(&mut line).ok()? == 0 {
                return None;
            }
            let l = line.trim_end_matches(['\r', '\n']);
            if l.is_empty() {
                if !name.is_empty() || !data.is_empty() {
                    return Some((name, data));
                }
                continue;
            }
            if let Some(v) = l.strip_prefix("event:") {
                name = v.trim().to_string();
            } else if let Some(v) = l.strip_prefix("data:") {
                data.push_str(v.trim_start());
            }
        }
    }
}

/// A running `btfrig serve` on a free loopback port; killed on drop.
pub struct Daemon {
    pub child: Child,
    pub port: u16,
}

impl Daemon {
    pub fn start(args: &[&str]) -> Daemon {
        let mut child = super::btfrig()
            .arg("serve")
            .args(["--listen", "127.0.0.1:0"])
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("start btfrig serve");
        let mut first = String::new();
        BufReader::new(child.stdout.take().unwrap()).read_line(&mut first).unwrap();
        let port = first
            .trim()
            .rsplit(':')
            .next()
            .and_then(|p| p.parse().ok())
            .unwrap_or_else(|| panic!("first line of btfrig serve: {first:?}"));
        Daemon { child, port }
    }

    pub fn get(&self, path: &str, token: &str) -> Response {
        request(self.port, "GET", path, Some(token), None)
    }

    pub fn post(&self, path: &str, token: &str, body: &str) -> Response {
        request(self.port, "POST", path, Some(token), Some(body))
    }

    /// Polls the run until `pred` holds on its status (or panics after `secs`).
    pub fn wait_run(
        &self,
        id: &str,
        token: &str,
        secs: u64,
        what: &str,
        pred: impl Fn(&serde_json::Value) -> bool,
    ) -> serde_json::Value {
        let t0 = Instant::now();
        loop {
            let s = self.get(&format!("/api/v1/runs/{id}"), token).json();
            if pred(&s) {
                return s;
            }
            assert!(t0.elapsed().as_secs() < secs, "run {id}: not {what} after {secs} s: {s}");
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// SIGTERM, then the exit status.
    pub fn terminate(mut self) -> std::process::ExitStatus {
        let pid = self.child.id().to_string();
        assert!(std::process::Command::new("kill").args(["-TERM", &pid]).status().unwrap().success());
        let t0 = Instant::now();
        loop {
            if let Some(s) = self.child.try_wait().unwrap() {
                return s;
            }
            assert!(t0.elapsed().as_secs() < 120, "btfrig serve did not exit within 120 s of SIGTERM");
            std::thread::sleep(Duration::from_millis(100));
        }
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Tokens of the daemon tests that start `btfrig serve` with `--auth`: a viewer, two
/// operators (ada, bob) and an admin.
pub const AUTH: &str = r#"
[[token]]
name = "viewer"
token = "viewer-token"
role = "viewer"
[[token]]
name = "ada"
token = "operator-ada"
role = "operator"
[[token]]
name = "bob"
token = "operator-bob"
role = "operator"
[[token]]
name = "root"
token = "admin-token"
role = "admin"
"#;
