//! A rig described as data: the TOML files in `rig-configs/`.
//!
//! Each section of the file is a struct in its own module; every struct denies unknown
//! fields so that a typo is an error naming the field, never a silently ignored setting.
//! The format is documented in `docs/rig-config.md`.

pub mod camera;
pub mod devices;
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
        ConfigError::from_list(errors)
    }
}
