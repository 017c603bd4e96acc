//! Multiplexed-illumination numerics for btfrig: S-matrix codes, demultiplexing, fault
//! detection and the noise theory that decides whether multiplexing pays (no I/O, no devices,
//! no renderer).
//!
//! Brief overview: the main types and how data moves between them.
//!
//! * [`SMatrix`] ([`smatrix`]) is the code: `n` patterns over `n` sources, built by
//!   Sylvester (`n = 2^k − 1`), Paley (`n = p ≡ 3 mod 4`, cyclic) or twin-prime
//!   (`n = p(p+2)`, cyclic); [`SMatrix::for_sources`] pads a source count to an available
//!   order with always-off slots.
//! * Captures are a **pattern-major stack** of `f32`: frame `r` (one image per pattern, in
//!   capture order) holds `cols` values (pixels × channels) at `data[r*cols..(r+1)*cols]`
//!   ([`tile`]). Work is cut into tiles of columns so memory and cache stay bounded.
//! * [`Demuxer`] ([`demux`]) applies `S⁻¹` (or `S`) to every column in place: fast
//!   Walsh–Hadamard for Sylvester, FFT circular convolution for the cyclic orders, or a dense
//!   matrix product; f32 or f64 accumulation; explicit per-thread [`DemuxScratch`] and [`Par`].
//! * [`lsq`] handles the real rig: calibrated per-LED intensities (`W = S diag(a)`), a
//!   least-squares solve ([`LeastSquares`], SVD) for any pattern matrix and any set of
//!   excluded, dead or stuck sources, [`detect_faults`] (dead and stuck LEDs from the data),
//!   and the owning high-level [`Demultiplexer`] that runs fast path → detection → re-solve and
//!   returns images plus a [`DemuxReport`].
//! * [`noise`] predicts the SNR of single-light against multiplexed capture for a sensor and a
//!   scene, and [`noise::choose`] picks the mode with the reason.
//!
//! Formulas: module docs and `docs/multiplexing.md`.
//!
//! ```
//! use btfrig_mux::{Demultiplexer, DemuxParams, SMatrix};
//! // 7 LEDs, 3 pixels: multiplex known single-light images, then recover them.
//! let s = SMatrix::of_order(7).unwrap();
//! let cols = 3;
//! let truth: Vec<f32> = (0..7 * cols).map(|i| (i % 5) as f32 + 0.5).collect();
//! let frames = btfrig_mux::Demuxer::new(&s, &DemuxParams::default()).unwrap().multiplex(&truth, cols).unwrap();
//! let dm = Demultiplexer::new(s, vec![1.0; 7], Default::default()).unwrap();
//! let out = dm.run(frames, cols).unwrap();
//! for (a, b) in out.images().iter().zip(&truth) {
//!     assert!((a - b).abs() < 1e-5);
//! }
//! assert!(out.report().faults.is_empty());
//! ```
#![warn(missing_docs)]
#![allow(non_snake_case)]

// The files, one job each:
// - smatrix: S-matrix constructions
// - tile:    pattern-major stacks and their pixel tiles
// - demux:   the Demuxer (fast, FFT, dense); kernel, lanes: what its kernels share
// - vwht, rader, vfft: the Walsh-Hadamard and Rader-FFT kernels on pixel vectors
// - lsq:     least squares with calibrated intensities, dead/stuck LEDs, the Demultiplexer
// - denoise: denoising by projection onto a linear basis
// - noise:   noise theory and the mode chooser
// - error:   MuxError

pub mod demux;
pub mod denoise;
pub mod error;
mod kernel;
mod lanes;
pub mod lsq;
pub mod noise;
mod rader;
pub mod smatrix;
pub mod tile;
mod vfft;
mod vwht;

pub use demux::{Accumulate, DemuxParams, DemuxScratch, Demuxer, DenseLayout, Engine, Method};
pub use denoise::{project_onto_own_basis, Projection};
pub use error::MuxError;
pub use lsq::{
    detect_faults, Demultiplexed, Demultiplexer, DemultiplexerParams, DemuxReport, Fault, FaultEvidence, FaultKind,
    FaultParams, LeastSquares, LsParams, PatternModel, SourceState,
};
pub use noise::{choose, predict, Choice, ChooseParams, Mode, Prediction, SceneLight, SensorNoise};
pub use smatrix::{available_orders, construction_of, Construction, Padded, SMatrix};
pub use tile::Par;
