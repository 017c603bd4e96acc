//! Issue 26, acceptance: a plan runs end to end on a rig of real protocol stacks on the wall
//! clock. The camera is Aravis's GigE Vision fake camera (`arv-fake-gv-camera-0.8`, Debian's
//! aravis-tools: written by others, the real GVCP/GVSP stack), a separate process on
//! 127.0.0.1 that the test starts, kills and restarts; robot, rail and lamp are the emulated
//! serial firmware on pseudo-terminals (`tests/data/realtime/rig-serial-fast.toml` with its
//! camera replaced). Through `btfrig serve`: the run is paused and resumed, the daemon is
//! SIGKILLed and the same request resumes the dataset; then the camera process is killed: the
//! run retries, pauses with a message naming the camera (no hang), and after the camera is
//! restarted an operator's resume finishes it. Every capture is journaled once, the dataset
//! verifies, and every raw frame is the fake camera's diagonal ramp at the configured size,
//! format, exposure and gain.
//!
//! The whole test runs in a network namespace with only `lo` (the GenICam tests' support
//! module), so nothing it does on the network leaves the machine.

#[path = "../crates/genicam/tests/support/mod.rs"]
mod netns;
mod support;

use std::collections::BTreeSet;
use std::path::Path;
use std::process::Child;
use std::time::{Duration, Instant};

use support::http::{Daemon, AUTH};
use support::*;

const CAPTURES: usize = 12;
const SERIAL: &str = "GV26";
/// The plan's fixed exposure and gain: 10 ms at 0 dB. The frames must carry them.
const EXPOSURE_S: f64 = 0.01;

/// The emulated serial rig with its camera a GenICam camera at 127.0.0.1: 8-bit RGGB Bayer on
/// the wire, as the fake camera offers, and a sensor of 8 bits without black level to match.
fn rig_text() -> String {
    let text = std::fs::read_to_string(repo("tests/data/realtime/rig-serial-fast.toml")).unwrap();
    let replacements = [
        (
            "kind = \"ptp\"\nlink = { emulated = true }",
            "kind = \"genicam\"\nlink = { address = \"127.0.0.1\", pixel_format = \"BayerRG8\", gain_unit = \"db\" }",
        ),
        ("bit_depth = 14", "bit_depth = 8"),
        ("black_level_dn = 256", "black_level_dn = 0"),
    ];
    let mut text = text;
    for (from, to) in replacements {
        assert!(text.contains(from), "rig-serial-fast.toml no longer has {from:?}");
        text = text.replace(from, to);
    }
    text
}

fn plan() -> String {
    format!(
        r#"name = "genicam-wall"
description = "a few captures on emulated serial firmware with a GenICam camera over loopback GigE Vision"
[rig]
config = "../rig/rig.toml"
seed = 11
[sampling]
light = {{ preset = "bonn81", theta_max_deg = 30 }}
view = {{ preset = "bonn81", theta_max_deg = 30 }}
[texture]
size = 32
[registration]
method = "nominal"
[exposure]
mode = "fixed"
exposure_s = {EXPOSURE_S}
gain = 1.0
[outputs]
textures = true
raw_frames = true
format = "exr-half"
[skip]
max_captures = {CAPTURES}
[run]
max_retries = 2
backoff_s = 0.5
capture_timeout_s = 5
"#
    )
}

/// Starts the fake camera on 127.0.0.1 and waits until it answers on its control channel.
fn start_camera() -> Child {
    let child = netns::spawn_fake_gv(SERIAL);
    let t0 = Instant::now();
    let silent = loop {
        let o = btfrig().args(["hw", "probe", "--genicam", "127.0.0.1"]).output().unwrap();
        if o.status.success() && String::from_utf8_lossy(&o.stdout).contains(SERIAL) {
            break None;
        }
        if t0.elapsed() >= Duration::from_secs(30) {
            break Some(text(&o));
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    match silent {
        None => child,
        Some(out) => {
            kill(child); // not left behind by a failing test
            panic!("the fake camera did not answer within 30 s:\n{out}");
        }
    }
}

fn kill(mut child: Child) {
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
}

/// Waits until the dataset's journal holds at least `n` steps.
fn wait_journaled(dir: &Path, n: usize, what: &str) {
    let t0 = Instant::now();
    while journaled_steps(dir) < n {
        assert!(t0.elapsed() < Duration::from_secs(180), "{what}: {} of {n} steps after 180 s", journaled_steps(dir));
        std::thread::sleep(Duration::from_millis(10));
    }
}

#[test]
fn a_genicam_camera_over_gige_and_serial_firmware_on_the_wall_clock_survive_pauses_kills_and_a_camera_loss() {
    if !netns::in_netns(
        "a_genicam_camera_over_gige_and_serial_firmware_on_the_wall_clock_survive_pauses_kills_and_a_camera_loss",
    ) {
        return;
    }
    netns::assert_loopback_only();
    let dir = scratch("genicam-rig");
    let (rig_dir, plans, data) = (dir.join("rig"), dir.join("plans"), dir.join("data"));
    for d in [&rig_dir, &plans] {
        std::fs::create_dir_all(d).unwrap();
    }
    let rig = rig_dir.join("rig.toml");
    std::fs::write(&rig, rig_text()).unwrap();
    std::fs::write(plans.join("genicam-wall.toml"), plan()).unwrap();
    let auth = dir.join("auth.toml");
    std::fs::write(&auth, AUTH).unwrap();
    let daemon = || {
        Daemon::start(&[
            "--auth",
            auth.to_str().unwrap(),
            "--data",
            data.to_str().unwrap(),
            "--rig",
            rig.to_str().unwrap(),
            "--plans",
            plans.to_str().unwrap(),
        ])
    };
    let body = serde_json::json!({"plan": "genicam-wall", "dataset": "B"}).to_string();
    let b = data.join("B");
    let t_all = Instant::now();

    let mut camera = start_camera();

    // Session 1: pause and resume, then SIGKILL the daemon mid-run.
    let d = daemon();
    let r = d.post("/api/v1/runs", "operator-ada", &body);
    assert_eq!(r.status, 201, "{}", r.text());
    let id = r.json()["id"].as_str().unwrap().to_string();
    let s = d.wait_run(&id, "viewer-token", 120, "capturing", |s| {
        s["done"].as_u64().unwrap_or(0) >= 2 || s["state"] == "failed" || s["state"] == "paused"
    });
    assert_eq!(s["state"], "running", "the run stopped before its second capture: {s}");
    let p = d.post(&format!("/api/v1/runs/{id}/pause"), "operator-ada", "");
    assert_eq!(p.status, 200, "{}", p.text());
    let paused = d.wait_run(&id, "viewer-token", 60, "paused", |s| s["state"] == "paused");
    // The captures delivered before the pause are committed (processing lags capture); after
    // that nothing may follow while paused (each capture takes well under a second here).
    let journaled = paused["done"].as_u64().unwrap() as usize;
    wait_journaled(&b, journaled, "the captures delivered before the pause");
    std::thread::sleep(Duration::from_millis(1500));
    let still = d.get(&format!("/api/v1/runs/{id}"), "viewer-token").json();
    assert_eq!((&still["state"], &still["done"]), (&paused["state"], &paused["done"]), "captures went on while paused");
    assert_eq!(journaled_steps(&b), journaled, "the journal grew while paused");
    let rs = d.post(&format!("/api/v1/runs/{id}/resume"), "operator-ada", "");
    assert_eq!(rs.status, 200, "{}", rs.text());
    wait_journaled(&b, journaled + 2, "after the resume");
    let mut d = d;
    d.child.kill().unwrap(); // SIGKILL: the daemon and its run die at once
    d.child.wait().unwrap();
    drop(d);
    let killed_at = journaled_steps(&b);
    assert!(killed_at < CAPTURES, "the run had finished before the kill ({killed_at} of {CAPTURES})");
    eprintln!("daemon SIGKILLed with {killed_at} captures journaled");

    // Session 2: the same request resumes the dataset; then the camera process dies.
    let d = daemon();
    let r = d.post("/api/v1/runs", "operator-ada", &body);
    assert_eq!(r.status, 201, "{}", r.text());
    let id = r.json()["id"].as_str().unwrap().to_string();
    let s = d.wait_run(&id, "viewer-token", 180, "capturing after the daemon's restart", |s| {
        s["done"].as_u64().unwrap_or(0) as usize >= killed_at + 2 || s["state"] == "failed" || s["state"] == "paused"
    });
    assert_eq!(s["state"], "running", "the run stopped after the daemon's restart: {s}");
    kill(camera);
    let lost_at = Instant::now();
    // A retry, then a clear paused state naming the camera, within the retry budget: the
    // 180 s bound only catches a hang (the retries and their reconnects take ~10-30 s here).
    let faulted = d.wait_run(&id, "viewer-token", 180, "paused on the lost camera", |s| s["state"] == "paused");
    let lost_s = lost_at.elapsed().as_secs_f64();
    let message = faulted["message"].as_str().unwrap_or_default();
    assert!(
        message.contains("camera") && message.contains("127.0.0.1"),
        "the pause does not name the camera: {faulted}"
    );
    let warnings = faulted["warnings"].to_string();
    assert!(warnings.contains("retry 1 of 2"), "no retry before the pause: {faulted}");
    let done_at_loss = faulted["done"].as_u64().unwrap() as usize;
    assert!(done_at_loss < CAPTURES, "{faulted}");
    // Paused on the fault stays paused while the camera is away.
    std::thread::sleep(Duration::from_millis(1000));
    assert_eq!(d.get(&format!("/api/v1/runs/{id}"), "viewer-token").json()["state"], "paused");

    // The camera is back (a new process: its registers are reset, its frame ids start over);
    // the operator resumes and the run finishes.
    camera = start_camera();
    let rs = d.post(&format!("/api/v1/runs/{id}/resume"), "operator-ada", "");
    assert_eq!(rs.status, 200, "{}", rs.text());
    let end = d.wait_run(&id, "viewer-token", 300, "finished", |s| s["state"] == "finished" || s["state"] == "failed");
    assert_eq!(end["state"], "finished", "{end}");
    drop(d);
    kill(camera);

    // Every capture journaled once; the dataset verifies.
    let journal = read_journal(&b);
    let steps: Vec<Step> = journal.steps.iter().map(|s| s.0).collect();
    let distinct: BTreeSet<Step> = steps.iter().copied().collect();
    assert_eq!(distinct.len(), steps.len(), "a step journaled twice: {steps:?}");
    assert_eq!(steps.len(), CAPTURES);
    verify(&b);

    // Every raw frame came whole through the GenICam stream: the configured size, format,
    // exposure and gain, and the fake camera's test pattern in every pixel. For Bayer formats
    // Aravis 0.8 fills colour ramps (red falling and blue rising along a row, green flat), each
    // colour's samples constant along the anti-diagonals of its own 2x2 lattice: a row shifted,
    // cut or torn on the way breaks that.
    for (step, files) in journal.committed() {
        let (raw, _) =
            files.iter().find(|(p, _)| p.starts_with("raw/")).unwrap_or_else(|| panic!("{step:?}: {files:?}"));
        let f = btfrig_imageio::read_raw_exr(&b.join(raw)).unwrap();
        assert_eq!((f.width, f.height), (160, 120), "{raw}");
        let m = &f.meta;
        assert_eq!((m.bit_depth, m.bayer.map(|b| format!("{b:?}"))), (8, Some("Rggb".into())), "{raw}: {m:?}");
        assert_eq!((m.exposure_s, m.gain), (EXPOSURE_S, 1.0), "{raw}: {m:?}");
        let at = |x: usize, y: usize| f.data[y * f.width + x];
        for y in 2..f.height {
            for x in 0..f.width - 2 {
                assert_eq!(at(x, y), at(x + 2, y - 2), "{raw}: not the fake camera's pattern at ({x}, {y})");
            }
        }
        assert!((0..f.width - 2).any(|x| at(x, 0) != at(x + 2, 0)), "{raw}: a flat red row");
    }

    // The report: wall clock, the camera by identity, the dropped buffers of the loss counted.
    let report = read_json(&b.join("report.json"));
    assert_eq!(report["rig_time"], "wall", "{report}");
    let camera_link =
        report["links"].as_array().unwrap().iter().find(|l| l["role"] == "camera").expect("the camera's link").clone();
    assert!(camera_link["target"].as_str().unwrap().contains(SERIAL), "{camera_link}");
    let dropped = camera_link["dropped_buffers"].as_u64().unwrap();
    assert!(dropped >= 1, "the lost camera's failed frames were not counted: {camera_link}");
    eprintln!(
        "{CAPTURES} captures: daemon killed at {killed_at}, camera lost at {done_at_loss} (paused {lost_s:.1} s after the \
         kill: {message}); {dropped} dropped buffer(s) in the last session; {:.1} s wall in all",
        t_all.elapsed().as_secs_f64()
    );
}

/// The small simulated rig with its camera seen through a fed fake camera over loopback GigE
/// Vision (as `rig-configs/bonn-gonio-genicam.toml` does for the default rig).
fn small_genicam_rig_text() -> String {
    let text = std::fs::read_to_string(repo("rig-configs/bonn-gonio-sim-small.toml")).unwrap();
    let from = "[devices.camera]\nkind = \"sim\"\n";
    assert!(text.contains(from), "bonn-gonio-sim-small.toml no longer has {from:?}");
    text.replace(
        from,
        "[devices.camera]\nkind = \"genicam\"\nlink = { emulated = true, address = \"127.0.0.1\", pixel_format = \"BayerRG16\", serial = \"BTFRIG-CAL\" }\n",
    )
}

/// A calibration runs through a GenICam camera like through any other (issue 26: no
/// calibration refuses a rig): dark and flat fields captured through the fed fake camera over
/// loopback GigE Vision are bit for bit those captured from the simulated camera directly.
#[test]
fn a_calibration_through_a_genicam_camera_equals_the_direct_one() {
    if !netns::in_netns("a_calibration_through_a_genicam_camera_equals_the_direct_one") {
        return;
    }
    netns::assert_loopback_only();
    let dir = scratch("genicam-calibration");
    let rig = dir.join("small-genicam.toml");
    std::fs::write(&rig, small_genicam_rig_text()).unwrap();
    let (direct, genicam) = (dir.join("direct"), dir.join("genicam"));
    ok(btfrig()
        .args(["calibrate", "radiometric", "--rig"])
        .arg(repo("rig-configs/bonn-gonio-sim-small.toml"))
        .arg("--out")
        .arg(&direct));
    let out = ok(btfrig().args(["calibrate", "radiometric", "--rig"]).arg(&rig).arg("--out").arg(&genicam));
    println!("{out}");
    let files = |d: &Path| -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(d)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n.ends_with(".exr"))
            .collect();
        v.sort();
        v
    };
    let maps = files(&direct);
    assert!(maps.iter().any(|n| n == "dark.exr"), "{maps:?}");
    assert_eq!(files(&genicam), maps);
    for m in &maps {
        assert!(std::fs::read(direct.join(m)).unwrap() == std::fs::read(genicam.join(m)).unwrap(), "{m} differs");
    }
}

/// Before anything is created, a run asks the GenICam camera who it is: with no camera at the
/// address, `btfrig run` fails naming the camera and its address, and writes nothing;
/// `btfrig hw probe --rig` exits 1 naming it.
#[test]
fn a_run_with_no_camera_at_the_address_fails_before_anything_is_created() {
    if !netns::in_netns("a_run_with_no_camera_at_the_address_fails_before_anything_is_created") {
        return;
    }
    netns::assert_loopback_only();
    let dir = scratch("genicam-no-camera");
    let (rig_dir, plans) = (dir.join("rig"), dir.join("plans"));
    for d in [&rig_dir, &plans] {
        std::fs::create_dir_all(d).unwrap();
    }
    std::fs::write(rig_dir.join("rig.toml"), rig_text()).unwrap();
    let plan_file = plans.join("plan.toml");
    std::fs::write(&plan_file, plan()).unwrap();
    let out = dir.join("out");
    let o = btfrig().args(["run", "--plan"]).arg(&plan_file).arg("--out").arg(&out).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert!(err.contains("devices.camera on GenICam 127.0.0.1") && err.contains("preflight"), "{}", text(&o));
    assert!(!out.exists(), "{} was created", out.display());
    let o = btfrig().args(["hw", "probe", "--rig"]).arg(rig_dir.join("rig.toml")).output().unwrap();
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert!(String::from_utf8_lossy(&o.stderr).contains("127.0.0.1"), "{}", text(&o));
}
