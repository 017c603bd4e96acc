//! Dome runs through the HTTP API: a dome plan started on the LED dome daemon runs through
//! `btfrig_measurement::dome::run_controlled`; its status counts steps (a pattern at a rotation, a
//! frame per camera) with the committed textures beside them, it pauses (no step while paused),
//! resumes and aborts through the same endpoints as a gonio run (and is interrupted as on
//! SIGTERM), its events stream progress and the end, the preview shows the latest view group's
//! brightest texture, and its dataset is where gonio runs' are and verifies. Bad starts are
//! problem documents naming what is wrong.
//! The daemon runs in-process ([`btfrig_daemon::router`] on a loopback port), driven over HTTP.
//!
//! The plan is small so the test takes seconds: one camera at one rotation, 8-texel textures
//! (199 S-matrix patterns and 4 single-LED reference frames: 203 steps, 198 textures).

mod support;

use std::time::{Duration, Instant};

use serde_json::{json, Value};
use support::Daemon;

const PLAN: &str = "name = \"api-dome\"\ntexture_size = 8\nfault_scenario = \"none\"\n[rig]\n\
                    config = \"builtin:bonn-dome-sim\"\nmaterial = \"leather\"\n[dome]\ncameras = [4]\n\
                    rotations = [1]\nsample_brightness = 0.1\n";
const STEPS: u64 = 203;
const TEXTURES: u64 = 198;

/// Polls run `id` until `done(status)`, or panics naming `what` after two minutes.
fn wait_for(d: &Daemon, id: &str, what: &str, done: impl Fn(&Value) -> bool) -> Value {
    let t0 = Instant::now();
    loop {
        let s = d.get(&format!("/api/v1/runs/{id}"));
        if done(&s) {
            return s;
        }
        assert!(t0.elapsed() < Duration::from_secs(120), "no {what} after 120 s: {s}");
        std::thread::sleep(Duration::from_millis(5));
    }
}

fn is_over(s: &Value) -> bool {
    ["finished", "aborted", "interrupted", "failed"].iter().any(|st| s["state"] == *st)
}

fn n(v: &Value) -> u64 {
    v.as_u64().unwrap_or_else(|| panic!("not a count: {v}"))
}

#[test]
fn a_dome_run_starts_pauses_resumes_and_completes_into_a_dataset_that_verifies() {
    let t0 = Instant::now();
    let d = Daemon::start("dome_runs_led_dome", Some("rig-configs/bonn-dome-sim.toml"));
    let r = d.post("/api/v1/runs", Some(&json!({ "plan_text": PLAN, "dataset": "dome-1" })));
    assert_eq!(r.status, 201, "{}", r.text());
    assert_eq!(r.header("location"), Some("/api/v1/runs/r1"));
    let s = r.json();
    assert_eq!(
        (s["id"].as_str(), s["plan"].as_str(), s["dataset"].as_str()),
        (Some("r1"), Some("api-dome"), Some("dome-1"))
    );
    assert_eq!(s["unit"], "steps", "a dome run counts steps: {s}");
    let events = d.events("r1");

    // Running: steps of the plan, no texture yet (the view group commits at its last step).
    let running = wait_for(&d, "r1", "20 steps", |s| n(&s["done"]) >= 20);
    assert_eq!((n(&running["total"]), running["textures_total"].as_u64()), (STEPS, Some(TEXTURES)), "{running}");
    assert_eq!(running["textures"], 0, "{running}");
    assert!(running["eta_s"].as_f64().is_some_and(|e| e > 0.0), "an ETA from the measured steps: {running}");

    // Pause: after the step under way, and nothing moves until resumed.
    let r = d.post("/api/v1/runs/r1/pause", None);
    assert_eq!(r.status, 200, "{}", r.text());
    let paused = wait_for(&d, "r1", "pause", |s| s["state"] == "paused");
    assert_eq!(paused["message"], "paused on request");
    assert!(n(&paused["done"]) < STEPS, "paused before the end: {paused}");
    std::thread::sleep(Duration::from_millis(400));
    let still = d.get("/api/v1/runs/r1");
    assert_eq!((still["state"].as_str(), &still["done"]), (Some("paused"), &paused["done"]), "steps while paused");
    // The rig is held: a second start names the run and its progress in steps.
    let e = d.problem("POST", "/api/v1/runs", Some(&json!({ "plan_text": PLAN, "dataset": "dome-x" })), 409);
    assert!(e.contains("run r1 of ada (plan api-dome, Paused") && e.contains(&format!("/{STEPS} steps")), "{e}");
    let e = d.problem("POST", "/api/v1/runs/r1/pause", None, 409);
    assert!(e.contains("is Paused") && e.contains("only to a starting or running run"), "{e}");

    let r = d.post("/api/v1/runs/r1/resume", None);
    assert_eq!(r.status, 200, "{}", r.text());
    let end = wait_for(&d, "r1", "end", is_over);
    assert_eq!(end["state"], "finished", "{end}");
    assert_eq!((n(&end["done"]), n(&end["total"]), end["fraction"].as_f64()), (STEPS, STEPS, Some(1.0)), "{end}");
    assert_eq!((end["textures"].as_u64(), end["eta_s"].as_f64()), (Some(TEXTURES), Some(0.0)), "{end}");
    assert!(end["message"].is_null(), "{end}");
    let summary = &end["summary"];
    assert_eq!((summary["status"].as_str(), summary["captures"].as_u64()), (Some("finished"), Some(TEXTURES)));
    assert_eq!((summary["frames"].as_u64(), summary["mode"].as_str()), (Some(STEPS), Some("s-matrix 199")));
    assert_eq!(end["preview_seq"], 1, "one view group, one preview: {end}");

    // The events: progress in steps (never backwards), the pause and the resume, the textures
    // committed, then the end.
    let events = events.join().unwrap();
    let (last, last_status) = events.last().unwrap();
    assert_eq!((last.as_str(), &last_status["state"]), ("end", &json!("finished")));
    let statuses: Vec<&Value> = events.iter().filter(|(e, _)| e == "status").map(|(_, s)| s).collect();
    let done: Vec<u64> = statuses.iter().map(|s| n(&s["done"])).collect();
    assert!(done.windows(2).all(|w| w[0] <= w[1]), "progress went backwards: {done:?}");
    assert!(done.len() > 100, "a status per step: {} statuses", done.len());
    let p = statuses.iter().position(|s| s["state"] == "paused").expect("a paused status");
    assert!(statuses[p..].iter().any(|s| s["state"] == "running"), "resumed after the pause");
    assert!(statuses.iter().any(|s| s["textures"] == TEXTURES), "the view group's commit");

    // The preview: the view group's brightest texture, 8 texels enlarged to 256 px.
    let r = d.request("GET", "/api/v1/preview", "viewer-token", None);
    assert_eq!((r.status, r.content_type.as_deref(), r.header("x-preview-seq")), (200, Some("image/png"), Some("1")));
    assert_eq!(&r.body[..8], b"\x89PNG\r\n\x1a\n");
    let size = |at: usize| u32::from_be_bytes(r.body[at..at + 4].try_into().unwrap());
    assert_eq!((size(16), size(20)), (256, 256), "IHDR width and height");

    // The dataset is where gonio runs' are, listed, served and valid.
    let list = d.get("/api/v1/datasets");
    let entry = list["datasets"].as_array().unwrap().iter().find(|e| e["name"] == "dome-1").expect("listed");
    assert_eq!((entry["state"].as_str(), entry["captures"].as_u64()), (Some("finished"), Some(TEXTURES)), "{list}");
    assert_eq!(entry["plan"], "api-dome");
    let report = d.get("/api/v1/datasets/dome-1/files/report.json");
    assert_eq!((report["status"].as_str(), report["captures"].as_u64()), (Some("finished"), Some(TEXTURES)));
    let manifest = d.get("/api/v1/datasets/dome-1");
    assert_eq!(manifest["rig"]["name"], "bonn-dome-sim", "{}", manifest["rig"]["name"]);
    let textures: Vec<String> = std::fs::read_dir(d.data.join("dome-1/textures"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(textures.len() as u64, TEXTURES);
    let r = d.request("GET", &format!("/api/v1/datasets/dome-1/files/textures/{}", textures[0]), "viewer-token", None);
    assert_eq!((r.status, r.content_type.as_deref()), (200, Some("image/x-exr")), "{}", r.text());
    let v = btfrig_store::verify(&d.data.join("dome-1"));
    assert!(v.is_ok(), "{v:?}");

    // Metrics: every step once, stage times of the dome pipeline.
    let m = d.request("GET", "/metrics", "", None).text();
    assert!(m.contains(&format!("btfrig_dome_steps_total {STEPS}\n")), "{m}");
    assert!(m.contains("btfrig_stage_seconds_total{stage=\"demultiplex\"}"), "{m}");
    assert!(m.contains("btfrig_captures_total 0\n"), "no gonio captures: {m}");

    // Bad starts are problem documents naming what is wrong and what is allowed.
    let e = d.refused_start(json!({ "plan_text": PLAN.replace("leather", "velvet-x") }));
    assert!(e.contains("rig.material") && e.contains("\"velvet-x\"") && e.contains("allowed"), "{e}");
    let e = d.refused_start(json!({ "plan_text": PLAN.replace("cameras = [4]", "cameras = [4, 99]") }));
    assert!(e.contains("dome.cameras") && e.contains("99"), "{e}");
    let e = d.refused_start(json!({ "plan_text": PLAN, "dataset": "../dome-1" }));
    assert!(e.contains("dataset name") && e.contains("letters, digits"), "{e}");
    let other = PLAN.replace("rotations = [1]", "rotations = [2]");
    let e = d.problem("POST", "/api/v1/runs", Some(&json!({ "plan_text": other, "dataset": "dome-1" })), 409);
    assert!(e.contains("\"dome-1\" holds another plan's captures"), "{e}");

    // Abort: a second run paused as it starts and aborted keeps a resumable dataset whose
    // report says so.
    let r = d.post("/api/v1/runs", Some(&json!({ "plan_text": PLAN, "dataset": "dome-2" })));
    assert_eq!(r.status, 201, "{}", r.text());
    let id = r.json()["id"].as_str().unwrap().to_string();
    let r = d.post(&format!("/api/v1/runs/{id}/pause"), None);
    assert_eq!(r.status, 200, "{}", r.text());
    wait_for(&d, &id, "pause", |s| s["state"] == "paused");
    let r = d.post(&format!("/api/v1/runs/{id}/abort"), None);
    assert_eq!(r.status, 200, "{}", r.text());
    let end = wait_for(&d, &id, "abort", is_over);
    assert_eq!(
        (end["state"].as_str(), end["message"].as_str()),
        (Some("aborted"), Some("aborted on request")),
        "{end}"
    );
    assert!(n(&end["done"]) < STEPS && end["textures"] == 0, "{end}");
    let report = d.get("/api/v1/datasets/dome-2/files/report.json");
    assert_eq!((report["status"].as_str(), report["captures"].as_u64()), (Some("aborted"), Some(0)), "{report}");

    // What SIGTERM does (`serve`'s shutdown): the same plan started into the aborted dataset
    // resumes it, and the interrupt returns once the run has stopped and reported.
    let r = d.post("/api/v1/runs", Some(&json!({ "plan_text": PLAN, "dataset": "dome-2" })));
    assert_eq!(r.status, 201, "{}", r.text());
    let id = r.json()["id"].as_str().unwrap().to_string();
    wait_for(&d, &id, "a step", |s| n(&s["done"]) >= 1);
    d.state.runs.interrupt_and_wait(btfrig_measurement::Signal::Term);
    let end = d.get(&format!("/api/v1/runs/{id}"));
    assert_eq!(end["state"], "interrupted", "{end}");
    assert!(n(&end["done"]) < STEPS, "{end}");
    let report = d.get("/api/v1/datasets/dome-2/files/report.json");
    assert_eq!(
        (report["status"].as_str(), report["reason"].as_str()),
        (Some("interrupted"), Some("interrupted (SIGTERM)")),
        "{report}"
    );
    eprintln!("dome runs through the API: {:.1} s", t0.elapsed().as_secs_f64());
}

/// Issue 25 item 5: a dome plan's `outputs.compressed_model` is built by the daemon's run as
/// by `btfrig run` (the runner builds the sink, not the CLI): written next to the dataset,
/// journaled in it, named with its figures in the run's status; the dataset still verifies.
#[test]
fn a_dome_plan_with_a_compressed_model_gets_its_model_through_the_daemon() {
    let d = Daemon::start("dome_runs_compressed_model", Some("rig-configs/bonn-dome-sim.toml"));
    let plan = format!("{PLAN}[outputs]\ncompressed_model = \"fmf\"\n");
    let r = d.post("/api/v1/runs", Some(&json!({ "plan_text": plan, "dataset": "dome-model" })));
    assert_eq!(r.status, 201, "the daemon must accept a dome plan's compressed_model: {}", r.text());
    let end = wait_for(&d, "r1", "end", is_over);
    assert_eq!(end["state"], "finished", "{end}");
    let sum = &end["summary"];
    let model = d.data.join("dome-model.fmf.btfm");
    assert_eq!(sum["compression_status"], "built", "{end}");
    assert_eq!(sum["compression_model"].as_str(), Some(model.to_str().unwrap()), "{end}");
    assert_eq!(
        (sum["compression_streamed"].as_u64(), sum["compression_from_disk"].as_u64()),
        (Some(TEXTURES), Some(0))
    );
    assert!(sum["compression_rel_rmse"].as_f64().is_some_and(|e| e > 0.0 && e < 1.0), "{end}");
    let models = btfrig_store::journaled_models(&d.data.join("dome-model")).unwrap();
    assert_eq!(
        models.iter().map(|m| (m.method.as_str(), m.file.as_str())).collect::<Vec<_>>(),
        [("fmf", "dome-model.fmf.btfm")]
    );
    assert_eq!(models[0].hash, btfrig_store::content_hash(&std::fs::read(&model).unwrap()));
    let layout = btfrig_compress::file::read(&model).unwrap().layout;
    // Camera 4 at rotation 1 of 11 cameras: view id 15, under every LED.
    assert_eq!((layout.n_light(), layout.captures.as_ref().map(|c| c.view_ids.clone())), (198, Some(vec![15])));
    let v = btfrig_store::verify(&d.data.join("dome-model"));
    assert!(v.is_ok(), "{v:?}");
}
