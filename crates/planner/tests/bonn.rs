//! Acceptance of issue 3 (timing model only, no devices): the full Bonn 81 x 81 plan.

use std::time::Instant;

use btfrig_core::config::{geometry::GonioGeometry, timing::TimingConfig};
use btfrig_core::kinematics::{Gonio, UnreachableKind};
use btfrig_core::sampling::Sampling;
use btfrig_planner::{format_hms, plan, DiskEstimate, PlanRequest, SkipKind};

#[test]
fn bonn_81x81_optimised_within_2_percent_of_lower_bound_and_faster_than_naive() {
    let gonio = Gonio::new(GonioGeometry::bonn()).unwrap();
    let s = Sampling::bonn81();
    let timing = TimingConfig::bonn();
    let frame_bytes = timing.camera.frame_bytes.unwrap();
    let req = PlanRequest::new(&gonio, &s, &s, &timing, 0.01, frame_bytes);
    let t0 = Instant::now();
    let schedule = plan(&req).unwrap();
    let wall = t0.elapsed().as_secs_f64();
    let hw = schedule.timing.hardware_s;
    let lb = schedule.critical_path_s;
    let naive = schedule.naive_order_hardware_s;
    println!(
        "bonn 81x81: captures {} hardware_s {hw:.1} ({}) naive {naive:.1} ({}) critical_path {lb:.1} ({}) \
         above bound {:.3} % ({:.3} s) naive above bound {:.3} % idle {:.1} s planning wall {wall:.3} s",
        schedule.captures.len(),
        format_hms(hw),
        format_hms(naive),
        format_hms(lb),
        100.0 * (hw / lb - 1.0),
        hw - lb,
        100.0 * (naive / lb - 1.0),
        schedule.timing.idle_s,
    );
    println!(
        "{}",
        schedule
            .dry_run(DiskEstimate { raw_bytes_per_capture: frame_bytes, texture_bytes_per_capture: 256 * 256 * 3 * 2 })
    );
    assert_eq!(schedule.captures.len(), 6480);
    // Every reachable pair exactly once in the order.
    let mut seen = vec![0u32; 81 * 81];
    for &i in &schedule.order {
        let c = &schedule.captures[i];
        seen[c.light_index * 81 + c.view_index] += 1;
    }
    for l in 0..81 {
        for v in 0..81 {
            let want = u32::from(gonio.ik(s.get(l), s.get(v)).is_ok());
            assert_eq!(seen[l * 81 + v], want, "pair ({l}, {v})");
        }
    }
    assert_eq!(
        schedule.dry_run(DiskEstimate::default()).skipped,
        vec![(SkipKind::Unreachable(UnreachableKind::CameraBlocksLamp), 81)]
    );
    assert!(lb <= hw + 1e-6);
    assert!(hw <= 1.02 * lb, "hardware {hw} vs bound {lb}");
    assert!(hw < naive, "optimised {hw} not faster than naive {naive}");
    // Quality kept from before the ordering was bounded (issue 24): 37002.3 s, which is the
    // lower bound itself; planning speed is printed above, not asserted (shared machine).
    assert!(hw <= lb + 0.01, "hardware {hw} vs bound {lb}");
}
