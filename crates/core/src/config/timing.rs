//! The `[timing]` section of a rig config: how long device operations take.
//!
//! The simulator turns these figures into waits on the rig's clock; a real rig's backend may
//! use them as expectations (for timeouts and progress estimates). Angles in degrees, times
//! in seconds, as in every rig file. The model and the default figures (which resemble the
//! Bonn gonioreflectometer, where one 14-hour run took 6561 images and most of the time went
//! into transferring the raw frames) are documented in `docs/timing.md`.

use serde::{Deserialize, Serialize};

use crate::error::ConfigError;

/// Timing of one rotary axis (rail, turntable).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AxisTiming {
    /// Top speed, degrees per second.
    pub max_speed_deg_per_s: f64,
    /// Acceleration and deceleration, degrees per second squared (trapezoidal profile).
    pub accel_deg_per_s2: f64,
    /// Time from reaching the target until the axis is still (vibration dies down), seconds.
    pub settle_s: f64,
    /// Duration of a homing run, seconds.
    pub home_s: f64,
}

/// Timing of the robot: per joint speed and acceleration, one settle time.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotTiming {
    /// Top speed of each joint, degrees per second.
    pub max_speed_deg_per_s: [f64; 3],
    /// Acceleration and deceleration of each joint, degrees per second squared.
    pub accel_deg_per_s2: [f64; 3],
    /// Time from the last joint reaching its target until the sample is still, seconds.
    pub settle_s: f64,
    /// Duration of a homing run, seconds.
    pub home_s: f64,
}

/// Timing of the lamp.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LampTiming {
    /// Time from switch-on until the output is stable (the lamp reports ready), seconds.
    pub warm_up_s: f64,
    /// Time a switch-on, switch-off or intensity command takes, seconds.
    pub switch_s: f64,
    /// Time the shutter takes to open or close, seconds.
    pub shutter_s: f64,
}

/// Timing of an LED array.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LedTiming {
    /// Time from sending a pattern until it is lit, seconds.
    pub switch_s: f64,
}

/// Timing of the camera.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraTiming {
    /// Time a settings command (exposure, gain, aperture) takes, seconds.
    pub command_s: f64,
    /// Delay from the trigger command to the start of the exposure, seconds.
    pub trigger_latency_s: f64,
    /// Time to read the sensor into the camera's buffer after the exposure, seconds.
    pub read_out_s: f64,
    /// Speed of the link from camera to host, bytes per second.
    pub transfer_bytes_per_s: f64,
    /// Bytes sent per frame. The Bonn camera sent 12 MB (lossless-compressed 12-bit raw of
    /// 4500x3000); this figure is used whatever the simulated resolution, so a small
    /// simulated frame still costs the real transfer time. Omit it to use the simulated
    /// frame's own size (2 bytes per photosite).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub frame_bytes: Option<u64>,
}

/// The `[timing]` section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TimingConfig {
    /// The robot orienting the sample.
    pub robot: RobotTiming,
    /// The camera rail.
    pub rail: AxisTiming,
    /// The turntable (ignored when the rig has none).
    pub turntable: AxisTiming,
    /// The lamp.
    pub lamp: LampTiming,
    /// The LED array (ignored when the rig has none).
    pub leds: LedTiming,
    /// The camera.
    pub camera: CameraTiming,
}

impl TimingConfig {
    /// Bonn-like defaults; see `docs/timing.md` for where each figure comes from.
    pub const fn bonn() -> Self {
        TimingConfig {
            robot: RobotTiming {
                max_speed_deg_per_s: [60.0, 60.0, 90.0],
                accel_deg_per_s2: [120.0, 120.0, 180.0],
                settle_s: 0.3,
                home_s: 20.0,
            },
            rail: AxisTiming { max_speed_deg_per_s: 30.0, accel_deg_per_s2: 60.0, settle_s: 0.5, home_s: 30.0 },
            turntable: AxisTiming { max_speed_deg_per_s: 30.0, accel_deg_per_s2: 60.0, settle_s: 0.3, home_s: 10.0 },
            lamp: LampTiming { warm_up_s: 180.0, switch_s: 0.5, shutter_s: 0.2 },
            leds: LedTiming { switch_s: 0.005 },
            camera: CameraTiming {
                command_s: 0.05,
                trigger_latency_s: 0.1,
                read_out_s: 0.6,
                transfer_bytes_per_s: 2.4e6,
                frame_bytes: Some(12_000_000),
            },
        }
    }

    /// Appends every out-of-range value of this section to `errors`.
    pub fn validate(&self, errors: &mut Vec<ConfigError>) {
        const SPEED: (f64, f64, &str) = (1e-6, 3600.0, "(0, 3600] deg/s");
        const ACCEL: (f64, f64, &str) = (1e-6, 1e5, "(0, 100000] deg/s^2");
        const TIME: (f64, f64, &str) = (0.0, 3600.0, "[0, 3600] s");
        let mut check = |field: String, v: f64, (lo, hi, allowed): (f64, f64, &str)| {
            // `!(..)` also rejects NaN.
            if !(v >= lo && v <= hi) {
                errors.push(ConfigError::out_of_range(&field, v, allowed));
            }
        };
        let r = &self.robot;
        for j in 0..3 {
            check(format!("timing.robot.max_speed_deg_per_s[{j}]"), r.max_speed_deg_per_s[j], SPEED);
            check(format!("timing.robot.accel_deg_per_s2[{j}]"), r.accel_deg_per_s2[j], ACCEL);
        }
        check("timing.robot.settle_s".into(), r.settle_s, TIME);
        check("timing.robot.home_s".into(), r.home_s, TIME);
        for (name, a) in [("rail", &self.rail), ("turntable", &self.turntable)] {
            check(format!("timing.{name}.max_speed_deg_per_s"), a.max_speed_deg_per_s, SPEED);
            check(format!("timing.{name}.accel_deg_per_s2"), a.accel_deg_per_s2, ACCEL);
            check(format!("timing.{name}.settle_s"), a.settle_s, TIME);
            check(format!("timing.{name}.home_s"), a.home_s, TIME);
        }
        check("timing.lamp.warm_up_s".into(), self.lamp.warm_up_s, TIME);
        check("timing.lamp.switch_s".into(), self.lamp.switch_s, TIME);
        check("timing.lamp.shutter_s".into(), self.lamp.shutter_s, TIME);
        check("timing.leds.switch_s".into(), self.leds.switch_s, TIME);
        let c = &self.camera;
        check("timing.camera.command_s".into(), c.command_s, TIME);
        check("timing.camera.trigger_latency_s".into(), c.trigger_latency_s, TIME);
        check("timing.camera.read_out_s".into(), c.read_out_s, TIME);
        check("timing.camera.transfer_bytes_per_s".into(), c.transfer_bytes_per_s, (1.0, 1e11, "[1, 1e11] bytes/s"));
        if let Some(b) = c.frame_bytes {
            if !(1..=10_000_000_000).contains(&b) {
                errors.push(ConfigError::out_of_range("timing.camera.frame_bytes", b, "1..=10000000000"));
            }
        }
    }
}

impl Default for TimingConfig {
    fn default() -> Self {
        Self::bonn()
    }
}

impl Default for RobotTiming {
    fn default() -> Self {
        Self::bonn_default()
    }
}

impl RobotTiming {
    const fn bonn_default() -> Self {
        TimingConfig::bonn().robot
    }
}

impl Default for AxisTiming {
    /// The Bonn rail's figures.
    fn default() -> Self {
        TimingConfig::bonn().rail
    }
}

impl Default for LampTiming {
    fn default() -> Self {
        TimingConfig::bonn().lamp
    }
}

impl Default for LedTiming {
    fn default() -> Self {
        TimingConfig::bonn().leds
    }
}

impl Default for CameraTiming {
    fn default() -> Self {
        TimingConfig::bonn().camera
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_validate_and_empty_section_means_defaults() {
        let mut errors = Vec::new();
        TimingConfig::default().validate(&mut errors);
        assert!(errors.is_empty(), "{errors:?}");
        let parsed: TimingConfig = toml::from_str("").unwrap();
        assert_eq!(parsed, TimingConfig::bonn());
    }

    #[test]
    fn every_bad_value_is_reported_with_field_value_and_range() {
        let text = r#"
            [robot]
            max_speed_deg_per_s = [60.0, -1.0, 90.0]
            accel_deg_per_s2 = [120.0, 120.0, 180.0]
            settle_s = 0.5
            home_s = 20.0
            [camera]
            command_s = 0.05
            trigger_latency_s = 0.1
            read_out_s = nan
            transfer_bytes_per_s = 0.0
            frame_bytes = 0
        "#;
        let cfg: TimingConfig = toml::from_str(text).unwrap();
        let mut errors = Vec::new();
        cfg.validate(&mut errors);
        let msgs: Vec<String> = errors.iter().map(|e| e.to_string()).collect();
        assert_eq!(msgs.len(), 4, "{msgs:#?}");
        assert_eq!(msgs[0], "timing.robot.max_speed_deg_per_s[1] = -1 is out of range: allowed (0, 3600] deg/s");
        assert!(msgs[1].starts_with("timing.camera.read_out_s = NaN"), "{}", msgs[1]);
        assert!(msgs[2].starts_with("timing.camera.transfer_bytes_per_s = 0"), "{}", msgs[2]);
        assert!(msgs[3].starts_with("timing.camera.frame_bytes = 0"), "{}", msgs[3]);
    }

    #[test]
    fn unknown_field_is_rejected() {
        let err = toml::from_str::<TimingConfig>("[rail]\nmax_speed = 3.0").unwrap_err();
        assert!(err.to_string().contains("max_speed"), "{err}");
    }
}
