//! `btfrig serve`: the control daemon (`btfrig-daemon`) on a multi-threaded runtime; runs
//! capture on threads of their own, so the two async workers only answer requests.

use crate::args::ServeArgs;

/// Log lines when RUST_LOG is not set: warnings and errors only.
const DEFAULT_LOG_FILTER: &str = "warn";

/// Runs the daemon until SIGTERM or SIGINT.
pub fn serve(a: &ServeArgs) -> anyhow::Result<()> {
    init_logging()?;
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build()?;
    rt.block_on(btfrig_daemon::serve(btfrig_daemon::ServeConfig {
        rig: a.rig.clone(),
        listen: a.listen,
        data: a.data.clone(),
        auth: a.auth.clone(),
        plans: a.plans.clone(),
        header_read_timeout: btfrig_daemon::server::HEADER_READ_TIMEOUT,
        plan_job_time_limit: btfrig_daemon::plan_jobs::PLAN_JOB_TIME_LIMIT,
    }))?;
    Ok(())
}

/// The daemon's `tracing` events on stderr, filtered by RUST_LOG (`RUST_LOG=trace`,
/// `RUST_LOG=btfrig_daemon=debug,hyper=info`, ...; docs/http-api.md).
fn init_logging() -> anyhow::Result<()> {
    use tracing_subscriber::EnvFilter;
    let filter = match std::env::var("RUST_LOG") {
        Ok(v) if !v.trim().is_empty() => EnvFilter::try_new(&v).map_err(|e| {
            anyhow::anyhow!("RUST_LOG={v:?}: {e}; use e.g. RUST_LOG=debug or RUST_LOG=btfrig_daemon=trace,warn")
        })?,
        _ => EnvFilter::new(DEFAULT_LOG_FILTER),
    };
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(false)
        .try_init()
        .map_err(|e| anyhow::anyhow!("cannot set up logging: {e}"))?;
    Ok(())
}
