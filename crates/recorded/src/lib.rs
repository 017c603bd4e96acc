//! The recorded ("replay") camera: a directory of recorded raw frames and its sidecar run
//! through a plan like a rig (`docs/recorded-camera.md`).
//!
//! Brief overview. A [`Recording`] is a directory with frame files (PNG, TIFF, OpenEXR, DNG
//! and camera raw with the `raw` feature) and a sidecar `recording.toml` ([`Sidecar`]): once
//! the camera (size, bit depth, black and white level, Bayer layout, setting ranges), then per
//! frame its file, the commanded pose (joints, or light and view directions), exposure and
//! gain. [`Recording::open`] checks all of it and reports every problem at once, each naming
//! the file and the field. [`RecordedBackend`] is the device backend of `kind = "recorded"`
//! rigs: before a run creates anything it checks that the recording holds every step of the
//! plan ([`RigBackend::check_steps`]), then opens stand-in robot, rail and lamp that accept
//! the commands and a camera that serves, at each trigger, the recorded frame of the commanded
//! pose, exposure and gain ([`devices`]). Nothing moves and nothing waits: the run's time is
//! virtual. [`export::export_recording`] writes a recording from a dataset that kept its raw
//! frames, so a run's frames can be run again; [`probe::describe`] is `btfrig hw probe
//! --recorded`.
//!
//! ```no_run
//! let rec = btfrig_recorded::Recording::open(std::path::Path::new("my-recording")).unwrap();
//! println!("{} frames of {}x{}", rec.frames.len(), rec.sidecar.camera.width, rec.sidecar.camera.height);
//! ```
#![warn(missing_docs)]

// The files, one job each:
// - sidecar:   the sidecar's schema (recording.toml)
// - format:    frame file formats: detection, size, DNs, writing
// - recording: a recording directory read and checked; finding a frame by pose and settings
// - devices:   the stand-in robot, rail, lamp and the recorded camera
// - export:    a recording from a dataset's kept raw frames
// - probe:     what `btfrig hw probe --recorded` prints

use std::path::{Path, PathBuf};
use std::sync::Arc;

use btfrig_acquire::StepKind;
use btfrig_core::config::RigConfig;
use btfrig_core::kinematics::Gonio;
use btfrig_hw::TokioClock;
use btfrig_measurement::backend::{GonioOpenRequest, InProcess, OpenedGonio, RigBackend, SceneOptions, StepsCheck};
use btfrig_measurement::RunError;

pub mod devices;
pub mod export;
pub mod format;
pub mod probe;
pub mod recording;
pub mod sidecar;

pub use recording::{RecordedFrame, Recording, DEFAULT_POSE_TOLERANCE_DEG};
pub use sidecar::{Sidecar, SIDECAR_FILE};

/// The device kind of a recorded rig (`[devices.ROLE] kind = "recorded"`).
pub const KIND: &str = "recorded";

/// The device kinds [`RecordedBackend`] opens.
pub const KINDS: &[&str] = &[KIND];

/// What is wrong with a recording; every variant names the file and, where one is to
/// blame, the sidecar field.
#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    /// The recording directory itself.
    #[error("recording {}: {message}", dir.display())]
    Directory {
        /// The directory.
        dir: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// The sidecar is missing, malformed or out of range.
    #[error("{}: {message}", path.display())]
    Sidecar {
        /// The sidecar file.
        path: PathBuf,
        /// What is wrong (the field, and what is allowed).
        message: String,
    },
    /// A frame file.
    #[error("{}: {message}", path.display())]
    Frame {
        /// The frame file.
        path: PathBuf,
        /// What is wrong (the sidecar field that names it, and what is allowed).
        message: String,
    },
    /// Several problems, each one of the above.
    #[error("recording {}: {} problems:\n  {}", dir.display(), problems.len(), problems.iter().map(|p| p.to_string()).collect::<Vec<_>>().join("\n  "))]
    Problems {
        /// The directory.
        dir: PathBuf,
        /// Every problem found.
        problems: Vec<RecordingError>,
    },
}

/// The options of a recorded rig's devices: `[devices.camera] recording` (the directory,
/// relative to the rig config's directory) and `pose_tolerance_deg`; the stand-ins take none.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordedOptions {
    /// The recording directory as written.
    pub recording: String,
    /// How far a commanded joint may be from a recorded one, degrees.
    pub pose_tolerance_deg: f64,
}

impl RecordedOptions {
    /// The options of `rig`, checked; the message names the field and what is allowed.
    pub fn of(rig: &RigConfig) -> Result<RecordedOptions, String> {
        let mut problems = Vec::new();
        for (role, e) in rig.devices.entries() {
            if e.kind != KIND {
                problems.push(format!(
                    "devices.{role}.kind = {:?}: a recorded rig's devices are all kind = \"{KIND}\" (the camera serves the \
                     recording, the others stand in for the motion and the light)",
                    e.kind
                ));
                continue;
            }
            let allowed: &[&str] = if role == "camera" { &["recording", "pose_tolerance_deg"] } else { &[] };
            for key in e.options.keys().filter(|k| !allowed.contains(&k.as_str())) {
                problems.push(format!(
                    "devices.{role}.{key}: unknown option of a recorded device: allowed {}",
                    if allowed.is_empty() { "none".to_string() } else { allowed.join(", ") }
                ));
            }
        }
        let camera = rig.devices.entries().into_iter().find(|(r, _)| *r == "camera").map(|(_, e)| e.options.clone());
        let recording = match camera.as_ref().and_then(|o| o.get("recording")) {
            Some(toml::Value::String(s)) => s.clone(),
            Some(other) => {
                problems.push(format!("devices.camera.recording = {other}: allowed a directory path (a string)"));
                String::new()
            }
            None => {
                problems.push(
                    "devices.camera.recording is missing: a recorded camera names its recording directory".to_string(),
                );
                String::new()
            }
        };
        let pose_tolerance_deg = match camera.as_ref().and_then(|o| o.get("pose_tolerance_deg")) {
            None => DEFAULT_POSE_TOLERANCE_DEG,
            Some(v) => match v.as_float().or_else(|| v.as_integer().map(|i| i as f64)) {
                Some(t) if t > 0.0 && t.is_finite() => t,
                _ => {
                    problems
                        .push(format!("devices.camera.pose_tolerance_deg = {v}: allowed a positive number of degrees"));
                    DEFAULT_POSE_TOLERANCE_DEG
                }
            },
        };
        if problems.is_empty() {
            Ok(RecordedOptions { recording, pose_tolerance_deg })
        } else {
            Err(problems.join("; "))
        }
    }

    /// The recording directory: relative to the rig config's directory (`rig_file`), or to
    /// the working directory when the rig config is not a file.
    pub fn dir(&self, rig_file: Option<&Path>) -> PathBuf {
        let p = Path::new(&self.recording);
        match rig_file.and_then(Path::parent) {
            // Through components: `recording = "."` names the directory itself, not `dir/.`.
            Some(base) if p.is_relative() => base.join(p).components().collect(),
            _ => p.to_path_buf(),
        }
    }
}

/// Opens the recording of `rig` (the rig config at `rig_file`) with every pose resolved.
pub fn open_for_rig(rig: &RigConfig, rig_file: Option<&Path>) -> Result<(Recording, RecordedOptions), RunError> {
    let options =
        RecordedOptions::of(rig).map_err(|m| RunError::Input { what: "rig config [devices]".into(), message: m })?;
    let dir = options.dir(rig_file);
    let what = format!("devices.camera.recording {:?}", options.recording);
    let mut recording =
        Recording::open(&dir).map_err(|e| RunError::Input { what: what.clone(), message: e.to_string() })?;
    let gonio = Gonio::new(rig.geometry.clone()).map_err(|e| RunError::Rig(e.to_string()))?;
    recording
        .resolve_poses(&gonio, options.pose_tolerance_deg)
        .map_err(|e| RunError::Input { what, message: e.to_string() })?;
    Ok((recording, options))
}

/// The backend of recorded rigs.
pub struct RecordedBackend;

#[async_trait::async_trait]
impl RigBackend for RecordedBackend {
    fn name(&self) -> &'static str {
        "recorded frames (btfrig-recorded)"
    }

    fn kinds(&self) -> &'static [&'static str] {
        KINDS
    }

    async fn open_gonio(&self, req: GonioOpenRequest<'_>) -> Result<OpenedGonio, RunError> {
        let rig_file = req.plan.rig_config_path(req.plan_file);
        let (recording, options) = open_for_rig(req.rig, rig_file.as_deref())?;
        // Nothing moves: the run's time is virtual whatever the request says, and only time
        // stamps the frames.
        let clock = TokioClock::shared();
        let d = devices::RecordedDevices::new(Arc::new(recording), options.pose_tolerance_deg, clock.clone());
        Ok(OpenedGonio {
            robot: d.robot,
            rail: d.rail,
            lamp: d.lamp,
            camera: d.camera,
            clock,
            truth: None,
            links: Box::new(InProcess),
        })
    }

    fn check_rig(&self, rig: &RigConfig) -> Result<(), String> {
        RecordedOptions::of(rig).map(|_| ())
    }

    fn check_steps(&self, req: &StepsCheck<'_>) -> Result<(), RunError> {
        let (recording, options) = open_for_rig(req.rig, req.rig_file)?;
        let gain = recording.frames.first().map_or(1.0, |f| f.entry.gain);
        let mut missing = Vec::new();
        for s in req.steps {
            let StepKind::Gonio { joints } = &s.kind else { continue };
            let found = if req.exposures_fixed {
                recording.find(joints, s.exposure_s, gain, options.pose_tolerance_deg).map(|_| ())
            } else {
                // HDR: the brackets are chosen while the run goes; the pose must be there.
                let at_pose = recording
                    .frames
                    .iter()
                    .filter_map(|f| f.joints)
                    .any(|j| recording::max_joint_diff_deg(&j, joints) <= options.pose_tolerance_deg);
                if at_pose {
                    Ok(())
                } else {
                    Err(format!("no frame at {}", recording::joints_deg(joints)))
                }
            };
            if let Err(m) = found {
                missing.push(format!("step {} ({}): {m}", s.key, recording::joints_deg(joints)));
            }
        }
        if missing.is_empty() {
            return Ok(());
        }
        let shown = missing.len().min(5);
        Err(RunError::Input {
            what: format!("devices.camera.recording {:?}", options.recording),
            message: format!(
                "the plan asks for {} capture(s) the recording lacks; nothing was written:\n  {}{}",
                missing.len(),
                missing[..shown].join("\n  "),
                if missing.len() > shown {
                    format!("\n  ... and {} more", missing.len() - shown)
                } else {
                    String::new()
                }
            ),
        })
    }

    fn check_scene(&self, options: &SceneOptions<'_>) -> Result<(), RunError> {
        // The plan's material is the simulator's scene: a recording's sample is in its frames,
        // so the name is ignored. Injected faults have nothing to act on.
        match options.faults {
            Some((name, _, field)) if name != "none" => Err(RunError::Input {
                what: format!("{field} {name:?}"),
                message: "a recorded rig replays its frames and injects no faults: allowed \"none\" or no scenario"
                    .into(),
            }),
            _ => Ok(()),
        }
    }
}
