//! Planning time and quality of plans far larger than Bonn's (issue 24): the ordering is
//! bounded beyond `EXACT_MAX_CAPTURES`, so 100 000 captures plan in seconds, not hours.
//! Times are printed (`--nocapture`), never asserted; the assertions are about the order.

use std::time::Instant;

use btfrig_core::config::{geometry::GonioGeometry, timing::TimingConfig};
use btfrig_core::direction::Direction;
use btfrig_core::kinematics::Gonio;
use btfrig_core::sampling::Sampling;
use btfrig_planner::order::EXACT_MAX_CAPTURES;
use btfrig_planner::{plan, Cancel, PlanError, PlanRequest};

/// `rings` rings of `per_ring` directions between theta 2 and 80 degrees.
fn rings(name: &str, rings: usize, per_ring: usize) -> Sampling {
    let mut dirs = Vec::new();
    for r in 0..rings {
        let theta = 2.0 + 78.0 * r as f64 / (rings - 1) as f64;
        for j in 0..per_ring {
            dirs.push(Direction::from_degrees(theta, j as f64 * 360.0 / per_ring as f64 + r as f64));
        }
    }
    Sampling::from_list(name, dirs).unwrap()
}

#[test]
fn a_plan_of_about_100000_captures_is_ordered_in_bounded_time_and_beats_the_naive_order() {
    let gonio = Gonio::new(GonioGeometry::bonn()).unwrap();
    let s = rings("rings-10x32", 10, 32);
    // Bonn timing, and motion five times slower (moves no longer hide under transfers).
    let mut slow = TimingConfig::bonn();
    slow.robot.max_speed_deg_per_s = slow.robot.max_speed_deg_per_s.map(|v| v / 5.0);
    slow.robot.accel_deg_per_s2 = slow.robot.accel_deg_per_s2.map(|v| v / 5.0);
    slow.rail.max_speed_deg_per_s /= 5.0;
    slow.rail.accel_deg_per_s2 /= 5.0;
    for (label, timing) in [("bonn", TimingConfig::bonn()), ("slow motion", slow)] {
        let req = PlanRequest::new(&gonio, &s, &s, &timing, 0.01, timing.camera.frame_bytes.unwrap());
        let t0 = Instant::now();
        let p = plan(&req).unwrap();
        let wall = t0.elapsed().as_secs_f64();
        let (hw, naive, lb) = (p.timing.hardware_s, p.naive_order_hardware_s, p.critical_path_s);
        println!(
        "{label}: {} captures ({} requested): planning wall {wall:.2} s, hardware {hw:.0} s, naive {naive:.0} s, bound {lb:.0} s ({:.3} % above)",
        p.captures.len(),
        p.requested,
        100.0 * (hw / lb - 1.0)
    );
        assert!(p.captures.len() > EXACT_MAX_CAPTURES, "the bounded ordering is what this test is about");
        let mut seen = vec![false; p.captures.len()];
        for &i in &p.order {
            assert!(!std::mem::replace(&mut seen[i], true), "capture {i} twice");
        }
        assert!(seen.iter().all(|&s| s), "every capture in the order");
        assert!(lb <= hw + 1e-6 && hw < naive, "bound {lb} hardware {hw} naive {naive}");
    }
}

#[test]
fn a_cancelled_request_plans_nothing() {
    let gonio = Gonio::new(GonioGeometry::bonn()).unwrap();
    let s = rings("rings-10x32", 10, 32);
    let timing = TimingConfig::bonn();
    let cancel = Cancel::new();
    cancel.cancel();
    let req = PlanRequest::new(&gonio, &s, &s, &timing, 0.01, timing.camera.frame_bytes.unwrap()).with_cancel(&cancel);
    assert_eq!(plan(&req).map(|p| p.captures.len()), Err(PlanError::Cancelled));
}
