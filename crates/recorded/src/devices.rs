//! The recorded rig's devices: stand-in robot, rail and lamp that accept commands (nothing
//! moves, nothing waits) and remember the commanded pose, and the camera that serves the
//! recorded frame of that pose, exposure and gain.

use std::sync::{Arc, Mutex};

use async_trait::async_trait;
use btfrig_core::frame::RawFrame;
use btfrig_core::kinematics::JointState;
use btfrig_hw::{
    AxisLimits, Camera, CameraCapabilities, CaptureSettings, Device, DeviceError, DeviceInfo, ErrorKind, Lamp,
    LampCapabilities, LampStatus, MoveOptions, Rail, Robot, SharedClock, WarmUp,
};

use crate::recording::{joints_deg, max_joint_diff_deg, Recording};
use crate::KIND;

/// What the stand-ins were commanded last, which the camera reads at its trigger.
#[derive(Debug, Default)]
struct Commanded {
    robot: Option<[f64; 3]>,
    rail: Option<f64>,
    robot_homed: bool,
    rail_homed: bool,
}

/// The recorded rig's devices, sharing the recording and the commanded pose.
pub struct RecordedDevices {
    /// Stand-in robot.
    pub robot: Box<dyn Robot>,
    /// Stand-in rail.
    pub rail: Box<dyn Rail>,
    /// Stand-in lamp.
    pub lamp: Box<dyn Lamp>,
    /// The camera that serves the recording's frames.
    pub camera: Box<dyn Camera>,
}

impl RecordedDevices {
    /// The devices over `recording` (its poses resolved), on `clock` (the frames' time stamps).
    pub fn new(recording: Arc<Recording>, tolerance_deg: f64, clock: SharedClock) -> RecordedDevices {
        let state = Arc::new(Mutex::new(Commanded::default()));
        let info = |role: &str, model: &str| DeviceInfo {
            name: role.into(),
            backend: KIND.into(),
            model: model.into(),
            serial: None,
            firmware: None,
        };
        let cam = &recording.sidecar.camera;
        let settings = CaptureSettings {
            exposure_s: recording.frames.first().map_or(cam.exposure_range_s[0], |f| f.entry.exposure_s),
            gain: recording.frames.first().map_or(cam.gain_range[0], |f| f.entry.gain),
            f_number: cam.f_number,
        };
        let camera_model =
            format!("recording {} ({})", recording.dir.display(), cam.model.as_deref().unwrap_or("camera not named"));
        RecordedDevices {
            robot: Box::new(StandInRobot {
                info: info("robot", "stand-in (recorded rig)"),
                state: state.clone(),
                recording: recording.clone(),
                tolerance_deg,
            }),
            rail: Box::new(StandInRail {
                info: info("rail", "stand-in (recorded rig)"),
                state: state.clone(),
                recording: recording.clone(),
                tolerance_deg,
            }),
            lamp: Box::new(StandInLamp { info: info("lamp", "stand-in (recorded rig)"), on: false }),
            camera: Box::new(RecordedCamera {
                info: info("camera", &camera_model),
                state,
                recording,
                tolerance_deg,
                settings,
                clock,
                sequence: 0,
                buffered: None,
            }),
        }
    }
}

fn wide_axis() -> AxisLimits {
    // Nothing moves: a stand-in accepts any recorded angle, instantly.
    AxisLimits {
        min_rad: -4.0 * std::f64::consts::PI,
        max_rad: 4.0 * std::f64::consts::PI,
        max_speed_rad_per_s: f64::INFINITY,
    }
}

struct StandInRobot {
    info: DeviceInfo,
    state: Arc<Mutex<Commanded>>,
    recording: Arc<Recording>,
    tolerance_deg: f64,
}

#[async_trait]
impl Device for StandInRobot {
    fn info(&self) -> &DeviceInfo {
        &self.info
    }
}

#[async_trait]
impl Robot for StandInRobot {
    fn joint_limits(&self) -> [AxisLimits; 3] {
        [wide_axis(); 3]
    }

    async fn home(&mut self, _opts: MoveOptions) -> Result<(), DeviceError> {
        let mut s = self.state.lock().expect("commanded pose lock");
        s.robot_homed = true;
        s.robot = None;
        Ok(())
    }

    async fn move_to_rad(&mut self, joints_rad: [f64; 3], _opts: MoveOptions) -> Result<[f64; 3], DeviceError> {
        if !self.state.lock().expect("commanded pose lock").robot_homed {
            return Err(DeviceError::new(&self.info.name, ErrorKind::NotHomed, "move before home"));
        }
        let recorded = self.recording.frames.iter().filter_map(|f| f.joints).any(|j| {
            let probe = JointState { robot: joints_rad, ..j };
            max_joint_diff_deg(&probe, &j) <= self.tolerance_deg
        });
        if !recorded {
            let probe = JointState { robot: joints_rad, rail: f64::NAN, turntable: 0.0 };
            return Err(DeviceError::new(
                &self.info.name,
                ErrorKind::OutOfRange,
                format!(
                    "no frame of the recording {} was taken at robot joints {}: the plan asks for a capture the \
                     recording lacks",
                    self.recording.dir.display(),
                    joints_deg(&probe).split(", rail").next().unwrap_or_default()
                ),
            ));
        }
        self.state.lock().expect("commanded pose lock").robot = Some(joints_rad);
        Ok(joints_rad)
    }

    async fn position_rad(&mut self) -> Result<[f64; 3], DeviceError> {
        let s = self.state.lock().expect("commanded pose lock");
        if !s.robot_homed {
            return Err(DeviceError::new(&self.info.name, ErrorKind::NotHomed, "not homed"));
        }
        Ok(s.robot.unwrap_or([0.0; 3]))
    }
}

struct StandInRail {
    info: DeviceInfo,
    state: Arc<Mutex<Commanded>>,
    recording: Arc<Recording>,
    tolerance_deg: f64,
}

#[async_trait]
impl Device for StandInRail {
    fn info(&self) -> &DeviceInfo {
        &self.info
    }
}

#[async_trait]
impl Rail for StandInRail {
    fn limits(&self) -> AxisLimits {
        wide_axis()
    }

    async fn home(&mut self, _opts: MoveOptions) -> Result<(), DeviceError> {
        let mut s = self.state.lock().expect("commanded pose lock");
        s.rail_homed = true;
        s.rail = None;
        Ok(())
    }

    async fn move_to_rad(&mut self, angle_rad: f64, _opts: MoveOptions) -> Result<f64, DeviceError> {
        if !self.state.lock().expect("commanded pose lock").rail_homed {
            return Err(DeviceError::new(&self.info.name, ErrorKind::NotHomed, "move before home"));
        }
        let recorded = self
            .recording
            .frames
            .iter()
            .filter_map(|f| f.joints)
            .any(|j| (j.rail - angle_rad).abs().to_degrees() <= self.tolerance_deg);
        if !recorded {
            return Err(DeviceError::new(
                &self.info.name,
                ErrorKind::OutOfRange,
                format!(
                    "no frame of the recording {} was taken at rail {:.4} deg: the plan asks for a capture the recording lacks",
                    self.recording.dir.display(),
                    angle_rad.to_degrees()
                ),
            ));
        }
        self.state.lock().expect("commanded pose lock").rail = Some(angle_rad);
        Ok(angle_rad)
    }

    async fn position_rad(&mut self) -> Result<f64, DeviceError> {
        let s = self.state.lock().expect("commanded pose lock");
        if !s.rail_homed {
            return Err(DeviceError::new(&self.info.name, ErrorKind::NotHomed, "not homed"));
        }
        Ok(s.rail.unwrap_or(0.0))
    }
}

struct StandInLamp {
    info: DeviceInfo,
    on: bool,
}

#[async_trait]
impl Device for StandInLamp {
    fn info(&self) -> &DeviceInfo {
        &self.info
    }
}

#[async_trait]
impl Lamp for StandInLamp {
    fn capabilities(&self) -> LampCapabilities {
        // The light is in the frames already: no warm-up to wait for.
        LampCapabilities { has_shutter: false, intensity_range: None, warm_up_s: 0.0 }
    }

    async fn set_on(&mut self, on: bool) -> Result<(), DeviceError> {
        self.on = on;
        Ok(())
    }

    async fn status(&mut self) -> Result<LampStatus, DeviceError> {
        Ok(LampStatus {
            on: self.on,
            shutter_open: true,
            intensity: 1.0,
            warm_up: if self.on { WarmUp::Ready } else { WarmUp::Off },
        })
    }

    async fn wait_ready(&mut self, _timeout_s: f64) -> Result<(), DeviceError> {
        if self.on {
            Ok(())
        } else {
            Err(DeviceError::new(&self.info.name, ErrorKind::Other, "the lamp is off"))
        }
    }
}

/// The camera of a recording: a trigger looks up the frame of the commanded pose, exposure
/// and gain and reads it from its file; the read-out hands it over.
struct RecordedCamera {
    info: DeviceInfo,
    state: Arc<Mutex<Commanded>>,
    recording: Arc<Recording>,
    tolerance_deg: f64,
    settings: CaptureSettings,
    clock: SharedClock,
    sequence: u64,
    buffered: Option<RawFrame>,
}

impl RecordedCamera {
    fn check(&self, what: &str, v: f64, range: [f64; 2]) -> Result<(), DeviceError> {
        // The recording's range, with the matching tolerance at its ends.
        let slack = crate::recording::SETTING_TOLERANCE * range[1].abs();
        if !(v >= range[0] - slack && v <= range[1] + slack) {
            return Err(DeviceError::out_of_range(
                &self.info.name,
                what,
                v,
                format!("the recording's [{}, {}] (recording.toml camera)", range[0], range[1]),
            ));
        }
        Ok(())
    }
}

#[async_trait]
impl Device for RecordedCamera {
    fn info(&self) -> &DeviceInfo {
        &self.info
    }
}

#[async_trait]
impl Camera for RecordedCamera {
    fn capabilities(&self) -> CameraCapabilities {
        let c = &self.recording.sidecar.camera;
        CameraCapabilities {
            width: c.width,
            height: c.height,
            bit_depth: c.bit_depth,
            bayer: self.recording.bayer,
            black_level: c.black_level,
            white_level: c.white_level,
            exposure_range_s: (c.exposure_range_s[0], c.exposure_range_s[1]),
            gain_range: (c.gain_range[0], c.gain_range[1]),
            f_number_range: None,
        }
    }

    fn settings(&self) -> CaptureSettings {
        self.settings
    }

    async fn set_exposure_s(&mut self, exposure_s: f64) -> Result<(), DeviceError> {
        self.check("exposure (s)", exposure_s, self.recording.sidecar.camera.exposure_range_s)?;
        self.settings.exposure_s = exposure_s;
        Ok(())
    }

    async fn set_gain(&mut self, gain: f64) -> Result<(), DeviceError> {
        self.check("gain", gain, self.recording.sidecar.camera.gain_range)?;
        self.settings.gain = gain;
        Ok(())
    }

    async fn trigger(&mut self, _timeout_s: f64) -> Result<u64, DeviceError> {
        self.buffered = None;
        let joints =
            {
                let s = self.state.lock().expect("commanded pose lock");
                match (s.robot, s.rail) {
                    (Some(robot), Some(rail)) => JointState { robot, rail, turntable: 0.0 },
                    _ => return Err(DeviceError::new(
                        &self.info.name,
                        ErrorKind::Other,
                        "triggered before the robot and the rail were moved to a recorded pose: a recorded frame is \
                         chosen by the commanded pose",
                    )),
                }
            };
        let frame = self
            .recording
            .find(&joints, self.settings.exposure_s, self.settings.gain, self.tolerance_deg)
            .map_err(|m| DeviceError::new(&self.info.name, ErrorKind::Other, m))?;
        // Read at the trigger, synchronously: a blocking task would let the paused (virtual)
        // clock run on while it works, and the engine's guard time out.
        let sequence = self.sequence;
        let raw = self
            .recording
            .read(frame, sequence, self.clock.now_s())
            .map_err(|e| DeviceError::new(&self.info.name, ErrorKind::Other, e.to_string()))?;
        self.sequence += 1;
        self.buffered = Some(raw);
        Ok(sequence)
    }

    async fn read_frame(&mut self, _timeout_s: f64) -> Result<RawFrame, DeviceError> {
        self.buffered.take().ok_or_else(|| {
            DeviceError::new(&self.info.name, ErrorKind::Other, "read_frame without a triggered frame in the buffer")
        })
    }
}
