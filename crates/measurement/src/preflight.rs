//! Preflight: every device a run or a calibration needs is asked, before anything is created,
//! who it is, how it feels and whether it is homed.
//!
//! [`check_devices`] takes the rig config and the [`Role`]s the caller needs. A role the rig
//! does not have is an error naming it. The others go to the rig's backend
//! ([`RigBackend::preflight`](crate::backend::RigBackend::preflight)), which asks each real
//! device whatever its protocol offers (identity, health, homing state) without moving it;
//! simulated devices, and emulated firmware that only exists once the rig is opened, need no
//! questions. [`Preflight::into_result`] turns failed devices into one error naming each
//! device, its port and what failed. `btfrig run` (gonioreflectometer and dome), and the
//! calibration commands, call it before they create a dataset or a calibration file.

use btfrig_core::config::RigConfig;
use btfrig_hw::DeviceInfo;
use serde_json::json;

use crate::backend::BackendRegistry;
use crate::RunError;

/// A device of a rig, as its `[devices.ROLE]` table names it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Role {
    /// `[devices.robot]`: the robot holding the sample.
    Robot,
    /// `[devices.rail]`: the camera's rail.
    Rail,
    /// `[devices.turntable]`.
    Turntable,
    /// `[devices.lamp]`.
    Lamp,
    /// `[devices.led_array]`: a dome's LEDs (a camera array's flash triggers).
    LedArray,
    /// `[devices.camera]`.
    Camera,
}

impl Role {
    /// What a gonioreflectometer run needs.
    pub const GONIO: &'static [Role] = &[Role::Robot, Role::Rail, Role::Lamp, Role::Camera];
    /// What a dome or camera-array run needs (the turntable where the rig has one).
    pub const DOME: &'static [Role] = &[Role::LedArray, Role::Camera];

    /// Its name in the rig config (`robot`, `led_array`, ...).
    pub const fn name(self) -> &'static str {
        match self {
            Role::Robot => "robot",
            Role::Rail => "rail",
            Role::Turntable => "turntable",
            Role::Lamp => "lamp",
            Role::LedArray => "led_array",
            Role::Camera => "camera",
        }
    }

    /// The role of a rig-config name.
    pub fn from_name(name: &str) -> Option<Role> {
        [Role::Robot, Role::Rail, Role::Turntable, Role::Lamp, Role::LedArray, Role::Camera]
            .into_iter()
            .find(|r| r.name() == name)
    }
}

/// What preflight found out about one device.
#[derive(Debug, Clone, PartialEq)]
pub struct DeviceCheck {
    /// Its role (`robot`, ...).
    pub role: &'static str,
    /// `[devices.ROLE] kind`.
    pub kind: String,
    /// What it is reached through (a real controller's port at its baud rate); `None`
    /// in-process.
    pub port: Option<String>,
    /// The identity it reported; `None` where it was not asked or could not answer.
    pub identity: Option<DeviceInfo>,
    /// Its health as it reported it (`Ok`, `Warning(..)`, `Fault(..)`); `None` if not asked.
    pub health: Option<String>,
    /// Whether it is homed, for devices that home and say so; `None` otherwise.
    pub homed: Option<bool>,
    /// Why it cannot be used; `None`: it passed.
    pub failure: Option<String>,
    /// What else the operator should know (why no questions were asked, a warning).
    pub note: Option<String>,
}

impl DeviceCheck {
    /// A device that needs no questions (`note` says why).
    pub fn unasked(role: &'static str, kind: &str, note: impl Into<String>) -> DeviceCheck {
        DeviceCheck {
            role,
            kind: kind.to_string(),
            port: None,
            identity: None,
            health: None,
            homed: None,
            failure: None,
            note: Some(note.into()),
        }
    }

    /// `devices.ROLE (PORT)`: how messages name it.
    pub fn label(&self) -> String {
        match &self.port {
            Some(p) => format!("devices.{} on {p}", self.role),
            None => format!("devices.{}", self.role),
        }
    }

    /// As a JSON object (the run report's `preflight` entries).
    pub fn to_json(&self) -> serde_json::Value {
        json!({
            "role": self.role,
            "kind": self.kind,
            "port": self.port,
            "identity": self.identity.as_ref().map(identity_json),
            "health": self.health,
            "homed": self.homed,
            "failure": self.failure,
            "note": self.note,
        })
    }
}

/// A device's identity as JSON (`name`, `backend`, `model`, `serial`, `firmware`).
pub fn identity_json(i: &DeviceInfo) -> serde_json::Value {
    json!({"name": i.name, "backend": i.backend, "model": i.model, "serial": i.serial, "firmware": i.firmware})
}

/// Every checked device of a rig.
#[derive(Debug, Clone, PartialEq)]
pub struct Preflight {
    /// The rig config's name.
    pub rig: String,
    /// The devices, in the rig config's order.
    pub devices: Vec<DeviceCheck>,
}

impl Preflight {
    /// The devices that failed.
    pub fn failed(&self) -> Vec<&DeviceCheck> {
        self.devices.iter().filter(|d| d.failure.is_some()).collect()
    }

    /// Itself if every device passed; otherwise an error naming each failed device, its
    /// port and what failed.
    pub fn into_result(self) -> Result<Preflight, RunError> {
        let failed: Vec<String> = self
            .failed()
            .iter()
            .map(|d| format!("{}: {}", d.label(), d.failure.as_deref().unwrap_or_default()))
            .collect();
        if failed.is_empty() {
            return Ok(self);
        }
        Err(RunError::Preflight { rig: self.rig, failures: failed })
    }
}

/// Checks the devices `roles` of `rig` through the backend that opens it: a role the rig does
/// not have is an error naming each missing one; the others are asked what their protocol
/// offers (see the module documentation). Failed devices are in the result, not an error:
/// [`Preflight::into_result`] makes them one. Builds its own runtime on a thread of its own
/// where it asks real devices: call it from anywhere.
pub fn check_devices(rig: &RigConfig, roles: &[Role], backends: &BackendRegistry) -> Result<Preflight, RunError> {
    let present: Vec<&str> = rig.devices.entries().into_iter().map(|(r, _)| r).collect();
    let missing: Vec<String> =
        roles.iter().filter(|r| !present.contains(&r.name())).map(|r| format!("[devices.{}]", r.name())).collect();
    if !missing.is_empty() {
        return Err(RunError::Rig(format!(
            "rig {:?} has no {}: this needs {} (its devices: {})",
            rig.rig.name,
            missing.join(", "),
            roles.iter().map(|r| r.name()).collect::<Vec<_>>().join(", "),
            present.join(", ")
        )));
    }
    let backend = backends.for_rig(rig)?;
    let devices = backend.preflight(rig, roles);
    Ok(Preflight { rig: rig.rig.name.clone(), devices })
}

/// The roles of a gonioreflectometer run or a dome run of `rig` (a dome's turntable where it
/// has one).
pub fn run_roles(rig: &RigConfig) -> Vec<Role> {
    if rig.dome.is_some() {
        let mut r = Role::DOME.to_vec();
        if rig.devices.turntable.is_some() {
            r.insert(0, Role::Turntable);
        }
        r
    } else {
        Role::GONIO.to_vec()
    }
}

/// The opened devices' identities by role, as the run report's `devices` array.
pub fn identities_json(identities: &[(&'static str, DeviceInfo)]) -> serde_json::Value {
    identities
        .iter()
        .map(|(role, info)| {
            let mut v = identity_json(info);
            v["role"] = json!(role);
            v
        })
        .collect()
}
