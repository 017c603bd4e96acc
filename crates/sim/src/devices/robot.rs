//! The simulated sample robot.

use async_trait::async_trait;
use btfrig_core::config::timing::RobotTiming;
use btfrig_hw::{AxisLimits, DeviceError, DeviceInfo, MoveOptions, Robot};

use super::motion::{AxisModel, Motion};
use crate::faults::{FaultGate, COMMAND_TIMEOUT_S};
use crate::options::SimRobotOptions;
use crate::SimWorld;

/// A simulated three-joint robot: trapezoidal moves, settle time, positioning error.
/// It reports the commanded joints; the world holds where they truly are.
#[derive(Debug)]
pub struct SimRobot {
    info: DeviceInfo,
    gate: FaultGate,
    motion: Motion<3>,
    world: SimWorld,
}

impl SimRobot {
    pub(crate) fn new(
        opts: &SimRobotOptions,
        timing: &RobotTiming,
        gate: FaultGate,
        world: SimWorld,
        seed: u64,
    ) -> Self {
        let axes = std::array::from_fn(|j| AxisModel {
            limits: AxisLimits {
                min_rad: opts.joint_min_deg[j].to_radians(),
                max_rad: opts.joint_max_deg[j].to_radians(),
                max_speed_rad_per_s: timing.max_speed_deg_per_s[j].to_radians(),
            },
            accel_rad_per_s2: timing.accel_deg_per_s2[j].to_radians(),
            offset_rad: opts.offset_deg[j].to_radians(),
            jitter_rad: opts.jitter_deg[j].to_radians(),
        });
        let name = gate.name().to_string();
        let motion =
            Motion::new(&name, axes, timing.settle_s, timing.home_s, opts.homed_at_start, seed, world.clock().clone());
        SimRobot { info: super::info(&name, &opts.model), gate, motion, world }
    }

    /// Time a move from the current commanded position to `joints_rad` would take,
    /// settle included, seconds.
    pub fn move_duration_s(&self, joints_rad: [f64; 3]) -> f64 {
        self.motion.duration_s(&joints_rad)
    }
}

impl_sim_device!(SimRobot);

#[async_trait]
impl Robot for SimRobot {
    fn joint_limits(&self) -> [AxisLimits; 3] {
        self.motion.limits()
    }

    async fn home(&mut self, opts: MoveOptions) -> Result<(), DeviceError> {
        self.gate.begin("home", opts.timeout_s).await?;
        let world = &self.world;
        self.motion
            .home(opts.timeout_s, |truth, cmd| {
                let mut w = world.lock();
                w.true_joints.robot = truth;
                w.commanded.robot = cmd;
            })
            .await
    }

    async fn move_to_rad(&mut self, joints_rad: [f64; 3], opts: MoveOptions) -> Result<[f64; 3], DeviceError> {
        self.gate.begin("move_to_rad", opts.timeout_s).await?;
        let world = &self.world;
        self.motion
            .move_to("move_to_rad", joints_rad, opts.timeout_s, |truth, cmd| {
                let mut w = world.lock();
                w.true_joints.robot = truth;
                w.commanded.robot = cmd;
            })
            .await
    }

    async fn position_rad(&mut self) -> Result<[f64; 3], DeviceError> {
        self.gate.begin("position_rad", COMMAND_TIMEOUT_S).await?;
        self.motion.position("position_rad")
    }
}
