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
}

impl RigKind {
    /// The name written in `[rig] kind`.
    pub fn as_str(self) -> &'static str {
        match self {
            RigKind::Gonioreflectometer => "gonioreflectometer",
            RigKind::LedDome => "led_dome",
        }
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
    /// LEDs, camera arc and turntable of an LED dome (`kind = "led_dome"` only).
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

    /// The `[dome]` section of an LED dome, or an error naming the rig and what `what` needs.
    pub fn require_dome(&self, what: &str) -> Result<&dome::DomeConfig, ConfigError> {
        match (&self.rig.kind, &self.dome) {
            (RigKind::LedDome, Some(d)) => Ok(d),
            _ => Err(ConfigError::Unknown {
                field: "rig.kind".into(),
                value: self.rig.kind.as_str().into(),
                allowed: format!("\"led_dome\" with a [dome] section for {what}"),
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
                allowed: format!("\"gonioreflectometer\" for {what} (an LED dome runs with `btfrig demo --rig dome`, docs/multiplexing.md)"),
            }),
        }
    }

    fn validate_kind(&self, errors: &mut Vec<ConfigError>) {
        match (self.rig.kind, &self.dome) {
            (RigKind::Gonioreflectometer, Some(_)) => errors.push(ConfigError::out_of_range(
                "dome",
                "a [dome] section",
                "only with [rig] kind = \"led_dome\"",
            )),
            (RigKind::LedDome, None) => {
                errors.push(ConfigError::out_of_range("dome", "missing", "a [dome] section for kind = \"led_dome\""))
            }
            (RigKind::LedDome, Some(d)) => {
                d.validate(errors);
                if self.devices.turntable.is_none() {
                    errors.push(ConfigError::out_of_range(
                        "devices.turntable",
                        "missing",
                        "a [devices.turntable] entry on an LED dome",
                    ));
                }
                match &self.devices.led_array {
                    None => errors.push(ConfigError::out_of_range(
                        "devices.led_array",
                        "missing",
                        "a [devices.led_array] entry on an LED dome",
                    )),
                    Some(e) => {
                        let count = e.options.get("count").and_then(|v| v.as_integer());
                        if count.is_some_and(|c| c as usize != d.led_count()) {
                            errors.push(ConfigError::out_of_range(
                                "devices.led_array.count",
                                count.unwrap_or(0),
                                &format!("{} (the LEDs of [dome] led_rings)", d.led_count()),
                            ));
                        }
                    }
                }
            }
            (RigKind::Gonioreflectometer, None) => {}
        }
    }
}
