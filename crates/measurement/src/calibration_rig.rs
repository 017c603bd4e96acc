//! A gonioreflectometer opened for a calibration: the devices a procedure needs, checked by
//! role before anything moves, homed, the lamp lit; and the moves and captures procedures
//! share. Every device is reached through the backend registry and the `btfrig-hw` traits,
//! so a procedure runs the same on a simulated, emulated or real rig.

use std::sync::Arc;

use btfrig_core::config::RigConfig;
use btfrig_core::frame::RawFrame;
use btfrig_core::kinematics::JointState;
use btfrig_hw::truth::TruthProbe;
use btfrig_hw::{Camera, Device, Health, Lamp, MoveOptions, Rail, Robot};

use crate::backend::{self, BackendRegistry, CalibrationOpenRequest, MountedTarget, OpenedRig, RigTime};
use crate::RunError;

pub use crate::preflight::Role;

/// Where the rig config says a device is connected: its `port` (or its link's), else its
/// kind (an in-process device has no port).
pub fn device_location(rig: &RigConfig, role: &str) -> String {
    let Some((_, e)) = rig.devices.entries().into_iter().find(|(r, _)| *r == role) else {
        return "not in the rig config".into();
    };
    let port = e.options.get("port").or_else(|| e.options.get("link").and_then(|l| l.get("port")));
    match port.and_then(|p| p.as_str()) {
        Some(p) => format!("kind {:?}, port {p}", e.kind),
        None => format!("kind {:?}", e.kind),
    }
}

/// A gonioreflectometer with a calibration target mounted, its devices checked and ready.
pub struct CalibrationRig {
    /// The robot.
    pub robot: Box<dyn Robot>,
    /// The rail.
    pub rail: Box<dyn Rail>,
    /// The lamp (on and warm).
    pub lamp: Box<dyn Lamp>,
    /// The camera.
    pub camera: Box<dyn Camera>,
    /// The truth behind the frames, for error figures only (simulated backends).
    pub truth: Option<Arc<dyn TruthProbe>>,
    /// Keeps firmware emulators alive (dropped last).
    _links: Box<dyn backend::LinkReport>,
    rig_name: String,
    locations: Vec<(Role, String)>,
}

impl CalibrationRig {
    /// Opens `rig` through `backends` (the installed registry when `None`) with `target`
    /// mounted, checks that each device of `needs` answers and is healthy (an error names its
    /// role and port), homes robot and rail and, if the lamp is needed, lights it and waits
    /// for it to warm up. Call inside the runtime the devices run on.
    pub async fn open(
        rig: &RigConfig,
        backends: Option<&BackendRegistry>,
        target: &MountedTarget,
        needs: &[Role],
        seed: u64,
        time: RigTime,
    ) -> Result<CalibrationRig, RunError> {
        let registry = backends.cloned().unwrap_or_else(backend::installed);
        crate::preflight::check_devices(rig, needs, &registry)?.into_result()?;
        let backend = registry.for_rig(rig)?;
        let opened = backend.open_calibration(CalibrationOpenRequest { rig, target, cameras: &[], seed, time }).await?;
        let OpenedRig::Gonio(g) = opened else {
            return Err(RunError::Rig(format!(
                "{} opened rig {} as a dome: this calibration needs a gonioreflectometer",
                backend.name(),
                rig.rig.name
            )));
        };
        let locations = needs.iter().map(|r| (*r, device_location(rig, r.name()))).collect();
        let mut c = CalibrationRig {
            robot: g.robot,
            rail: g.rail,
            lamp: g.lamp,
            camera: g.camera,
            truth: g.truth,
            _links: g.links,
            rig_name: rig.rig.name.clone(),
            locations,
        };
        c.check(needs).await?;
        let opts = MoveOptions::default();
        let (r, t) = tokio::join!(c.robot.home(opts), c.rail.home(opts));
        r.map_err(|e| c.device_error(Role::Robot, format!("homing: {e}")))?;
        t.map_err(|e| c.device_error(Role::Rail, format!("homing: {e}")))?;
        if needs.contains(&Role::Lamp) {
            c.lamp.set_on(true).await.map_err(|e| c.device_error(Role::Lamp, format!("switching on: {e}")))?;
            let warm_up = c.lamp.capabilities().warm_up_s;
            c.lamp
                .wait_ready(warm_up + 60.0)
                .await
                .map_err(|e| c.device_error(Role::Lamp, format!("warming up: {e}")))?;
        }
        Ok(c)
    }

    /// An error naming the device by role, rig config name and port.
    pub fn device_error(&self, role: Role, message: String) -> RunError {
        let at = self.locations.iter().find(|(r, _)| *r == role).map_or("?", |(_, l)| l.as_str());
        RunError::Rig(format!("rig {}: device {} ({at}): {message}", self.rig_name, role.name()))
    }

    /// Each needed device's health; a failing or faulty one is an error naming it.
    async fn check(&mut self, needs: &[Role]) -> Result<(), RunError> {
        for &role in needs {
            let dev: &mut dyn Device = match role {
                Role::Robot => self.robot.as_mut(),
                Role::Rail => self.rail.as_mut(),
                Role::Lamp => self.lamp.as_mut(),
                Role::Camera => self.camera.as_mut(),
                Role::Turntable | Role::LedArray => continue,
            };
            match dev.health().await {
                Ok(Health::Ok) | Ok(Health::Warning(_)) => {}
                Ok(Health::Fault(f)) => return Err(self.device_error(role, format!("reports a fault: {f}"))),
                Err(e) => return Err(self.device_error(role, format!("does not answer: {e}"))),
            }
        }
        Ok(())
    }

    /// The devices as `role: name (model)`, for the procedure's first line.
    pub fn describe(&self) -> String {
        let mut parts = Vec::new();
        for (role, loc) in &self.locations {
            let info = match role {
                Role::Robot => self.robot.info(),
                Role::Rail => self.rail.info(),
                Role::Lamp => self.lamp.info(),
                Role::Camera => self.camera.info(),
                Role::Turntable | Role::LedArray => continue,
            };
            parts.push(format!("{} {} ({}, {loc})", role.name(), info.name, info.model));
        }
        parts.join("; ")
    }

    /// Moves robot and rail together to `joints` (the turntable stays where it is).
    pub async fn move_to(&mut self, joints: &JointState) -> Result<(), RunError> {
        let opts = MoveOptions::default();
        let (r, t) = tokio::join!(self.robot.move_to_rad(joints.robot, opts), self.rail.move_to_rad(joints.rail, opts));
        r.map_err(|e| self.device_error(Role::Robot, format!("moving: {e}")))?;
        t.map_err(|e| self.device_error(Role::Rail, format!("moving: {e}")))?;
        Ok(())
    }

    /// One frame at `exposure_s`, gain 1.
    pub async fn capture(&mut self, exposure_s: f64) -> Result<RawFrame, RunError> {
        let (lo, hi) = self.camera.capabilities().exposure_range_s;
        let exposure_s = exposure_s.clamp(lo, hi);
        self.camera.set_gain(1.0).await.map_err(|e| self.device_error(Role::Camera, format!("setting gain: {e}")))?;
        self.camera
            .set_exposure_s(exposure_s)
            .await
            .map_err(|e| self.device_error(Role::Camera, format!("setting exposure: {e}")))?;
        self.camera
            .capture(exposure_s + 60.0)
            .await
            .map_err(|e| self.device_error(Role::Camera, format!("capturing: {e}")))
    }

    /// The camera's exposure range, seconds.
    pub fn exposure_range_s(&self) -> (f64, f64) {
        self.camera.capabilities().exposure_range_s
    }

    /// Switches the lamp off (end of a procedure; errors ignored: nothing depends on it).
    pub async fn finish(mut self) {
        let _ = self.lamp.set_on(false).await;
    }
}

/// The fraction of full scale (above black) that `quantile` of a frame's photosites stay
/// below: the metering figure of an exposure.
pub fn level_quantile(frame: &RawFrame, quantile: f64) -> f64 {
    let black = f64::from(frame.meta.black_level);
    let range = (f64::from(frame.meta.white_level) - black).max(1.0);
    let mut v: Vec<u16> = frame.data.iter().step_by(7).copied().collect();
    if v.is_empty() {
        return 0.0;
    }
    let k = ((v.len() - 1) as f64 * quantile.clamp(0.0, 1.0)) as usize;
    let (_, x, _) = v.select_nth_unstable(k);
    ((f64::from(*x) - black) / range).max(0.0)
}

/// Runs `f` on a runtime of `time`: paused virtual time for a simulated rig, the wall clock
/// for real devices.
pub fn block_on<T>(time: RigTime, f: impl std::future::Future<Output = T>) -> Result<T, RunError> {
    Ok(time.runtime()?.block_on(f))
}
