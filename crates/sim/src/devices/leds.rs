//! The simulated LED array.

use async_trait::async_trait;
use btfrig_core::config::timing::LedTiming;
use btfrig_hw::{DeviceError, DeviceInfo, LedArray, LedCapabilities, LedPattern};

use crate::faults::{FaultGate, COMMAND_TIMEOUT_S};
use crate::options::SimLedOptions;
use crate::SimWorld;

/// A simulated array of dimmable LEDs. It reports the commanded pattern; stuck LEDs show
/// only in [`crate::TrueState::leds`] (and hence in the frames), as with real hardware.
#[derive(Debug)]
pub struct SimLedArray {
    info: DeviceInfo,
    gate: FaultGate,
    opts: SimLedOptions,
    timing: LedTiming,
    world: SimWorld,
}

impl SimLedArray {
    pub(crate) fn new(opts: &SimLedOptions, timing: &LedTiming, gate: FaultGate, world: SimWorld) -> Self {
        SimLedArray { info: super::info(gate.name(), &opts.model), gate, opts: opts.clone(), timing: *timing, world }
    }
}

impl_sim_device!(SimLedArray);

#[async_trait]
impl LedArray for SimLedArray {
    fn capabilities(&self) -> LedCapabilities {
        LedCapabilities { count: self.opts.count, intensity_steps: self.opts.intensity_steps }
    }

    async fn set_pattern(&mut self, pattern: &LedPattern) -> Result<(), DeviceError> {
        let n = self.opts.count;
        if pattern.intensities.len() != n {
            return Err(DeviceError::out_of_range(&self.info.name, "pattern length", pattern.intensities.len(), n));
        }
        if let Some((i, v)) = pattern.intensities.iter().enumerate().find(|(_, v)| !(0.0..=1.0).contains(*v)) {
            return Err(DeviceError::out_of_range(&self.info.name, &format!("intensity of LED {i}"), v, "[0, 1]"));
        }
        self.gate.begin("set_pattern", COMMAND_TIMEOUT_S).await?;
        self.world.clock().sleep_s(self.timing.switch_s).await;
        // The controller quantises to its PWM steps.
        let steps = f64::from(self.opts.intensity_steps - 1);
        self.world.lock().led_commanded = pattern.intensities.iter().map(|v| (v * steps).round() / steps).collect();
        Ok(())
    }

    async fn pattern(&mut self) -> Result<LedPattern, DeviceError> {
        self.gate.begin("pattern", COMMAND_TIMEOUT_S).await?;
        Ok(LedPattern { intensities: self.world.lock().led_commanded.clone() })
    }
}
