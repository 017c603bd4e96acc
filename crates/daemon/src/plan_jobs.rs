//! Plan checks and dry runs in flight (`POST /api/v1/plans/validate`, `/plans/dry-run`,
//! the start of a run): each runs on a blocking thread with a [`Cancel`] flag that is set
//! when its client goes away (the handler's future is dropped), when
//! [`PLAN_JOB_TIME_LIMIT`] passes, or when the daemon shuts down, so that no request keeps
//! a core and memory after nobody waits for it. Memory is bounded by the plan limits
//! (`btfrig_core::plan::limits`).

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use btfrig_measurement::Cancel;

/// Longest a plan check or dry run may take before it is cancelled (docs/http-api.md).
pub const PLAN_JOB_TIME_LIMIT: Duration = Duration::from_secs(30);

/// The plan jobs of a daemon: the live ones' flags and two figures for `/metrics`.
#[derive(Debug, Default)]
pub struct PlanJobs {
    live: Mutex<BTreeMap<u64, Cancel>>,
    next_id: AtomicU64,
    in_flight: AtomicU64,
    cancelled: AtomicU64,
}

impl PlanJobs {
    /// Registers a job: the [`PlanJobGuard`] stays with the request's handler (dropping it
    /// cancels the job), the [`PlanJobRecord`] goes with the work (dropping it counts the
    /// job as ended, and as cancelled if its flag was set).
    pub fn start(self: &Arc<Self>) -> (PlanJobGuard, PlanJobRecord) {
        let id = self.next_id.fetch_add(1, Ordering::Relaxed);
        let cancel = Cancel::new();
        self.live.lock().unwrap_or_else(|e| e.into_inner()).insert(id, cancel.clone());
        self.in_flight.fetch_add(1, Ordering::Relaxed);
        (PlanJobGuard { cancel: cancel.clone() }, PlanJobRecord { jobs: self.clone(), id, cancel })
    }

    /// Cancels every job in flight (the daemon's shutdown).
    pub fn cancel_all(&self) {
        for c in self.live.lock().unwrap_or_else(|e| e.into_inner()).values() {
            c.cancel();
        }
    }

    /// Jobs running now.
    pub fn in_flight(&self) -> u64 {
        self.in_flight.load(Ordering::Relaxed)
    }

    /// Jobs that ended after their flag was set.
    pub fn cancelled(&self) -> u64 {
        self.cancelled.load(Ordering::Relaxed)
    }
}

/// Held by the request's handler: cancels the job when dropped (the client went away, or
/// the handler is done and the job no longer matters).
#[derive(Debug)]
pub struct PlanJobGuard {
    cancel: Cancel,
}

impl PlanJobGuard {
    /// Cancels the job now (its time limit passed).
    pub fn cancel(&self) {
        self.cancel.cancel();
    }
}

impl Drop for PlanJobGuard {
    fn drop(&mut self) {
        self.cancel.cancel();
    }
}

/// Moved into the blocking work: its flag, and the bookkeeping when the work ends.
#[derive(Debug)]
pub struct PlanJobRecord {
    jobs: Arc<PlanJobs>,
    id: u64,
    cancel: Cancel,
}

impl PlanJobRecord {
    /// The job's flag, for the work to check.
    pub fn cancel(&self) -> &Cancel {
        &self.cancel
    }
}

impl Drop for PlanJobRecord {
    fn drop(&mut self) {
        self.jobs.live.lock().unwrap_or_else(|e| e.into_inner()).remove(&self.id);
        if self.cancel.is_cancelled() {
            self.jobs.cancelled.fetch_add(1, Ordering::Relaxed);
        }
        self.jobs.in_flight.fetch_sub(1, Ordering::Relaxed);
    }
}
