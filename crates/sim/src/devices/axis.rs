//! A simulated single rotary axis: the camera rail or the turntable.

use async_trait::async_trait;
use btfrig_core::config::timing::AxisTiming;
use btfrig_hw::{AxisLimits, DeviceError, DeviceInfo, MoveOptions, Rail, Turntable};

use super::motion::{AxisModel, Motion};
use crate::faults::{DeviceRole, FaultGate, COMMAND_TIMEOUT_S};
use crate::options::SimAxisOptions;
use crate::world::WorldState;
use crate::SimWorld;

/// A simulated rail or turntable (which one is fixed at construction and decides which
/// joint of the world it moves). Use it as `Box<dyn Rail>` or `Box<dyn Turntable>`.
#[derive(Debug)]
pub struct SimAxis {
    info: DeviceInfo,
    gate: FaultGate,
    motion: Motion<1>,
    world: SimWorld,
    role: DeviceRole,
}

fn write(role: DeviceRole, w: &mut WorldState, truth: f64, cmd: f64) {
    if role == DeviceRole::Turntable {
        w.true_joints.turntable = truth;
        w.commanded.turntable = cmd;
    } else {
        w.true_joints.rail = truth;
        w.commanded.rail = cmd;
    }
}

impl SimAxis {
    pub(crate) fn new(
        role: DeviceRole,
        opts: &SimAxisOptions,
        timing: &AxisTiming,
        gate: FaultGate,
        world: SimWorld,
        seed: u64,
    ) -> Self {
        let axis = AxisModel {
            limits: AxisLimits {
                min_rad: opts.min_deg.to_radians(),
                max_rad: opts.max_deg.to_radians(),
                max_speed_rad_per_s: timing.max_speed_deg_per_s.to_radians(),
            },
            accel_rad_per_s2: timing.accel_deg_per_s2.to_radians(),
            offset_rad: opts.offset_deg.to_radians(),
            jitter_rad: opts.jitter_deg.to_radians(),
        };
        let name = gate.name().to_string();
        let motion = Motion::new(
            &name,
            [axis],
            timing.settle_s,
            timing.home_s,
            opts.homed_at_start,
            seed,
            world.clock().clone(),
        );
        SimAxis { info: super::info(&name, &opts.model), gate, motion, world, role }
    }

    /// Time a move from the commanded position to `angle_rad` would take, seconds.
    pub fn move_duration_s(&self, angle_rad: f64) -> f64 {
        self.motion.duration_s(&[angle_rad])
    }

    async fn do_home(&mut self, opts: MoveOptions) -> Result<(), DeviceError> {
        self.gate.begin("home", opts.timeout_s).await?;
        let (world, role) = (&self.world, self.role);
        self.motion.home(opts.timeout_s, |t, c| write(role, &mut world.lock(), t[0], c[0])).await
    }

    async fn do_move(&mut self, angle_rad: f64, opts: MoveOptions) -> Result<f64, DeviceError> {
        self.gate.begin("move_to_rad", opts.timeout_s).await?;
        let (world, role) = (&self.world, self.role);
        let r = self
            .motion
            .move_to("move_to_rad", [angle_rad], opts.timeout_s, |t, c| write(role, &mut world.lock(), t[0], c[0]))
            .await?;
        Ok(r[0])
    }

    async fn do_position(&mut self) -> Result<f64, DeviceError> {
        self.gate.begin("position_rad", COMMAND_TIMEOUT_S).await?;
        Ok(self.motion.position("position_rad")?[0])
    }
}

impl_sim_device!(SimAxis);

#[async_trait]
impl Rail for SimAxis {
    fn limits(&self) -> AxisLimits {
        self.motion.limits()[0]
    }

    async fn home(&mut self, opts: MoveOptions) -> Result<(), DeviceError> {
        self.do_home(opts).await
    }

    async fn move_to_rad(&mut self, angle_rad: f64, opts: MoveOptions) -> Result<f64, DeviceError> {
        self.do_move(angle_rad, opts).await
    }

    async fn position_rad(&mut self) -> Result<f64, DeviceError> {
        self.do_position().await
    }
}

#[async_trait]
impl Turntable for SimAxis {
    fn limits(&self) -> AxisLimits {
        self.motion.limits()[0]
    }

    async fn home(&mut self, opts: MoveOptions) -> Result<(), DeviceError> {
        self.do_home(opts).await
    }

    async fn move_to_rad(&mut self, angle_rad: f64, opts: MoveOptions) -> Result<f64, DeviceError> {
        self.do_move(angle_rad, opts).await
    }

    async fn position_rad(&mut self) -> Result<f64, DeviceError> {
        self.do_position().await
    }
}
