//! The one task that owns a rig's devices and executes the steps, for every kind of rig: the
//! loop over the steps, skipping done ones, stopping, pausing and resuming; the run's state
//! (commands, retries, progress, summary) is `crate::session`'s, and what a step does to the
//! devices is the rig's (`crate::gonio`, `crate::dome`).

use crate::dome::Dome;
use crate::gonio::{Gonio, Pending};
use crate::session::Core;
use crate::{PauseReason, RigDevices, RunOutcome};

/// What the rig's steps do: the devices and the channel their frames leave through.
pub(crate) enum Rig {
    Gonio(Gonio),
    Dome(Dome),
}

impl Rig {
    fn into_devices(self) -> RigDevices {
        match self {
            Rig::Gonio(g) => RigDevices::Gonio(g.dev),
            Rig::Dome(d) => RigDevices::Dome { devices: d.dev, patterns: d.patterns },
        }
    }
}

/// The run: every step not done, in order, on the rig's devices; returns how it ended and
/// the devices.
pub(crate) async fn run(mut core: Core, mut rig: Rig) -> (RunOutcome, RigDevices) {
    core.start_s = core.now();
    core.last_mark_s = core.start_s;
    let n = core.steps.len();
    let mut next = 0;
    // Gonio only: the step whose last exposure is triggered, read during the next move.
    let mut pending: Option<Pending> = None;
    loop {
        core.poll_commands();
        let stopping = core.pause_req || core.abort_req;
        // Skip steps already done (resume); at the end, or when asked to stop, finish the
        // step under way (its frame) first.
        while !stopping && next < n && core.done.contains(&core.steps[next].key) {
            core.skipped += 1;
            next += 1;
            core.progress();
        }
        if stopping || next == n {
            if let (Some(p), Rig::Gonio(g)) = (pending.take(), &mut rig) {
                if let Err(stop) = g.finish_pending(&mut core, p).await {
                    if !core.on_stop(stop, &mut next).await {
                        return (core.aborted(), rig.into_devices());
                    }
                    continue;
                }
            }
            if core.abort_req {
                return (core.aborted(), rig.into_devices());
            }
            if core.pause_req {
                if !core.pause(PauseReason::Requested).await {
                    return (core.aborted(), rig.into_devices());
                }
                continue;
            }
            return (core.finished(), rig.into_devices());
        }
        let r = match &mut rig {
            Rig::Gonio(g) if core.s.overlap => g.overlapped_step(&mut core, next, pending.take()).await.map(Some),
            Rig::Gonio(g) => g.sequential_step(&mut core, next).await.map(|()| None),
            Rig::Dome(d) => d.step(&mut core, next).await.map(|()| None),
        };
        match r {
            Ok(p) => {
                pending = p;
                next += 1;
            }
            Err(stop) => {
                if !core.on_stop(stop, &mut next).await {
                    return (core.aborted(), rig.into_devices());
                }
            }
        }
    }
}
