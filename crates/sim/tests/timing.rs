//! The timing model: move durations against the analytic trapezoid, and a whole Bonn-sized
//! run in virtual time.

mod common;

use std::time::Instant;

use btfrig_core::config::timing::TimingConfig;
use btfrig_hw::MoveOptions;
use btfrig_sim::FaultScenario;
use common::*;

const OPTS: MoveOptions = MoveOptions::with_timeout_s(60.0);
/// tokio's timer rounds each deadline up to the next millisecond.
const TICK: f64 = 0.0011;

#[tokio::test(start_paused = true)]
async fn robot_and_rail_moves_take_the_trapezoid_time() {
    let mut rig = rig(&devices(""), 1, &FaultScenario::none());
    let clock = rig.world.clock().clone();
    let t = TimingConfig::bonn();
    let settle = t.robot.settle_s;

    // Joint 0: 90 deg at 60 deg/s, 120 deg/s^2: reaches speed after 0.5 s (15 deg), so
    // trapezoid: 90/60 + 60/120 = 2.0 s, plus settle.
    let t0 = clock.now_s();
    rig.robot.move_to_rad([90f64.to_radians(), 0.0, 0.0], OPTS).await.unwrap();
    let dt = clock.now_s() - t0;
    assert!((dt - (2.0 + settle)).abs() < TICK, "{dt}");

    // Joint 1: 10 deg < v^2/a = 30 deg: triangle, 2 sqrt(10/120) = 0.577 s. Joint 2 moves
    // 20 deg at 90 deg/s, 180 deg/s^2 (threshold 45 deg): triangle 2 sqrt(20/180) = 0.667 s.
    // Joints move together: the slowest decides.
    let t0 = clock.now_s();
    rig.robot.move_to_rad([90f64.to_radians(), 10f64.to_radians(), 20f64.to_radians()], OPTS).await.unwrap();
    let dt = clock.now_s() - t0;
    let expect = 2.0 * (20.0f64 / 180.0).sqrt() + settle;
    assert!((dt - expect).abs() < TICK, "{dt} vs {expect}");

    // Zero move: no time, no settle.
    let t0 = clock.now_s();
    rig.robot.move_to_rad([90f64.to_radians(), 10f64.to_radians(), 20f64.to_radians()], OPTS).await.unwrap();
    assert_eq!(clock.now_s(), t0);

    // Rail: 120 deg at 30 deg/s, 60 deg/s^2: 120/30 + 30/60 = 4.5 s, plus settle 0.5 s.
    let t0 = clock.now_s();
    rig.rail.move_to_rad(120f64.to_radians(), OPTS).await.unwrap();
    let dt = clock.now_s() - t0;
    assert!((dt - 5.0).abs() < TICK, "{dt}");
}

#[tokio::test(start_paused = true)]
async fn homing_lamp_warm_up_and_camera_take_their_configured_times() {
    let mut rig = rig(&devices("[robot]\nkind = \"sim\"\n"), 1, &FaultScenario::none());
    let clock = rig.world.clock().clone();
    let t = TimingConfig::bonn();

    let t0 = clock.now_s();
    rig.robot.home(OPTS).await.unwrap();
    assert!((clock.now_s() - t0 - t.robot.home_s).abs() < TICK);

    let t0 = clock.now_s();
    rig.lamp.set_on(true).await.unwrap();
    rig.lamp.wait_ready(600.0).await.unwrap();
    assert!((clock.now_s() - t0 - t.lamp.warm_up_s - t.lamp.switch_s).abs() < 2.0 * TICK);

    // Capture: latency + exposure + read-out, then 12 MB at 2.4 MB/s.
    let c = &t.camera;
    let t0 = clock.now_s();
    rig.camera.trigger(30.0).await.unwrap();
    let t1 = clock.now_s();
    rig.camera.read_frame(30.0).await.unwrap();
    let t2 = clock.now_s();
    assert!((t1 - t0 - (c.trigger_latency_s + 0.2 + c.read_out_s)).abs() < 2.0 * TICK, "{}", t1 - t0);
    assert!((t2 - t1 - 12e6 / 2.4e6).abs() < TICK, "{}", t2 - t1);
}

/// The Bonn 81-direction table, degrees.
fn bonn81() -> Vec<(f64, f64)> {
    let rings = [(0.0, 1), (15.0, 6), (30.0, 12), (45.0, 18), (60.0, 20), (75.0, 24)];
    let mut v = Vec::new();
    for (theta, n) in rings {
        for k in 0..n {
            v.push((theta, 360.0 / n as f64 * k as f64));
        }
    }
    v
}

fn unit(theta_deg: f64, phi_deg: f64) -> [f64; 3] {
    let (t, p) = (theta_deg.to_radians(), phi_deg.to_radians());
    [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()]
}

/// A whole Bonn run (81 views x 81 lights, views outer) with a stand-in for the inverse
/// kinematics that produces moves of the right size: the rail angle is the angle between
/// light and view, the robot's joints follow the light's azimuth and elevation and the
/// view's azimuth. Capture is sequential (move, trigger, read), as in the Bonn setup.
#[tokio::test(start_paused = true)]
async fn bonn_run_of_6561_images_takes_about_14_hours_of_virtual_time() {
    let wall = Instant::now();
    let mut rig = rig(&devices(""), 7, &FaultScenario::none());
    let clock = rig.world.clock().clone();
    rig.lamp.set_on(true).await.unwrap();
    rig.lamp.wait_ready(600.0).await.unwrap();
    let dirs = bonn81();
    let start = clock.now_s();
    let (mut t_move, mut t_expose, mut t_transfer) = (0.0, 0.0, 0.0);
    let mut frames = 0;
    for &(tv, pv) in &dirs {
        for &(tl, pl) in &dirs {
            let (l, v) = (unit(tl, pl), unit(tv, pv));
            let rail = (l[0] * v[0] + l[1] * v[1] + l[2] * v[2]).clamp(-1.0, 1.0).acos();
            let wrap = |a: f64| if a >= 180.0 { a - 360.0 } else { a };
            let robot = [wrap(pl).to_radians(), (tl - 45.0).to_radians(), wrap(pv).to_radians()];
            let t0 = clock.now_s();
            let (r1, r2) = (rig.rail.move_to_rad(rail, OPTS), rig.robot.move_to_rad(robot, OPTS));
            // Rail and robot are separate devices: they move at the same time.
            let (a, b) = tokio::join!(r1, r2);
            a.unwrap();
            b.unwrap();
            let t1 = clock.now_s();
            rig.camera.trigger(30.0).await.unwrap();
            let t2 = clock.now_s();
            let f = rig.camera.read_frame(30.0).await.unwrap();
            let t3 = clock.now_s();
            assert_eq!(f.meta.sequence, frames);
            frames += 1;
            t_move += t1 - t0;
            t_expose += t2 - t1;
            t_transfer += t3 - t2;
        }
    }
    let total_h = (clock.now_s() - start) / 3600.0;
    let per = |t: f64| t / frames as f64;
    println!(
        "6561 images: {total_h:.2} h simulated, per image: move {:.2} s, trigger+exposure+read-out {:.2} s, transfer {:.2} s; wall {:?}",
        per(t_move),
        per(t_expose),
        per(t_transfer),
        wall.elapsed()
    );
    assert_eq!(frames, 6561);
    assert!((12.5..15.5).contains(&total_h), "{total_h} h");
    // Transfer dominates, as in Bonn.
    assert!(t_transfer > 0.6 * (clock.now_s() - start));
}
