//! The processing pipeline of a run: from the engine's captured frames to committed textures
//! in a dataset.
//!
//! Per frame, on a blocking thread (never on the async threads that drive the devices):
//! demosaic (a normalisation only for mono sensors), registration (the holder plate's markers
//! detected in the green channel, the sample pose estimated from them with the nominal pose
//! as prior: `btfrig_registration::PlateRegistrar`), rectification onto the sample plane with the
//! REGISTERED pose, conversion to radiance factor, the OpenEXR write, then the journal commit
//! with how the pose was found ([`StepRegistration`]). Each stage is timed. The plan's
//! `[registration]` ([`RegistrationPolicy`]) may ask for the nominal pose (kinematics of the
//! commanded joints) instead, and says what a failed registration does: fall back to the
//! nominal pose, recorded and counted as a fallback, or stop ([`PipelineError::Registration`]).
//!
//! On the simulated rig the texture is also compared with the ground truth of the TRUE state
//! at exposure (from the truth probe, [`Processor::with_truth`], read for error figures only), accumulated into an overall relative RMSE, and the
//! texel position error of the pose used and of the nominal pose is measured against the true
//! pose; optionally ([`Processor::with_nominal_comparison`]) the texture is rectified a second
//! time with the nominal pose to measure what registration gained.
//!
//! What is written follows the plan's `[outputs]` ([`Outputs`], set with
//! [`Processor::with_outputs`]): the texture, the raw frame, or both, committed in ONE journal
//! record so a crash never leaves one counted without the other; and, rate-limited, a live
//! preview ([`PreviewSettings`]): `preview.png` in the dataset directory (atomic, never
//! journaled) and the same PNG in memory ([`Processor::subscribe_preview`]) for the HTTP daemon.
//!
//! Back-pressure: [`run`] keeps at most [`MAX_IN_FLIGHT`] frames in processing and commits them
//! in arrival order; while both slots are busy it stops receiving, so the engine's bounded
//! frame channel fills and the engine waits before its next trigger.
#![warn(missing_docs)]

// The files, one job each:
// - settings:  what to make of each frame and what to write (ProcessSettings, Outputs, ...)
// - processor: the Processor (model, settings, registrar), its builders and accessors
// - stages:    the per-frame stages: demosaic or HDR merge, register, rectify, radiometry, truth
// - preview:   the live preview: tone mapping, rate gate, making one on a processing thread
// - sink:      TextureSink, which receives every committed texture
// - run:       the run loop: bounded parallel processing, commits in arrival order
// - totals:    running totals of a run: counts, stage times, error figures
// - error:     PipelineError
// - model:     the processing model (camera, sensor, plate, kinematics, calibrations)
// - color, dark_flat, light: applying the colour, dark/flat and light calibrations
// - dome:      the LED dome's pipeline

pub mod color;
pub mod dark_flat;
pub mod dome;
mod error;
pub mod light;
pub mod model;
mod preview;
mod processor;
mod run;
mod settings;
mod sink;
mod stages;
mod totals;

pub use btfrig_core::plan::{OnRegistrationFailure, RegistrationMethod, RegistrationPolicy};
pub use btfrig_store::{PoseSource, StepRegistration};
pub use error::PipelineError;
pub use model::{ModelSource, ProcessingModel, SensorConstants};
pub use preview::{tone_map_preview, Preview};
pub use processor::Processor;
pub use run::{run, MAX_IN_FLIGHT, STAGES};
pub use settings::{HdrRecording, Outputs, PreviewSettings, ProcessSettings};
pub use sink::TextureSink;
pub use stages::{PoseErrors, Processed};
pub use totals::{TexelErrorTotals, Totals};
