//! Prometheus metrics at `/metrics`, in the text exposition format (version 0.0.4).
//!
//! Written by hand: a dozen counters and gauges need no registry crate, and the format is
//! three line kinds (`# HELP`, `# TYPE`, samples).

use std::collections::BTreeMap;
use std::fmt::Write;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;

/// Counters and gauges of the daemon and its runs.
#[derive(Default)]
pub struct Metrics {
    captures: AtomicU64,
    dome_steps: AtomicU64,
    retries: AtomicU64,
    warnings: AtomicU64,
    runs_started: AtomicU64,
    queue_depth: AtomicU64,
    events_dropped: AtomicU64,
    http: Mutex<BTreeMap<u16, u64>>,
    /// Stage seconds of finished sessions, and of the session under way.
    stages_done: Mutex<BTreeMap<String, f64>>,
    stages_current: Mutex<BTreeMap<String, f64>>,
    /// Plan checks and dry runs in flight, with their cancel flags.
    pub plan_jobs: std::sync::Arc<crate::plan_jobs::PlanJobs>,
}

impl Metrics {
    /// A capture delivered after `attempts` attempts.
    pub fn step_done(&self, attempts: u32) {
        self.captures.fetch_add(1, Ordering::Relaxed);
        self.retries.fetch_add(u64::from(attempts.saturating_sub(1)), Ordering::Relaxed);
    }

    /// A dome step (a frame per camera) delivered after `attempts` attempts.
    pub fn dome_step_done(&self, attempts: u32) {
        self.dome_steps.fetch_add(1, Ordering::Relaxed);
        self.retries.fetch_add(u64::from(attempts.saturating_sub(1)), Ordering::Relaxed);
    }

    /// A run warning.
    pub fn warning(&self) {
        self.warnings.fetch_add(1, Ordering::Relaxed);
    }

    /// A run started.
    pub fn run_started(&self) {
        self.runs_started.fetch_add(1, Ordering::Relaxed);
        self.stages_current.lock().unwrap_or_else(|e| e.into_inner()).clear();
    }

    /// The pipeline committed a capture: its queue and the session's stage seconds so far.
    pub fn committed(&self, queued: u64, stage_s: &BTreeMap<String, f64>) {
        self.queue_depth.store(queued, Ordering::Relaxed);
        *self.stages_current.lock().unwrap_or_else(|e| e.into_inner()) = stage_s.clone();
    }

    /// A dome run committed a view group: the session's stage seconds so far (its frames are
    /// held per view group, not queued: the queue depth is a gonio figure).
    pub fn stages(&self, stage_s: &BTreeMap<String, f64>) {
        *self.stages_current.lock().unwrap_or_else(|e| e.into_inner()) = stage_s.clone();
    }

    /// A session ended: its stage seconds move to the finished total.
    pub fn session_ended(&self) {
        let current = std::mem::take(&mut *self.stages_current.lock().unwrap_or_else(|e| e.into_inner()));
        let mut done = self.stages_done.lock().unwrap_or_else(|e| e.into_inner());
        for (k, v) in current {
            *done.entry(k).or_insert(0.0) += v;
        }
        self.queue_depth.store(0, Ordering::Relaxed);
    }

    /// An event stream fell behind and skipped `n` events.
    pub fn events_dropped(&self, n: u64) {
        self.events_dropped.fetch_add(n, Ordering::Relaxed);
    }

    /// A response with `status` was sent.
    pub fn http(&self, status: u16) {
        *self.http.lock().unwrap_or_else(|e| e.into_inner()).entry(status).or_insert(0) += 1;
    }

    /// The exposition text; `run_state` is the current run's state name, if one holds the rig.
    pub fn render(&self, run_state: Option<&str>, progress: Option<f64>) -> String {
        let mut out = String::new();
        let mut counter = |name: &str, help: &str, v: u64| {
            let _ = writeln!(out, "# HELP {name} {help}\n# TYPE {name} counter\n{name} {v}");
        };
        counter("btfrig_captures_total", "Captures delivered by the engine.", self.captures.load(Ordering::Relaxed));
        counter(
            "btfrig_dome_steps_total",
            "Dome steps delivered by the engine (a pattern at a rotation, a frame per camera).",
            self.dome_steps.load(Ordering::Relaxed),
        );
        counter(
            "btfrig_capture_retries_total",
            "Attempts beyond the first (gonio captures and dome steps).",
            self.retries.load(Ordering::Relaxed),
        );
        counter("btfrig_run_warnings_total", "Run warnings.", self.warnings.load(Ordering::Relaxed));
        counter("btfrig_runs_started_total", "Runs started.", self.runs_started.load(Ordering::Relaxed));
        counter(
            "btfrig_events_dropped_total",
            "Run events a slow event-stream client skipped.",
            self.events_dropped.load(Ordering::Relaxed),
        );
        counter(
            "btfrig_plan_jobs_cancelled_total",
            "Plan checks and dry runs stopped by their cancel flag (client gone, time limit, shutdown).",
            self.plan_jobs.cancelled(),
        );
        let _ = writeln!(
            out,
            "# HELP btfrig_plan_jobs_in_flight Plan checks and dry runs running now.\n# TYPE btfrig_plan_jobs_in_flight gauge\nbtfrig_plan_jobs_in_flight {}",
            self.plan_jobs.in_flight()
        );
        let _ = writeln!(
            out,
            "# HELP btfrig_pipeline_queue_depth Frames captured and not yet committed.\n# TYPE btfrig_pipeline_queue_depth gauge\nbtfrig_pipeline_queue_depth {}",
            self.queue_depth.load(Ordering::Relaxed)
        );
        let _ = writeln!(out, "# HELP btfrig_run_active 1 while a run holds the rig.\n# TYPE btfrig_run_active gauge");
        let _ = writeln!(
            out,
            "btfrig_run_active{{state=\"{}\"}} {}",
            run_state.unwrap_or("none"),
            u8::from(run_state.is_some())
        );
        let _ = writeln!(out, "# HELP btfrig_run_progress_ratio Captures (dome runs: steps) done over planned, current run.\n# TYPE btfrig_run_progress_ratio gauge");
        let _ = writeln!(out, "btfrig_run_progress_ratio {}", progress.unwrap_or(0.0));
        let _ = writeln!(
            out,
            "# HELP btfrig_stage_seconds_total Pipeline thread time per stage.\n# TYPE btfrig_stage_seconds_total counter"
        );
        let mut stages = self.stages_done.lock().unwrap_or_else(|e| e.into_inner()).clone();
        for (k, v) in self.stages_current.lock().unwrap_or_else(|e| e.into_inner()).iter() {
            *stages.entry(k.clone()).or_insert(0.0) += v;
        }
        for (k, v) in stages {
            let _ = writeln!(out, "btfrig_stage_seconds_total{{stage=\"{k}\"}} {v}");
        }
        let _ = writeln!(
            out,
            "# HELP btfrig_http_responses_total Responses by status.\n# TYPE btfrig_http_responses_total counter"
        );
        for (status, n) in self.http.lock().unwrap_or_else(|e| e.into_inner()).iter() {
            let _ = writeln!(out, "btfrig_http_responses_total{{status=\"{status}\"}} {n}");
        }
        out
    }
}
