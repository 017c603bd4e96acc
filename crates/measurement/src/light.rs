//! The lamp figures of a run with a light calibration (`RunRequest::light`): lamp factor
//! range and per-step factors in `report.json` and the summary JSON.

use btfrig_process::light::LampTotals;
use serde_json::{json, Value};

/// The report's `lamp` object: range, largest standard error, brightness against the truth
/// at the nominal lamp (simulated rig), and every step's factor (with a light calibration).
pub fn lamp_json(l: &LampTotals) -> Value {
    let range = l.factor_range();
    // Per-step figures only with measured factors (a light calibration): a run without one
    // would list every capture for its brightness figure alone.
    let steps: Vec<Value> = l
        .steps
        .iter()
        .filter(|_| l.frames > 0)
        .map(|s| {
            json!({
                "light": s.step.light,
                "view": s.step.view,
                "factor": s.factor.map(|f| f.factor),
                "sigma": s.factor.map(|f| f.sigma),
                "points": s.factor.map(|f| f.points),
                "brightness_err": s.brightness_err,
            })
        })
        .collect();
    json!({
        "frames_measured": l.frames,
        "lamp_factor_min": range.map(|r| r.0),
        "lamp_factor_max": range.map(|r| r.1),
        "lamp_factor_sigma_max": (l.frames > 0).then_some(l.sigma_max),
        "brightness_err_abs_max": l.brightness_err_abs_max(),
        "steps": steps,
    })
}

/// Adds `lamp_factor_min`, `lamp_factor_max` and `brightness_err_abs_max` to a summary object
/// (`null` without a light calibration).
pub fn add_summary_fields(v: &mut Value, l: Option<&LampTotals>) {
    let range = l.and_then(|l| l.factor_range());
    v["lamp_factor_min"] = json!(range.map(|r| r.0));
    v["lamp_factor_max"] = json!(range.map(|r| r.1));
    v["brightness_err_abs_max"] = json!(l.and_then(|l| l.brightness_err_abs_max()));
}
