//! Options of the simulated devices: the keys of a `[devices.X]` table with `kind = "sim"`.
//!
//! Each table is laid over the role's defaults, then parsed with unknown fields denied, so a
//! typo is an error naming the key. Angles in degrees, as in every rig file. The positioning
//! error model lives here: a move lands at `target + offset_deg + jitter_deg * N(0, 1)` per
//! axis, seeded from the rig seed.

use btfrig_core::ConfigError;
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

/// Options of the simulated robot.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimRobotOptions {
    /// Model name reported in [`btfrig_hw::DeviceInfo`].
    pub model: String,
    /// Lowest angle of each joint, degrees (the controller's own soft limits).
    pub joint_min_deg: [f64; 3],
    /// Highest angle of each joint, degrees.
    pub joint_max_deg: [f64; 3],
    /// Systematic positioning error of each joint, degrees (added to every move).
    pub offset_deg: [f64; 3],
    /// Standard deviation of the random positioning error of each joint, degrees.
    pub jitter_deg: [f64; 3],
    /// Start homed, skipping the need to call `home` (convenient for tests and demos).
    pub homed_at_start: bool,
}

impl Default for SimRobotOptions {
    fn default() -> Self {
        SimRobotOptions {
            model: "sim 3-joint sample robot".into(),
            joint_min_deg: [-180.0, -90.0, -360.0],
            joint_max_deg: [180.0, 90.0, 360.0],
            offset_deg: [0.02, -0.03, 0.01],
            jitter_deg: [0.05, 0.05, 0.05],
            homed_at_start: false,
        }
    }
}

/// Options of a simulated single axis (rail or turntable).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimAxisOptions {
    /// Model name reported in [`btfrig_hw::DeviceInfo`].
    pub model: String,
    /// Lowest angle, degrees.
    pub min_deg: f64,
    /// Highest angle, degrees.
    pub max_deg: f64,
    /// Systematic positioning error, degrees.
    pub offset_deg: f64,
    /// Standard deviation of the random positioning error, degrees.
    pub jitter_deg: f64,
    /// Start homed.
    pub homed_at_start: bool,
}

impl SimAxisOptions {
    /// Defaults of the camera rail: 0..180 degrees between lamp and camera, 0.1 degree
    /// jitter (a long rail with a heavy camera is the least precise axis).
    pub fn rail() -> Self {
        SimAxisOptions {
            model: "sim camera rail".into(),
            min_deg: 0.0,
            max_deg: 180.0,
            offset_deg: 0.05,
            jitter_deg: 0.1,
            homed_at_start: false,
        }
    }

    /// Defaults of a turntable: two turns either way, 0.02 degree jitter.
    pub fn turntable() -> Self {
        SimAxisOptions {
            model: "sim turntable".into(),
            min_deg: -720.0,
            max_deg: 720.0,
            offset_deg: 0.0,
            jitter_deg: 0.02,
            homed_at_start: false,
        }
    }
}

/// Options of the simulated lamp.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimLampOptions {
    /// Model name.
    pub model: String,
    /// Whether the lamp has a shutter.
    pub has_shutter: bool,
    /// Whether the intensity can be set.
    pub dimmable: bool,
    /// Lowest intensity setpoint when dimmable, fraction of full output (HMI ballasts dim
    /// to about half).
    pub min_intensity: f64,
}

impl Default for SimLampOptions {
    fn default() -> Self {
        SimLampOptions { model: "sim HMI lamp".into(), has_shutter: true, dimmable: true, min_intensity: 0.5 }
    }
}

/// Options of the simulated LED array.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimLedOptions {
    /// Model name.
    pub model: String,
    /// Number of LEDs (Dome II: 198).
    pub count: usize,
    /// Distinct intensity steps per LED (PWM resolution).
    pub intensity_steps: u32,
}

impl Default for SimLedOptions {
    fn default() -> Self {
        SimLedOptions { model: "sim LED array".into(), count: 198, intensity_steps: 4096 }
    }
}

/// Options of the simulated camera. The sensor layout comes from the frame source.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimCameraOptions {
    /// Model name.
    pub model: String,
    /// Shortest and longest exposure, seconds.
    pub exposure_range_s: [f64; 2],
    /// Lowest and highest gain.
    pub gain_range: [f64; 2],
    /// Whether the aperture can be set.
    pub has_aperture: bool,
    /// Widest and narrowest f-number.
    pub f_number_range: [f64; 2],
    /// Exposure at start, seconds.
    pub exposure_s: f64,
    /// Gain at start.
    pub gain: f64,
    /// f-number at start.
    pub f_number: f64,
}

impl Default for SimCameraOptions {
    fn default() -> Self {
        SimCameraOptions {
            model: "sim raw camera (Kodak DCS Pro 14N-like timing)".into(),
            exposure_range_s: [1e-4, 30.0],
            gain_range: [1.0, 8.0],
            has_aperture: true,
            f_number_range: [2.8, 22.0],
            exposure_s: 0.2,
            gain: 1.0,
            f_number: 8.0,
        }
    }
}

/// Lays `options` over `defaults` and parses the result; `field` (e.g. `devices.robot`)
/// prefixes errors.
pub(crate) fn parse_over<T: Serialize + DeserializeOwned>(
    defaults: T,
    options: &toml::Table,
    field: &str,
) -> Result<T, ConfigError> {
    let parse_err = |message: String| ConfigError::Parse { path: field.to_string(), message };
    let mut table = toml::Table::try_from(defaults).map_err(|e| parse_err(e.to_string()))?;
    for (k, v) in options {
        table.insert(k.clone(), v.clone());
    }
    table.try_into().map_err(|e: toml::de::Error| parse_err(e.to_string()))
}

fn check(errors: &mut Vec<ConfigError>, field: String, v: f64, lo: f64, hi: f64, allowed: &str) {
    if !(v >= lo && v <= hi) {
        errors.push(ConfigError::out_of_range(&field, v, allowed));
    }
}

fn check_range(errors: &mut Vec<ConfigError>, field: &str, [lo, hi]: [f64; 2], min: f64, max: f64, allowed: &str) {
    check(errors, format!("{field}[0]"), lo, min, max, allowed);
    check(errors, format!("{field}[1]"), hi, min, max, allowed);
    if lo > hi {
        errors.push(ConfigError::out_of_range(field, format!("[{lo}, {hi}]"), "[low, high] with low <= high"));
    }
}

fn check_limits(errors: &mut Vec<ConfigError>, min_field: &str, max_field: &str, lo: f64, hi: f64) {
    check(errors, min_field.to_string(), lo, -720.0, 720.0, "[-720, 720] deg");
    check(errors, max_field.to_string(), hi, -720.0, 720.0, "[-720, 720] deg");
    if lo >= hi {
        errors.push(ConfigError::out_of_range(min_field, lo, &format!("below {max_field} = {hi}")));
    }
}

impl SimRobotOptions {
    /// Appends every out-of-range value to `errors`; `f` is the table's field path.
    pub fn validate(&self, f: &str, errors: &mut Vec<ConfigError>) {
        for j in 0..3 {
            check_limits(
                errors,
                &format!("{f}.joint_min_deg[{j}]"),
                &format!("{f}.joint_max_deg[{j}]"),
                self.joint_min_deg[j],
                self.joint_max_deg[j],
            );
            check(errors, format!("{f}.offset_deg[{j}]"), self.offset_deg[j], -10.0, 10.0, "[-10, 10] deg");
            check(errors, format!("{f}.jitter_deg[{j}]"), self.jitter_deg[j], 0.0, 10.0, "[0, 10] deg");
        }
    }
}

impl SimAxisOptions {
    /// Appends every out-of-range value to `errors`.
    pub fn validate(&self, f: &str, errors: &mut Vec<ConfigError>) {
        check_limits(errors, &format!("{f}.min_deg"), &format!("{f}.max_deg"), self.min_deg, self.max_deg);
        check(errors, format!("{f}.offset_deg"), self.offset_deg, -10.0, 10.0, "[-10, 10] deg");
        check(errors, format!("{f}.jitter_deg"), self.jitter_deg, 0.0, 10.0, "[0, 10] deg");
    }
}

impl SimLampOptions {
    /// Appends every out-of-range value to `errors`.
    pub fn validate(&self, f: &str, errors: &mut Vec<ConfigError>) {
        check(errors, format!("{f}.min_intensity"), self.min_intensity, 0.0, 1.0, "[0, 1]");
    }
}

impl SimLedOptions {
    /// Appends every out-of-range value to `errors`.
    pub fn validate(&self, f: &str, errors: &mut Vec<ConfigError>) {
        if !(1..=100_000).contains(&self.count) {
            errors.push(ConfigError::out_of_range(&format!("{f}.count"), self.count, "1..=100000"));
        }
        if self.intensity_steps < 2 {
            errors.push(ConfigError::out_of_range(&format!("{f}.intensity_steps"), self.intensity_steps, "2.."));
        }
    }
}

impl SimCameraOptions {
    /// Appends every out-of-range value to `errors`.
    pub fn validate(&self, f: &str, errors: &mut Vec<ConfigError>) {
        let [e0, e1] = self.exposure_range_s;
        check_range(errors, &format!("{f}.exposure_range_s"), self.exposure_range_s, 1e-7, 3600.0, "[1e-7, 3600] s");
        check_range(errors, &format!("{f}.gain_range"), self.gain_range, 0.01, 1e4, "[0.01, 10000]");
        check_range(errors, &format!("{f}.f_number_range"), self.f_number_range, 0.5, 128.0, "[0.5, 128]");
        check(errors, format!("{f}.exposure_s"), self.exposure_s, e0, e1, &format!("exposure_range_s [{e0}, {e1}]"));
        let [g0, g1] = self.gain_range;
        check(errors, format!("{f}.gain"), self.gain, g0, g1, &format!("gain_range [{g0}, {g1}]"));
        let [a0, a1] = self.f_number_range;
        check(errors, format!("{f}.f_number"), self.f_number, a0, a1, &format!("f_number_range [{a0}, {a1}]"));
    }
}
