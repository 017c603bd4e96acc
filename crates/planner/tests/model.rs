//! Timing model, ordering and bound against hand computation and brute force.

use btfrig_core::config::{geometry::GonioGeometry, timing::TimingConfig};
use btfrig_core::kinematics::{Gonio, JointState};
use btfrig_core::sampling::Sampling;
use btfrig_core::Direction;
use btfrig_planner::{
    expand, naive_order, optimise_order, plan, schedule_expansion, OrderOptions, PairSelection, PlanCapture, PlanError,
    PlanRequest, SkipKind, Start, TimingModel,
};
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn deg(d: f64) -> f64 {
    d.to_radians()
}

fn cap(rail_deg: f64, robot_deg: [f64; 3], exposure_s: f64) -> PlanCapture {
    PlanCapture {
        light_index: 0,
        view_index: 0,
        light: Direction::new(0.0, 0.0),
        view: Direction::new(0.0, 0.0),
        joints: JointState { rail: deg(rail_deg), robot: robot_deg.map(deg), turntable: 0.0 },
        exposure_s,
        frame_bytes: 12_000_000,
    }
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() < 1e-9
}

#[test]
fn single_step_matches_hand_computation() {
    let m = TimingModel::new(&TimingConfig::bonn());
    let to = cap(60.0, [30.0, 0.0, 90.0], 0.01);
    let home = JointState::default();
    let mv = m.move_time(&home, &to.joints);
    // pan 30 deg at 60 deg/s, 120 deg/s^2: exactly at the full-speed threshold v^2/a = 30:
    // 0.5 + 0.5 s. roll 90 deg at 90, 180: 90/90 + 90/180 = 1.5 s. Robot 1.5 + settle 0.3.
    assert!(close(mv.robot_s, 1.8), "{mv:?}");
    // rail 60 deg at 30, 60: 60/30 + 30/60 = 2.5 s, settle 0.5.
    assert!(close(mv.rail_s, 3.0), "{mv:?}");
    assert_eq!(mv.turntable_s, 0.0);
    assert!(close(mv.total_s(), 3.0));
    let step = m.step_time(Some(&home), None, &to);
    assert!(close(step.move_s, 3.0));
    assert!(close(step.command_s, 0.05));
    assert!(close(step.trigger_s, 0.1 + 0.01 + 0.6));
    assert!(close(step.transfer_s, 5.0));
    assert!(close(step.sequential_s(), 8.76));
    // Same exposure: no command. Triangle profile: rail 3.75 deg, peak speed sqrt(60*3.75)
    // = 15 deg/s < 30, t = 2 sqrt(3.75/60) = 0.5 s, + settle 0.5.
    let near = cap(63.75, [30.0, 0.0, 90.0], 0.01);
    let step = m.step_time(Some(&to.joints), Some(0.01), &near);
    assert!(close(step.command_s, 0.0));
    assert!(close(step.move_s, 1.0), "{step:?}");
    // No motion: no settle either.
    assert_eq!(m.step_time(Some(&near.joints), Some(0.01), &near).move_s, 0.0);
}

#[test]
fn three_step_toy_overlaps_moves_with_transfers() {
    let m = TimingModel::new(&TimingConfig::bonn());
    let caps = [cap(20.0, [0.0; 3], 0.01), cap(20.0, [30.0, 0.0, 0.0], 0.01), cap(175.0, [30.0, 0.0, 0.0], 0.02)];
    let t = m.schedule_time(&caps, &[0, 1, 2], &Start::homed());
    let s = &t.per_step;
    // Step 0: rail 20 deg from home (20/30 + 0.5 s + settle 0.5) while the exposure command
    // (0.05 s) runs; then trigger 0.71 s, transfer 5 s.
    let r0 = 20.0 / 30.0 + 1.0;
    assert!(close(s[0].move_end_s, r0) && close(s[0].trigger_start_s, r0));
    assert!(close(s[0].trigger_end_s, r0 + 0.71) && close(s[0].transfer_end_s, r0 + 5.71));
    assert!(close(s[0].camera_idle_s, r0 - 0.05));
    // Step 1: pan 30 deg (1.0 + settle 0.3 s) starts when step 0's read-out is done and is
    // hidden under its transfer; the trigger waits for the camera, not for the robot.
    assert!(close(s[1].move_start_s, r0 + 0.71) && close(s[1].move_end_s, r0 + 2.01));
    assert!(close(s[1].trigger_start_s, r0 + 5.71) && s[1].camera_idle_s == 0.0 && s[1].command_s == 0.0);
    assert!(close(s[1].transfer_end_s, r0 + 11.42));
    // Step 2: rail 155 deg (155/30 + 0.5 + settle 0.5 = 6.1667 s) from r0 + 6.42 outlasts the
    // transfer plus the exposure command (ready at r0 + 11.47).
    let r2 = 155.0 / 30.0 + 1.0;
    assert!(close(s[2].move_start_s, r0 + 6.42) && close(s[2].move_end_s, r0 + 6.42 + r2));
    assert!(close(s[2].command_s, 0.05));
    assert!(close(s[2].camera_idle_s, 6.42 + r2 - 11.47));
    assert!(close(s[2].trigger_end_s, r0 + 6.42 + r2 + 0.72));
    assert!(close(t.hardware_s, r0 + 6.42 + r2 + 0.72 + 5.0));
    assert!(close(t.hardware_s, t.capture_s + t.transfer_s + t.idle_s));
    assert!(close(t.transfer_s, 15.0) && close(t.capture_s, 0.76 + 0.71 + 0.77));
    assert!(close(t.motion_s, r0 + 1.3 + r2));
    // The bound: shortest first move (r0) + every trigger and transfer + one more exposure
    // command (two exposure values, the camera's exposure unknown at the start).
    let lb = m.critical_path_s(&caps, &Start::homed());
    assert!(close(lb, r0 + 0.71 + 0.71 + 0.72 + 15.0 + 0.05), "{lb}");
    assert!(lb <= t.hardware_s);
    // Order 0, 2, 1 makes the long rail move twice (20 -> 175 -> 20), once with a command:
    // more waiting.
    let t2 = m.schedule_time(&caps, &[0, 2, 1], &Start::homed());
    assert!(t2.hardware_s > t.hardware_s);
}

fn bonn_subset(n: usize, seed: u64) -> Vec<(usize, usize)> {
    let mut all: Vec<(usize, usize)> = (0..81).flat_map(|l| (0..81).map(move |v| (l, v))).collect();
    all.shuffle(&mut ChaCha8Rng::seed_from_u64(seed));
    all.truncate(n);
    all
}

/// A rig whose motion is five times slower: moves no longer hide under the transfer.
fn slow_timing() -> TimingConfig {
    let mut t = TimingConfig::bonn();
    t.robot.max_speed_deg_per_s = t.robot.max_speed_deg_per_s.map(|v| v / 5.0);
    t.robot.accel_deg_per_s2 = t.robot.accel_deg_per_s2.map(|v| v / 5.0);
    t.rail.max_speed_deg_per_s /= 5.0;
    t.rail.accel_deg_per_s2 /= 5.0;
    t
}

#[test]
fn lower_bound_holds_for_random_orders_and_mixed_exposures() {
    let gonio = Gonio::new(GonioGeometry::bonn()).unwrap();
    let s = Sampling::bonn81();
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    for timing in [TimingConfig::bonn(), slow_timing()] {
        let model = TimingModel::new(&timing);
        let mut ex = expand(&gonio, &s, &s, &PairSelection::List(bonn_subset(120, 3)), 0.01, 12_000_000).unwrap();
        // Three exposure values and two frame sizes make commands and transfers vary.
        for c in &mut ex.captures {
            c.exposure_s = [0.01, 0.02, 0.05][rng.gen_range(0..3)];
            c.frame_bytes = [6_000_000, 12_000_000][rng.gen_range(0..2)];
        }
        for start in [Start::homed(), Start::default(), Start { joints: None, exposure_s: Some(0.02) }] {
            let lb = model.critical_path_s(&ex.captures, &start);
            let mut order: Vec<usize> = (0..ex.captures.len()).collect();
            for _ in 0..200 {
                order.shuffle(&mut rng);
                let t = model.schedule_time(&ex.captures, &order, &start);
                assert!(lb <= t.hardware_s + 1e-9, "bound {lb} above an order's {}", t.hardware_s);
                assert!((t.hardware_s - (t.capture_s + t.transfer_s + t.idle_s)).abs() < 1e-6);
            }
            let opt = optimise_order(&model, &ex.captures, &start, &OrderOptions::default());
            let t_opt = model.schedule_time(&ex.captures, &opt, &start).hardware_s;
            let t_naive = model.schedule_time(&ex.captures, &naive_order(&ex.captures), &start).hardware_s;
            assert!(lb <= t_opt + 1e-9 && t_opt <= t_naive + 1e-9, "lb {lb} opt {t_opt} naive {t_naive}");
        }
    }
}

#[test]
fn lower_bound_is_exact_on_tiny_instances_by_brute_force() {
    // With every move hidden the bound is reached; brute force over all 5! orders confirms
    // the optimiser finds the best order and nothing beats the bound.
    let model = TimingModel::new(&slow_timing());
    let caps = [
        cap(20.0, [0.0; 3], 0.01),
        cap(40.0, [10.0, 0.0, 0.0], 0.01),
        cap(90.0, [10.0, 20.0, 0.0], 0.01),
        cap(150.0, [0.0, 20.0, 90.0], 0.01),
        cap(100.0, [0.0; 3], 0.01),
    ];
    let start = Start::homed();
    let lb = model.critical_path_s(&caps, &start);
    let mut best = f64::INFINITY;
    let mut perm = [0usize, 1, 2, 3, 4];
    permutations(&mut perm, 0, &mut |o| best = best.min(model.schedule_time(&caps, o, &start).hardware_s));
    let opt = optimise_order(&model, &caps, &start, &OrderOptions::default());
    let t_opt = model.schedule_time(&caps, &opt, &start).hardware_s;
    assert!(lb <= best + 1e-9);
    assert!(t_opt <= best + 1e-6, "opt {t_opt} best {best}");
}

fn permutations(a: &mut [usize; 5], k: usize, f: &mut impl FnMut(&[usize])) {
    if k == a.len() {
        f(a);
        return;
    }
    for i in k..a.len() {
        a.swap(k, i);
        permutations(a, k + 1, f);
        a.swap(k, i);
    }
}

#[test]
fn optimised_order_is_a_permutation_and_deterministic() {
    let gonio = Gonio::new(GonioGeometry::bonn()).unwrap();
    let s = Sampling::bonn81();
    let timing = slow_timing();
    let pairs = PairSelection::List(bonn_subset(1500, 11));
    let req = PlanRequest::new(&gonio, &s, &s, &timing, 0.01, 12_000_000).with_pairs(pairs.clone());
    let a = plan(&req).unwrap();
    let b = plan(&req).unwrap();
    assert_eq!(a, b);
    let mut seen = vec![0u32; a.captures.len()];
    for &i in &a.order {
        seen[i] += 1;
    }
    assert!(seen.iter().all(|&n| n == 1));
    // Every requested pair is either captured or skipped, exactly once.
    let PairSelection::List(list) = pairs else { unreachable!() };
    let mut got: Vec<(usize, usize)> = a
        .captures
        .iter()
        .map(|c| (c.light_index, c.view_index))
        .chain(a.skipped.iter().map(|s| (s.light_index, s.view_index)))
        .collect();
    let mut want = list.clone();
    got.sort_unstable();
    want.sort_unstable();
    assert_eq!(got, want);
    // Steps follow the order.
    assert!(a.steps().zip(&a.order).all(|((c, t), &i)| t.capture == i && *c == a.captures[i]));
}

#[test]
fn slow_motion_rig_optimised_order_beats_naive_clearly() {
    let gonio = Gonio::new(GonioGeometry::bonn()).unwrap();
    let s = Sampling::bonn81();
    let timing = slow_timing();
    let req = PlanRequest::new(&gonio, &s, &s, &timing, 0.01, 12_000_000);
    let t0 = std::time::Instant::now();
    let p = plan(&req).unwrap();
    let wall = t0.elapsed().as_secs_f64();
    let (hw, naive, lb) = (p.timing.hardware_s, p.naive_order_hardware_s, p.critical_path_s);
    println!(
        "slow rig (motion / 5): hardware {hw:.0} s, naive {naive:.0} s ({:+.1} %), bound {lb:.0} s ({:.2} % above), wall {wall:.2} s",
        100.0 * (naive / hw - 1.0),
        100.0 * (hw / lb - 1.0)
    );
    assert!(lb <= hw + 1e-6);
    assert!(hw < 0.95 * naive, "optimised {hw} vs naive {naive}");
    // Nearest neighbour alone, for the record (docs/planner.md).
    let model = TimingModel::new(&timing);
    let nn = optimise_order(&model, &p.captures, &p.start, &OrderOptions { max_passes: 0, ..OrderOptions::default() });
    let nn_s = model.schedule_time(&p.captures, &nn, &p.start).hardware_s;
    println!("slow rig nearest neighbour only: {nn_s:.0} s");
    // The improvement passes must help beyond the construction; and the result stays where
    // it was before the ordering was bounded (37004 s against the bound 37004 s, issue 24).
    // Planning speed is printed above, not asserted (shared machine).
    assert!(hw < nn_s, "improved {hw} not below nearest neighbour {nn_s}");
    assert!(hw <= 1.001 * lb, "hardware {hw} vs bound {lb}");
}

#[test]
fn bad_requests_name_the_input_and_not_needed_hook_counts() {
    let gonio = Gonio::new(GonioGeometry::bonn()).unwrap();
    let s = Sampling::bonn81();
    let e = expand(&gonio, &s, &s, &PairSelection::List(vec![(0, 81)]), 0.01, 1).unwrap_err();
    assert_eq!(e, PlanError::PairOutOfRange { light_index: 0, view_index: 81, lights: 81, views: 81 });
    assert!(e.to_string().contains("view 81") && e.to_string().contains("81 views"), "{e}");
    let e = expand(&gonio, &s, &s, &PairSelection::List(vec![(1, 2), (1, 2)]), 0.01, 1).unwrap_err();
    assert_eq!(e, PlanError::DuplicatePair { light_index: 1, view_index: 2 });
    assert!(matches!(expand(&gonio, &s, &s, &PairSelection::All, f64::NAN, 1), Err(PlanError::BadExposure { .. })));
    assert!(matches!(expand(&gonio, &s, &s, &PairSelection::All, 0.0, 1), Err(PlanError::BadExposure { .. })));
    assert_eq!(expand(&gonio, &s, &s, &PairSelection::All, 0.01, 0), Err(PlanError::ZeroFrameBytes));

    let mut ex = expand(&gonio, &s, &s, &PairSelection::List(vec![(0, 1), (1, 0), (2, 2), (3, 4)]), 0.01, 1).unwrap();
    assert_eq!(ex.captures.len(), 3);
    // Reciprocity stand-in: (1, 0) repeats (0, 1).
    ex.mark_not_needed(|c| (c.light_index > c.view_index).then(|| "reciprocal of a captured pair".to_string()));
    assert_eq!(ex.captures.len(), 2);
    let counts = ex.skip_counts();
    assert_eq!(counts.len(), 2);
    assert_eq!(counts[1], (SkipKind::NotNeeded, 1));
    assert_eq!(counts[0].1, 1); // (2, 2): the camera blocks the lamp
    let model = TimingModel::new(&TimingConfig::bonn());
    let sched = schedule_expansion("bonn81", "bonn81", ex, &model, &Start::homed(), &OrderOptions::default());
    let text = sched.to_string();
    assert!(
        text.contains("not needed") && text.contains("camera blocks lamp") && text.contains("captures         2"),
        "{text}"
    );
}
