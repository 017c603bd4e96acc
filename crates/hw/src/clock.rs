//! The clock devices and the run engine use instead of sleeping on their own.
//!
//! [`TokioClock`] follows tokio's timer: under `tokio::time::pause()` (or
//! `#[tokio::test(start_paused = true)]`) time is virtual and jumps forward whenever every task
//! waits, so a 14-hour plan runs in well under a second. [`ScaledClock`] runs `speed` times
//! faster than the wall clock, for a person watching a simulated run.

use std::sync::Arc;
use std::time::Duration;

use async_trait::async_trait;

/// A source of time and of waiting. Shared as `Arc<dyn Clock>` by all devices of a rig.
#[async_trait]
pub trait Clock: Send + Sync + std::fmt::Debug {
    /// Time since the clock's epoch (usually when the rig was built).
    fn now(&self) -> Duration;

    /// Waits for `duration` of this clock's time.
    async fn sleep(&self, duration: Duration);

    /// [`Clock::now`] in seconds.
    fn now_s(&self) -> f64 {
        self.now().as_secs_f64()
    }

    /// Waits for `seconds` of this clock's time; negative or NaN waits nothing.
    async fn sleep_s(&self, seconds: f64) {
        if seconds > 0.0 {
            self.sleep(Duration::from_secs_f64(seconds)).await;
        }
    }
}

/// A clock shared between devices.
pub type SharedClock = Arc<dyn Clock>;

/// tokio's clock: real time normally, virtual time when the runtime is paused.
///
/// Create it inside the runtime that will use it, so that it reads that runtime's (possibly
/// paused) time.
#[derive(Debug, Clone)]
pub struct TokioClock {
    epoch: tokio::time::Instant,
}

impl TokioClock {
    /// A clock whose epoch is now.
    pub fn new() -> Self {
        TokioClock { epoch: tokio::time::Instant::now() }
    }

    /// The same, ready to share.
    pub fn shared() -> SharedClock {
        Arc::new(Self::new())
    }
}

impl Default for TokioClock {
    fn default() -> Self {
        Self::new()
    }
}

#[async_trait]
impl Clock for TokioClock {
    fn now(&self) -> Duration {
        tokio::time::Instant::now().duration_since(self.epoch)
    }

    async fn sleep(&self, duration: Duration) {
        tokio::time::sleep(duration).await;
    }
}

/// Wall-clock time sped up by a constant factor: `speed = 10` makes a 7 s transfer take
/// 0.7 s of real time while `now()` advances by 7 s.
#[derive(Debug, Clone)]
pub struct ScaledClock {
    epoch: tokio::time::Instant,
    speed: f64,
}

impl ScaledClock {
    /// A clock running `speed` times faster than real time. `speed` must be finite and > 0.
    pub fn new(speed: f64) -> Result<Self, crate::DeviceError> {
        if !(speed.is_finite() && speed > 0.0) {
            return Err(crate::DeviceError::out_of_range("clock", "speed", speed, "(0, inf)"));
        }
        Ok(ScaledClock { epoch: tokio::time::Instant::now(), speed })
    }

    /// How many times faster than real time this clock runs.
    pub fn speed(&self) -> f64 {
        self.speed
    }
}

#[async_trait]
impl Clock for ScaledClock {
    fn now(&self) -> Duration {
        tokio::time::Instant::now().duration_since(self.epoch).mul_f64(self.speed)
    }

    async fn sleep(&self, duration: Duration) {
        tokio::time::sleep(duration.div_f64(self.speed)).await;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test(start_paused = true)]
    async fn tokio_clock_runs_virtual_hours_instantly() {
        let wall = std::time::Instant::now();
        let clock = TokioClock::new();
        for _ in 0..100 {
            clock.sleep(Duration::from_secs(3600)).await;
        }
        assert_eq!(clock.now(), Duration::from_secs(360_000));
        // 100 virtual hours; real sleeping would take them all, so a minute's bound cannot
        // be hit by a slow machine, only by a clock that sleeps for real.
        assert!(wall.elapsed() < Duration::from_secs(60));
    }

    #[tokio::test(start_paused = true)]
    async fn scaled_clock_advances_speed_times_faster_than_tokio_time() {
        let clock = ScaledClock::new(10.0).unwrap();
        let tokio_start = tokio::time::Instant::now();
        clock.sleep(Duration::from_secs(7)).await;
        let real = tokio::time::Instant::now() - tokio_start;
        assert_eq!(real, Duration::from_millis(700));
        assert!((clock.now_s() - 7.0).abs() < 1e-9, "{}", clock.now_s());
        assert!(ScaledClock::new(0.0).is_err());
        assert!(ScaledClock::new(f64::NAN).is_err());
    }
}
