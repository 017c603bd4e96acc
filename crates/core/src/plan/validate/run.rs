//! `[run]`: fault scenario, retries and timeouts.

use crate::config::RigConfig;

use super::rig::is_simulated;
use super::PlanContext;
use crate::plan::{PlanError, RunSpec};

pub(super) fn resolve_run(
    r: &RunSpec,
    ctx: &PlanContext,
    rig: Option<&RigConfig>,
    errors: &mut Vec<PlanError>,
) -> RunSpec {
    let mut out = r.clone();
    if let Some(f) = &r.fault_scenario {
        let stem = f.strip_suffix(".toml").unwrap_or(f);
        if !ctx.known_faults.iter().any(|k| k == stem) {
            errors.push(PlanError::unknown(
                "run.fault_scenario",
                f,
                format!("{} (files in sim/faults/), or leave it out", ctx.known_faults.join(", ")),
            ));
        }
        if rig.is_some_and(|r| !is_simulated(r)) && stem != "none" {
            errors.push(PlanError::invalid(
                "run.fault_scenario",
                format!("{f:?}"),
                "fault injection only applies to a simulated rig",
                "no fault scenario for a real rig",
            ));
        }
        out.fault_scenario = Some(stem.to_string());
    }
    if r.max_retries > 100 {
        errors.push(PlanError::out_of_range("run.max_retries", r.max_retries, "0..=100"));
    }
    if !(r.backoff_s.is_finite() && (0.0..=600.0).contains(&r.backoff_s)) {
        errors.push(PlanError::out_of_range("run.backoff_s", r.backoff_s, "0 ..= 600 seconds"));
    }
    for (key, v) in [("move_timeout_s", r.move_timeout_s), ("capture_timeout_s", r.capture_timeout_s)] {
        if !(v.is_finite() && v > 0.0 && v <= 3600.0) {
            errors.push(PlanError::out_of_range(format!("run.{key}"), v, "> 0 and <= 3600 seconds"));
        }
    }
    out
}
