//! The simulated lamp.

use async_trait::async_trait;
use btfrig_core::config::timing::LampTiming;
use btfrig_hw::{Device, DeviceError, DeviceInfo, ErrorKind, Health, Lamp, LampCapabilities, LampStatus, WarmUp};

use crate::faults::{FaultGate, COMMAND_TIMEOUT_S};
use crate::options::SimLampOptions;
use crate::SimWorld;

/// A simulated lamp with warm-up, shutter and (optionally) a dimmer. Its true output
/// (warm-up curve, drift) is in [`crate::TrueState::lamp_intensity`].
#[derive(Debug)]
pub struct SimLamp {
    info: DeviceInfo,
    gate: FaultGate,
    opts: SimLampOptions,
    timing: LampTiming,
    world: SimWorld,
}

impl SimLamp {
    pub(crate) fn new(opts: &SimLampOptions, timing: &LampTiming, gate: FaultGate, world: SimWorld) -> Self {
        SimLamp { info: super::info(gate.name(), &opts.model), gate, opts: opts.clone(), timing: *timing, world }
    }

    fn warm_up(&self) -> WarmUp {
        let w = self.world.lock();
        if !w.lamp.on {
            return WarmUp::Off;
        }
        let remaining_s = w.lamp.on_since_s + self.timing.warm_up_s - self.world.clock().now_s();
        if remaining_s > 0.0 {
            WarmUp::WarmingUp { remaining_s }
        } else {
            WarmUp::Ready
        }
    }
}

#[async_trait]
impl Device for SimLamp {
    fn info(&self) -> &DeviceInfo {
        &self.info
    }

    async fn health(&mut self) -> Result<Health, DeviceError> {
        self.gate.begin("health", COMMAND_TIMEOUT_S).await?;
        Ok(match self.warm_up() {
            WarmUp::WarmingUp { remaining_s } => Health::Warning(format!("warming up, {remaining_s:.0} s left")),
            _ => Health::Ok,
        })
    }

    async fn reconnect(&mut self) -> Result<(), DeviceError> {
        self.gate.begin("reconnect", COMMAND_TIMEOUT_S).await.map(|_| ())
    }
}

#[async_trait]
impl Lamp for SimLamp {
    fn capabilities(&self) -> LampCapabilities {
        LampCapabilities {
            has_shutter: self.opts.has_shutter,
            intensity_range: self.opts.dimmable.then_some((self.opts.min_intensity, 1.0)),
            warm_up_s: self.timing.warm_up_s,
        }
    }

    async fn set_on(&mut self, on: bool) -> Result<(), DeviceError> {
        self.gate.begin("set_on", COMMAND_TIMEOUT_S).await?;
        self.world.clock().sleep_s(self.timing.switch_s).await;
        let now = self.world.clock().now_s();
        let mut w = self.world.lock();
        if on && !w.lamp.on {
            w.lamp.on_since_s = now;
        }
        w.lamp.on = on;
        Ok(())
    }

    async fn status(&mut self) -> Result<LampStatus, DeviceError> {
        self.gate.begin("status", COMMAND_TIMEOUT_S).await?;
        let warm_up = self.warm_up();
        let w = self.world.lock();
        Ok(LampStatus { on: w.lamp.on, shutter_open: w.lamp.shutter_open, intensity: w.lamp.setpoint, warm_up })
    }

    async fn wait_ready(&mut self, timeout_s: f64) -> Result<(), DeviceError> {
        self.gate.begin("wait_ready", timeout_s).await?;
        match self.warm_up() {
            WarmUp::Off => Err(DeviceError::new(&self.info.name, ErrorKind::Other, "wait_ready: the lamp is off")),
            WarmUp::Ready => Ok(()),
            WarmUp::WarmingUp { remaining_s } if remaining_s > timeout_s => {
                self.world.clock().sleep_s(timeout_s).await;
                Err(DeviceError::new(
                    &self.info.name,
                    ErrorKind::Timeout,
                    format!("wait_ready: still warming up after {timeout_s} s ({:.0} s left)", remaining_s - timeout_s),
                ))
            }
            WarmUp::WarmingUp { remaining_s } => {
                self.world.clock().sleep_s(remaining_s).await;
                Ok(())
            }
        }
    }

    async fn set_shutter_open(&mut self, open: bool) -> Result<(), DeviceError> {
        if !self.opts.has_shutter {
            return Err(DeviceError::unsupported(&self.info.name, "shutter"));
        }
        self.gate.begin("set_shutter_open", COMMAND_TIMEOUT_S).await?;
        self.world.clock().sleep_s(self.timing.shutter_s).await;
        self.world.lock().lamp.shutter_open = open;
        Ok(())
    }

    async fn set_intensity(&mut self, fraction: f64) -> Result<(), DeviceError> {
        if !self.opts.dimmable {
            return Err(DeviceError::unsupported(&self.info.name, "intensity control"));
        }
        if !(fraction >= self.opts.min_intensity && fraction <= 1.0) {
            return Err(DeviceError::out_of_range(
                &self.info.name,
                "intensity",
                fraction,
                format!("[{}, 1]", self.opts.min_intensity),
            ));
        }
        self.gate.begin("set_intensity", COMMAND_TIMEOUT_S).await?;
        self.world.clock().sleep_s(self.timing.switch_s).await;
        self.world.lock().lamp.setpoint = fraction;
        Ok(())
    }
}
