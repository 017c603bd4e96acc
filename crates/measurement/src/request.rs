//! What a run is asked to do: the plan, the dataset, the backends, the calibration inputs.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::backend;
use crate::RunError;

/// What to run.
#[derive(Debug, Clone)]
pub struct RunRequest {
    /// The plan's TOML text (stored in the manifest; its hash identifies the dataset).
    pub plan_text: String,
    /// The plan's file: names it in messages; its directory anchors relative paths in it.
    /// For text without a file, any path in the directory the relative paths refer to.
    pub plan_path: PathBuf,
    /// The dataset directory (created, or a dataset of the same plan resumed).
    pub out: PathBuf,
    /// Fault scenario of the simulated rig instead of the plan's `run.fault_scenario`: an
    /// embedded name or a file (relative to the working directory). Fault injection belongs
    /// to the simulated rig, not to the measurement, so the plan hash does not change: a
    /// run that paused on a fatal fault resumes with the fault gone.
    pub faults: Option<String>,
    /// When a step fails with an error no retry helps: end the session, report `paused`
    /// and return (true, the CLI: nobody is there to fix the cause), or keep the engine
    /// paused and wait for [`RunControl::resume`] or [`RunControl::abort`] (false, a daemon
    /// with an operator).
    pub stop_on_fault: bool,
    /// On a simulated rig, also rectify every registered frame with the nominal pose and
    /// compare it with the truth (`texture_rel_rmse_nominal`): a second rectification per
    /// frame, so off by default (`btfrig demo` turns it on).
    pub compare_nominal: bool,
    /// The light calibration frames are converted with, and whether the lamp's drift is
    /// measured on the plate and corrected (`btfrig_process::light`); `None`: the lamp's
    /// power and colour come from the rig model.
    pub light: Option<btfrig_process::light::LightCorrection>,
    /// A measured dark model and master flats every frame is corrected with before
    /// demosaicing (`docs/dark-flat.md`); `None`: the sensor model's black level, dark current
    /// and the lens model's vignetting.
    pub dark_flat: Option<DarkFlatInput>,
    /// The compressed model to build while the run captures, instead of the plan's
    /// `outputs.compressed_model` (`btfrig run --compress`, `btfrig demo`); `None`: the
    /// plan's. The runner builds its sink ([`sinks::CompressionSink`]).
    pub compressed_model: Option<btfrig_core::plan::CompressedModel>,
    /// The device backends to open the rig with; `None`: the process's
    /// ([`backend::installed`]).
    pub backends: Option<BackendsHandle>,
    /// Run on the wall clock even when the rig needs no more than virtual time (`btfrig run
    /// --wall-clock`; the plan's `[run] clock = "wall"` does the same; `backend::RigTime::for_run`).
    pub wall_clock: bool,
}

/// A [`backend::BackendRegistry`] in a [`RunRequest`].
#[derive(Clone)]
pub struct BackendsHandle(pub backend::BackendRegistry);

impl std::fmt::Debug for BackendsHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("BackendRegistry")
    }
}

/// A dark/flat calibration for a run, with where it came from (recorded in the manifest).
#[derive(Debug, Clone)]
pub struct DarkFlatInput {
    /// Where the calibration was read from (e.g. the directory `btfrig calibrate radiometric` wrote).
    pub source: String,
    /// The dark model and master flats.
    pub calibration: Arc<btfrig_process::dark_flat::DarkFlat>,
}

impl RunRequest {
    /// A request for the plan file `plan` into `out`.
    pub fn from_file(plan: &Path, out: &Path) -> Result<RunRequest, RunError> {
        let plan_text = std::fs::read_to_string(plan).map_err(|source| RunError::Read { path: plan.into(), source })?;
        Ok(RunRequest::from_text(plan_text, plan, out))
    }

    /// A request for plan text; `plan_path` as in [`RunRequest::plan_path`].
    pub fn from_text(plan_text: impl Into<String>, plan_path: &Path, out: &Path) -> RunRequest {
        RunRequest {
            plan_text: plan_text.into(),
            plan_path: plan_path.into(),
            out: out.into(),
            faults: None,
            stop_on_fault: true,
            compare_nominal: false,
            light: None,
            dark_flat: None,
            compressed_model: None,
            backends: None,
            wall_clock: false,
        }
    }

    /// On the wall clock or not (see [`RunRequest::wall_clock`]).
    pub fn with_wall_clock(mut self, on: bool) -> RunRequest {
        self.wall_clock = on;
        self
    }

    /// With a compressed model instead of the plan's (see [`RunRequest::compressed_model`]).
    pub fn with_compressed_model(mut self, model: Option<btfrig_core::plan::CompressedModel>) -> RunRequest {
        self.compressed_model = model;
        self
    }

    /// With a dark/flat calibration (see [`RunRequest::dark_flat`]).
    pub fn with_dark_flat(mut self, dark_flat: Option<DarkFlatInput>) -> RunRequest {
        self.dark_flat = dark_flat;
        self
    }

    /// With a light calibration (see [`RunRequest::light`]).
    pub fn with_light(mut self, light: Option<btfrig_process::light::LightCorrection>) -> RunRequest {
        self.light = light;
        self
    }

    /// With the nominal-pose comparison on or off (see [`RunRequest::compare_nominal`]).
    pub fn with_nominal_comparison(mut self, on: bool) -> RunRequest {
        self.compare_nominal = on;
        self
    }

    /// With a fault-scenario override (see [`RunRequest::faults`]).
    pub fn with_faults(mut self, faults: Option<String>) -> RunRequest {
        self.faults = faults;
        self
    }

    /// With these device backends (see [`RunRequest::backends`]).
    pub fn with_backends(mut self, backends: backend::BackendRegistry) -> RunRequest {
        self.backends = Some(BackendsHandle(backends));
        self
    }
}
