//! Calibrations started through the API: they hold the rig like a run does and run on a
//! thread of their own; the result and the file written are kept for `GET`.

use std::sync::{Arc, Mutex};

use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

use crate::auth::Caller;
use crate::problem::Problem;
use crate::AppState;

/// Start a calibration.
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct StartCalibration {
    /// `color` (ColorChecker and SG charts on the rig; docs/color.md).
    #[schema(example = "color")]
    pub kind: String,
    /// Seed of the simulated rig; default the rig config's.
    pub seed: Option<u64>,
}

/// A calibration and, when done, its result.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct Calibration {
    /// `c1`, `c2`, ...
    pub id: String,
    /// What is calibrated.
    pub kind: String,
    /// `running`, `finished`, `failed`.
    pub state: String,
    /// Who started it.
    pub owner: String,
    /// Why it failed.
    pub message: Option<String>,
    /// The chosen model and its held-out CIEDE2000 when finished.
    #[schema(value_type = Option<Object>)]
    pub result: Option<serde_json::Value>,
    /// The calibration file written, relative to the data directory.
    pub file: Option<String>,
}

/// Every calibration of this daemon.
#[derive(Default)]
pub struct Calibrations {
    list: Mutex<Vec<Calibration>>,
}

impl Calibrations {
    /// Oldest first.
    pub fn all(&self) -> Vec<Calibration> {
        self.list.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }

    /// The one with `id`.
    pub fn get(&self, id: &str) -> Option<Calibration> {
        self.all().into_iter().find(|c| c.id == id)
    }

    /// The one running, if any.
    pub fn running(&self) -> Option<Calibration> {
        self.all().into_iter().find(|c| c.state == "running")
    }

    fn set(&self, id: &str, f: impl FnOnce(&mut Calibration)) {
        let mut l = self.list.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(c) = l.iter_mut().find(|c| c.id == id) {
            f(c);
        }
    }
}

/// Kinds `POST /api/v1/calibrations` accepts.
pub const KINDS: &[&str] = &["color"];

/// Starts a calibration of `b.kind` if the rig is free.
pub fn start(s: &Arc<AppState>, caller: &Caller, b: StartCalibration) -> Result<Calibration, Problem> {
    if !KINDS.contains(&b.kind.as_str()) {
        return Err(Problem::unprocessable(format!("calibration kind {:?}: allowed are {KINDS:?}", b.kind)));
    }
    if s.rig.devices.camera.kind != "sim" {
        return Err(Problem::unprocessable("calibrations through the daemon drive only simulated rigs so far"));
    }
    // Hold the rig: under the runs' lock, so a run cannot start in between.
    let cal = s.runs.hold_for_calibration(|| {
        let mut l = s.calibrations.list.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(c) = l.iter().find(|c| c.state == "running") {
            return Err(Problem::conflict(format!("the rig is held by calibration {} of {}", c.id, c.owner)));
        }
        let c = Calibration {
            id: format!("c{}", l.len() + 1),
            kind: b.kind.clone(),
            state: "running".into(),
            owner: caller.name.clone(),
            message: None,
            result: None,
            file: None,
        };
        l.push(c.clone());
        Ok(c)
    })?;
    let st = s.clone();
    let id = cal.id.clone();
    let seed = b.seed.unwrap_or(s.rig.rig.seed);
    std::thread::Builder::new()
        .name(format!("calibration-{id}"))
        .spawn(move || {
            let outcome = color(&st, &id, seed);
            st.calibrations.set(&id, |c| match outcome {
                Ok((result, file)) => {
                    c.state = "finished".into();
                    c.result = Some(result);
                    c.file = Some(file);
                }
                Err(e) => {
                    c.state = "failed".into();
                    c.message = Some(e);
                }
            });
        })
        .map_err(|e| Problem::internal(format!("cannot start the calibration's thread: {e}")))?;
    Ok(cal)
}

/// The colour calibration of `btfrig calibrate color`, written to `calibrations/<id>-color.toml`.
fn color(s: &AppState, id: &str, seed: u64) -> Result<(serde_json::Value, String), String> {
    use btfrig_calibrate::color::ColorPlan;
    let camera = btfrig_calibrate::processing_camera(&s.rig, s.rig_path.as_deref()).map_err(|e| e.to_string())?;
    let plan = ColorPlan::default_plan();
    // The charts are photographed through the rig's devices, against their published values.
    let references = btfrig_measurement::color_calibration::chart_references(&s.rig, s.rig_path.as_deref(), &plan, &[])
        .map_err(|e| e.to_string())?;
    let time = btfrig_measurement::backend::RigTime::for_rig(&s.rig);
    let r = btfrig_measurement::color_calibration::calibrate_color_on_rig(
        &s.rig,
        None,
        &camera,
        &plan,
        &references,
        seed,
        time,
        |_| {},
    )
    .map_err(|e| e.to_string())?;
    let chosen = r.chosen();
    let held = chosen.held_out.as_ref().map_err(|e| e.to_string())?;
    let rel = format!("calibrations/{id}-color.toml");
    let path = s.data.join(&rel);
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|e| format!("cannot create {}: {e}", dir.display()))?;
    }
    std::fs::write(&path, r.file(&s.rig.rig.name, &plan, seed).to_toml())
        .map_err(|e| format!("cannot write {}: {e}", path.display()))?;
    let result = serde_json::json!({
        "model": chosen.kind.name(),
        "held_out_delta_e00": { "mean": held.mean, "median": held.median, "p95": held.p95, "max": held.max },
        "fit_ms": chosen.fit_s * 1e3,
        "seed": seed,
    });
    Ok((result, rel))
}
