//! Building a simulated rig from its config: the factory list keyed by `kind` and
//! [`SimRig`], which owns one device of each role and the shared [`SimWorld`].

use std::sync::Arc;

use btfrig_core::config::devices::{DeviceEntry, DevicesConfig};
use btfrig_core::config::timing::TimingConfig;
use btfrig_core::config::RigConfig;
use btfrig_core::ConfigError;
use btfrig_hw::{Camera, Lamp, LedArray, Rail, Robot, SharedClock, Turntable};

use crate::devices::{SimAxis, SimCamera, SimLamp, SimLedArray, SimRobot};
use crate::faults::{derive_seed, DeviceRole, FaultGate, FaultScenario, FrameFaults, StuckState};
use crate::options::{parse_over, SimAxisOptions, SimCameraOptions, SimLampOptions, SimLedOptions, SimRobotOptions};
use crate::{FrameSource, SimWorld};

/// What a factory needs besides the device's own options.
pub struct BuildContext<'a> {
    /// The world the device will act on.
    pub world: &'a SimWorld,
    /// The `[timing]` section.
    pub timing: &'a TimingConfig,
    /// The fault scenario.
    pub faults: &'a FaultScenario,
    /// The rig seed.
    pub seed: u64,
    /// Where camera pixels come from.
    pub frames: &'a Arc<dyn FrameSource>,
}

/// Builds one device from its options table; errors name `devices.<role>.<key>`.
pub type Build<T> = fn(&BuildContext<'_>, &toml::Table) -> Result<T, ConfigError>;

/// The constructors of one backend kind, one per device role.
pub struct DeviceFactory {
    /// The `kind = "..."` value that selects this backend.
    pub kind: &'static str,
    /// Builds the robot.
    pub robot: Build<Box<dyn Robot>>,
    /// Builds the rail.
    pub rail: Build<Box<dyn Rail>>,
    /// Builds the turntable.
    pub turntable: Build<Box<dyn Turntable>>,
    /// Builds the lamp.
    pub lamp: Build<Box<dyn Lamp>>,
    /// Builds the LED array.
    pub led_array: Build<Box<dyn LedArray>>,
    /// Builds the camera.
    pub camera: Build<Box<dyn Camera>>,
}

/// Every backend this crate can build, keyed by kind. Real backends register in the
/// daemon's list next to this one.
pub static FACTORIES: &[DeviceFactory] = &[DeviceFactory {
    kind: "sim",
    robot: build_robot,
    rail: build_rail,
    turntable: build_turntable,
    lamp: build_lamp,
    led_array: build_led_array,
    camera: build_camera,
}];

/// The factory for `entry.kind`, or an error naming `field` and the known kinds.
pub fn factory_for(entry: &DeviceEntry, field: &str) -> Result<&'static DeviceFactory, ConfigError> {
    FACTORIES.iter().find(|f| f.kind == entry.kind).ok_or_else(|| ConfigError::Unknown {
        field: field.to_string(),
        value: entry.kind.clone(),
        allowed: FACTORIES.iter().map(|f| format!("{:?}", f.kind)).collect::<Vec<_>>().join(", "),
    })
}

fn gate(cx: &BuildContext<'_>, role: DeviceRole) -> FaultGate {
    FaultGate::new(role, cx.faults, cx.seed, cx.world.clone())
}

fn checked<T>(value: T, field: &str, validate: impl Fn(&T, &str, &mut Vec<ConfigError>)) -> Result<T, ConfigError> {
    let mut errors = Vec::new();
    validate(&value, field, &mut errors);
    ConfigError::from_list(errors).map(|()| value)
}

/// Checks the options of every simulated device of `devices` (and the simulated device behind
/// each emulated one, [`DeviceEntry::simulated`]) as building them would, without building
/// anything: so that `btfrig plan check` refuses a NaN `jitter_deg` or an inverted
/// `exposure_range_s` before a run creates its dataset. Real devices are their backends'
/// business. All problems at once.
pub fn check_sim_options(devices: &DevicesConfig) -> Result<(), ConfigError> {
    let mut errors = Vec::new();
    devices.validate(&mut errors);
    let mut check = |entry: Option<&DeviceEntry>, role: DeviceRole| {
        let Some(sim) = entry.and_then(DeviceEntry::simulated) else { return };
        let f = format!("devices.{}", role.as_str());
        let o = &sim.options;
        let r = match role {
            DeviceRole::Robot => parse_over(SimRobotOptions::default(), o, &f).map(|v| v.validate(&f, &mut errors)),
            DeviceRole::Rail => parse_over(SimAxisOptions::rail(), o, &f).map(|v| v.validate(&f, &mut errors)),
            DeviceRole::Turntable => {
                parse_over(SimAxisOptions::turntable(), o, &f).map(|v| v.validate(&f, &mut errors))
            }
            DeviceRole::Lamp => parse_over(SimLampOptions::default(), o, &f).map(|v| v.validate(&f, &mut errors)),
            DeviceRole::LedArray => parse_over(SimLedOptions::default(), o, &f).map(|v| v.validate(&f, &mut errors)),
            DeviceRole::Camera => parse_over(SimCameraOptions::default(), o, &f).map(|v| v.validate(&f, &mut errors)),
        };
        if let Err(e) = r {
            errors.push(e);
        }
    };
    check(Some(&devices.robot), DeviceRole::Robot);
    check(Some(&devices.rail), DeviceRole::Rail);
    check(devices.turntable.as_ref(), DeviceRole::Turntable);
    check(Some(&devices.lamp), DeviceRole::Lamp);
    check(devices.led_array.as_ref(), DeviceRole::LedArray);
    check(Some(&devices.camera), DeviceRole::Camera);
    let errors = errors
        .into_iter()
        .flat_map(|e| match e {
            ConfigError::Many(list) => list,
            e => vec![e],
        })
        .collect();
    ConfigError::from_list(errors)
}

fn build_robot(cx: &BuildContext<'_>, options: &toml::Table) -> Result<Box<dyn Robot>, ConfigError> {
    let f = "devices.robot";
    let o = checked(parse_over(SimRobotOptions::default(), options, f)?, f, SimRobotOptions::validate)?;
    let seed = derive_seed(cx.seed, "robot", 3);
    Ok(Box::new(SimRobot::new(&o, &cx.timing.robot, gate(cx, DeviceRole::Robot), cx.world.clone(), seed)))
}

fn build_axis(cx: &BuildContext<'_>, options: &toml::Table, role: DeviceRole) -> Result<SimAxis, ConfigError> {
    let (f, defaults, timing) = match role {
        DeviceRole::Turntable => ("devices.turntable", SimAxisOptions::turntable(), &cx.timing.turntable),
        _ => ("devices.rail", SimAxisOptions::rail(), &cx.timing.rail),
    };
    let o = checked(parse_over(defaults, options, f)?, f, SimAxisOptions::validate)?;
    let seed = derive_seed(cx.seed, role.as_str(), 3);
    Ok(SimAxis::new(role, &o, timing, gate(cx, role), cx.world.clone(), seed))
}

fn build_rail(cx: &BuildContext<'_>, options: &toml::Table) -> Result<Box<dyn Rail>, ConfigError> {
    Ok(Box::new(build_axis(cx, options, DeviceRole::Rail)?))
}

fn build_turntable(cx: &BuildContext<'_>, options: &toml::Table) -> Result<Box<dyn Turntable>, ConfigError> {
    Ok(Box::new(build_axis(cx, options, DeviceRole::Turntable)?))
}

fn build_lamp(cx: &BuildContext<'_>, options: &toml::Table) -> Result<Box<dyn Lamp>, ConfigError> {
    let f = "devices.lamp";
    let o = checked(parse_over(SimLampOptions::default(), options, f)?, f, SimLampOptions::validate)?;
    Ok(Box::new(SimLamp::new(&o, &cx.timing.lamp, gate(cx, DeviceRole::Lamp), cx.world.clone())))
}

fn build_led_array(cx: &BuildContext<'_>, options: &toml::Table) -> Result<Box<dyn LedArray>, ConfigError> {
    let f = "devices.led_array";
    let o = checked(parse_over(SimLedOptions::default(), options, f)?, f, SimLedOptions::validate)?;
    {
        let mut w = cx.world.lock();
        w.led_commanded = vec![0.0; o.count];
        w.led_stuck = vec![None; o.count];
        for s in cx.faults.stuck_leds.iter().filter(|s| s.index < o.count) {
            w.led_stuck[s.index] = Some(if s.state == StuckState::On { 1.0 } else { 0.0 });
        }
    }
    Ok(Box::new(SimLedArray::new(&o, &cx.timing.leds, gate(cx, DeviceRole::LedArray), cx.world.clone())))
}

fn build_camera(cx: &BuildContext<'_>, options: &toml::Table) -> Result<Box<dyn Camera>, ConfigError> {
    let f = "devices.camera";
    let o = checked(parse_over(SimCameraOptions::default(), options, f)?, f, SimCameraOptions::validate)?;
    Ok(Box::new(SimCamera::new(
        &o,
        &cx.timing.camera,
        gate(cx, DeviceRole::Camera),
        cx.world.clone(),
        cx.frames.clone(),
        FrameFaults::new(cx.faults, cx.seed),
        cx.seed,
    )))
}

/// A simulated rig: one device per role, all acting on one [`SimWorld`].
///
/// The fields are public so the run engine can take the devices apart (each is used only
/// through its trait); keep `world` to read the truth.
pub struct SimRig {
    /// The shared world: true and commanded state, fault log.
    pub world: SimWorld,
    /// The robot.
    pub robot: Box<dyn Robot>,
    /// The camera rail.
    pub rail: Box<dyn Rail>,
    /// The turntable, if configured.
    pub turntable: Option<Box<dyn Turntable>>,
    /// The lamp.
    pub lamp: Box<dyn Lamp>,
    /// The LED array, if configured.
    pub led_array: Option<Box<dyn LedArray>>,
    /// The camera.
    pub camera: Box<dyn Camera>,
}

impl SimRig {
    /// Builds every device of `[devices]` with the `[timing]` figures, the rig seed, a fault
    /// scenario, a clock (create it inside the runtime that runs the rig) and the source of
    /// camera pixels. All configuration problems are reported at once.
    pub fn build(
        devices: &DevicesConfig,
        timing: &TimingConfig,
        seed: u64,
        faults: &FaultScenario,
        clock: SharedClock,
        frames: Arc<dyn FrameSource>,
    ) -> Result<SimRig, ConfigError> {
        let mut errors = Vec::new();
        timing.validate(&mut errors);
        devices.validate(&mut errors);
        faults.validate(&mut errors);
        let world = SimWorld::new(clock, timing, faults.lamp_drift.clone(), 0);
        let cx = BuildContext { world: &world, timing, faults, seed, frames: &frames };
        // Build each device even after a failure, so every problem is reported.
        fn take<T>(r: Result<T, ConfigError>, errors: &mut Vec<ConfigError>) -> Option<T> {
            r.map_err(|e| match e {
                ConfigError::Many(list) => errors.extend(list),
                e => errors.push(e),
            })
            .ok()
        }
        macro_rules! build {
            ($entry:expr, $role:ident) => {
                take(
                    factory_for($entry, concat!("devices.", stringify!($role), ".kind"))
                        .and_then(|f| (f.$role)(&cx, &$entry.options)),
                    &mut errors,
                )
            };
        }
        let robot = build!(&devices.robot, robot);
        let rail = build!(&devices.rail, rail);
        let turntable = devices.turntable.as_ref().map(|e| build!(e, turntable));
        let lamp = build!(&devices.lamp, lamp);
        let led_array = devices.led_array.as_ref().map(|e| build!(e, led_array));
        let camera = build!(&devices.camera, camera);

        let mut present = vec![DeviceRole::Robot, DeviceRole::Rail, DeviceRole::Lamp, DeviceRole::Camera];
        if devices.turntable.is_some() {
            present.push(DeviceRole::Turntable);
        }
        if devices.led_array.is_some() {
            present.push(DeviceRole::LedArray);
        }
        let led_count = led_array.as_ref().and_then(|l| l.as_ref()).map_or(0, |l| l.count());
        faults.validate_for_rig(&present, led_count, &mut errors);
        ConfigError::from_list(errors)?;
        let some = "every device was built, since no error was reported";
        Ok(SimRig {
            world,
            robot: robot.expect(some),
            rail: rail.expect(some),
            turntable: turntable.map(|t| t.expect(some)),
            lamp: lamp.expect(some),
            led_array: led_array.map(|l| l.expect(some)),
            camera: camera.expect(some),
        })
    }

    /// [`SimRig::build`] from a whole rig config (its `[devices]`, `[timing]` and seed).
    pub fn from_rig_config(
        cfg: &RigConfig,
        faults: &FaultScenario,
        clock: SharedClock,
        frames: Arc<dyn FrameSource>,
    ) -> Result<SimRig, ConfigError> {
        Self::build(&cfg.devices, &cfg.timing, cfg.rig.seed, faults, clock, frames)
    }
}
