//! Runs a measurement plan on a rig into a dataset, resumable: the one entry point that the
//! `btfrig` CLI (`btfrig run`, `btfrig demo`) uses, and that the HTTP daemon wraps.
//!
//! [`run`] loads and validates the plan, creates the dataset or resumes the same plan's,
//! plans the schedule, checks the rig's devices ([`preflight`]), opens them through the backend
//! registry ([`backend`]) on a virtual-time tokio runtime (the wall clock for a rig with real
//! devices, or when asked: [`backend::RigTime`]), spawns the engine, runs the processing pipeline and writes `report.json`. The caller watches
//! [`RunEvent`]s through a callback and steers the run from any thread with a
//! [`RunControl`]. However a session ends (finished, paused by a fault, interrupted,
//! aborted), the frames already captured are processed and committed first and the report
//! says how it ended; the dataset stays resumable with the same request.

#![warn(missing_docs)]

// The files, one job each:
// - request:  what a run is asked to do (RunRequest)
// - control:  steering a run from any thread (RunControl, Signal)
// - events:   what a run tells its watcher (RunEvent, Fault, RunOutcome)
// - summary:  what a session measured (RunSummary) and peak memory
// - error:    RunError
// - runtime:  the virtual-time runtime, the frame channel's depth
// - gonio:    a gonioreflectometer run ([`run`]): dataset, schedule, engine, pipeline, report
// - dome:     an LED dome's or camera array's run; dome_reprocess, reprocess: runs again from kept frames
// - reprocess_io: what both reprocesses share (request, summary, source dataset, calibration directory)
// - raw_schedule: how a dome run captured its view groups (manifest `raw_groups`), for reprocessing
// - calibration_rig: a gonio opened for a calibration (devices checked by role, homed, lamp lit)
// - geometric_calibration, color_calibration, rig_geometry_calibration: those calibrations through the devices
// - captured_calibration: the radiometric calibrations through the devices (dark/flat, sensor, lamp, LEDs)
// - backend:  the device backends by rig kind (the registry, what a backend opens and reports), RigTime
// - preflight: every device asked who it is, how it feels and whether it is homed, before anything is created
// - model:    the processing model from the rig config and calibration files
// - sinks:    the sinks the plan's outputs ask for (the streaming compression model)
// - plan, check, dry_run, dome_dry_run: loading a plan, checking it against the rig, dry runs
// - report, hdr, light: report.json, HDR and light-calibration records

pub mod backend;
pub mod calibration_rig;
pub mod captured_calibration;
pub mod check;
pub mod color_calibration;
mod control;
pub mod dome;
pub mod dome_dry_run;
pub mod dome_reprocess;
pub mod dry_run;
mod error;
mod events;
pub mod geometric_calibration;
mod gonio;
mod hdr;
mod light;
pub mod model;
pub mod plan;
pub mod preflight;
pub mod raw_schedule;
pub mod report;
pub mod reprocess;
mod reprocess_io;
mod request;
pub mod rig_geometry_calibration;
mod runtime;
pub mod sinks;
mod summary;

pub use crate::control::{ControlError, RunControl, Signal, CONTROL_CAPACITY};
pub use crate::error::RunError;
pub use crate::events::{Fault, RunEvent, RunOutcome};
pub use crate::gonio::run;
pub use crate::hdr::{journal_hdr, HdrFigures};
pub use crate::request::{BackendsHandle, DarkFlatInput, RunRequest};
pub use crate::runtime::virtual_time_runtime;
pub use crate::summary::{peak_rss_mib, ProcessingInfo, RunSummary};
pub use btfrig_planner::Cancel;
