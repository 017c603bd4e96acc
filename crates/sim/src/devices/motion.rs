//! The motion model shared by the simulated robot, rail and turntable: limits, homing,
//! trapezoidal move time plus settle, positioning error, busy tracking.

use btfrig_hw::{AxisLimits, DeviceError, ErrorKind, SharedClock};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use crate::profile::move_time_s;

/// Per-axis constants, radians and seconds.
#[derive(Debug, Clone)]
pub(crate) struct AxisModel {
    pub limits: AxisLimits,
    pub accel_rad_per_s2: f64,
    pub offset_rad: f64,
    pub jitter_rad: f64,
}

/// The state machine of `N` axes that move together.
#[derive(Debug)]
pub(crate) struct Motion<const N: usize> {
    pub name: String,
    pub axes: [AxisModel; N],
    pub settle_s: f64,
    pub home_s: f64,
    pub homed: bool,
    /// Commanded (and reported) position.
    pub commanded: [f64; N],
    /// Until when (clock seconds) an earlier move is still running.
    pub busy_until_s: f64,
    seed: u64,
    clock: SharedClock,
}

impl<const N: usize> Motion<N> {
    pub fn new(
        name: &str,
        axes: [AxisModel; N],
        settle_s: f64,
        home_s: f64,
        homed: bool,
        seed: u64,
        clock: SharedClock,
    ) -> Self {
        Motion {
            name: name.to_string(),
            axes,
            settle_s,
            home_s,
            homed,
            commanded: [0.0; N],
            busy_until_s: f64::NEG_INFINITY,
            seed,
            clock,
        }
    }

    pub fn limits(&self) -> [AxisLimits; N] {
        std::array::from_fn(|i| self.axes[i].limits)
    }

    fn check_idle(&self, op: &str) -> Result<(), DeviceError> {
        let now = self.clock.now_s();
        if now < self.busy_until_s {
            return Err(DeviceError::new(
                &self.name,
                ErrorKind::Busy,
                format!("{op}: still moving for {:.3} s", self.busy_until_s - now),
            ));
        }
        Ok(())
    }

    /// Time a move from the commanded position to `target` takes: the slowest axis's
    /// profile, plus the settle time if anything moves.
    pub fn duration_s(&self, target: &[f64; N]) -> f64 {
        let motion = (0..N)
            .map(|i| {
                let a = &self.axes[i];
                move_time_s(target[i] - self.commanded[i], a.limits.max_speed_rad_per_s, a.accel_rad_per_s2)
            })
            .fold(0.0, f64::max);
        if motion > 0.0 {
            motion + self.settle_s
        } else {
            0.0
        }
    }

    /// Where the axes truly land when commanded to `target`: offset plus a jitter drawn from
    /// a stream keyed by the seed and the target itself (a pose-dependent repeatability
    /// error). Keyed by the target, not by the number of moves so far, so a run resumed
    /// after a crash lands exactly where the uninterrupted run landed.
    fn landing(&self, target: &[f64; N]) -> [f64; N] {
        let words: [u64; N] = std::array::from_fn(|i| target[i].to_bits());
        let mut rng = ChaCha8Rng::seed_from_u64(crate::faults::seed_for(self.seed, &words));
        std::array::from_fn(|i| {
            let a = &self.axes[i];
            let z: f64 = StandardNormal.sample(&mut rng);
            target[i] + a.offset_rad + a.jitter_rad * z
        })
    }

    /// Moves to `target`; returns (true landing, reported position) after settling, or
    /// fails. `apply` writes the outcome into the world. When the move needs longer than
    /// `timeout_s`, the call fails after `timeout_s` with `Timeout` while the axes go on to
    /// the target (and report `Busy` until they are there); the world shows the final
    /// position from then on.
    pub async fn move_to(
        &mut self,
        op: &str,
        target: [f64; N],
        timeout_s: f64,
        apply: impl FnOnce([f64; N], [f64; N]),
    ) -> Result<[f64; N], DeviceError> {
        self.check_idle(op)?;
        if !self.homed {
            return Err(DeviceError::new(&self.name, ErrorKind::NotHomed, format!("{op}: call home first")));
        }
        for (i, (&t, a)) in target.iter().zip(&self.axes).enumerate() {
            if !a.limits.contains(t) {
                let what = if N == 1 { format!("{op} target") } else { format!("{op} target of joint {i}") };
                return Err(DeviceError::out_of_range(
                    &self.name,
                    &what,
                    format!("{:.4} deg", t.to_degrees()),
                    format!("[{:.4}, {:.4}] deg", a.limits.min_rad.to_degrees(), a.limits.max_rad.to_degrees()),
                ));
            }
        }
        let duration = self.duration_s(&target);
        let landing = self.landing(&target);
        self.commanded = target;
        if duration > timeout_s {
            self.busy_until_s = self.clock.now_s() + duration;
            apply(landing, target);
            self.clock.sleep_s(timeout_s).await;
            return Err(DeviceError::new(
                &self.name,
                ErrorKind::Timeout,
                format!("{op}: move needs {duration:.3} s, more than the timeout {timeout_s} s"),
            ));
        }
        self.clock.sleep_s(duration).await;
        apply(landing, target);
        Ok(target)
    }

    /// Runs a homing cycle: every axis goes to 0 (clamped into its limits).
    pub async fn home(&mut self, timeout_s: f64, apply: impl FnOnce([f64; N], [f64; N])) -> Result<(), DeviceError> {
        self.check_idle("home")?;
        if self.home_s > timeout_s {
            self.clock.sleep_s(timeout_s).await;
            return Err(DeviceError::new(
                &self.name,
                ErrorKind::Timeout,
                format!("home: homing takes {} s, more than the timeout {timeout_s} s", self.home_s),
            ));
        }
        self.clock.sleep_s(self.home_s).await;
        let target: [f64; N] =
            std::array::from_fn(|i| 0f64.clamp(self.axes[i].limits.min_rad, self.axes[i].limits.max_rad));
        let landing = self.landing(&target);
        self.commanded = target;
        self.homed = true;
        apply(landing, target);
        Ok(())
    }

    pub fn position(&self, op: &str) -> Result<[f64; N], DeviceError> {
        if !self.homed {
            return Err(DeviceError::new(
                &self.name,
                ErrorKind::NotHomed,
                format!("{op}: position unknown before homing"),
            ));
        }
        Ok(self.commanded)
    }
}
