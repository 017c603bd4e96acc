//! The simulated rig: devices that implement the `btfrig-hw` traits on a timing model, with
//! seeded positioning errors and injected faults.
//!
//! Brief overview: [`SimRig::build`] takes the `[devices]` and `[timing]` sections, a seed,
//! a [`FaultScenario`] (from `sim/faults/*.toml`), a [`btfrig_hw::Clock`] and a
//! [`FrameSource`], and returns one boxed device per role plus a [`SimWorld`]. Devices wait
//! on the clock for as long as the [`profile`] and `[timing]` say, land with positioning
//! error, and write the TRUE state into the world, apart from the commanded one. The camera
//! snapshots [`TrueState`] at the start of each exposure and asks the frame source for the
//! pixels when the frame is read out. See `docs/devices.md` and `docs/timing.md`.
//!
//! ```
//! # #[tokio::main(flavor = "current_thread", start_paused = true)]
//! # async fn main() {
//! use std::sync::Arc;
//! use btfrig_core::config::{devices::DevicesConfig, timing::TimingConfig};
//! use btfrig_hw::{Camera, MoveOptions, Robot, TokioClock};
//! use btfrig_sim::{FaultScenario, FlatFrameSource, SimRig};
//!
//! let source = Arc::new(FlatFrameSource::new(8, 6, 1000.0));
//! let mut rig = SimRig::build(&DevicesConfig::default(), &TimingConfig::bonn(), 1,
//!     &FaultScenario::none(), TokioClock::shared(), source).unwrap();
//! rig.robot.home(MoveOptions::default()).await.unwrap();
//! rig.robot.move_to_rad([0.5, 0.2, 0.0], MoveOptions::default()).await.unwrap();
//! let frame = rig.camera.capture(30.0).await.unwrap();
//! assert_eq!(frame.meta.sequence, 0);
//! let truth = rig.world.truth();
//! assert!((truth.joints.robot[0] - 0.5).abs() < 0.01); // landed near, not at, the target
//! # }
//! ```
#![warn(missing_docs)]

// The files, one job each:
// - rig:       SimRig from the config's [devices] (the factory list by kind); options: device options
// - devices/:  the simulated devices; world: the true state they share
// - frame_source, rendered: where the camera's pixels come from
// - capture:   one capture's device sequence
// - dome:      a simulated dome or camera array
// - faults:    fault scenarios and injection
// - truth:     the gonio's truth probe

pub mod capture;
pub mod devices;
pub mod dome;
pub mod faults;
pub mod frame_source;
pub mod options;
pub mod rendered;
pub mod rig;
pub mod truth;
pub mod world;

/// The trapezoidal move-time profile; it lives in `btfrig-core` so the planner shares it.
pub use btfrig_core::profile;

pub use faults::{DeviceRole, FaultScenario};
pub use frame_source::{FlatFrameSource, FrameSource, SensorFormat};
pub use rendered::RenderedFrameSource;
pub use rig::{check_sim_options, SimRig, FACTORIES};
pub use world::{FaultEvent, FaultKind, SimWorld, TrueState};
