//! The planner: expands a measurement's (light, view) pairs into captures with joint states
//! (or skips with reasons), estimates each step's time from the rig's timing model, orders
//! the captures to minimise hardware time, bounds that time from below, and summarises the
//! result as a dry run. No I/O, no async. Model, heuristic and bound: `docs/planner.md`.
//!
//! ```
//! use btfrig_core::config::{geometry::GonioGeometry, timing::TimingConfig};
//! use btfrig_core::kinematics::Gonio;
//! use btfrig_core::sampling::Sampling;
//! use btfrig_planner::{plan, PairSelection, PlanRequest};
//!
//! let gonio = Gonio::new(GonioGeometry::bonn()).unwrap();
//! let s = Sampling::bonn81();
//! let timing = TimingConfig::bonn();
//! let req = PlanRequest::new(&gonio, &s, &s, &timing, 0.01, 12_000_000)
//!     .with_pairs(PairSelection::List(vec![(0, 5), (3, 7), (4, 4)]));
//! let schedule = plan(&req).unwrap();
//! assert_eq!(schedule.captures.len(), 2); // (4, 4): the camera would block the lamp
//! assert!(schedule.critical_path_s <= schedule.timing.hardware_s);
//! ```
#![warn(missing_docs)]

use std::fmt;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use btfrig_core::config::timing::TimingConfig;
use btfrig_core::kinematics::Gonio;
use btfrig_core::sampling::Sampling;

// The files, one job each:
// - lib:     PlanRequest, Schedule and plan
// - expand:  (light, view) pairs to captures with joint states, or skips
// - order:   the capture order that minimises hardware time
// - timing:  the timing model of a schedule and its lower bound
// - summary: the dry-run summary
// - dome:    a dome's or camera array's schedule and multiplexing choice

pub mod dome;
pub mod expand;
pub mod order;
pub mod summary;
pub mod timing;

pub use expand::{expand, skip_counts, Expansion, PairSelection, PlanCapture, Skip, SkipKind, SkipReason};
pub use order::{naive_order, optimise_order, optimise_order_cancellable, OrderOptions};
pub use summary::{format_hms, DiskEstimate, DryRun};
pub use timing::{MoveTime, ScheduleTiming, Start, StepCost, StepTiming, TimingModel};

/// Why a request cannot be planned.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlanError {
    /// A pair names a direction the samplings do not have.
    #[error("pair (light {light_index}, view {view_index}) is out of range: {lights} lights, {views} views")]
    PairOutOfRange {
        /// Requested light index.
        light_index: usize,
        /// Requested view index.
        view_index: usize,
        /// Number of lights.
        lights: usize,
        /// Number of views.
        views: usize,
    },
    /// A pair is requested twice.
    #[error("pair (light {light_index}, view {view_index}) is requested more than once")]
    DuplicatePair {
        /// Light index.
        light_index: usize,
        /// View index.
        view_index: usize,
    },
    /// The exposure is not a positive finite number of seconds.
    #[error("exposure {exposure_s} s is not allowed: must be finite and > 0")]
    BadExposure {
        /// The value given.
        exposure_s: f64,
    },
    /// Frames of zero bytes.
    #[error("frame bytes = 0 is not allowed: must be >= 1")]
    ZeroFrameBytes,
    /// The [`Cancel`] flag was set (a signal, a client that went away, a time limit).
    #[error("cancelled")]
    Cancelled,
}

/// A cancellation flag shared between threads: set it from a signal handler, a request
/// guard's `Drop` or a timer, and the planner's loops stop soon after with
/// [`PlanError::Cancelled`]. Clones share the flag.
#[derive(Debug, Clone, Default)]
pub struct Cancel(Arc<AtomicBool>);

impl Cancel {
    /// A flag that is not set.
    pub fn new() -> Cancel {
        Cancel::default()
    }

    /// Sets the flag (for every clone).
    pub fn cancel(&self) {
        self.0.store(true, Ordering::Relaxed);
    }

    /// Whether the flag is set.
    pub fn is_cancelled(&self) -> bool {
        self.0.load(Ordering::Relaxed)
    }

    /// `Err(PlanError::Cancelled)` once the flag is set.
    pub fn check(&self) -> Result<(), PlanError> {
        if self.is_cancelled() {
            Err(PlanError::Cancelled)
        } else {
            Ok(())
        }
    }
}

/// Everything [`plan`] needs.
#[derive(Debug, Clone)]
pub struct PlanRequest<'a> {
    /// The rig's kinematics.
    pub gonio: &'a Gonio,
    /// Light directions.
    pub lights: &'a Sampling,
    /// View directions.
    pub views: &'a Sampling,
    /// Which pairs.
    pub pairs: PairSelection,
    /// The rig's `[timing]`.
    pub timing: &'a TimingConfig,
    /// Exposure per capture, seconds.
    pub exposure_s: f64,
    /// Bytes sent per frame.
    pub frame_bytes: u64,
    /// Rig state before the first capture.
    pub start: Start,
    /// Improvement limits of the ordering.
    pub order: OrderOptions,
    /// Stops the planning with [`PlanError::Cancelled`] when set (never, by default).
    pub cancel: Cancel,
}

impl<'a> PlanRequest<'a> {
    /// All pairs, starting from the homed rig, default ordering options.
    pub fn new(
        gonio: &'a Gonio,
        lights: &'a Sampling,
        views: &'a Sampling,
        timing: &'a TimingConfig,
        exposure_s: f64,
        frame_bytes: u64,
    ) -> Self {
        PlanRequest {
            gonio,
            lights,
            views,
            pairs: PairSelection::All,
            timing,
            exposure_s,
            frame_bytes,
            start: Start::homed(),
            order: OrderOptions::default(),
            cancel: Cancel::new(),
        }
    }

    /// The same request, stopped when `cancel` is set.
    pub fn with_cancel(mut self, cancel: &Cancel) -> Self {
        self.cancel = cancel.clone();
        self
    }

    /// The same request for other pairs.
    pub fn with_pairs(mut self, pairs: PairSelection) -> Self {
        self.pairs = pairs;
        self
    }
}

/// A planned measurement: what to capture, in which order, and how long it takes.
#[derive(Debug, Clone, PartialEq)]
pub struct Schedule {
    /// Name of the light sampling.
    pub lights: String,
    /// Name of the view sampling.
    pub views: String,
    /// Pairs requested.
    pub requested: usize,
    /// Captures, in request order; [`Schedule::order`] indexes into this.
    pub captures: Vec<PlanCapture>,
    /// Pairs not captured, with reasons.
    pub skipped: Vec<Skip>,
    /// Execution order: a permutation of `0..captures.len()`.
    pub order: Vec<usize>,
    /// Rig state before the first capture.
    pub start: Start,
    /// Timing of [`Schedule::order`].
    pub timing: ScheduleTiming,
    /// Hardware time of the naive nested-loop order (for each view, for each light).
    pub naive_order_hardware_s: f64,
    /// Lower bound on the hardware time of any order of these captures.
    pub critical_path_s: f64,
}

impl Schedule {
    /// The captures in execution order, with their timing.
    pub fn steps(&self) -> impl Iterator<Item = (&PlanCapture, &StepTiming)> + '_ {
        self.timing.per_step.iter().map(move |t| (&self.captures[t.capture], t))
    }

    /// The dry-run summary, with the caller's bytes per capture on disk.
    pub fn dry_run(&self, disk: DiskEstimate) -> DryRun {
        DryRun {
            lights: self.lights.clone(),
            views: self.views.clone(),
            requested: self.requested,
            captures: self.captures.len(),
            skipped: skip_counts(&self.skipped),
            hardware_s: self.timing.hardware_s,
            naive_order_hardware_s: self.naive_order_hardware_s,
            critical_path_s: self.critical_path_s,
            motion_s: self.timing.motion_s,
            capture_s: self.timing.capture_s,
            transfer_s: self.timing.transfer_s,
            idle_s: self.timing.idle_s,
            disk,
        }
    }
}

/// Expands, orders and times a request.
pub fn plan(req: &PlanRequest) -> Result<Schedule, PlanError> {
    req.cancel.check()?;
    let ex = expand(req.gonio, req.lights, req.views, &req.pairs, req.exposure_s, req.frame_bytes)?;
    schedule_expansion_cancellable(
        req.lights.name(),
        req.views.name(),
        ex,
        &TimingModel::new(req.timing),
        &req.start,
        &req.order,
        &req.cancel,
    )
}

/// Orders and times an expansion (e.g. after [`Expansion::mark_not_needed`] or per-capture
/// exposures).
pub fn schedule_expansion(
    lights: &str,
    views: &str,
    ex: Expansion,
    model: &TimingModel,
    start: &Start,
    opts: &OrderOptions,
) -> Schedule {
    schedule_expansion_cancellable(lights, views, ex, model, start, opts, &Cancel::new()).expect("never cancelled")
}

/// [`schedule_expansion`], stopping with [`PlanError::Cancelled`] soon after `cancel` is set.
pub fn schedule_expansion_cancellable(
    lights: &str,
    views: &str,
    ex: Expansion,
    model: &TimingModel,
    start: &Start,
    opts: &OrderOptions,
    cancel: &Cancel,
) -> Result<Schedule, PlanError> {
    let order = optimise_order_cancellable(model, &ex.captures, start, opts, cancel)?;
    cancel.check()?;
    let timing = model.schedule_time(&ex.captures, &order, start);
    let naive = model.schedule_time(&ex.captures, &naive_order(&ex.captures), start);
    Ok(Schedule {
        lights: lights.to_string(),
        views: views.to_string(),
        requested: ex.captures.len() + ex.skipped.len(),
        critical_path_s: model.critical_path_s(&ex.captures, start),
        naive_order_hardware_s: naive.hardware_s,
        captures: ex.captures,
        skipped: ex.skipped,
        order,
        start: *start,
        timing,
    })
}

impl fmt::Display for Schedule {
    /// The dry run without a disk estimate.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.dry_run(DiskEstimate::default()).fmt(f)
    }
}
