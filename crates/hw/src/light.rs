//! Light sources: a single lamp (e.g. the Bonn HMI lamp) and arrays of LEDs (domes).

use async_trait::async_trait;

use crate::{Device, DeviceError};

/// What a lamp can do.
#[derive(Debug, Clone, PartialEq)]
pub struct LampCapabilities {
    /// Whether the lamp has a shutter that blocks the light without switching it off.
    pub has_shutter: bool,
    /// Range of the intensity setpoint (fraction of full output), or `None` if fixed.
    pub intensity_range: Option<(f64, f64)>,
    /// Time from switch-on until the output is stable, seconds.
    pub warm_up_s: f64,
}

/// Warm-up state of a lamp.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum WarmUp {
    /// Switched off.
    Off,
    /// On, but the output is not yet stable.
    WarmingUp {
        /// Time left until ready, seconds.
        remaining_s: f64,
    },
    /// On and stable.
    Ready,
}

/// What a lamp reports about itself.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LampStatus {
    /// Switched on.
    pub on: bool,
    /// Shutter open (always `true` for a lamp without shutter).
    pub shutter_open: bool,
    /// Intensity setpoint, fraction of full output.
    pub intensity: f64,
    /// Warm-up state.
    pub warm_up: WarmUp,
}

/// A single lamp.
#[async_trait]
pub trait Lamp: Device {
    /// What this lamp can do.
    fn capabilities(&self) -> LampCapabilities;

    /// Switches the lamp on or off. Switching on starts the warm-up.
    async fn set_on(&mut self, on: bool) -> Result<(), DeviceError>;

    /// On/off, shutter, setpoint and warm-up state.
    async fn status(&mut self) -> Result<LampStatus, DeviceError>;

    /// Waits until the lamp is warmed up; fails with [`crate::ErrorKind::Timeout`] if that
    /// takes longer than `timeout_s`, or [`crate::ErrorKind::Other`] if it is off.
    async fn wait_ready(&mut self, timeout_s: f64) -> Result<(), DeviceError>;

    /// Opens or closes the shutter. Default: [`crate::ErrorKind::Unsupported`].
    async fn set_shutter_open(&mut self, open: bool) -> Result<(), DeviceError> {
        let _ = open;
        Err(DeviceError::unsupported(self.name(), "shutter"))
    }

    /// Sets the intensity, fraction of full output. Default: [`crate::ErrorKind::Unsupported`].
    async fn set_intensity(&mut self, fraction: f64) -> Result<(), DeviceError> {
        let _ = fraction;
        Err(DeviceError::unsupported(self.name(), "intensity control"))
    }
}

/// Intensities of every LED of an array, each a fraction of full output in `[0, 1]`.
#[derive(Debug, Clone, PartialEq)]
pub struct LedPattern {
    /// One intensity per LED, indexed like the rig's LED list.
    pub intensities: Vec<f64>,
}

impl LedPattern {
    /// All `count` LEDs off.
    pub fn all_off(count: usize) -> Self {
        LedPattern { intensities: vec![0.0; count] }
    }

    /// Only LED `index` on at full output.
    pub fn single(count: usize, index: usize) -> Self {
        let mut p = Self::all_off(count);
        if index < count {
            p.intensities[index] = 1.0;
        }
        p
    }

    /// Number of LEDs that are not off.
    pub fn lit_count(&self) -> usize {
        self.intensities.iter().filter(|&&v| v > 0.0).count()
    }
}

/// What an LED array can do.
#[derive(Debug, Clone, PartialEq)]
pub struct LedCapabilities {
    /// Number of LEDs.
    pub count: usize,
    /// Number of distinct intensity steps per LED (2 = on/off only).
    pub intensity_steps: u32,
}

/// An array of individually dimmable LEDs.
#[async_trait]
pub trait LedArray: Device {
    /// Count and resolution.
    fn capabilities(&self) -> LedCapabilities;

    /// Sets every LED at once; returns when the pattern is lit. A pattern of the wrong
    /// length or with an intensity outside `[0, 1]` fails with
    /// [`crate::ErrorKind::OutOfRange`].
    async fn set_pattern(&mut self, pattern: &LedPattern) -> Result<(), DeviceError>;

    /// The pattern the controller reports as set.
    async fn pattern(&mut self) -> Result<LedPattern, DeviceError>;

    /// Number of LEDs.
    fn count(&self) -> usize {
        self.capabilities().count
    }

    /// Switches every LED off.
    async fn all_off(&mut self) -> Result<(), DeviceError> {
        let p = LedPattern::all_off(self.count());
        self.set_pattern(&p).await
    }
}
