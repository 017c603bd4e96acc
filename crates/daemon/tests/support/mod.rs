//! The daemon in-process for the integration tests: [`btfrig_daemon::router`] on a free
//! loopback port with an auth file of a viewer and an operator, driven over plain HTTP/1.0
//! (the body ends with the connection, so no client crate is needed).

#![allow(dead_code)] // each test binary uses a part

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use btfrig_daemon::{AppState, ServeConfig};
use serde_json::{json, Value};

const AUTH: &str = r#"
[[token]]
name = "viewer"
token = "viewer-token"
role = "viewer"
[[token]]
name = "ada"
token = "operator-ada"
role = "operator"
"#;

/// A file of the repository.
pub fn repo(rel: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..").join(rel)
}

/// A shipped plan's text (`rig-configs/plans/<name>.toml`).
pub fn plan_file(name: &str) -> String {
    std::fs::read_to_string(repo(&format!("rig-configs/plans/{name}.toml"))).unwrap()
}

/// An HTTP response.
pub struct Response {
    pub status: u16,
    pub content_type: Option<String>,
    /// Every header, names in lower case.
    pub headers: Vec<(String, String)>,
    pub body: Vec<u8>,
}

impl Response {
    pub fn json(&self) -> Value {
        serde_json::from_slice(&self.body)
            .unwrap_or_else(|e| panic!("not JSON ({e}): {}", String::from_utf8_lossy(&self.body)))
    }

    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers.iter().find(|(k, _)| k == name).map(|(_, v)| v.as_str())
    }

    pub fn text(&self) -> String {
        String::from_utf8_lossy(&self.body).into_owned()
    }
}

/// A daemon on a free loopback port (`rig`: a rig config of the repository, or the embedded
/// gonioreflectometer), with its embedded plans; it serves until the test process ends.
pub struct Daemon {
    pub port: u16,
    pub data: PathBuf,
    /// What the handlers share (e.g. for what `serve` does on SIGTERM:
    /// `state.runs.interrupt_and_wait(Signal::Term)`).
    pub state: Arc<AppState>,
}

impl Daemon {
    pub fn start(name: &str, rig: Option<&str>) -> Daemon {
        Daemon::start_with(name, rig, btfrig_daemon::server::HEADER_READ_TIMEOUT)
    }

    /// [`Daemon::start`] with another header-read timeout.
    pub fn start_with(name: &str, rig: Option<&str>, header_read_timeout: Duration) -> Daemon {
        Daemon::start_limits(name, rig, header_read_timeout, btfrig_daemon::plan_jobs::PLAN_JOB_TIME_LIMIT)
    }

    /// [`Daemon::start`] with another header-read timeout and plan-job time limit.
    pub fn start_limits(
        name: &str,
        rig: Option<&str>,
        header_read_timeout: Duration,
        plan_job_time_limit: Duration,
    ) -> Daemon {
        // The device backends runs open rigs with, as the btfrig binary installs them.
        btfrig_sim_backend::install();
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("auth.toml"), AUTH).unwrap();
        let cfg = ServeConfig {
            rig: rig.map(repo),
            listen: "127.0.0.1:0".parse().unwrap(),
            data: dir.join("data"),
            auth: Some(dir.join("auth.toml")),
            plans: None,
            header_read_timeout,
            plan_job_time_limit,
        };
        let (state, _) = AppState::load(&cfg).unwrap_or_else(|e| panic!("{e}"));
        let state = Arc::new(state);
        let app = btfrig_daemon::router(state.clone());
        let (tx, rx) = std::sync::mpsc::channel();
        let cfg_timeout = cfg.header_read_timeout;
        std::thread::spawn(move || {
            let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().unwrap();
            rt.block_on(async move {
                let l = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
                tx.send(l.local_addr().unwrap().port()).unwrap();
                // The daemon's own connection handling (limits, problem documents for hyper's
                // refusals), as `serve` runs it.
                let forever = std::future::pending::<()>();
                btfrig_daemon::server::serve_connections(l, app, cfg_timeout, forever).await.unwrap();
            });
        });
        Daemon { port: rx.recv().unwrap(), data: cfg.data, state }
    }

    fn send(&self, method: &str, path: &str, token: &str, body: Option<&Value>) -> BufReader<TcpStream> {
        let mut s = TcpStream::connect(("127.0.0.1", self.port)).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(300))).unwrap();
        let mut req = format!("{method} {path} HTTP/1.0\r\nHost: 127.0.0.1\r\nAuthorization: Bearer {token}\r\n");
        match body {
            Some(b) => {
                let b = b.to_string();
                req.push_str(&format!("Content-Type: application/json\r\nContent-Length: {}\r\n\r\n{b}", b.len()));
            }
            None => req.push_str("\r\n"),
        }
        s.write_all(req.as_bytes()).unwrap();
        BufReader::new(s)
    }

    /// Reads the status line and headers.
    fn head(r: &mut BufReader<TcpStream>) -> (u16, Vec<(String, String)>) {
        let mut line = String::new();
        r.read_line(&mut line).unwrap();
        let status = line.split_whitespace().nth(1).and_then(|s| s.parse().ok()).expect("a status line");
        let mut headers = Vec::new();
        loop {
            line.clear();
            r.read_line(&mut line).unwrap();
            let l = line.trim_end();
            if l.is_empty() {
                break;
            }
            if let Some((k, v)) = l.split_once(':') {
                headers.push((k.trim().to_ascii_lowercase(), v.trim().to_string()));
            }
        }
        (status, headers)
    }

    /// One HTTP/1.0 request (the body ends with the connection).
    pub fn request(&self, method: &str, path: &str, token: &str, body: Option<&Value>) -> Response {
        let mut r = self.send(method, path, token, body);
        let (status, headers) = Self::head(&mut r);
        let content_type = headers.iter().find(|(k, _)| k == "content-type").map(|(_, v)| v.clone());
        let mut body = Vec::new();
        r.read_to_end(&mut body).unwrap();
        Response { status, content_type, headers, body }
    }

    /// A GET as the viewer that must answer 200 with JSON.
    pub fn get(&self, path: &str) -> Value {
        let r = self.request("GET", path, "viewer-token", None);
        assert_eq!(r.status, 200, "GET {path}: {}", r.text());
        r.json()
    }

    /// A POST as the operator.
    pub fn post(&self, path: &str, body: Option<&Value>) -> Response {
        self.request("POST", path, "operator-ada", body)
    }

    /// `POST /api/v1/plans/{what}` (validate or dry-run): always 200 with a plan check.
    pub fn check(&self, what: &str, body: Value) -> Value {
        let r = self.request("POST", &format!("/api/v1/plans/{what}"), "viewer-token", Some(&body));
        assert_eq!(r.status, 200, "{what}: {}", r.text());
        r.json()
    }

    /// A request (as the operator) that must be refused with `status` and a problem document.
    pub fn problem_doc(&self, method: &str, path: &str, body: Option<&Value>, status: u16) -> Value {
        let r = self.request(method, path, "operator-ada", body);
        let text = r.text();
        assert_eq!(r.status, status, "{method} {path}: {text}");
        assert_eq!(r.content_type.as_deref(), Some("application/problem+json"), "{text}");
        let p = r.json();
        assert_eq!(p["status"].as_u64(), Some(u64::from(status)), "{p}");
        p
    }

    /// [`Daemon::problem_doc`]'s detail.
    pub fn problem(&self, method: &str, path: &str, body: Option<&Value>, status: u16) -> String {
        self.problem_doc(method, path, body, status)["detail"].as_str().unwrap().to_string()
    }

    /// `POST /api/v1/runs` that must be refused with 422: the problem's detail.
    pub fn refused_start(&self, body: Value) -> String {
        let runs_before = self.get("/api/v1/runs")["runs"].as_array().unwrap().len();
        let p = self.problem_doc("POST", "/api/v1/runs", Some(&body), 422);
        assert_eq!(p["title"], "Unprocessable Entity", "{p}");
        let runs = self.get("/api/v1/runs");
        assert_eq!(runs["runs"].as_array().unwrap().len(), runs_before, "a refused start starts no run: {runs}");
        p["detail"].as_str().unwrap().to_string()
    }

    /// The event stream of run `id` on a thread of its own, from now until its `end` event:
    /// every `(event, data)` in order.
    pub fn events(&self, id: &str) -> std::thread::JoinHandle<Vec<(String, Value)>> {
        let mut r = self.send("GET", &format!("/api/v1/runs/{id}/events"), "viewer-token", None);
        std::thread::spawn(move || {
            let (status, _) = Self::head(&mut r);
            assert_eq!(status, 200);
            let (mut out, mut event, mut line) = (Vec::new(), String::new(), String::new());
            loop {
                line.clear();
                if r.read_line(&mut line).unwrap() == 0 {
                    return out;
                }
                let l = line.trim_end();
                if let Some(e) = l.strip_prefix("event:") {
                    event = e.trim().to_string();
                } else if let Some(d) = l.strip_prefix("data:") {
                    let end = event == "end";
                    out.push((std::mem::take(&mut event), serde_json::from_str(d.trim()).unwrap_or(json!(d.trim()))));
                    if end {
                        return out;
                    }
                }
            }
        })
    }
}
