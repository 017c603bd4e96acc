//! `btfrig serve` on the simulated rig, driven through its HTTP API only: a whole small run
//! (start, events, pause, resume, completion, dataset download), tokens and roles on every
//! write endpoint (401, 403, 409), and SIGTERM pausing a run resumably.

mod support;

use std::time::Duration;

use support::http::{request, Daemon, EventStream, AUTH};
use support::{read_journal, scratch};

/// A small plan on the embedded rig: `n` captures of 32-texel textures.
fn plan(n: usize) -> String {
    format!(
        r#"name = "serve-test"
description = "small plan for the daemon tests"
[rig]
config = "builtin:bonn-gonio-sim"
material = "corduroy"
seed = 11
[sampling]
light = {{ preset = "bonn81", theta_max_deg = 30 }}
view = {{ preset = "bonn81", theta_max_deg = 30 }}
[texture]
size = 32
region = {{ u = [0.25, 0.75], v = [0.25, 0.75] }}
[exposure]
mode = "auto"
[outputs]
preview = true
texture_previews = true
[skip]
max_captures = {n}
"#
    )
}

fn start_body(n: usize, dataset: &str) -> String {
    serde_json::json!({ "plan_text": plan(n), "dataset": dataset }).to_string()
}

fn setup(name: &str) -> (std::path::PathBuf, std::path::PathBuf) {
    let dir = scratch(name);
    let auth = dir.join("auth.toml");
    std::fs::write(&auth, AUTH).unwrap();
    let data = dir.join("data");
    (auth, data)
}

fn daemon(auth: &std::path::Path, data: &std::path::Path) -> Daemon {
    Daemon::start(&["--auth", auth.to_str().unwrap(), "--data", data.to_str().unwrap()])
}

#[test]
fn a_whole_run_through_the_api_with_events_pause_resume_and_download() {
    let (auth, data) = setup("serve_whole_run");
    let d = daemon(&auth, &data);
    // The OpenAPI document is served and names the run endpoints.
    let doc = request(d.port, "GET", "/api/v1/openapi.json", None, None).json();
    assert!(doc["paths"]["/api/v1/runs/{id}/pause"]["post"].is_object(), "{}", doc["paths"]);

    let r = d.post("/api/v1/runs", "operator-ada", &start_body(10, "whole"));
    assert_eq!(r.status, 201, "{}", r.text());
    let id = r.json()["id"].as_str().unwrap().to_string();
    assert_eq!(r.header("location"), Some(format!("/api/v1/runs/{id}").as_str()));

    // Events in a thread while the test steers the run.
    let port = d.port;
    let path = format!("/api/v1/runs/{id}/events");
    let events = std::thread::spawn(move || {
        let mut s = EventStream::open(port, &path, "viewer-token");
        assert_eq!(s.status, 200);
        let mut out = Vec::new();
        while let Some((name, data)) = s.next_event() {
            let end = name == "end";
            out.push((name, serde_json::from_str::<serde_json::Value>(&data).unwrap_or(serde_json::Value::Null)));
            if end {
                break;
            }
        }
        out
    });

    // Another operator cannot start a second run, nor steer ada's.
    let busy = d.post("/api/v1/runs", "operator-bob", &start_body(10, "other"));
    assert_eq!(busy.status, 409, "{}", busy.text());
    assert!(busy.json()["detail"].as_str().unwrap().contains("ada"), "409 names who holds the rig: {}", busy.text());
    assert_eq!(busy.header("content-type"), Some("application/problem+json"));
    assert!(!data.join("other").exists(), "a refused start creates nothing");
    assert_eq!(d.post(&format!("/api/v1/runs/{id}/pause"), "operator-bob", "").status, 403);

    d.wait_run(&id, "viewer-token", 120, "capturing", |s| s["done"].as_u64().unwrap_or(0) >= 2);
    let p = d.post(&format!("/api/v1/runs/{id}/pause"), "operator-ada", "");
    assert_eq!(p.status, 200, "{}", p.text());
    let paused = d.wait_run(&id, "viewer-token", 60, "paused", |s| s["state"] == "paused");
    // Paused means paused: no capture is made until resumed.
    std::thread::sleep(Duration::from_millis(1500));
    let still = d.get(&format!("/api/v1/runs/{id}"), "viewer-token").json();
    assert_eq!(still["state"], "paused");
    assert_eq!(still["done"], paused["done"], "captures went on while paused");
    assert_eq!(d.post(&format!("/api/v1/runs/{id}/pause"), "operator-ada", "").status, 409, "pausing a paused run");
    let rs = d.post(&format!("/api/v1/runs/{id}/resume"), "operator-ada", "");
    assert_eq!(rs.status, 200, "{}", rs.text());
    let end = d.wait_run(&id, "viewer-token", 300, "finished", |s| s["state"] == "finished");
    assert_eq!(end["done"], 10);
    assert_eq!(end["total"], 10);
    assert_eq!(end["summary"]["captures"], 10);

    let ev = events.join().unwrap();
    let states: Vec<&str> = ev.iter().filter_map(|(_, v)| v["state"].as_str()).collect();
    assert!(states.contains(&"running") && states.contains(&"paused"), "states seen: {states:?}");
    let (last, last_v) = ev.last().unwrap();
    assert_eq!(last, "end");
    assert_eq!(last_v["state"], "finished");
    let dones: Vec<u64> = ev.iter().filter_map(|(_, v)| v["done"].as_u64()).collect();
    assert!(dones.windows(2).all(|w| w[0] <= w[1]), "progress never goes back: {dones:?}");
    assert!(dones.iter().filter(|&&d| d > 0).count() >= 3, "progress events: {dones:?}");

    // Preview, datasets, manifest and files, byte for byte as on disk.
    let pv = d.get("/api/v1/preview", "viewer-token");
    assert_eq!(pv.status, 200);
    assert_eq!(&pv.body[..8], b"\x89PNG\r\n\x1a\n");
    assert!(pv.header("x-preview-seq").unwrap().parse::<u64>().unwrap() >= 1);
    let list = d.get("/api/v1/datasets", "viewer-token").json();
    let entry =
        list["datasets"].as_array().unwrap().iter().find(|e| e["name"] == "whole").expect("dataset listed").clone();
    assert_eq!(entry["state"], "finished");
    assert_eq!(entry["plan"], "serve-test");
    let manifest = d.get("/api/v1/datasets/whole", "viewer-token").json();
    assert_eq!(manifest["plan"]["text"], plan(10));
    let journal = read_journal(&data.join("whole"));
    let committed = journal.committed();
    assert_eq!(committed.len(), 10);
    for files in committed.values().take(3) {
        for (file, _) in files {
            let got = d.get(&format!("/api/v1/datasets/whole/files/{file}"), "viewer-token");
            assert_eq!(got.status, 200, "{file}");
            assert_eq!(
                got.body,
                std::fs::read(data.join("whole").join(file)).unwrap(),
                "{file} downloaded byte for byte"
            );
        }
    }
    // No way out of the data directory.
    std::fs::write(data.parent().unwrap().join("secret.txt"), "no").unwrap();
    for bad in ["..%2F..%2Fsecret.txt", "%2Fetc%2Fpasswd", "../../secret.txt", "textures/../../../secret.txt"] {
        let r = d.get(&format!("/api/v1/datasets/whole/files/{bad}"), "viewer-token");
        assert!(matches!(r.status, 400 | 404), "{bad}: {} {}", r.status, r.text());
        assert!(!r.text().contains("no\n") && r.body != b"no", "{bad} leaked a file outside");
    }
    assert!(matches!(d.get("/api/v1/datasets/..%2Fsecret.txt", "viewer-token").status, 400 | 404));
    // A finished run takes no more commands.
    assert_eq!(d.post(&format!("/api/v1/runs/{id}/abort"), "operator-ada", "").status, 409);
    let m = request(d.port, "GET", "/metrics", None, None).text();
    assert!(m.contains("btfrig_captures_total 10"), "{m}");
}

#[test]
fn every_write_endpoint_answers_401_403_and_409() {
    let (auth, data) = setup("serve_auth");
    let d = daemon(&auth, &data);
    // (path, body, the role below the one needed, or None when viewer suffices)
    let writes: &[(&str, String, Option<&str>)] = &[
        ("/api/v1/runs", start_body(40, "auth-run"), Some("viewer-token")),
        ("/api/v1/runs/r1/pause", String::new(), Some("viewer-token")),
        ("/api/v1/runs/r1/resume", String::new(), Some("viewer-token")),
        ("/api/v1/runs/r1/abort", String::new(), Some("viewer-token")),
        ("/api/v1/rig/stop", String::new(), Some("operator-ada")),
        ("/api/v1/calibrations", r#"{"kind":"color"}"#.into(), Some("operator-ada")),
        ("/api/v1/plans/validate", r#"{"plan":"demo"}"#.into(), None),
        ("/api/v1/plans/dry-run", r#"{"plan":"demo"}"#.into(), None),
    ];
    for (path, body, below) in writes {
        let none = request(d.port, "POST", path, None, Some(body));
        assert_eq!(none.status, 401, "{path} without a token: {}", none.text());
        assert_eq!(none.header("content-type"), Some("application/problem+json"), "{path}");
        assert_eq!(none.header("www-authenticate"), Some("Bearer"));
        let bad = request(d.port, "POST", path, Some("not-a-known-token"), Some(body));
        assert_eq!(bad.status, 401, "{path} with an unknown token");
        // The query token is for GET only.
        let q = request(d.port, "POST", &format!("{path}?access_token=admin-token"), None, Some(body));
        assert_eq!(q.status, 401, "{path}: a query token must not authorise a write");
        if let Some(t) = below {
            let r = request(d.port, "POST", path, Some(t), Some(body));
            assert_eq!(r.status, 403, "{path} with a lower role: {}", r.text());
            assert!(r.json()["detail"].as_str().unwrap().contains("needs role"), "{}", r.text());
        }
    }
    assert!(!data.join("auth-run").exists(), "refused requests created nothing");
    // 409: with ada's run holding the rig, every start (run or calibration) is refused with who holds it.
    let r = d.post("/api/v1/runs", "operator-ada", &start_body(40, "auth-run"));
    assert_eq!(r.status, 201, "{}", r.text());
    for (path, body, token) in [
        ("/api/v1/runs", start_body(5, "second"), "operator-bob"),
        ("/api/v1/runs", start_body(5, "second"), "admin-token"),
        ("/api/v1/calibrations", r#"{"kind":"color"}"#.to_string(), "admin-token"),
    ] {
        let c = d.post(path, token, &body);
        assert_eq!(c.status, 409, "{path}: {}", c.text());
        assert!(c.json()["detail"].as_str().unwrap().contains("ada"), "{}", c.text());
    }
    assert_eq!(d.post("/api/v1/runs/r1/resume", "operator-ada", "").status, 409, "resume of a running run");
    // Ownership: bob may not abort ada's run; an admin may stop the rig.
    assert_eq!(d.post("/api/v1/runs/r1/abort", "operator-bob", "").status, 403);
    let stop = d.post("/api/v1/rig/stop", "admin-token", "");
    assert_eq!(stop.status, 200);
    assert_eq!(stop.json()["run_id"], "r1");
    d.wait_run("r1", "viewer-token", 120, "aborted", |s| s["state"] == "aborted");
    // Bad bodies are problem documents, not panics.
    for (body, status) in
        [("{", 400), (r#"{"plan": 3}"#, 422), (r#"{"plan":"demo","plan_text":"x"}"#, 422), (r#"{"plan":"nope"}"#, 404)]
    {
        let r = d.post("/api/v1/runs", "operator-ada", body);
        assert_eq!(r.status, status, "{body}: {}", r.text());
        assert_eq!(r.header("content-type"), Some("application/problem+json"));
    }
    let big = format!(r#"{{"plan_text":"{}"}}"#, "x".repeat(300 * 1024));
    assert_eq!(d.post("/api/v1/runs", "operator-ada", &big).status, 413);
    let invalid = d.post("/api/v1/runs", "operator-ada", r#"{"plan_text":"[sampling]\nlight = \"nope\"\n"}"#);
    assert_eq!(invalid.status, 422, "{}", invalid.text());
    let r = d.post("/api/v1/runs", "operator-ada", &serde_json::json!({"plan":"demo","dataset":"../x"}).to_string());
    assert_eq!(r.status, 422, "{}", r.text());
    // The dataset of another plan is not overwritten.
    let r = d.post("/api/v1/runs", "operator-ada", &start_body(7, "auth-run"));
    assert_eq!(r.status, 409, "{}", r.text());
}

#[test]
fn sigterm_pauses_the_run_resumably_and_the_same_request_resumes_it() {
    let (auth, data) = setup("serve_sigterm");
    let d = daemon(&auth, &data);
    let r = d.post("/api/v1/runs", "operator-ada", &start_body(16, "kept"));
    assert_eq!(r.status, 201, "{}", r.text());
    d.wait_run("r1", "viewer-token", 120, "capturing", |s| s["done"].as_u64().unwrap_or(0) >= 3);
    let status = d.terminate();
    assert!(status.success(), "btfrig serve exit after SIGTERM: {status}");
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(data.join("kept/report.json")).unwrap()).unwrap();
    assert_eq!(
        (report["status"].as_str(), report["reason"].as_str()),
        (Some("interrupted"), Some("interrupted (SIGTERM)")),
        "{report}"
    );
    let before = read_journal(&data.join("kept")).committed().len();
    assert!((3..16).contains(&before), "captured before SIGTERM: {before}");

    let d = daemon(&auth, &data);
    let r = d.post("/api/v1/runs", "operator-ada", &start_body(16, "kept"));
    assert_eq!(r.status, 201, "{}", r.text());
    let s = d.wait_run("r1", "viewer-token", 300, "finished", |s| s["state"] == "finished");
    assert_eq!(s["done"], 16);
    assert_eq!(s["summary"]["captures_this_session"].as_u64().unwrap() as usize, 16 - before, "{s}");
    assert_eq!(read_journal(&data.join("kept")).committed().len(), 16);
}

/// Issue 24: `RUST_LOG=trace` gave no output from the daemon (no log subscriber). Now its
/// `tracing` events reach stderr, filtered by RUST_LOG: with `trace`, a connection and each
/// request are logged (the path only, never a token); with nothing set, neither is.
#[test]
fn r24_rust_log_trace_prints_the_daemons_log_lines() {
    use std::io::{BufRead, BufReader};
    use std::process::Stdio;
    let data = scratch("r24-rust-log").join("data");
    for (rust_log, logged) in [(Some("trace"), true), (None, false)] {
        let mut cmd = support::btfrig();
        cmd.args(["serve", "--listen", "127.0.0.1:0", "--data", data.to_str().unwrap()]);
        cmd.env_remove("RUST_LOG");
        if let Some(v) = rust_log {
            cmd.env("RUST_LOG", v);
        }
        let mut child = cmd.stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
        let mut first = String::new();
        BufReader::new(child.stdout.take().unwrap()).read_line(&mut first).unwrap();
        let port: u16 = first.trim().rsplit(':').next().and_then(|p| p.parse().ok()).expect("listening on ...");
        assert_eq!(request(port, "GET", "/healthz?access_token=secret-in-query", None, None).status, 200);
        // The request is logged after its answer: ask once more, then stop the daemon and
        // read everything it wrote.
        assert_eq!(request(port, "GET", "/healthz", None, None).status, 200);
        let pid = child.id().to_string();
        assert!(std::process::Command::new("kill").args(["-TERM", &pid]).status().unwrap().success());
        let out = child.wait_with_output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        let request_lines: Vec<&str> =
            err.lines().filter(|l| l.contains("request") && l.contains("/healthz")).collect();
        if logged {
            assert!(err.contains("TRACE") && err.contains("connection accepted"), "RUST_LOG=trace:\n{err}");
            assert!(
                request_lines.iter().any(|l| l.contains("DEBUG") && l.contains("status=200")),
                "RUST_LOG=trace, a request line:\n{err}"
            );
            assert!(!err.contains("secret-in-query"), "a query (it may hold a token) is not logged:\n{err}");
        } else {
            assert!(!err.contains("connection accepted") && request_lines.is_empty(), "RUST_LOG unset:\n{err}");
        }
    }
}

/// A big plan the limits allow: 12 rings x 50 directions for light and view (360 000
/// pairs, `[limits] max_captures` raised), whose dry run takes seconds of planning.
fn big_plan_body() -> String {
    let rings: Vec<String> =
        (0..12).map(|r| format!("{{ theta_deg = {}, count = 50 }}", 5.0 + 72.0 * r as f64 / 11.0)).collect();
    let rings = rings.join(", ");
    let text = format!(
        "name = \"big\"\n[sampling]\nlight = {{ rings = [{rings}] }}\nview = {{ rings = [{rings}] }}\n[texture]\nsize = 8\n[limits]\nmax_captures = 400000\n"
    );
    serde_json::json!({ "plan_text": text }).to_string()
}

/// Sends the big dry run on a keep-alive HTTP/1.1 connection (so the daemon watches it for
/// the client going away) and returns the open connection.
fn send_big_dry_run(port: u16) -> std::net::TcpStream {
    use std::io::Write;
    let body = big_plan_body();
    let mut s = std::net::TcpStream::connect(("127.0.0.1", port)).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(120))).unwrap();
    let req = format!(
        "POST /api/v1/plans/dry-run HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer viewer-token\r\nContent-Type: application/json\r\nContent-Length: {}\r\n\r\n{body}",
        body.len()
    );
    s.write_all(req.as_bytes()).unwrap();
    s
}

/// A sample of `/metrics`.
fn metric(d: &Daemon, name: &str) -> u64 {
    let text = request(d.port, "GET", "/metrics", None, None).text();
    let line = text.lines().find(|l| l.starts_with(&format!("{name} "))).unwrap_or_else(|| panic!("{name}:\n{text}"));
    line.rsplit(' ').next().unwrap().parse().unwrap()
}

/// Polls `/metrics` until `name` has `want` (the event), or panics after 120 s.
fn wait_metric(d: &Daemon, name: &str, want: u64) {
    let t0 = std::time::Instant::now();
    while metric(d, name) != want {
        assert!(t0.elapsed().as_secs() < 120, "{name} never became {want}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// r24 (issue 24, item 2): a viewer's dry run of a big plan whose client disconnects is
/// cancelled (seen in `/metrics`: the job ends, counted as cancelled), not left running.
#[test]
fn r24_a_dry_run_whose_client_goes_away_is_cancelled() {
    let (auth, data) = setup("serve_r24_disconnect");
    let d = daemon(&auth, &data);
    assert_eq!(metric(&d, "btfrig_plan_jobs_cancelled_total"), 0);
    let conn = send_big_dry_run(d.port);
    wait_metric(&d, "btfrig_plan_jobs_in_flight", 1);
    drop(conn);
    wait_metric(&d, "btfrig_plan_jobs_in_flight", 0);
    assert_eq!(metric(&d, "btfrig_plan_jobs_cancelled_total"), 1);
    // The runaway plan itself is refused from its counts, naming the limit.
    let rings: Vec<String> = (0..10).map(|r| format!("{{ theta_deg = {}, count = 360 }}", 5 + 8 * r)).collect();
    let text = format!("[sampling]\nlight = {{ rings = [{0}] }}\nview = {{ rings = [{0}] }}\n", rings.join(", "));
    let r = d.post("/api/v1/plans/dry-run", "viewer-token", &serde_json::json!({ "plan_text": text }).to_string());
    let v = r.json();
    assert_eq!(v["valid"], false, "{v}");
    let e = v["errors"].to_string();
    assert!(e.contains("12960000 pairs") && e.contains("[limits] max_captures = N"), "{e}");
}

/// r24: SIGTERM to `btfrig serve` while a dry run is planning: the dry run is cancelled
/// (its client is told so) and the daemon exits.
#[test]
fn r24_sigterm_during_a_dry_run_cancels_it_and_the_daemon_exits() {
    use std::io::Read;
    let (auth, data) = setup("serve_r24_sigterm");
    let d = daemon(&auth, &data);
    let mut conn = send_big_dry_run(d.port);
    wait_metric(&d, "btfrig_plan_jobs_in_flight", 1);
    let status = d.terminate();
    assert!(status.success(), "btfrig serve exit after SIGTERM: {status}");
    let mut answer = String::new();
    let _ = conn.read_to_string(&mut answer);
    assert!(answer.contains("\"valid\":false") && answer.contains("cancelled"), "{answer}");
}

/// Issue 25 item 5: the daemon builds the compressed model a plan asks for
/// (`outputs.compressed_model`), as `btfrig run` does, also across an abort and a resume
/// (the first session's textures are read back from the dataset). The model is written next
/// to the dataset and journaled in it, the run's status names it with its figures, it loads,
/// and it reconstructs the daemon's textures within the error `btfrig run` reports for the
/// same plan.
#[test]
fn r25_a_plan_with_a_compressed_model_gets_its_model_across_an_abort_and_a_resume() {
    const N: u64 = 20; // the streaming FMF's 16 terms need at least 16 captures
    let (auth, data) = setup("serve_compress");
    let text = plan(N as usize).replace("[outputs]\n", "[outputs]\ncompressed_model = \"fmf\"\n");
    assert!(text.contains("compressed_model = \"fmf\""));
    let body = serde_json::json!({ "plan_text": text, "dataset": "modelled" }).to_string();
    let d = daemon(&auth, &data);
    let r = d.post("/api/v1/runs", "operator-ada", &body);
    assert_eq!(r.status, 201, "the daemon must accept outputs.compressed_model: {}", r.text());
    d.wait_run("r1", "viewer-token", 120, "capturing", |s| s["done"].as_u64().unwrap_or(0) >= 4);
    assert_eq!(d.post("/api/v1/runs/r1/abort", "operator-ada", "").status, 200);
    let aborted = d.wait_run("r1", "viewer-token", 120, "aborted", |s| s["state"] == "aborted");
    let before = read_journal(&data.join("modelled")).committed().len() as u64;
    assert!((4..N).contains(&before), "captured before the abort: {before}");
    assert_eq!(aborted["summary"]["compression_status"], "not_finished", "{aborted}");
    let model = data.join("modelled.fmf.btfm");
    assert!(!model.exists(), "an unfinished run wrote a model");

    // The same plan into the same dataset resumes it and builds the model.
    let r = d.post("/api/v1/runs", "operator-ada", &body);
    assert_eq!(r.status, 201, "{}", r.text());
    let s = d.wait_run("r2", "viewer-token", 600, "over", |s| {
        s["state"] != "starting" && s["state"] != "running" && s["state"] != "stopping"
    });
    assert_eq!(s["state"], "finished", "{s}");
    let sum = &s["summary"];
    assert_eq!((sum["captures"].as_u64(), sum["captures_this_session"].as_u64()), (Some(N), Some(N - before)), "{s}");
    assert_eq!(sum["compression_status"], "built", "{s}");
    assert_eq!(sum["compression_model"].as_str(), Some(model.to_str().unwrap()), "{s}");
    assert_eq!(sum["compression_method"], "fmf");
    // The first session's textures were read back from the dataset, the second's streamed.
    assert_eq!(
        (sum["compression_from_disk"].as_u64(), sum["compression_streamed"].as_u64()),
        (Some(before), Some(N - before)),
        "{s}"
    );
    assert!(sum["compression_ratio"].as_f64().unwrap() > 1.0, "{s}");
    let models = read_journal(&data.join("modelled")).models;
    assert_eq!(models.len(), 1, "{models:?}");
    assert_eq!(models[0]["file"], "modelled.fmf.btfm");
    let written = std::fs::read(&model).unwrap();
    assert_eq!(models[0]["hash"].as_str(), Some(btfrig_store::content_hash(&written).as_str()));

    // It loads, and is as close to the daemon's textures as the status says.
    let m = btfrig_compress::file::read(&model).unwrap();
    assert_eq!(m.method, btfrig_compress::Method::Fmf);
    let mut src = btfrig_compress::dataset::DatasetSource::open(&data.join("modelled")).unwrap();
    let err = btfrig_compress::eval::error_against(&m, &mut src).unwrap().rel_rmse();
    let reported = sum["compression_rel_rmse"].as_f64().unwrap();
    assert!((err - reported).abs() <= 1e-6 * reported.max(1e-3), "measured {err}, status says {reported}");

    // `btfrig run` of the same plan (same seed) in one go: the daemon's model is as good.
    let dir = data.parent().unwrap();
    let file = dir.join("plan.toml");
    std::fs::write(&file, &text).unwrap();
    let out = support::ok(support::btfrig().args(["run", "--plan"]).arg(&file).arg("--out").arg(dir.join("cli")));
    let cli: f64 = out
        .split("relative RMSE ")
        .nth(1)
        .and_then(|r| r.split_whitespace().next())
        .and_then(|x| x.parse().ok())
        .unwrap_or_else(|| panic!("no model error in `btfrig run`'s output:\n{out}"));
    eprintln!("model rel. RMSE against the textures: daemon (aborted, resumed) {err:.6}, btfrig run {cli:.6}");
    assert!(cli > 0.0 && err <= cli * 1.02 + 1e-5, "daemon's model {err}, btfrig run's {cli}");
    // A third start has nothing to capture and finds the model journaled.
    let r = d.post("/api/v1/runs", "operator-ada", &body);
    assert_eq!(r.status, 201, "{}", r.text());
    let s = d.wait_run("r3", "viewer-token", 120, "finished", |s| s["state"] == "finished");
    assert_eq!(s["summary"]["compression_status"], "built_earlier", "{s}");
    assert_eq!(s["summary"]["compression_model"].as_str(), Some(model.to_str().unwrap()), "{s}");
    assert!(!data.join("modelled.fmf-2.btfm").exists(), "a second model was built");
}

/// Issue 25 item 5: when the model a plan asks for cannot be written (here a directory is
/// where its temporary file goes), the daemon's run ends `failed` with a message naming the
/// model and why, the complete dataset is kept, and the same start builds the model from it.
#[test]
fn r25_a_model_that_cannot_be_written_fails_the_run_visibly_and_the_same_start_builds_it() {
    const N: u64 = 16;
    let (auth, data) = setup("serve_compress_failed");
    let blocker = data.join("blocked.fmf.btfm.tmp");
    std::fs::create_dir_all(blocker.join("keep")).unwrap();
    let text = plan(N as usize).replace("[outputs]\n", "[outputs]\ncompressed_model = \"fmf\"\n");
    let body = serde_json::json!({ "plan_text": text, "dataset": "blocked" }).to_string();
    let d = daemon(&auth, &data);
    assert_eq!(d.post("/api/v1/runs", "operator-ada", &body).status, 201);
    let s = d.wait_run("r1", "viewer-token", 600, "over", |s| {
        !matches!(s["state"].as_str(), Some("starting" | "running" | "stopping"))
    });
    assert_eq!(s["state"], "failed", "{s}");
    let message = s["message"].as_str().unwrap_or_default();
    eprintln!("the failed run's message: {message}");
    assert!(
        message.contains("outputs.compressed_model")
            && message.contains(blocker.to_str().unwrap())
            && message.contains("same plan into the same dataset"),
        "{s}"
    );
    assert_eq!(s["summary"]["compression_status"], "failed", "{s}");
    assert_eq!(s["summary"]["captures"], N, "{s}");
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(data.join("blocked/report.json")).unwrap()).unwrap();
    assert_eq!(report["status"], "finished", "the captures are complete: {report}");
    assert!(read_journal(&data.join("blocked")).models.is_empty());
    assert!(!data.join("blocked.fmf.btfm").exists());

    std::fs::remove_dir_all(&blocker).unwrap();
    assert_eq!(d.post("/api/v1/runs", "operator-ada", &body).status, 201);
    let s = d.wait_run("r2", "viewer-token", 120, "finished", |s| s["state"] == "finished");
    let sum = &s["summary"];
    assert_eq!(sum["compression_status"], "built", "{s}");
    assert_eq!(
        (sum["compression_from_disk"].as_u64(), sum["compression_streamed"].as_u64()),
        (Some(N), Some(0)),
        "{s}"
    );
    assert!(data.join("blocked.fmf.btfm").exists(), "{s}");
    assert_eq!(read_journal(&data.join("blocked")).models.len(), 1);
}
