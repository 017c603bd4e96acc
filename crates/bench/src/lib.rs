//! Benchmark harnesses: time against error for every algorithm.
//!
//! Each module measures one family of algorithms on the simulated rig (or on synthetic data
//! with a known answer) and returns its figures; `btfrig bench ...` (crates/cli) parses the
//! arguments and prints them (docs/benchmarks.md). This crate may depend on the simulator
//! (`btfrig-sim`, `btfrig-render`): its error figures are against the simulator's truth. The
//! processing crates never depend on it (tests/crate_layout.rs).
//!
//! - [`render`]: frame render time with and without the renderer's skips (`bench render`)
//! - [`registration`]: marker detection, pose estimation and rectification filters against
//!   the true pose and the ground-truth texture (`btfrig bench registration`)
//! - [`opencv`]: the OpenCV peer of the registration benchmark, on the same frames
//! - [`pipeline`]: raw frame to texture stage by stage, against OpenCV and a memory pass;
//!   the HDR merge before and after (`btfrig bench pipeline`)
//! - [`color`]: colour-correction models' fit and apply time and CIEDE2000 (`bench color`)
//! - [`demux`]: demultiplexing methods' time against a memory-bandwidth floor (`bench demux`)
//! - [`compress`]: linear BTF models on a simulated BTF: size, speed, error (`bench compress`)
//! - [`model`]: the true surface of a simulated dataset for photometric stereo's and the
//!   reflectance fits' error figures (`bench model`)
//! - [`serve`]: HTTP client and helpers of the daemon load benchmark (`bench serve`)

pub mod color;
pub mod compress;
pub mod demux;
pub mod model;
pub mod opencv;
pub mod pipeline;
pub mod registration;
pub mod render;
pub mod serve;
