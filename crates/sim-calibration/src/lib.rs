//! The simulated rig's side of the calibration procedures.
//!
//! `btfrig-calibrate` holds each procedure's numerics and file format and works on frames,
//! whoever made them; this crate makes those frames on the simulated rig (true lens, lamp,
//! LEDs and sensor, seeded noise) and may read the simulator's truth to report how far a
//! calibration is from it. Processing crates never depend on it.
#![warn(missing_docs)]

pub mod leds;
