//! A rig described as data: the TOML files in `rig-configs/`.
//!
//! Each section of the file is a struct in its own module; every struct denies unknown
//! fields so that a typo is an error naming the field, never a silently ignored setting.
//! The format is documented in `docs/rig-config.md`.

pub mod camera;
pub mod devices;
pub mod dome;
pub mod geometry;
pub mod lamp;
pub mod plate;
pub mod sensor;
pub mod target;
pub mod timing;

use serde::{Deserialize, Serialize};

use crate::error::ConfigError;

/// Which kind of rig a config describes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RigKind {
    /// Fixed lamp, camera on a semicircular rail, robot orienting the sample.
    Gonioreflectometer,
    /// Fixed LEDs on a hemisphere, fixed cameras on an arc, the sample on a turntable
    /// (`kind = "led_dome"`, with a `[dome]` section).
    LedDome,
    /// Fixed cameras on a hemisphere whose flashes are the lights, no turntable
    /// (`kind = "camera_array"`, with a `[dome]` section holding `[dome.flash]`).
    CameraArray,
}

impl RigKind {
    /// The name written in `[rig] kind`.
    pub fn as_str(self) -> &'static str {
        match self {
            RigKind::Gonioreflectometer => "gonioreflectometer",
            RigKind::LedDome => "led_dome",
            RigKind::CameraArray => "camera_array",
        }
    }

    /// Whether this is a dome rig (LED dome or camera array), run by the dome machinery.
    pub fn is_dome(self) -> bool {
        matches!(self, RigKind::LedDome | RigKind::CameraArray)
    }
}

/// Name and kind of the rig.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigInfo {
    /// Human-readable name, shown in reports.
    pub name: String,
    /// What sort of rig this is.
    pub kind: RigKind,
    /// Seed of every random process of a simulated rig (noise, jitter, faults).
    #[serde(default)]
    pub seed: u64,
}

/// A whole rig: geometry, devices, camera, sensor, light, holder plate, timing.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigConfig {
    /// Name and kind.
    pub rig: RigInfo,
    /// Gonioreflectometer geometry and joint limits.
    pub geometry: geometry::GonioGeometry,
    /// Which backend drives each device.
    pub devices: devices::DevicesConfig,
    /// Camera intrinsics, lens distortion and vignetting.
    pub camera: camera::CameraConfig,
    /// The raw sensor behind the lens.
    pub sensor: sensor::SensorConfig,
    /// The light source.
    pub lamp: lamp::LampConfig,
    /// The sample holder plate with its markers.
    pub plate: plate::PlateConfig,
    /// Speeds, settle times and transfer rates of the devices.
    pub timing: timing::TimingConfig,
    /// Lights, cameras and turntable of a dome rig (`kind = "led_dome"` or `"camera_array"` only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dome: Option<dome::DomeConfig>,
}

impl RigConfig {
    /// Parses a rig config from TOML text; `origin` names the file in error messages.
    pub fn from_toml(text: &str, origin: &str) -> Result<Self, ConfigError> {
        let cfg: RigConfig = toml::from_str(text)
            .map_err(|e| ConfigError::Parse { path: origin.to_string(), message: e.to_string() })?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// Checks every value against its allowed range and reports all problems at once.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let mut errors = Vec::new();
        self.geometry.validate(&mut errors);
        self.devices.validate(&mut errors);
        self.camera.validate(&mut errors);
        self.sensor.validate(&mut errors);
        self.lamp.validate(&mut errors);
        self.plate.validate(&mut errors);
        self.timing.validate(&mut errors);
        self.validate_kind(&mut errors);
        ConfigError::from_list(errors)
    }

    /// The `[dome]` section of a dome rig (LED dome or camera array), or an error naming the
    /// rig and what `what` needs.
    pub fn require_dome(&self, what: &str) -> Result<&dome::DomeConfig, ConfigError> {
        match (&self.rig.kind, &self.dome) {
            (k, Some(d)) if k.is_dome() => Ok(d),
            _ => Err(ConfigError::Unknown {
                field: "rig.kind".into(),
                value: self.rig.kind.as_str().into(),
                allowed: format!("\"led_dome\" or \"camera_array\" with a [dome] section for {what}"),
            }),
        }
    }

    /// Refuses an LED dome where only a gonioreflectometer makes sense (kinematics, the
    /// gonio planner and engine), naming what was asked for.
    pub fn require_gonio(&self, what: &str) -> Result<(), ConfigError> {
        match self.rig.kind {
            RigKind::Gonioreflectometer => Ok(()),
            k => Err(ConfigError::Unknown {
                field: "rig.kind".into(),
                value: k.as_str().into(),
                allowed: format!("\"gonioreflectometer\" for {what} (LED domes and camera arrays run with `btfrig demo --rig dome` / `--rig camera-array`, docs/multiplexing.md)"),
            }),
        }
    }

    fn validate_kind(&self, errors: &mut Vec<ConfigError>) {
        let kind = self.rig.kind;
        let name = kind.as_str();
        match (kind, &self.dome) {
            (RigKind::Gonioreflectometer, Some(_)) => errors.push(ConfigError::out_of_range(
                "dome",
                "a [dome] section",
                "only with [rig] kind = \"led_dome\" or \"camera_array\"",
            )),
            (RigKind::Gonioreflectometer, None) => {}
            (_, None) => errors.push(ConfigError::out_of_range(
                "dome",
                "missing",
                &format!("a [dome] section for kind = \"{name}\""),
            )),
            (_, Some(d)) => {
                d.validate(kind, errors);
                let what = if kind == RigKind::CameraArray { "a camera array" } else { "an LED dome" };
                match (kind, &self.devices.turntable) {
                    (RigKind::LedDome, None) => errors.push(ConfigError::out_of_range(
                        "devices.turntable",
                        "missing",
                        "a [devices.turntable] entry on an LED dome",
                    )),
                    (RigKind::CameraArray, Some(_)) => errors.push(ConfigError::out_of_range(
                        "devices.turntable",
                        "an entry",
                        "absent on a camera array (no turntable)",
                    )),
                    _ => {}
                }
                // A camera array's flash triggers are driven as an LED array: a pattern says
                // which flashes fire in the next exposure, and at what power.
                let lights = if kind == RigKind::CameraArray {
                    "the flashes: one per camera"
                } else {
                    "the LEDs of [dome] led_rings"
                };
                match &self.devices.led_array {
                    None => errors.push(ConfigError::out_of_range(
                        "devices.led_array",
                        "missing",
                        &format!("a [devices.led_array] entry on {what}"),
                    )),
                    Some(e) => {
                        let count = e.options.get("count").and_then(|v| v.as_integer());
                        if count.is_some_and(|c| c as usize != d.led_count()) {
                            errors.push(ConfigError::out_of_range(
                                "devices.led_array.count",
                                count.unwrap_or(0),
                                &format!("{} ({lights})", d.led_count()),
                            ));
                        }
                    }
                }
            }
        }
    }
}
