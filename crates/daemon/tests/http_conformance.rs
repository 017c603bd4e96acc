//! Issue 24, item 7: the daemon's HTTP conformance as the probe found it. Half-sent requests
//! were held for ever (no header-read timeout); `[null, null]` bodies got 200; non-ASCII
//! dataset names got 400 although the schema allowed them; 414 and 431 answers had empty
//! bodies. Each test replays the probe against the daemon in-process (the router under
//! `server::serve_connections`, as `btfrig serve` runs it) and checks the fixed behaviour.

mod support;

use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

use serde_json::{json, Value};
use support::Daemon;

/// Sends `raw` bytes as they are and reads the answer to the end of the connection:
/// (status, content type, body).
fn raw(port: u16, raw: &[u8]) -> (u16, Option<String>, Vec<u8>) {
    let mut s = TcpStream::connect(("127.0.0.1", port)).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(60))).unwrap();
    // The daemon may answer and close before it has read everything (a head over its limit).
    let _ = s.write_all(raw);
    let mut bytes = Vec::new();
    let _ = s.read_to_end(&mut bytes);
    let text = String::from_utf8_lossy(&bytes).into_owned();
    let (head, _) = text.split_once("\r\n\r\n").unwrap_or_else(|| panic!("no answer head: {text:?}"));
    let status = head.split_whitespace().nth(1).and_then(|s| s.parse().ok()).unwrap_or_else(|| panic!("{head}"));
    let content_type = head
        .lines()
        .find_map(|l| l.split_once(':').filter(|(k, _)| k.eq_ignore_ascii_case("content-type")))
        .map(|(_, v)| v.trim().to_string());
    let body_at = bytes.windows(4).position(|w| w == b"\r\n\r\n").unwrap() + 4;
    (status, content_type, bytes[body_at..].to_vec())
}

/// A problem document with `status`; its detail.
fn problem(answer: (u16, Option<String>, Vec<u8>), status: u16, what: &str) -> String {
    let (got, ct, body) = answer;
    let text = String::from_utf8_lossy(&body).into_owned();
    assert_eq!(got, status, "{what}: {text:?}");
    assert_eq!(ct.as_deref(), Some("application/problem+json"), "{what}: {text:?}");
    let p: Value = serde_json::from_slice(&body).unwrap_or_else(|e| panic!("{what}: not JSON ({e}): {text:?}"));
    assert_eq!(p["status"], status, "{what}: {p}");
    p["detail"].as_str().unwrap().to_string()
}

/// 1,000 connections that stop in the middle of a request head (or send nothing) are all
/// closed by the daemon after its header-read timeout, and a whole request is answered while
/// they are open. The wait is for the close (EOF or reset) with a generous bound, not a time.
#[test]
fn r24_half_sent_requests_are_closed_after_the_header_read_timeout() {
    let d = Daemon::start_with("r24-header-timeout", None, Duration::from_secs(1));
    let partial: [&[u8]; 4] = [
        b"",
        b"GET /api/v1/ri",
        b"GET /api/v1/rig HTTP/1.1\r\nHost: 127.0.0.1\r\n",
        b"POST /api/v1/plans/validate HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Ty",
    ];
    let mut held = Vec::new();
    for i in 0..1000 {
        let mut s = TcpStream::connect(("127.0.0.1", d.port)).unwrap();
        s.write_all(partial[i % partial.len()]).unwrap();
        held.push(s);
    }
    let health = d.request("GET", "/healthz", "", None);
    assert_eq!(health.status, 200, "a whole request while 1,000 half-sent ones are open: {}", health.text());
    let t0 = Instant::now();
    for (i, mut s) in held.into_iter().enumerate() {
        // Generous: the timeout is 1 s; a daemon that holds the connection fails here.
        let left = Duration::from_secs(60).saturating_sub(t0.elapsed()).max(Duration::from_millis(1));
        s.set_read_timeout(Some(left)).unwrap();
        let mut buf = [0u8; 256];
        match s.read(&mut buf) {
            Ok(0) => {}
            Err(e) if e.kind() == std::io::ErrorKind::ConnectionReset => {}
            Ok(n) => {
                panic!("connection {i}: the daemon answered a half-sent head: {:?}", String::from_utf8_lossy(&buf[..n]))
            }
            Err(e) => panic!("connection {i} ({:?}) still open after 60 s: {e}", partial[i % partial.len()]),
        }
    }
    // The daemon still serves.
    assert_eq!(d.request("GET", "/healthz", "", None).status, 200);
}

/// `[null, null]` (and any body that is not an object) was taken as a struct with two absent
/// fields and answered 200; now 422 with a problem document, and no run starts.
#[test]
fn r24_json_bodies_that_are_not_objects_are_refused() {
    let d = Daemon::start("r24-body-object", None);
    for body in [json!([null, null]), json!(["demo", null]), json!(null), json!("demo"), json!(7), json!(true)] {
        for path in ["/api/v1/plans/validate", "/api/v1/plans/dry-run"] {
            let p = d.problem_doc("POST", path, Some(&body), 422);
            let detail = p["detail"].as_str().unwrap();
            assert!(detail.contains("must be a JSON object"), "{path} {body}: {detail}");
        }
        let e = d.refused_start(body.clone());
        assert!(e.contains("must be a JSON object"), "{body}: {e}");
    }
    // An object is still taken, with its problems in the plan check.
    let c = d.check("validate", json!({}));
    assert_eq!(c["valid"], false, "{c}");
    let c = d.check("validate", json!({ "plan": "demo" }));
    assert_eq!(c["valid"], true, "{c}");
}

/// Dataset names of any script (the schema allowed them; the daemon said 400) start runs and
/// are served; a path, a leading '.', a control character or a name too long is refused
/// with what is allowed.
#[test]
fn r24_unicode_dataset_names_are_accepted_and_paths_refused() {
    let d = Daemon::start("r24-unicode-names", None);
    let name = "façade-Ω-測定 ü";
    let r = d.post("/api/v1/runs", Some(&json!({ "plan": "demo", "dataset": name })));
    assert_eq!(r.status, 201, "{}", r.text());
    let id = r.json()["id"].as_str().unwrap().to_string();
    assert_eq!(r.json()["dataset"], name, "{}", r.text());
    let t0 = Instant::now();
    loop {
        let s = d.get(&format!("/api/v1/runs/{id}"));
        if ["finished", "aborted", "interrupted", "failed"].contains(&s["state"].as_str().unwrap()) {
            assert_eq!(s["state"], "finished", "{s}");
            break;
        }
        assert!(t0.elapsed() < Duration::from_secs(300), "run {id} not over after 300 s: {s}");
        std::thread::sleep(Duration::from_millis(100));
    }
    assert!(d.data.join(name).join("manifest.json").is_file(), "the dataset is DATA/{name}");
    let encoded: String = name.bytes().map(|b| format!("%{b:02X}")).collect();
    let manifest = d.get(&format!("/api/v1/datasets/{encoded}"));
    assert!(manifest["plan"]["text"].as_str().unwrap().contains("name = \"demo\""), "{manifest}");
    let list = d.get("/api/v1/datasets");
    assert!(list["datasets"].as_array().unwrap().iter().any(|e| e["name"] == name), "{list}");

    let long = "ж".repeat(64);
    for (bad, why) in [
        ("../x", "'.'"),
        ("a/b", "'/'"),
        (".hidden", "'.'"),
        ("a\nb", "'\\n'"),
        ("nul\0", "'\\0'"),
        ("back\\slash", "'\\\\'"),
        ("", "empty"),
        (long.as_str(), "64 characters"),
    ] {
        let e = d.refused_start(json!({ "plan": "demo", "dataset": bad }));
        assert!(e.contains(why) && e.contains("1 to 63") && e.contains("any script"), "{bad:?}: {e}");
    }
    // The same rule for the path parameter (400: it is not a name at all).
    let e = d.problem("GET", "/api/v1/datasets/.hidden", None, 400);
    assert!(e.contains("starts with '.'"), "{e}");
}

/// hyper refused over-long or unparsable heads with an empty body; every such answer is now
/// a problem document naming the limit.
#[test]
fn r24_uri_too_long_and_header_fields_too_large_are_problem_documents() {
    use btfrig_daemon::server::{MAX_HEADERS, MAX_HEADER_BYTES, MAX_HEAD_BYTES, MAX_URI_BYTES};
    let d = Daemon::start("r24-head-limits", None);
    let get = |target: &str, headers: &str| {
        format!("GET {target} HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer viewer-token\r\n{headers}\r\n")
    };
    // Over the daemon's target limit, within hyper's head limit: the router's 414.
    let target = format!("/api/v1/runs/{}", "x".repeat(MAX_URI_BYTES));
    let e = problem(raw(d.port, get(&target, "").as_bytes()), 414, "a 8 KiB target");
    assert!(e.contains(&MAX_URI_BYTES.to_string()) && e.contains("\"Connection limits\""), "names the limit: {e}");
    // Over hyper's limits: its own 414 and 431 (empty bodies), rewritten.
    let target = format!("/api/v1/runs/{}", "x".repeat(MAX_HEAD_BYTES + 10));
    let e = problem(raw(d.port, get(&target, "").as_bytes()), 414, "a 64 KiB target");
    assert!(e.contains("is too long") && e.contains(&MAX_URI_BYTES.to_string()), "hyper's 414: {e}");
    let many: String = (0..MAX_HEADERS + 20).map(|i| format!("X-H{i}: {i}\r\n")).collect();
    let e = problem(raw(d.port, get("/api/v1/rig", &many).as_bytes()), 431, "120 headers");
    assert!(e.contains(&MAX_HEADERS.to_string()), "{e}");
    // Over the daemon's header limit, within hyper's buffer: the router's 431.
    let big = format!("X-Big: {}\r\n", "y".repeat(MAX_HEADER_BYTES));
    let e = problem(raw(d.port, get("/api/v1/rig", &big).as_bytes()), 431, "a 32 KiB header");
    assert!(e.contains("headers have") && e.contains(&MAX_HEADER_BYTES.to_string()), "{e}");
    // Far over hyper's buffer: hyper's 431, rewritten.
    let huge = format!("X-Huge: {}\r\n", "y".repeat(4 * MAX_HEAD_BYTES));
    let e = problem(raw(d.port, get("/api/v1/rig", &huge).as_bytes()), 431, "a 256 KiB header");
    assert!(e.contains("head is too large") && e.contains(&MAX_HEADER_BYTES.to_string()), "hyper's 431: {e}");
    // Not HTTP: hyper's 400, rewritten.
    let e = problem(raw(d.port, b"GARBAGE\x01 / HTTP/1.1\r\n\r\n"), 400, "a request line that does not parse");
    assert!(e.contains("does not parse"), "{e}");
    // Within the limits nothing changes: answers keep their own bodies.
    let (status, ct, body) = raw(d.port, get("/api/v1/rig", "Connection: close\r\n").as_bytes());
    assert_eq!((status, ct.as_deref()), (200, Some("application/json")), "{}", String::from_utf8_lossy(&body));
}
