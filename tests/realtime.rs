//! Issue 26, item 1: real-time runs and preflight, through the real `btfrig` binary.
//!
//! - A small plan on the emulated serial firmware (`tests/data/realtime/rig-serial-fast.toml`:
//!   robot, rail and lamp behind their firmware on pseudo-terminals, the camera behind a PTP
//!   responder, a fast timing model) runs on the wall clock through `btfrig serve` (`[run]
//!   clock = "wall"`): paused, resumed, SIGKILLed, then resumed and finished by `btfrig run`.
//!   Its textures equal those of the same plan run on virtual time, byte for byte.
//! - `btfrig run` on a rig whose robot names a port that does not exist, a pty nobody
//!   answers on, or a pty that was closed, fails before anything is created, naming the
//!   device and the port; `btfrig hw probe --rig` on it exits 1 naming it.

mod support;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use support::http::{Daemon, AUTH};
use support::*;

const RIG: &str = "tests/data/realtime/rig-serial-fast.toml";

/// A plan of `captures` captures on the rig at `rig` (relative to the plan), on `clock`
/// (`None`: the rig's own, virtual for this rig).
fn plan(rig: &str, captures: usize, clock: Option<&str>) -> String {
    let run = clock.map_or(String::new(), |c| format!("[run]\nclock = \"{c}\"\n"));
    format!(
        r#"name = "realtime"
description = "a few captures on the emulated serial rig, for the real-time tests"
[rig]
config = "{rig}"
material = "corduroy"
seed = 11
[sampling]
light = {{ preset = "bonn81", theta_max_deg = 30 }}
view = {{ preset = "bonn81", theta_max_deg = 30 }}
[texture]
size = 32
[registration]
method = "nominal"
[exposure]
mode = "auto"
[outputs]
textures = true
format = "exr-half"
[skip]
max_captures = {captures}
{run}"#
    )
}

/// Step -> (journaled hash, texture bytes) of a dataset.
fn textures(dir: &Path) -> BTreeMap<Step, (String, Vec<u8>)> {
    read_journal(dir)
        .committed()
        .into_iter()
        .map(|(step, files)| {
            let (path, hash) = files[0].clone();
            (step, (hash, std::fs::read(dir.join(&path)).unwrap_or_else(|e| panic!("{path}: {e}"))))
        })
        .collect()
}

#[test]
fn a_wall_clock_run_paused_resumed_killed_and_resumed_equals_a_virtual_time_run() {
    const N: usize = 12;
    let dir = scratch("realtime-wall");
    let (rig_dir, plans) = (dir.join("rig"), dir.join("plans"));
    std::fs::create_dir_all(&rig_dir).unwrap();
    std::fs::create_dir_all(&plans).unwrap();
    let rig = rig_dir.join("rig-serial-fast.toml");
    std::fs::copy(repo(RIG), &rig).unwrap();
    let virtual_plan = dir.join("virtual.toml");
    std::fs::write(&virtual_plan, plan("rig/rig-serial-fast.toml", N, None)).unwrap();
    let wall_plan = plans.join("realtime-wall.toml");
    std::fs::write(&wall_plan, plan("../rig/rig-serial-fast.toml", N, Some("wall"))).unwrap();

    // A: virtual time.
    let a = dir.join("A");
    let t0 = Instant::now();
    ok(btfrig().args(["run", "--plan"]).arg(&virtual_plan).arg("--out").arg(&a));
    let virtual_wall_s = t0.elapsed().as_secs_f64();
    let reference = textures(&a);
    assert_eq!(reference.len(), N);
    let report_a = read_json(&a.join("report.json"));
    assert_eq!(report_a["rig_time"], "virtual", "{report_a}");

    // B: the wall clock, through the daemon: pause, resume, SIGKILL.
    let auth = dir.join("auth.toml");
    std::fs::write(&auth, AUTH).unwrap();
    let data = dir.join("data");
    let t1 = Instant::now();
    let d = Daemon::start(&[
        "--auth",
        auth.to_str().unwrap(),
        "--data",
        data.to_str().unwrap(),
        "--rig",
        rig.to_str().unwrap(),
        "--plans",
        plans.to_str().unwrap(),
    ]);
    let body = serde_json::json!({"plan": "realtime-wall", "dataset": "B"}).to_string();
    let r = d.post("/api/v1/runs", "operator-ada", &body);
    assert_eq!(r.status, 201, "{}", r.text());
    let id = r.json()["id"].as_str().unwrap().to_string();
    d.wait_run(&id, "viewer-token", 120, "capturing", |s| s["done"].as_u64().unwrap_or(0) >= 2);
    let p = d.post(&format!("/api/v1/runs/{id}/pause"), "operator-ada", "");
    assert_eq!(p.status, 200, "{}", p.text());
    let paused = d.wait_run(&id, "viewer-token", 60, "paused", |s| s["state"] == "paused");
    // Paused means paused on the wall clock too: the journal does not grow. The daemon's
    // own counter is checked after a commit could have landed (each capture takes well under
    // a second here).
    let journaled = journaled_steps(&data.join("B"));
    std::thread::sleep(Duration::from_millis(1500));
    let still = d.get(&format!("/api/v1/runs/{id}"), "viewer-token").json();
    assert_eq!(still["state"], "paused", "{still}");
    assert_eq!(still["done"], paused["done"], "captures went on while paused: {still}");
    assert_eq!(journaled_steps(&data.join("B")), journaled, "the journal grew while paused");
    let rs = d.post(&format!("/api/v1/runs/{id}/resume"), "operator-ada", "");
    assert_eq!(rs.status, 200, "{}", rs.text());
    let before_kill = paused["done"].as_u64().unwrap() as usize;
    let b = data.join("B");
    let t_wait = Instant::now();
    while journaled_steps(&b) < before_kill + 2 {
        assert!(t_wait.elapsed() < Duration::from_secs(120), "no progress after resume");
        std::thread::sleep(Duration::from_millis(5));
    }
    let mut d = d;
    d.child.kill().unwrap(); // SIGKILL: the daemon and its run die at once
    d.child.wait().unwrap();
    drop(d);
    let killed_at = journaled_steps(&b);
    assert!(killed_at < N, "the run had finished before the kill ({killed_at} of {N})");
    assert!(!b.join("report.json").exists() || read_json(&b.join("report.json"))["status"] != "finished");

    // Resumed by `btfrig run` on the same plan file: the wall clock from the plan's [run].
    let o = btfrig().args(["run", "--plan"]).arg(&wall_plan).arg("--out").arg(&b).output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    let wall_s = t1.elapsed().as_secs_f64();
    let resumed = textures(&b);
    assert_eq!(resumed.keys().collect::<Vec<_>>(), reference.keys().collect::<Vec<_>>(), "captured steps differ");
    let differ: Vec<&Step> = reference.iter().filter(|(s, v)| resumed[*s] != **v).map(|(s, _)| s).collect();
    assert!(
        differ.is_empty(),
        "{} of {N} textures differ between virtual and wall-clock runs: {differ:?}",
        differ.len()
    );
    let report = read_json(&b.join("report.json"));
    assert_eq!(report["rig_time"], "wall", "{report}");
    let devices = report["devices"].as_array().expect("the report lists the devices");
    let robot = devices.iter().find(|d| d["role"] == "robot").expect("robot");
    assert_eq!(robot["backend"], "serial-robot", "{robot}");
    let hardware_s = report["hardware_s"].as_f64().unwrap();
    verify(&b);
    eprintln!(
        "virtual run: {virtual_wall_s:.2} s wall; wall-clock run (pause, kill, resume): {wall_s:.2} s wall, \
         {hardware_s:.2} s rig time over the reported sessions; killed at {killed_at}/{N}"
    );
}

/// The rig with its robot a real serial controller on `port`.
fn rig_with_robot_port(dir: &Path, port: &str) -> PathBuf {
    let text = std::fs::read_to_string(repo(RIG)).unwrap();
    let text = text.replace(
        "kind = \"serial\"\nlink = { emulated = true, poll_s = 0.005 }\njoint_min_deg",
        &format!(
            "kind = \"serial\"\nlink = {{ port = \"{port}\", baud = 115200, reply_timeout_ms = 500 }}\njoint_min_deg"
        ),
    );
    assert!(text.contains(port), "the robot's link was not replaced");
    let rig = dir.join("rig.toml");
    std::fs::write(&rig, text).unwrap();
    rig
}

/// `btfrig run` on the rig with the robot on `port` fails naming the robot and the port, and
/// creates nothing; `hw probe --rig` exits 1 naming them.
fn refused_before_anything_is_created(name: &str, port: &str, why: &str) {
    let dir = scratch(name);
    let rig = rig_with_robot_port(&dir, port);
    let plan_file = dir.join("plan.toml");
    std::fs::write(&plan_file, plan("rig.toml", 3, None)).unwrap();
    let out = dir.join("out");
    let o = btfrig().args(["run", "--plan"]).arg(&plan_file).arg("--out").arg(&out).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert!(
        err.contains(&format!("devices.robot on {port} at 115200 baud")) && err.contains(why),
        "the error names the device, the port and {why:?}:\n{}",
        text(&o)
    );
    assert!(err.contains("preflight") && err.contains("nothing was created"), "{}", text(&o));
    assert!(!out.exists(), "{} was created", out.display());

    let o = btfrig().args(["hw", "probe", "--rig"]).arg(&rig).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert!(err.contains(&format!("devices.robot on {port} at 115200 baud")) && err.contains(why), "{}", text(&o));
    // The other devices still answered.
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.lines().any(|l| l.trim_start().starts_with("rail") && l.contains(": Ok")), "{}", text(&o));
}

#[test]
fn an_unplugged_port_fails_before_anything_is_created_naming_device_and_port() {
    refused_before_anything_is_created("realtime-unplugged", "/dev/ttyNOPE", "No such file or directory");
}

#[test]
fn a_silent_pty_and_a_closed_pty_fail_before_anything_is_created() {
    let dir = scratch("realtime-ptys");
    // Nobody answers on this pty: its master is held open, silent.
    let silent = btfrig_serial::pty::PtyPort::open(&dir.join("silent")).unwrap();
    refused_before_anything_is_created("realtime-silent-pty", &silent.link().display().to_string(), "no answer");
    drop(silent);
    // A pty whose other end was closed: the port is gone.
    let closed_link = dir.join("closed");
    drop(btfrig_serial::pty::PtyPort::open(&closed_link).unwrap());
    refused_before_anything_is_created("realtime-closed-pty", &closed_link.display().to_string(), "lost");
}

#[test]
fn the_wall_clock_flag_runs_a_simulated_rig_on_the_wall_clock() {
    let dir = scratch("realtime-flag");
    std::fs::copy(repo(RIG), dir.join("rig.toml")).unwrap();
    let plan_file = dir.join("plan.toml");
    std::fs::write(&plan_file, plan("rig.toml", 2, None)).unwrap();
    let out = dir.join("out");
    ok(btfrig().args(["run", "--wall-clock", "--plan"]).arg(&plan_file).arg("--out").arg(&out));
    let report = read_json(&out.join("report.json"));
    assert_eq!(report["rig_time"], "wall", "{report}");
    let pre = report["preflight"].as_array().expect("preflight in the report");
    assert!(pre.iter().all(|d| d["failure"].is_null()), "{report}");
}
