//! The timing model of a schedule: moves, captures, transfers and how they overlap. The
//! derivation is in `docs/planner.md`.
//!
//! The model follows the simulated devices (`crates/sim/src/devices/`):
//!
//! * a device move (robot, rail, turntable) takes its slowest axis's trapezoid time plus the
//!   device's settle time, zero if nothing moves; the devices move at the same time;
//! * the camera is one serial resource: an exposure command (only when the exposure changes),
//!   `trigger` (latency + exposure + read-out into its one-frame buffer), `read_frame`
//!   (transfer). Both calls take the camera exclusively, so the next trigger starts only
//!   after the previous transfer has ended;
//! * the devices may move to the next pose as soon as `trigger` returns (the frame is in the
//!   buffer), i.e. during the previous frame's transfer.

use btfrig_core::config::timing::TimingConfig;
use btfrig_core::kinematics::JointState;
use btfrig_core::profile::move_time_s;

use crate::expand::PlanCapture;

/// Where the rig is before the first capture.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Start {
    /// Joint state before the first move; `None`: the first move is not timed (e.g. it
    /// happens during the lamp warm-up).
    pub joints: Option<JointState>,
    /// The camera's exposure setting before the first capture; `None`: unknown, so the first
    /// capture sends an exposure command.
    pub exposure_s: Option<f64>,
}

impl Start {
    /// The rig after homing (every joint at 0), camera exposure unknown.
    pub fn homed() -> Self {
        Start { joints: Some(JointState::default()), exposure_s: None }
    }
}

/// Duration of a move of each device, settle included, seconds.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct MoveTime {
    /// Robot: slowest joint plus settle (0 if no joint moves).
    pub robot_s: f64,
    /// Rail plus settle (0 if it does not move).
    pub rail_s: f64,
    /// Turntable plus settle (0 if it does not move).
    pub turntable_s: f64,
}

impl MoveTime {
    /// The devices move at the same time: the slowest one.
    pub fn total_s(&self) -> f64 {
        self.robot_s.max(self.rail_s).max(self.turntable_s)
    }
}

/// The parts of one capture step taken alone (no overlap with neighbours), seconds.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StepCost {
    /// Move from the previous pose, settle included.
    pub move_s: f64,
    /// Exposure command (0 when the exposure does not change).
    pub command_s: f64,
    /// Trigger latency + exposure + read-out into the camera buffer.
    pub trigger_s: f64,
    /// Transfer of the frame to the host.
    pub transfer_s: f64,
}

impl StepCost {
    /// The step done strictly one operation after the other.
    pub fn sequential_s(&self) -> f64 {
        self.move_s + self.command_s + self.trigger_s + self.transfer_s
    }
}

/// When one step of a schedule happens, seconds from the start of the schedule.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepTiming {
    /// Index of the capture (into the capture list the order refers to).
    pub capture: usize,
    /// Start of the move to this capture's pose (the previous trigger's end).
    pub move_start_s: f64,
    /// End of the move, settled.
    pub move_end_s: f64,
    /// The move's devices.
    pub moves: MoveTime,
    /// Exposure command time charged to this step (0 or `camera.command_s`).
    pub command_s: f64,
    /// Time the camera waited for the motion (after the previous transfer and command).
    pub camera_idle_s: f64,
    /// Trigger sent (pose reached, camera free).
    pub trigger_start_s: f64,
    /// Exposure and read-out done; the devices may move on.
    pub trigger_end_s: f64,
    /// Transfer to the host done.
    pub transfer_end_s: f64,
}

/// The timing of a whole order.
#[derive(Debug, Clone, PartialEq)]
pub struct ScheduleTiming {
    /// Hardware time from the first command to the last frame on the host, seconds.
    pub hardware_s: f64,
    /// One entry per step, in execution order.
    pub per_step: Vec<StepTiming>,
    /// Sum of the move durations (partly hidden under transfers), seconds.
    pub motion_s: f64,
    /// Sum of commands, trigger latencies, exposures and read-outs, seconds.
    pub capture_s: f64,
    /// Sum of transfers, seconds.
    pub transfer_s: f64,
    /// Time the camera waited for motion, seconds.
    /// `hardware_s == capture_s + transfer_s + idle_s` (the camera's timeline).
    pub idle_s: f64,
}

/// Device figures turned into per-axis speeds: the step, schedule and bound computations.
#[derive(Debug, Clone, PartialEq)]
pub struct TimingModel {
    timing: TimingConfig,
}

impl TimingModel {
    /// A model from a rig's `[timing]` section (degrees, as in the file).
    pub fn new(timing: &TimingConfig) -> Self {
        TimingModel { timing: timing.clone() }
    }

    /// The figures this model uses.
    pub fn timing(&self) -> &TimingConfig {
        &self.timing
    }

    /// Time each device needs to move from `a` to `b` (joint values in radians).
    pub fn move_time(&self, a: &JointState, b: &JointState) -> MoveTime {
        let t = &self.timing;
        let axis = |d_rad: f64, v_deg: f64, acc_deg: f64| move_time_s(d_rad.to_degrees(), v_deg, acc_deg);
        let robot = (0..3)
            .map(|j| axis(b.robot[j] - a.robot[j], t.robot.max_speed_deg_per_s[j], t.robot.accel_deg_per_s2[j]))
            .fold(0.0, f64::max);
        let rail = axis(b.rail - a.rail, t.rail.max_speed_deg_per_s, t.rail.accel_deg_per_s2);
        let tt = axis(b.turntable - a.turntable, t.turntable.max_speed_deg_per_s, t.turntable.accel_deg_per_s2);
        // As the simulated devices: settle only when something moved.
        let settled = |m: f64, settle: f64| if m > 0.0 { m + settle } else { 0.0 };
        MoveTime {
            robot_s: settled(robot, t.robot.settle_s),
            rail_s: settled(rail, t.rail.settle_s),
            turntable_s: settled(tt, t.turntable.settle_s),
        }
    }

    /// Move time from an optional start (`None`: not timed, 0).
    pub(crate) fn move_s(&self, a: Option<&JointState>, b: &JointState) -> f64 {
        a.map_or(0.0, |a| self.move_time(a, b).total_s())
    }

    /// Trigger latency + exposure + read-out, seconds.
    pub fn trigger_s(&self, exposure_s: f64) -> f64 {
        let c = &self.timing.camera;
        c.trigger_latency_s + exposure_s + c.read_out_s
    }

    /// Transfer time of a frame of `bytes`, seconds.
    pub fn transfer_s(&self, bytes: u64) -> f64 {
        bytes as f64 / self.timing.camera.transfer_bytes_per_s
    }

    /// Exposure command time charged when the exposure goes from `prev` (`None`: unknown)
    /// to `next`.
    pub fn command_s(&self, prev: Option<f64>, next: f64) -> f64 {
        if prev == Some(next) {
            0.0
        } else {
            self.timing.camera.command_s
        }
    }

    /// One step taken alone: move from `from` (`None`: not timed), exposure command if
    /// the camera's exposure `prev_exposure_s` differs, capture and transfer of `to`.
    pub fn step_time(&self, from: Option<&JointState>, prev_exposure_s: Option<f64>, to: &PlanCapture) -> StepCost {
        StepCost {
            move_s: self.move_s(from, &to.joints),
            command_s: self.command_s(prev_exposure_s, to.exposure_s),
            trigger_s: self.trigger_s(to.exposure_s),
            transfer_s: self.transfer_s(to.frame_bytes),
        }
    }

    /// Simulates the pipeline for `order` (indices into `captures`), exactly as the module
    /// documentation describes. Panics if an index is out of range.
    pub fn schedule_time(&self, captures: &[PlanCapture], order: &[usize], start: &Start) -> ScheduleTiming {
        let mut pose = start.joints;
        let mut exposure = start.exposure_s;
        let (mut trigger_end, mut transfer_end) = (0.0f64, 0.0f64);
        let mut out = ScheduleTiming {
            hardware_s: 0.0,
            per_step: Vec::with_capacity(order.len()),
            motion_s: 0.0,
            capture_s: 0.0,
            transfer_s: 0.0,
            idle_s: 0.0,
        };
        for &i in order {
            let c = &captures[i];
            let moves = pose.map_or(MoveTime::default(), |p| self.move_time(&p, &c.joints));
            let move_start = trigger_end;
            let move_end = move_start + moves.total_s();
            let command = self.command_s(exposure, c.exposure_s);
            // The command runs on the camera after the previous transfer, during the move.
            let camera_ready = transfer_end + command;
            let trigger_start = move_end.max(camera_ready);
            let trig = self.trigger_s(c.exposure_s);
            let xfer = self.transfer_s(c.frame_bytes);
            trigger_end = trigger_start + trig;
            transfer_end = trigger_end + xfer;
            let idle = trigger_start - camera_ready;
            out.per_step.push(StepTiming {
                capture: i,
                move_start_s: move_start,
                move_end_s: move_end,
                moves,
                command_s: command,
                camera_idle_s: idle,
                trigger_start_s: trigger_start,
                trigger_end_s: trigger_end,
                transfer_end_s: transfer_end,
            });
            out.motion_s += moves.total_s();
            out.capture_s += command + trig;
            out.transfer_s += xfer;
            out.idle_s += idle;
            pose = Some(c.joints);
            exposure = Some(c.exposure_s);
        }
        out.hardware_s = transfer_end;
        out
    }

    /// Exact time between the end of the trigger of `a` and the start of the trigger of the
    /// next capture `b`: the move runs alongside `a`'s transfer and `b`'s exposure command.
    pub(crate) fn gap_s(&self, a: &PlanCapture, b: &PlanCapture) -> f64 {
        let m = self.move_time(&a.joints, &b.joints).total_s();
        m.max(self.transfer_s(a.frame_bytes) + self.command_s(Some(a.exposure_s), b.exposure_s))
    }

    /// Time before the first trigger when the schedule starts with `b`.
    pub(crate) fn first_gap_s(&self, start: &Start, b: &PlanCapture) -> f64 {
        self.move_s(start.joints.as_ref(), &b.joints).max(self.command_s(start.exposure_s, b.exposure_s))
    }

    /// A lower bound on `schedule_time(captures, order, start).hardware_s` over every order
    /// of `captures` (derivation in `docs/planner.md`): the camera is busy with every
    /// trigger and transfer, with at least one exposure command per exposure value it does
    /// not already have, and waits at least for the shortest first move.
    pub fn critical_path_s(&self, captures: &[PlanCapture], start: &Start) -> f64 {
        if captures.is_empty() {
            return 0.0;
        }
        let busy: f64 = captures.iter().map(|c| self.trigger_s(c.exposure_s) + self.transfer_s(c.frame_bytes)).sum();
        let mut values: Vec<f64> = captures.iter().map(|c| c.exposure_s).collect();
        values.sort_by(f64::total_cmp);
        values.dedup();
        let initial_known = start.exposure_s.is_some_and(|e| values.contains(&e));
        let commands_needed = values.len() - usize::from(initial_known);
        // The first trigger waits for the first move and, if the first capture's exposure
        // cannot be the initial one, for a command; later commands are at least the rest.
        let first_command = if initial_known { 0.0 } else { self.timing.camera.command_s };
        let first_move =
            captures.iter().map(|c| self.move_s(start.joints.as_ref(), &c.joints)).fold(f64::INFINITY, f64::min);
        first_move.max(first_command) + busy + commands_needed.saturating_sub(1) as f64 * self.timing.camera.command_s
    }
}
