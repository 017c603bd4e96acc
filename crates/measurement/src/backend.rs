//! Device backends, chosen by the rig config's device kinds through a registry.
//!
//! A run does not build devices itself: it asks the [`BackendRegistry`] for the backend that
//! opens the rig's devices (each `[devices.ROLE] kind`), and gets them as device traits, with
//! the clock they run on and, from a simulated backend only, a truth probe for the report's
//! error figures. The simulated backend lives in `btfrig-sim-backend`, the emulated-firmware
//! backend (serial and PTP backends in front of simulated devices) in
//! `btfrig-emulated-backend`; the `btfrig` binary installs both ([`install`]); a library
//! user may install others or pass a registry with the request.
//!
//! A backend also checks what only it understands, before a run creates anything: the rig's
//! device options ([`RigBackend::check_rig`]) and a plan's scene options, the material and
//! fault scenario a simulated rig builds ([`RigBackend::check_scene`]); and it opens the rig
//! with a calibration target mounted ([`RigBackend::open_calibration`]). The runner itself
//! knows no simulator type.

use std::path::Path;
use std::sync::{Arc, OnceLock};

use btfrig_acquire::dome::DomeDevices;
use btfrig_core::config::RigConfig;
use btfrig_core::plan::dome::ValidatedDomePlan;
use btfrig_core::plan::{Plan, ValidatedPlan};
use btfrig_hw::truth::{DomeTruthProbe, TruthProbe};
use btfrig_hw::{Camera, Lamp, Rail, Robot, SharedClock};

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
    /// The time the devices run on.
    pub time: RigTime,
}

/// The time a rig's devices run on: a simulated rig's virtual time, or the wall clock of a
/// rig with real devices (simulated devices of a mixed rig then wait in real time too).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum RigTime {
    /// tokio's (paused, in a simulated run) time: a 14-hour plan runs in seconds.
    #[default]
    Virtual,
    /// The wall clock.
    Wall,
}

impl RigTime {
    /// The time `rig` needs: the wall clock when any device is real hardware (neither
    /// simulated nor emulated), virtual time otherwise.
    pub fn for_rig(rig: &RigConfig) -> RigTime {
        if rig.devices.simulated().is_some() {
            RigTime::Virtual
        } else {
            RigTime::Wall
        }
    }

    /// The time a run of `rig` uses: the wall clock when the rig needs it or the run asks for
    /// it (`[run] clock = "wall"`, `btfrig run --wall-clock`).
    pub fn for_run(rig: &RigConfig, wall_clock: bool) -> RigTime {
        if wall_clock {
            RigTime::Wall
        } else {
            RigTime::for_rig(rig)
        }
    }

    /// Its name in reports: `"virtual"` or `"wall"`.
    pub fn name(self) -> &'static str {
        match self {
            RigTime::Virtual => "virtual",
            RigTime::Wall => "wall",
        }
    }

    /// A current-thread runtime for devices on this time: paused (virtual) time, or tokio's
    /// own timer on the wall clock.
    pub fn runtime(self) -> Result<tokio::runtime::Runtime, RunError> {
        match self {
            RigTime::Virtual => crate::runtime::virtual_time_runtime(),
            RigTime::Wall => {
                tokio::runtime::Builder::new_current_thread().enable_time().build().map_err(RunError::Runtime)
            }
        }
    }
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

/// Links of a rig whose devices are all in-process: none to report.
pub struct InProcess;

impl LinkReport for InProcess {
    fn link_use(&self) -> Vec<LinkUse> {
        Vec::new()
    }

    fn skipped_lines(&self) -> Vec<(&'static str, u64)> {
        Vec::new()
    }

    fn camera_coding_wall_s(&self) -> Option<f64> {
        None
    }

    fn count(&self) -> usize {
        0
    }
}

/// What talking to one emulated device cost this session (the run report's `links`): the
/// time the serial and PTP paths add over calling the simulated device in-process.
#[derive(Debug, Clone, PartialEq)]
pub struct LinkUse {
    /// Role (`robot`, `rail`, ..., `camera`).
    pub role: &'static str,
    /// What the backend talks to (pty path at a nominal baud rate, or the PTP responder).
    pub target: String,
    /// Exchanges (serial) or transactions (PTP).
    pub exchanges: u64,
    /// Bytes sent to the device.
    pub bytes_out: u64,
    /// Bytes received from it.
    pub bytes_in: u64,
    /// Wall seconds spent on this link: serial exchanges as the caller waited for them, PTP
    /// coding on the host (see `LinkTotals::exchange_wall_s`, `PtpTotals::codec_wall_s`).
    /// Links overlap each other and the camera's work, so these do not add up to what the
    /// run lost: that is the report's `link_added_wall_s`.
    pub wall_s: f64,
    /// Rig seconds the same bytes would take on a real line at the nominal baud rate
    /// (serial only; a pty has no baud rate, so the emulated run's rig time does not have it).
    pub wire_s: Option<f64>,
    /// Frames a streaming camera dropped or received incomplete (a GenICam camera's
    /// buffers); `None` for links that do not stream.
    pub dropped_buffers: Option<u64>,
}

impl LinkUse {
    /// As a JSON object (the report's `links` entries).
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "role": self.role,
            "target": self.target,
            "exchanges": self.exchanges,
            "bytes_out": self.bytes_out,
            "bytes_in": self.bytes_in,
            "wall_s": self.wall_s,
            "wire_s": self.wire_s,
            "dropped_buffers": self.dropped_buffers,
        })
    }
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

/// What a run asks a backend for: a dome's devices (an LED dome's, or a camera array's,
/// whose flash triggers are its LED array).
pub struct DomeOpenRequest<'a> {
    /// The rig config.
    pub rig: &'a RigConfig,
    /// The dome plan, validated (its cameras are the ones opened, in its order).
    pub plan: &'a ValidatedDomePlan,
    /// The plan file (its directory resolves relative names).
    pub plan_file: &'a Path,
    /// The fault scenario: the plan's or an override (`--faults`); it resolves from the
    /// plan's directory.
    pub fault_scenario: &'a str,
    /// The time the devices run on.
    pub time: RigTime,
}

/// A dome's devices as a backend opened them (the turntable not yet homed).
pub struct OpenedDome {
    /// The turntable, LED array, one camera per plan camera, and their clock.
    pub devices: DomeDevices,
    /// The truth behind the frames: simulated backends only.
    pub truth: Option<Arc<dyn DomeTruthProbe>>,
    /// The links to the devices, for the report (keeps any firmware emulators and fed fake
    /// cameras alive: drop it after the devices).
    pub links: Box<dyn LinkReport>,
}

/// What a calibration puts in the sample's place. On a real rig the operator mounts it when
/// the procedure asks; a simulated backend puts it into its scene.
#[derive(Debug, Clone, PartialEq)]
#[non_exhaustive]
pub enum MountedTarget {
    /// The geometric calibration board.
    Board(btfrig_core::config::target::TargetBoard),
    /// A colour chart, by its built-in name (`btfrig_color::chart::CHART_NAMES`: the layout of
    /// its patches).
    ColorChart {
        /// The chart's name.
        chart: String,
    },
    /// The bare holder plate with its markers (any sample on it): rig geometry.
    Plate,
    /// A white reference tile of this diffuse albedo.
    WhiteTile {
        /// Diffuse albedo of the tile.
        albedo: f64,
    },
    /// A uniform diffuse field filling the view (a diffuser or integrating sphere in front
    /// of the lens, lit by the rig's light): flat fields, the photon-transfer series.
    UniformField,
    /// The lens capped: dark frames.
    Capped,
}

impl MountedTarget {
    /// Its name, for messages and prompts.
    pub fn name(&self) -> &'static str {
        match self {
            MountedTarget::Board(_) => "calibration board",
            MountedTarget::ColorChart { .. } => "colour chart",
            MountedTarget::Plate => "marker plate",
            MountedTarget::WhiteTile { .. } => "white reference tile",
            MountedTarget::UniformField => "uniform field (diffuser)",
            MountedTarget::Capped => "lens cap",
        }
    }
}

/// What a calibration procedure asks a backend for: the rig's devices with a target mounted.
pub struct CalibrationOpenRequest<'a> {
    /// The rig config.
    pub rig: &'a RigConfig,
    /// What is mounted in the sample's place.
    pub target: &'a MountedTarget,
    /// Dome and camera array: the cameras (arc positions) to open; gonioreflectometer: unused.
    pub cameras: &'a [usize],
    /// Seed of a simulated rig's noise.
    pub seed: u64,
    /// The time the devices run on.
    pub time: RigTime,
}

/// A rig's devices as a backend opened them for a calibration.
pub enum OpenedRig {
    /// A gonioreflectometer's.
    Gonio(OpenedGonio),
    /// A dome's or camera array's.
    Dome(OpenedDome),
}

/// A plan's scene options: what a simulated rig builds its scene and its faults from. A real
/// rig has neither, and its backend refuses them.
#[derive(Debug, Clone, Copy, Default)]
pub struct SceneOptions<'a> {
    /// `[rig] material`: an embedded name, or a material file's path as resolved against the
    /// plan's directory; `None`: the backend's default.
    pub material: Option<&'a str>,
    /// A fault scenario: an embedded name or a file, the directory it resolves from, and the
    /// setting that names it (`run.fault_scenario`, `fault_scenario`, `--faults`) for errors.
    pub faults: Option<(&'a str, &'a Path, &'a str)>,
}

/// What a run asks a backend to check before it creates anything: that the devices it will
/// open can take each of the plan's steps (a recorded rig: that its recording holds a frame for
/// each).
pub struct StepsCheck<'a> {
    /// The rig config.
    pub rig: &'a RigConfig,
    /// The rig config's file, if it is one (relative paths in it resolve from its directory).
    pub rig_file: Option<&'a Path>,
    /// The steps to capture, in schedule order.
    pub steps: &'a [btfrig_acquire::EngineStep],
    /// Whether each step is taken at its `exposure_s` only (false: the HDR control chooses
    /// brackets while the run goes).
    pub exposures_fixed: bool,
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

    /// Opens a dome's devices. Call inside the tokio runtime the devices run on.
    async fn open_dome(&self, req: DomeOpenRequest<'_>) -> Result<OpenedDome, RunError> {
        let _ = req;
        Err(RunError::Rig(format!("the device backend {} does not open LED domes or camera arrays", self.name())))
    }

    /// Opens the rig's devices for a calibration procedure, with `req.target` mounted.
    async fn open_calibration(&self, req: CalibrationOpenRequest<'_>) -> Result<OpenedRig, RunError> {
        Err(RunError::Rig(format!(
            "the device backend {} does not open rigs for calibration (target: {})",
            self.name(),
            req.target.name()
        )))
    }

    /// Asks each device of `roles` in `rig` (all present: [`crate::preflight::check_devices`]
    /// checked) for its identity, health and homing state, without moving it, before a run or
    /// calibration creates anything. Default: every device is in-process and needs no
    /// questions. A backend of real devices asks them on its own runtime (wall clock).
    fn preflight(&self, rig: &RigConfig, roles: &[crate::preflight::Role]) -> Vec<crate::preflight::DeviceCheck> {
        rig.devices
            .entries()
            .into_iter()
            .filter(|(r, _)| roles.iter().any(|x| x.name() == *r))
            .map(|(r, e)| crate::preflight::DeviceCheck::unasked(r, &e.kind, "in-process: opened with the run"))
            .collect()
    }

    /// Checks the rig config's device options as opening the devices would, without opening
    /// them (the message says what is wrong; the caller names the rig config).
    fn check_rig(&self, rig: &RigConfig) -> Result<(), String> {
        let _ = rig;
        Ok(())
    }

    /// Checks that the devices can take every step of a gonio plan, before the run creates
    /// anything ([`StepsCheck`]). Default: any step.
    fn check_steps(&self, req: &StepsCheck<'_>) -> Result<(), RunError> {
        let _ = req;
        Ok(())
    }

    /// Loads a plan's scene options as opening would, so that a plan is refused before a
    /// dataset exists. A backend of real devices has no scene: it refuses any.
    fn check_scene(&self, options: &SceneOptions<'_>) -> Result<(), RunError> {
        let (what, value) = match (options.material, options.faults) {
            (Some(m), _) => ("rig.material".to_string(), m),
            (None, Some((f, _, field))) => (field.to_string(), f),
            (None, None) => return Ok(()),
        };
        Err(RunError::Input {
            what: format!("{what} {value:?}"),
            message: format!(
                "the rig's devices are opened by {}, which has no simulated scene: materials and fault scenarios \
                 are options of simulated rigs (kind = \"sim\")",
                self.name()
            ),
        })
    }
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
                "none (a library user installs them: btfrig_measurement::backend::install)".into()
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
