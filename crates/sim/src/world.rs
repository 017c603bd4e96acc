//! The simulated world shared by all devices of one rig: the TRUE state (what the renderer
//! must draw, including the positioning errors the devices made) next to the commanded
//! state (what the devices were told and report), and a log of injected faults.

use std::sync::{Arc, Mutex, MutexGuard};

use btfrig_core::config::timing::TimingConfig;
use btfrig_core::kinematics::JointState;
use btfrig_hw::SharedClock;

use serde::{Deserialize, Serialize};

/// What is physically true at one instant: the input of a [`crate::FrameSource`].
#[derive(Debug, Clone, PartialEq)]
pub struct TrueState {
    /// True joint angles, radians (commanded target plus positioning error).
    pub joints: JointState,
    /// Whether the lamp is switched on.
    pub lamp_on: bool,
    /// Whether the lamp's shutter is open (`true` for a lamp without shutter).
    pub lamp_shutter_open: bool,
    /// Light leaving the lamp as a fraction of its nominal full output: setpoint times
    /// warm-up and drift; 0 when off or the shutter is closed.
    pub lamp_intensity: f64,
    /// True intensity of each LED, fraction of full output (stuck LEDs included); empty
    /// when the rig has no LED array.
    pub leds: Vec<f64>,
    /// Time on the rig's clock, seconds.
    pub time_s: f64,
}

/// Which fault was injected.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FaultKind {
    /// A call timed out.
    Timeout,
    /// A call found the device disconnected.
    Disconnected,
    /// A frame never arrived.
    DroppedFrame,
    /// A frame arrived damaged.
    CorruptFrame,
    /// A call failed with a fatal (non-retryable) device error.
    Failure,
}

/// One injected fault, for logs and determinism checks.
#[derive(Debug, Clone, PartialEq)]
pub struct FaultEvent {
    /// Rig clock time of the failing call's start, seconds.
    pub time_s: f64,
    /// Device name.
    pub device: String,
    /// The device's call number (1-based) that failed.
    pub call: u64,
    /// What happened.
    pub kind: FaultKind,
}

#[derive(Debug, Clone)]
pub(crate) struct LampTruth {
    pub on: bool,
    pub shutter_open: bool,
    pub setpoint: f64,
    pub on_since_s: f64,
}

#[derive(Debug)]
pub(crate) struct WorldState {
    pub true_joints: JointState,
    pub commanded: JointState,
    pub lamp: LampTruth,
    pub led_commanded: Vec<f64>,
    pub led_stuck: Vec<Option<f64>>,
    pub faults: Vec<FaultEvent>,
}

/// Handle on the shared world; cheap to clone.
#[derive(Debug, Clone)]
pub struct SimWorld {
    state: Arc<Mutex<WorldState>>,
    clock: SharedClock,
    warm_up_s: f64,
    drift: Option<LampDrift>,
}

impl SimWorld {
    pub(crate) fn new(clock: SharedClock, timing: &TimingConfig, drift: Option<LampDrift>, led_count: usize) -> Self {
        SimWorld {
            state: Arc::new(Mutex::new(WorldState {
                true_joints: JointState::default(),
                commanded: JointState::default(),
                lamp: LampTruth { on: false, shutter_open: true, setpoint: 1.0, on_since_s: 0.0 },
                led_commanded: vec![0.0; led_count],
                led_stuck: vec![None; led_count],
                faults: Vec::new(),
            })),
            clock,
            warm_up_s: timing.lamp.warm_up_s,
            drift,
        }
    }

    pub(crate) fn lock(&self) -> MutexGuard<'_, WorldState> {
        // A panic while holding the lock leaves plain data behind; keep going.
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// The rig's clock.
    pub fn clock(&self) -> &SharedClock {
        &self.clock
    }

    /// The true state now.
    pub fn truth(&self) -> TrueState {
        let now = self.clock.now_s();
        let s = self.lock();
        let lamp_intensity = if s.lamp.on && s.lamp.shutter_open {
            s.lamp.setpoint * self.lamp_output_factor(now - s.lamp.on_since_s)
        } else {
            0.0
        };
        let leds = s.led_commanded.iter().zip(&s.led_stuck).map(|(&c, stuck)| stuck.unwrap_or(c)).collect();
        TrueState {
            joints: s.true_joints,
            lamp_on: s.lamp.on,
            lamp_shutter_open: s.lamp.shutter_open,
            lamp_intensity,
            leds,
            time_s: now,
        }
    }

    /// The joint state the devices were commanded to (and report), radians.
    pub fn commanded(&self) -> JointState {
        self.lock().commanded
    }

    /// Every fault injected so far, in order.
    pub fn fault_log(&self) -> Vec<FaultEvent> {
        self.lock().faults.clone()
    }

    pub(crate) fn log_fault(&self, device: &str, call: u64, kind: FaultKind) {
        let time_s = self.clock.now_s();
        tracing::debug!(device, call, ?kind, time_s, "injected fault");
        self.lock().faults.push(FaultEvent { time_s, device: device.to_string(), call, kind });
    }

    /// Lamp output relative to its setpoint, `t_on_s` seconds after switch-on.
    ///
    /// Nominal lamp: a linear ramp to 1 over the warm-up time, then constant. With a
    /// [`LampDrift`] fault: `1 - (1 - start_fraction) exp(-t / tau) + drift_per_hour
    /// max(0, t - drift_delay_s) / 3600`, never negative.
    pub fn lamp_output_factor(&self, t_on_s: f64) -> f64 {
        let t = t_on_s.max(0.0);
        match &self.drift {
            Some(d) => {
                let drift_t = (t - d.drift_delay_s).max(0.0);
                (1.0 - (1.0 - d.start_fraction) * (-t / d.warm_up_tau_s).exp() + d.drift_per_hour * drift_t / 3600.0)
                    .max(0.0)
            }
            None if self.warm_up_s > 0.0 => (t / self.warm_up_s).min(1.0),
            None => 1.0,
        }
    }
}

/// A lamp whose output keeps changing: exponential warm-up plus slow linear drift. Output
/// factor `t` seconds after switch-on:
/// `1 - (1 - start_fraction) exp(-t / warm_up_tau_s) + drift_per_hour max(0, t - drift_delay_s) / 3600`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LampDrift {
    /// Output at switch-on relative to the settled output, in `[0, 1]`.
    pub start_fraction: f64,
    /// Time constant of the warm-up, seconds, > 0.
    pub warm_up_tau_s: f64,
    /// Change of the output per hour, fraction of the settled output (e.g. -0.01).
    pub drift_per_hour: f64,
    /// Seconds after switch-on before the linear drift starts (default 0): e.g. the rig's
    /// warm-up wait, so that a short simulated run starts near the settled output and drifts
    /// from there.
    #[serde(default)]
    pub drift_delay_s: f64,
}
