//! Compression of measured BTFs into linear models, and what linear models are good for.
//!
//! Brief overview: rectified textures stream in, one capture (light, view) at a time in any
//! order, into a [`Builder`] ([`build`] drives one from any [`RowSource`], e.g. a finished
//! dataset via [`dataset::DatasetSource`]); the builder holds only randomized-SVD sketches
//! ([`rsvd::StreamingRsvd`]), so its memory is bounded by the model, not by the number of
//! captures. It makes a [`Model`]: a full-matrix (FMF), per-view (PVMF) or per-cluster
//! (PCMF, local PCA) factorization of the colour channels of a [`ColorModel`]. A model
//! answers the BTF at measured pairs ([`Model::texel`], [`Model::texture`]) and at any
//! direction pair by barycentric interpolation of its angular factors ([`Model::query`]).
//! Models are written and read in our own format ([`file`], `docs/model-format.md`) and
//! exported to the Bonn `.btf` containers ([`ubo`]). [`sparse`] applies a model's basis:
//! denoising by projection, and the reconstruction of a full BTF from a well-chosen subset
//! of captures. [`eval`] measures models against reference BTFs.
//!
//! ```
//! use btfrig_compress::{build, Layout, MemorySource, Method, ModelParams};
//! use btfrig_core::sampling::Sampling;
//! // A 4-texel BTF over a 3 x 3 sampling, rank 1 per channel.
//! let dirs = |n: &str| Sampling::from_rings(n, &[btfrig_core::sampling::Ring::new(0.0, 1, 0.0),
//!                                              btfrig_core::sampling::Ring::new(40.0, 2, 0.0)]).unwrap();
//! let layout = Layout::full(dirs("l"), dirs("v"), 2, 2);
//! let textures: Vec<Option<Vec<[f32; 3]>>> = (0..9)
//!     .map(|a| Some((0..4).map(|x| [0.1 * (a + 1) as f32 * (x + 1) as f32; 3]).collect()))
//!     .collect();
//! let mut params = ModelParams::new(Method::Fmf);
//! params.terms = [2, 1, 1];
//! let (model, stats) = build::<f64>(layout.clone(), &params,
//!                                   &mut MemorySource { layout: &layout, textures: &textures }).unwrap();
//! assert_eq!(stats.passes, params.passes());
//! let t = model.texel(5, 3);
//! assert!((t[0] - 0.1 * 6.0 * 4.0).abs() < 1e-2);
//! ```
#![warn(missing_docs)]
#![allow(non_snake_case)]
// Index loops over several arrays at once read closer to the formulas than zipped iterators.
#![allow(clippy::needless_range_loop)]

// The files, one job each:
// - model:   linear BTF models (FMF, PVMF, PCMF), their layout and evaluation at any direction pair
// - build:   streaming construction of a model from textures in any order (Builder, RowSource)
// - rsvd:    streaming randomized SVD; linalg: the dense factorizations under it
// - cluster, refine, shared: PCMF's clustering, local-PCA reassignment, the shared angular basis
// - color:   the colour model of the stored channels (RGB, YUV, log-Y)
// - file:    our model file (.btfm); ubo: the Bonn .btf containers
// - dataset: a dataset directory read as a BTF
// - sink:    the streaming sink a run feeds while it measures
// - sparse:  denoising and sparse acquisition with a model's basis
// - eval:    a model measured against a reference BTF
// - error:   CompressError

pub mod build;
pub mod cluster;
pub mod color;
pub mod dataset;
pub mod error;
pub mod eval;
pub mod file;
pub mod linalg;
pub mod model;
pub mod refine;
pub mod rsvd;
pub mod shared;
pub mod sink;
pub mod sparse;
pub mod ubo;

pub use build::{build, check_finite, BuildStats, Builder, MemorySource, ModelParams, RowSink, RowSource};
pub use color::ColorModel;
pub use error::{CompressError, Result};
pub use model::{CaptureDirections, Channel, Layout, Method, Model, Part, PartRows, Precision, Query, SharedBasis};
pub use rsvd::{Real, RsvdParams, StreamingRsvd, Svd};
