//! The core model of btfrig: no I/O, no async.
//!
//! Brief overview: [`direction::Direction`] is a direction on the hemisphere in the one
//! convention of the project (see `docs/conventions.md`); [`sampling`] holds sets of
//! directions (the Bonn 81 table, lists, dome layouts) with nearest-direction lookup and
//! barycentric interpolation; [`kinematics`] turns a (light, view) pair into the poses of a
//! gonioreflectometer and back; [`config::RigConfig`] is a rig described as data;
//! [`camera`] is the pinhole-plus-distortion camera model shared by the simulator and the
//! calibration; [`homography`] is the one plane homography (normalised DLT) and its
//! decomposition into a pose; [`frame`] is a raw sensor frame with its full metadata, and
//! [`capture`] a step's frames as the run engine delivers them;
//! [`plan`] is a measurement plan (TOML) validated against a rig, reporting every problem at
//! once.
#![warn(missing_docs)]

// The files, one job each:
// - direction:  directions on the hemisphere, the one angle convention
// - sampling:   samplings of the hemisphere (sampling/: their triangulation for interpolation)
// - kinematics: the gonioreflectometer's kinematics; pose: scene poses; profile: move-time profile
// - camera:     the camera model; homography: the one plane homography
// - frame:      raw sensor frames and their metadata
// - capture:    a capture as the run engine delivers it (step key, frames, joints, times)
// - config/:    the rig config, one file per section
// - plan/:      measurement plans and their validation (plan/validate/)
// - error:      ConfigError

pub mod camera;
pub mod capture;
pub mod config;
pub mod direction;
pub mod error;
pub mod frame;
pub mod homography;
pub mod kinematics;
pub mod plan;
pub mod pose;
pub mod profile;
pub mod sampling;

pub use direction::Direction;
pub use error::ConfigError;
