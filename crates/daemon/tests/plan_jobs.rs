//! Issue 24, item 2: a plan check or dry run that outlives the daemon's plan-job time limit
//! is answered as refused, naming the limit, and its work is cancelled (not left running).
//! The limit is lowered to 100 ms here; the plan is one the plan limits allow (360 000 pairs,
//! `[limits]` raised) whose planning takes seconds, far beyond it.

mod support;

use std::time::{Duration, Instant};

use serde_json::json;
use support::Daemon;

/// 12 rings x 50 directions for light and view: 360 000 pairs.
fn big_plan() -> String {
    let rings: Vec<String> =
        (0..12).map(|r| format!("{{ theta_deg = {}, count = 50 }}", 5.0 + 72.0 * r as f64 / 11.0)).collect();
    let rings = rings.join(", ");
    format!(
        "name = \"big\"\n[sampling]\nlight = {{ rings = [{rings}] }}\nview = {{ rings = [{rings}] }}\n[texture]\nsize = 8\n[limits]\nmax_captures = 400000\n"
    )
}

#[test]
fn a_dry_run_beyond_the_time_limit_is_refused_naming_it_and_its_work_cancelled() {
    let limit = Duration::from_millis(100);
    let d = Daemon::start_limits("plan_job_time_limit", None, btfrig_daemon::server::HEADER_READ_TIMEOUT, limit);
    let r = d.check("dry-run", json!({ "plan_text": big_plan() }));
    assert_eq!(r["valid"], false, "{r}");
    let e = r["errors"][0].as_str().unwrap();
    assert!(e.contains("longer than its time limit of 0.1 s and was cancelled"), "{e}");
    // The work on the blocking thread sees its flag and ends: wait for that event.
    let jobs = &d.state.metrics.plan_jobs;
    let t0 = Instant::now();
    while jobs.in_flight() > 0 {
        assert!(t0.elapsed() < Duration::from_secs(120), "the timed-out plan job is still running after 120 s");
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_eq!(jobs.cancelled(), 1, "the job ended as cancelled");
}
