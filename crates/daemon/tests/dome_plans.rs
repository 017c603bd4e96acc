//! Dome plans through the HTTP API: the daemon on an LED dome and on a camera array validates
//! and dry-runs them (the multiplexing choice with its reason, every candidate mode with its
//! predicted gain, frames, rig time and disk), and a plan for the other kind of rig is refused
//! with both kinds named — by validate, dry run and start alike (dome runs themselves:
//! `dome_runs.rs`). The daemon runs in-process ([`btfrig_daemon::router`] on a loopback port)
//! and is driven over HTTP only.

mod support;

use serde_json::{json, Value};
use support::{plan_file, Daemon};

fn candidate<'a>(dome: &'a Value, mode: &str) -> &'a Value {
    dome["candidates"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["mode"] == mode)
        .unwrap_or_else(|| panic!("no candidate {mode:?} in {}", dome["candidates"]))
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("not a number: {v}"))
}

/// The dome demo on the LED dome: validate, dry run with every candidate, and starting it or
/// a plan of another rig refused by name.
#[test]
fn an_led_dome_daemon_dry_runs_dome_plans_and_refuses_gonio_plans() {
    let d = Daemon::start("dome_plans_led_dome", Some("rig-configs/bonn-dome-sim.toml"));
    let rig = d.get("/api/v1/rig");
    assert_eq!((rig["rig"]["name"].as_str(), rig["rig"]["kind"].as_str()), (Some("bonn-dome-sim"), Some("led_dome")));
    let devices: Vec<&str> = rig["devices"].as_array().unwrap().iter().map(|x| x["name"].as_str().unwrap()).collect();
    assert_eq!(devices, ["camera", "turntable", "led_array"], "a dome has no robot, rail or lamp");
    // Only the embedded plans for this rig are offered.
    let plans = d.get("/api/v1/plans");
    let names: Vec<&str> = plans["plans"].as_array().unwrap().iter().map(|p| p["name"].as_str().unwrap()).collect();
    assert_eq!(names, ["dome-demo"], "{plans}");
    assert_eq!(plans["plans"][0]["captures"], 792, "198 LEDs x 2 cameras x 2 rotations");

    let v = d.check("validate", json!({ "plan": "dome-demo" }));
    assert_eq!(
        (v["valid"].as_bool(), v["kind"].as_str(), v["captures"].as_u64()),
        (Some(true), Some("dome"), Some(792))
    );
    assert!(v["dome"].is_null() && v["estimate_s"].is_null(), "validation does not plan: {v}");

    // The dry run, by name and as text alike.
    let by_name = d.check("dry-run", json!({ "plan": "dome-demo" }));
    let by_text = d.check("dry-run", json!({ "plan_text": plan_file("dome-demo") }));
    assert_eq!(by_name["dome"], by_text["dome"]);
    let r = by_name;
    assert_eq!(
        (r["valid"].as_bool(), r["kind"].as_str(), r["captures"].as_u64()),
        (Some(true), Some("dome"), Some(792))
    );
    assert!(r["errors"].as_array().unwrap().is_empty(), "{r}");
    let dome = &r["dome"];
    assert_eq!((dome["rig_kind"].as_str(), dome["light"].as_str()), (Some("led_dome"), Some("LED")));
    assert_eq!(
        (dome["lights"].as_u64(), dome["views"].as_u64(), dome["textures"].as_u64()),
        (Some(198), Some(4), Some(792))
    );
    assert_eq!((&dome["cameras"], &dome["rotations"]), (&json!([2, 6]), &json!([0, 3])));
    // The noise model chooses the S-matrix (read-noise limited: a few e- per LED per frame).
    assert_eq!(
        (dome["mode"].as_str(), dome["noise_model_choice"].as_str()),
        (Some("s-matrix 199"), Some("s-matrix 199"))
    );
    assert!(
        dome["reason"].as_str().unwrap().starts_with("multiplexing with s-matrix 199: predicted gain 3.43"),
        "{dome}"
    );
    let gain = f(&dome["predicted_gain"]);
    assert!(gain > 3.0 && gain < 4.0, "predicted gain {gain} (docs: 3.425)");
    assert!(f(&dome["time_saved_fraction"]) > 0.3, "{dome}");
    // 199 frames per view group x 2 rotations, plus 4 single-LED reference frames.
    assert_eq!((dome["frames_per_view_group"].as_u64(), dome["reference_frames"].as_u64()), (Some(199), Some(4)));
    assert_eq!(dome["frames_per_camera"], 402);
    let parts: f64 = ["exposing_s", "transfer_s", "turntable_s", "commands_s"].iter().map(|k| f(&dome[*k])).sum();
    assert!((parts - f(&dome["rig_time_s"])).abs() < 1e-9 && f(&dome["turntable_s"]) > 0.0, "{dome}");
    assert_eq!(f(&r["estimate_s"]), f(&dome["rig_time_s"]));
    assert_eq!(r["disk_bytes"], dome["disk_bytes"]);
    assert!(dome["disk_bytes"].as_u64().unwrap() > 792 * 32 * 32 * 12, "{dome}");
    assert!(r["naive_order_s"].is_null() && r["lower_bound_s"].is_null(), "gonio-only figures: {r}");
    let text = r["text"].as_str().unwrap();
    assert!(text.starts_with("dome plan \"dome-demo\" from dome-demo on rig bonn-dome-sim (led_dome)"), "{text}");
    assert!(text.contains("mode s-matrix 199: multiplexing with s-matrix 199"), "{text}");

    // Every candidate: its gain, frames, rig time and disk; the chosen one is the plan's.
    let cands = dome["candidates"].as_array().unwrap();
    assert_eq!(cands[0]["mode"], "single-light");
    assert!(cands.len() > 10, "single light, the S-matrix and grouped codes: {}", cands.len());
    assert_eq!(cands.iter().filter(|c| c["chosen"] == true).count(), 1);
    assert_eq!(cands.iter().filter(|c| c["used"] == true).count(), 1);
    let single = candidate(dome, "single-light");
    assert_eq!((f(&single["predicted_gain"]), single["frames_per_camera"].as_u64()), (1.0, Some(396)), "{single}");
    let smatrix = candidate(dome, "s-matrix 199");
    assert_eq!((&smatrix["chosen"], &smatrix["used"]), (&json!(true), &json!(true)));
    assert_eq!(f(&smatrix["predicted_gain"]), gain);
    assert_eq!((smatrix["frames_per_camera"].as_u64(), f(&smatrix["rig_time_s"])), (Some(402), f(&dome["rig_time_s"])));
    let grouped = candidate(dome, "groups 7 x 31");
    assert_eq!(grouped["frames_per_view_group"], 217);
    assert_eq!(grouped["frames_per_camera"], 2 * 217 + 4);
    for c in cands {
        assert_eq!(c["disk_bytes"], dome["disk_bytes"], "one texture per LED and view in every mode");
        assert!(
            f(&c["predicted_gain"]) > 0.0 && f(&c["rig_time_s"]) > 0.0 && c["group_bytes"].as_u64() > Some(0),
            "{c}"
        );
        assert!(f(&c["predicted_gain"]) <= gain + 1e-12, "the choice has the best gain: {c}");
    }
    // More frames, more rig time (the exposure budget is the same in every mode).
    assert!(
        f(&grouped["rig_time_s"]) > f(&smatrix["rig_time_s"]) && f(&smatrix["rig_time_s"]) > f(&single["rig_time_s"])
    );

    // A forced mode is reported as used, the noise model's choice as chosen.
    let forced = plan_file("dome-demo").replace("multiplex = \"auto\"", "multiplex = \"off\"");
    let r = d.check("dry-run", json!({ "plan_text": forced }));
    assert_eq!(
        (r["dome"]["mode"].as_str(), r["dome"]["noise_model_choice"].as_str()),
        (Some("single-light"), Some("s-matrix 199"))
    );
    assert_eq!(f(&r["dome"]["predicted_gain"]), 1.0);
    assert_eq!(candidate(&r["dome"], "single-light")["used"], true);
    assert_eq!(candidate(&r["dome"], "s-matrix 199")["chosen"], true);
    // A broken dome plan names the field.
    let broken = plan_file("dome-demo").replace("cameras = [2, 6]", "cameras = [2, 99]");
    let r = d.check("dry-run", json!({ "plan_text": broken }));
    assert_eq!((r["valid"].as_bool(), r["kind"].as_str()), (Some(false), Some("dome")));
    assert!(
        r["errors"][0].as_str().unwrap().contains("dome.cameras") && r["errors"][0].as_str().unwrap().contains("99"),
        "{r}"
    );

    // Text that is no TOML at all is a syntax error, not a plan for another rig.
    let r = d.check("validate", json!({ "plan_text": "[dome\ncameras = [" }));
    let e = r["errors"][0].as_str().unwrap();
    assert!(r["valid"] == false && r["kind"].is_null(), "{r}");
    assert!(e.contains("TOML parse error") && !e.contains("allowed here are"), "{e}");

    // A gonio plan on the dome: refused everywhere, naming both kinds and what is allowed.
    for check in ["validate", "dry-run"] {
        let r = d.check(check, json!({ "plan_text": plan_file("demo") }));
        assert_eq!((r["valid"].as_bool(), r["kind"].as_str()), (Some(false), Some("gonioreflectometer")), "{r}");
        let e = r["errors"][0].as_str().unwrap();
        assert!(
            e.contains("gonioreflectometer plan")
                && e.contains("\"bonn-gonio-sim\" (gonioreflectometer)")
                && e.contains("\"bonn-dome-sim\" (led_dome)")
                && e.contains("allowed here are dome plans"),
            "{e}"
        );
    }
    let e = d.refused_start(json!({ "plan_text": plan_file("demo") }));
    assert!(
        e.contains("(gonioreflectometer)") && e.contains("(led_dome)") && e.contains("allowed here are dome plans"),
        "{e}"
    );
    // A camera-array plan is a dome plan, but for another rig.
    let r = d.check("dry-run", json!({ "plan_text": plan_file("camera-array-demo") }));
    let e = r["errors"][0].as_str().unwrap();
    assert!(r["valid"] == false && e.contains("(camera_array)") && e.contains("(led_dome)"), "{r}");
    let e = d.refused_start(json!({ "plan_text": plan_file("camera-array-demo") }));
    assert!(e.contains("(camera_array)") && e.contains("\"bonn-dome-sim\" (led_dome)"), "{e}");
    // The dome demo itself is valid here and runs: tests/dome_runs.rs.
    assert_eq!(std::fs::read_dir(&d.data).unwrap().count(), 0, "refused starts create nothing");
}

#[test]
fn a_camera_array_daemon_dry_runs_its_flashes_multiplexed() {
    let d = Daemon::start("dome_plans_camera_array", Some("rig-configs/bonn-camera-array-sim.toml"));
    let r = d.check("dry-run", json!({ "plan": "camera-array-demo" }));
    assert_eq!((r["valid"].as_bool(), r["captures"].as_u64()), (Some(true), Some(453)), "151 flashes x 3 cameras: {r}");
    let dome = &r["dome"];
    assert_eq!((dome["rig_kind"].as_str(), dome["light"].as_str()), (Some("camera_array"), Some("flash")));
    assert_eq!(dome["mode"], "s-matrix 151");
    let gain = f(&dome["predicted_gain"]);
    assert!(gain > 2.7 && gain < 3.5, "predicted gain {gain} (docs: 3.125)");
    // 151 frames and 4 reference flashes, one rotation: no turntable.
    assert_eq!((dome["frames_per_camera"].as_u64(), f(&dome["turntable_s"])), (Some(155), 0.0));
    assert_eq!(candidate(dome, "s-matrix 151")["chosen"], true);
    assert_eq!(candidate(dome, "single-light")["frames_per_camera"], 151);
    // The LED dome's plan is for another dome.
    let e = d.refused_start(json!({ "plan_text": plan_file("dome-demo") }));
    assert!(e.contains("(led_dome)") && e.contains("\"bonn-camera-array-sim\" (camera_array)"), "{e}");
}

/// The embedded gonioreflectometer: dome plans are refused with both kinds named, gonio
/// plans are dry-run as before.
#[test]
fn a_gonio_daemon_refuses_dome_plans_naming_both_kinds() {
    let d = Daemon::start("dome_plans_gonio", None);
    let plans = d.get("/api/v1/plans");
    let names: Vec<&str> = plans["plans"].as_array().unwrap().iter().map(|p| p["name"].as_str().unwrap()).collect();
    assert!(names.contains(&"demo") && !names.iter().any(|n| n.contains("dome") || n.contains("array")), "{names:?}");
    for plan in ["dome-demo", "camera-array-demo"] {
        for check in ["validate", "dry-run"] {
            let r = d.check(check, json!({ "plan_text": plan_file(plan) }));
            assert_eq!(
                (r["valid"].as_bool(), r["kind"].as_str(), r["captures"].as_u64()),
                (Some(false), Some("dome"), Some(0))
            );
            let e = r["errors"][0].as_str().unwrap();
            assert!(
                e.contains("dome plan (a [dome] table)")
                    && e.contains("\"bonn-gonio-sim\" (gonioreflectometer)")
                    && e.contains("allowed here are gonioreflectometer plans"),
                "{e}"
            );
        }
        let e = d.refused_start(json!({ "plan_text": plan_file(plan) }));
        let kind = if plan == "dome-demo" { "(led_dome)" } else { "(camera_array)" };
        assert!(e.contains(kind) && e.contains("(gonioreflectometer)"), "{e}");
    }
    assert_eq!(std::fs::read_dir(&d.data).unwrap().count(), 0, "refused starts create nothing");
    let r = d.check("dry-run", json!({ "plan": "demo" }));
    assert_eq!((r["valid"].as_bool(), r["kind"].as_str()), (Some(true), Some("gonioreflectometer")), "{r}");
    // The optimised order may reach the lower bound; the two sums then differ by rounding only.
    assert!(f(&r["estimate_s"]) >= f(&r["lower_bound_s"]) * (1.0 - 1e-12) && r["dome"].is_null(), "{r}");
}

/// The OpenAPI document describes the dome dry run field by field, and what a run's progress
/// counts.
#[test]
fn the_openapi_document_describes_the_dome_dry_run() {
    let d = Daemon::start("dome_plans_openapi", None);
    let doc = d.get("/api/v1/openapi.json");
    let s = &doc["components"]["schemas"];
    for (schema, fields) in [
        ("PlanCheck", &["kind", "dome", "estimate_s", "disk_bytes"][..]),
        (
            "DomeDryRun",
            &[
                "mode",
                "reason",
                "noise_model_choice",
                "predicted_gain",
                "frames_per_camera",
                "rig_time_s",
                "disk_bytes",
                "candidates",
            ],
        ),
        ("DomeCandidate", &["mode", "chosen", "predicted_gain", "frames_per_camera", "rig_time_s", "disk_bytes"]),
        // A run's status says what its progress counts (dome runs: steps, and textures beside).
        ("RunStatus", &["unit", "done", "total", "textures", "textures_total", "preview_seq"]),
    ] {
        for field in fields {
            let p = &s[schema]["properties"][*field];
            assert!(p.is_object(), "{schema}.{field} missing: {}", s[schema]);
            // An optional reference carries its description inside `oneOf` (utoipa).
            let mut described = std::iter::once(p).chain(p["oneOf"].as_array().into_iter().flatten());
            assert!(
                described.any(|x| x["description"].as_str().is_some_and(|d| !d.is_empty())),
                "{schema}.{field} has no description: {p}"
            );
        }
    }
    assert!(s["PlanKind"].to_string().contains("gonioreflectometer") && s["PlanKind"].to_string().contains("dome"));
    assert_eq!(s["ProgressUnit"]["enum"], json!(["captures", "steps"]), "{}", s["ProgressUnit"]);
}
