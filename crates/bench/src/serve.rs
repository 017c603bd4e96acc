//! Helpers of `btfrig bench serve` (a simulated run through `btfrig serve`, alternately
//! without load and with a second process sending status requests at a fixed rate): the
//! HTTP client, the run driver and the CPU-time probe. The CLI starts the processes and
//! prints the figures.
//!
//! The load is open-loop: request k is due at k / rate seconds and its latency is measured
//! from when it was due, so a stalled server cannot hide its stall by slowing the sender
//! (coordinated omission). Requests use keep-alive HTTP/1.1 connections, one per sender thread.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};

pub const AUTH: &str = "[[token]]\nname = \"bench\"\ntoken = \"bench-operator-token\"\nrole = \"operator\"\n";
pub const TOKEN: &str = "bench-operator-token";

/// User + system CPU seconds of process `pid` so far (Linux `/proc/PID/stat`).
pub fn cpu_s(pid: &str) -> Option<f64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // Fields after the command name (which may hold spaces) : state is field 3, utime 14, stime 15.
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0) // USER_HZ is 100 on Linux
}

/// Starts the plan, waits for it to finish, returns the runner's wall time of the session.
pub fn run_once(port: u16, plan: &str, dataset: &str) -> anyhow::Result<f64> {
    let body = serde_json::json!({ "plan_text": plan, "dataset": dataset }).to_string();
    let mut c = Conn::open(port, TOKEN)?;
    let (status, text) = c.call("POST", "/api/v1/runs", Some(&body))?;
    if status != 201 {
        bail!("starting the run: {status} {text}");
    }
    let id = serde_json::from_str::<serde_json::Value>(&text)?["id"].as_str().unwrap_or_default().to_string();
    loop {
        std::thread::sleep(Duration::from_millis(250));
        let (_, text) = c.call("GET", &format!("/api/v1/runs/{id}"), None)?;
        let v: serde_json::Value = serde_json::from_str(&text)?;
        match v["state"].as_str() {
            Some("finished") => return v["summary"]["wall_s"].as_f64().context("summary.wall_s"),
            Some("failed" | "aborted" | "interrupted") => bail!("the run ended {}: {}", v["state"], v["message"]),
            _ => {}
        }
    }
}

/// One keep-alive HTTP/1.1 connection.
pub struct Conn {
    r: BufReader<TcpStream>,
    w: TcpStream,
    token: String,
}

impl Conn {
    pub fn open(port: u16, token: &str) -> anyhow::Result<Conn> {
        let s = TcpStream::connect(("127.0.0.1", port))?;
        s.set_nodelay(true)?;
        s.set_read_timeout(Some(Duration::from_secs(30)))?;
        Ok(Conn { r: BufReader::new(s.try_clone()?), w: s, token: token.to_string() })
    }

    pub fn call(&mut self, method: &str, path: &str, body: Option<&str>) -> anyhow::Result<(u16, String)> {
        let mut req =
            format!("{method} {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer {}\r\n", self.token);
        match body {
            Some(b) => {
                req.push_str(&format!("Content-Type: application/json\r\nContent-Length: {}\r\n\r\n{b}", b.len()))
            }
            None => req.push_str("\r\n"),
        }
        self.w.write_all(req.as_bytes())?;
        let mut line = String::new();
        self.r.read_line(&mut line)?;
        let status: u16 = line
            .split_whitespace()
            .nth(1)
            .and_then(|s| s.parse().ok())
            .with_context(|| format!("status line {line:?}"))?;
        let mut len = 0usize;
        loop {
            line.clear();
            self.r.read_line(&mut line)?;
            let l = line.trim_end();
            if l.is_empty() {
                break;
            }
            if let Some((k, v)) = l.split_once(':') {
                if k.eq_ignore_ascii_case("content-length") {
                    len = v.trim().parse().unwrap_or(0);
                }
            }
        }
        let mut buf = vec![0; len];
        self.r.read_exact(&mut buf)?;
        Ok((status, String::from_utf8_lossy(&buf).into_owned()))
    }
}

/// What [`send_open_loop`] measured.
#[derive(Debug, Clone)]
pub struct LoadStats {
    /// Latency of each answered request (200 or 404) from when it was due, milliseconds, sorted.
    pub latencies_ms: Vec<f64>,
    /// Requests that failed (the connection is reopened after each).
    pub errors: u64,
    /// Seconds from the start to when the last sender stopped.
    pub seconds: f64,
}

/// Sends `GET path` open-loop at `rate` requests per second in total over `connections`
/// keep-alive connections to `127.0.0.1:port` until `stop` is set.
pub fn send_open_loop(
    port: u16,
    token: &str,
    path: &str,
    rate: f64,
    connections: usize,
    stop: &std::sync::Arc<std::sync::atomic::AtomicBool>,
) -> anyhow::Result<LoadStats> {
    let start = Instant::now();
    let per_thread = rate / connections as f64;
    let threads: Vec<_> = (0..connections)
        .map(|k| {
            let (stop, path, token) = (stop.clone(), path.to_string(), token.to_string());
            std::thread::spawn(move || -> (Vec<f64>, u64) {
                let mut lat = Vec::new();
                let mut errors = 0;
                let Ok(mut c) = Conn::open(port, &token) else { return (lat, 1) };
                // Thread k starts k / rate late, so the threads' requests interleave evenly.
                let offset = k as f64 / rate;
                let mut i = 0u64;
                while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                    let due = start + Duration::from_secs_f64(offset + i as f64 / per_thread);
                    if let Some(wait) = due.checked_duration_since(Instant::now()) {
                        std::thread::sleep(wait);
                    }
                    match c.call("GET", &path, None) {
                        Ok((200 | 404, _)) => lat.push(due.elapsed().as_secs_f64() * 1e3),
                        _ => {
                            errors += 1;
                            if let Ok(n) = Conn::open(port, &token) {
                                c = n;
                            }
                        }
                    }
                    i += 1;
                }
                (lat, errors)
            })
        })
        .collect();
    let mut lat = Vec::new();
    let mut errors = 0;
    for t in threads {
        let (l, e) = t.join().map_err(|_| anyhow::anyhow!("a sender thread panicked"))?;
        lat.extend(l);
        errors += e;
    }
    let secs = start.elapsed().as_secs_f64();
    lat.sort_by(|a, b| a.total_cmp(b));
    Ok(LoadStats { latencies_ms: lat, errors, seconds: secs })
}
