//! Move-time profile of an axis with limited speed and acceleration.
//!
//! An axis accelerates at `a` up to at most `v`, cruises, and decelerates at `a`. For a
//! distance `d`:
//!
//! * if `d >= v^2 / a` (the axis reaches top speed): trapezoid, `t = d / v + v / a`;
//! * otherwise: triangle, peak speed `sqrt(a d)`, `t = 2 sqrt(d / a)`.
//!
//! Both agree at `d = v^2 / a` (`t = 2 v / a`).

/// Time to travel `distance` (any unit, sign ignored) with top speed `max_speed` and
/// acceleration `accel` in the same unit per second and per second squared. Zero distance
/// takes zero time.
pub fn move_time_s(distance: f64, max_speed: f64, accel: f64) -> f64 {
    let d = distance.abs();
    if d == 0.0 {
        return 0.0;
    }
    if d >= max_speed * max_speed / accel {
        d / max_speed + max_speed / accel
    } else {
        2.0 * (d / accel).sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trapezoid_and_triangle_cases() {
        // v = 10, a = 20: top speed after 0.5 s and 2.5 units; full-speed threshold 5 units.
        assert_eq!(move_time_s(0.0, 10.0, 20.0), 0.0);
        // Triangle: 1.25 units up and 1.25 down, each in sqrt(2*1.25/20) = 0.3536 s.
        assert!((move_time_s(2.5, 10.0, 20.0) - 2.0 * (2.5f64 / 20.0).sqrt()).abs() < 1e-12);
        // Threshold: 0.5 s up + 0.5 s down, no cruise.
        assert!((move_time_s(5.0, 10.0, 20.0) - 1.0).abs() < 1e-12);
        // Trapezoid: 5 units in ramps (1 s) + 95 units at 10/s (9.5 s).
        assert!((move_time_s(-100.0, 10.0, 20.0) - 10.5).abs() < 1e-12);
        // Continuity just below the threshold.
        assert!((move_time_s(5.0 - 1e-9, 10.0, 20.0) - 1.0).abs() < 1e-6);
    }
}
