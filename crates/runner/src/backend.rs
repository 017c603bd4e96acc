//! Device backends, chosen by the rig config's device kinds through a registry.
//!
//! A run does not build devices itself: it asks the [`BackendRegistry`] for the backend that
//! opens the rig's devices (each `[devices.ROLE] kind`), and gets them as device traits, with
//! the clock they run on and, from a simulated backend only, a truth probe for the report's
//! error figures. The simulated and emulated-serial backends live in `btfrig-sim-backend`;
//! the `btfrig` binary installs them ([`install`]); a library user may install others or pass
//! a registry with the request.

use std::path::Path;
use std::sync::{Arc, OnceLock};

use btfrig_core::config::RigConfig;
use btfrig_core::plan::{Plan, ValidatedPlan};
use btfrig_hw::truth::TruthProbe;
use btfrig_hw::{Camera, Lamp, Rail, Robot, SharedClock};

use crate::emulated::{LinkFault, LinkUse};
use crate::RunError;

/// What a run asks a backend for: a gonioreflectometer's devices.
pub struct GonioOpenRequest<'a> {
    /// The rig config.
    pub rig: &'a RigConfig,
    /// The plan (simulated backends: `[rig] material`, `[run] fault_scenario`).
    pub plan: &'a Plan,
    /// The plan, validated.
    pub validated: &'a ValidatedPlan,
    /// The plan file (its directory resolves relative names).
    pub plan_file: &'a Path,
    /// A fault scenario instead of the plan's (`--faults`, relative to the working directory).
    pub fault_override: Option<&'a str>,
    /// The engine's read-out timeout, seconds.
    pub read_timeout_s: f64,
    /// Faults to inject into emulated firmware links (tests).
    pub link_faults: &'a [LinkFault],
}

/// How the links to a rig's devices went, for the report.
pub trait LinkReport: Send {
    /// Per link: what it cost.
    fn link_use(&self) -> Vec<LinkUse>;
    /// Undecodable lines each serial backend skipped, by role.
    fn skipped_lines(&self) -> Vec<(&'static str, u64)>;
    /// Wall seconds the camera link spent coding, if the camera is behind one.
    fn camera_coding_wall_s(&self) -> Option<f64>;
    /// Links in use (0: every device in-process).
    fn count(&self) -> usize;
}

/// A gonioreflectometer's devices as a backend opened them (not yet homed).
pub struct OpenedGonio {
    /// The robot holding the sample.
    pub robot: Box<dyn Robot>,
    /// The camera's rail.
    pub rail: Box<dyn Rail>,
    /// The lamp.
    pub lamp: Box<dyn Lamp>,
    /// The camera.
    pub camera: Box<dyn Camera>,
    /// The clock the devices run on.
    pub clock: SharedClock,
    /// The truth behind the frames: simulated backends only.
    pub truth: Option<Arc<dyn TruthProbe>>,
    /// The links to the devices (keeps any firmware emulators alive: drop it after them).
    pub links: Box<dyn LinkReport>,
}

/// A device backend.
#[async_trait::async_trait]
pub trait RigBackend: Send + Sync {
    /// Its name, for messages.
    fn name(&self) -> &'static str;

    /// The device kinds (`[devices.ROLE] kind`) it opens.
    fn kinds(&self) -> &'static [&'static str];

    /// Opens a gonioreflectometer's devices.
    async fn open_gonio(&self, req: GonioOpenRequest<'_>) -> Result<OpenedGonio, RunError>;
}

/// The backends a run may use.
#[derive(Clone, Default)]
pub struct BackendRegistry {
    backends: Vec<Arc<dyn RigBackend>>,
}

impl BackendRegistry {
    /// No backends.
    pub fn new() -> Self {
        BackendRegistry::default()
    }

    /// The same registry with `backend` added.
    pub fn with(mut self, backend: Arc<dyn RigBackend>) -> Self {
        self.backends.push(backend);
        self
    }

    /// The backend that opens every device of `rig`: the first whose kinds cover all of the
    /// rig's device kinds. None: an error naming each kind and what is registered.
    pub fn for_rig(&self, rig: &RigConfig) -> Result<Arc<dyn RigBackend>, RunError> {
        let kinds: Vec<(&str, &str)> =
            rig.devices.entries().into_iter().map(|(role, e)| (role, e.kind.as_str())).collect();
        if let Some(b) = self.backends.iter().find(|b| kinds.iter().all(|(_, k)| b.kinds().contains(k))) {
            return Ok(b.clone());
        }
        let have: Vec<String> =
            self.backends.iter().map(|b| format!("{} ({})", b.name(), b.kinds().join(", "))).collect();
        let asked: Vec<String> = kinds.iter().map(|(r, k)| format!("devices.{r}.kind = {k:?}")).collect();
        Err(RunError::Rig(format!(
            "no device backend of this build opens {}: registered backends: {}",
            asked.join(", "),
            if have.is_empty() {
                "none (a library user installs them: btfrig_runner::backend::install)".into()
            } else {
                have.join("; ")
            }
        )))
    }
}

static INSTALLED: OnceLock<BackendRegistry> = OnceLock::new();

/// Installs the process's registry (the `btfrig` binary installs the simulated and emulated
/// backends at start); later calls keep the first.
pub fn install(registry: BackendRegistry) {
    let _ = INSTALLED.set(registry);
}

/// The process's registry (empty if none was installed).
pub fn installed() -> BackendRegistry {
    INSTALLED.get().cloned().unwrap_or_default()
}
