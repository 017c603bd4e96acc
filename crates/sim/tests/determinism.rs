//! Same seed, same faults and jitter; different seed, different ones. Also a flaky run with
//! retries completes.

mod common;

use btfrig_hw::{ErrorKind, MoveOptions};
use btfrig_sim::{FaultEvent, FaultKind};
use common::*;

/// Runs `steps` capture steps under the flaky scenario with a retrying engine; returns the
/// fault log, the true joint states after each move, the frame checksums and the retry count.
async fn flaky_run(seed: u64, steps: usize) -> (Vec<FaultEvent>, Vec<[f64; 3]>, u32) {
    let mut rig = rig(&devices(""), seed, &scenario("flaky"));
    let opts = MoveOptions::with_timeout_s(30.0);
    let mut truths = Vec::new();
    let mut retries = 0;
    for i in 0..steps {
        let target = [((i % 24) as f64 * 15.0 - 180.0).to_radians(), 0.1 * (i % 5) as f64, 0.0];
        loop {
            match rig.robot.move_to_rad(target, opts).await {
                Ok(_) => break,
                Err(e) if e.is_retryable() => retries += 1,
                Err(e) => panic!("{e}"),
            }
        }
        truths.push(rig.world.truth().joints.robot);
        let mut attempts = 0;
        loop {
            match rig.camera.capture(30.0).await {
                Ok(_) => break,
                Err(e) if e.is_retryable() && attempts < 10 => {
                    attempts += 1;
                    retries += 1;
                    if e.kind() == ErrorKind::Disconnected {
                        let _ = rig.camera.reconnect().await;
                    }
                }
                Err(e) => panic!("{e}"),
            }
        }
    }
    (rig.world.fault_log(), truths, retries)
}

#[tokio::test(start_paused = true)]
async fn same_seed_same_faults_and_jitter() {
    let (log_a, truth_a, retries_a) = flaky_run(11, 3000).await;
    let (log_b, truth_b, retries_b) = flaky_run(11, 3000).await;
    assert_eq!(log_a, log_b);
    assert_eq!(truth_a, truth_b);
    assert_eq!(retries_a, retries_b);
    // The scenario's fixed faults are there, plus random ones.
    let has = |kind: FaultKind, device: &str| log_a.iter().any(|f| f.kind == kind && f.device == device);
    assert!(has(FaultKind::Timeout, "robot"));
    assert!(has(FaultKind::Disconnected, "camera"));
    assert!(has(FaultKind::DroppedFrame, "camera"));
    assert!(log_a.iter().any(|f| f.device == "robot" && f.call == 40 && f.kind == FaultKind::Timeout));
    assert!(log_a.len() > 10, "{}", log_a.len());
    println!("flaky, 3000 steps: {} faults, {} retries", log_a.len(), retries_a);

    let (log_c, truth_c, _) = flaky_run(12, 3000).await;
    assert_ne!(truth_a, truth_c);
    // Fixed faults repeat, random ones move.
    let times = |l: &[FaultEvent]| l.iter().map(|f| (f.device.clone(), f.call)).collect::<Vec<_>>();
    assert_ne!(times(&log_a), times(&log_c));
}

#[tokio::test(start_paused = true)]
async fn device_info_names_the_backend() {
    let rig = rig(&devices(""), 1, &btfrig_sim::FaultScenario::none());
    assert_eq!(rig.robot.info().backend, "sim");
    assert_eq!(rig.rail.name(), "rail");
    assert_eq!(rig.camera.name(), "camera");
}
