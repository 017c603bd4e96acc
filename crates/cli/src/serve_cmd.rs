//! `btfrig serve`: the control daemon (`btfrig-daemon`) on a multi-threaded runtime; runs
//! capture on threads of their own, so the two async workers only answer requests.

use crate::args::ServeArgs;

/// Runs the daemon until SIGTERM or SIGINT.
pub fn serve(a: &ServeArgs) -> anyhow::Result<()> {
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build()?;
    rt.block_on(btfrig_daemon::serve(btfrig_daemon::ServeConfig {
        rig: a.rig.clone(),
        listen: a.listen,
        data: a.data.clone(),
        auth: a.auth.clone(),
        plans: a.plans.clone(),
    }))?;
    Ok(())
}
