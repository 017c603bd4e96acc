//! Registration on RENDERED frames through the detector (issue 4 acceptance): all 81 Bonn
//! views on two materials, and the stress cases. Run with
//! `cargo test --release -p btfrig-registration --test stress_frames -- --nocapture` to see the figures.

mod common;
mod frames_common;

use btfrig_core::Direction;
use frames_common::{print_view, summarise, Bench, Outcome};
use rayon::prelude::*;

fn no_edit(_: &frames_common::Shot, _: &mut frames_common::Frame) {}

#[test]
fn all_81_bonn_views_on_two_materials() {
    let t0 = std::time::Instant::now();
    let views = common::bonn_views();
    let mut all: Vec<Outcome> = Vec::new();
    for material in ["lacquered-wood", "corduroy"] {
        let bench = Bench::new(material);
        // The same true joints and sensor seeds for both materials.
        let outcomes: Vec<Outcome> =
            views.par_iter().enumerate().map(|(k, v)| bench.run(*v, 1.0, 4000 + k as u64, &no_edit)).collect();
        for o in &outcomes {
            print_view(material, o);
        }
        for theta in [0.0, 15.0, 30.0, 45.0, 60.0, 75.0] {
            let ring: Vec<Outcome> = outcomes
                .iter()
                .filter(|o| (o.shot.view.theta.to_degrees() - theta).abs() < 1.0)
                .map(|o| Outcome {
                    shot: o.shot.clone(),
                    result: o.result.clone(),
                    render_s: o.render_s,
                    corners: Vec::new(),
                })
                .collect();
            summarise(&format!("  {material} theta {theta}"), &ring);
        }
        summarise(&format!("bonn81 {material}"), &outcomes);
        all.extend(outcomes);
    }
    let s = summarise("bonn81 both materials", &all);
    println!("total {:.1} s", t0.elapsed().as_secs_f64());
    assert_eq!(s.views, 2 * views.len(), "every view registers");
    for o in &all {
        let m = o.result.as_ref().unwrap();
        let (t, p) = o.shot.view.to_degrees();
        assert_eq!(m.reg.detected.len(), 12, "view ({t:.0}, {p:.0}): all markers found");
        assert!(m.reg.registration.rejected_markers.is_empty(), "view ({t:.0}, {p:.0}): clean markers rejected");
        // The predicted sigma tracks the error. Measured: at most 1.85 predicted sigma with this
        // detector, 2.7 with the model-based edge fit on branch h-markers (which states smaller
        // sigmas); the 0.01 texel floor (a fifth of the acceptance) keeps sub-0.02-texel views
        // from failing on the detector's sigma calibration alone.
        assert!(m.est.0 < 3.0 * m.predicted + 0.01, "view ({t:.0}, {p:.0}): {:?} predicted {}", m.est, m.predicted);
    }
    // Issue 4's acceptance: mean under 0.05 texel, max under 0.2 texel at 256x256.
    assert!(s.mean < 0.05 && s.max < 0.2, "acceptance: mean {} max {}", s.mean, s.max);
    assert!(s.mean < s.nom_mean / 10.0, "registered {} nominal {}", s.mean, s.nom_mean);
}

/// Views at `theta` degrees, six azimuths.
fn ring(theta: f64) -> Vec<Direction> {
    (0..6).map(|k| Direction::from_degrees(theta, 15.0 + 60.0 * k as f64)).collect()
}

#[test]
fn grazing_views_at_75_and_80_degrees() {
    let bench = Bench::new("lacquered-wood");
    for theta in [75.0, 80.0] {
        let outcomes: Vec<Outcome> = ring(theta)
            .par_iter()
            .enumerate()
            .map(|(k, v)| bench.run_with(*v, 1.0, 5000 + k as u64 + theta as u64 * 100, &no_edit, true))
            .collect();
        for o in &outcomes {
            print_view(&format!("theta {theta}"), o);
        }
        let s = summarise(&format!("theta {theta}, 6 azimuths"), &outcomes);
        assert_eq!(s.views, 6, "theta {theta}: every view registers");
        for o in &outcomes {
            let m = o.result.as_ref().unwrap();
            assert!(m.reg.detected.len() >= 10, "theta {theta}: markers {:?}", m.reg.detected);
        }
        // The acceptance at both: since the detector fits its edge model on the genuine
        // green photosites, 80 degrees measures 0.017 / 0.075 texel (docs/registration.md).
        let (mean_bound, max_bound) = (0.05, 0.2);
        assert!(s.mean < mean_bound && s.max < max_bound, "theta {theta}: mean {} max {}", s.mean, s.max);
        assert!(s.mean < s.nom_mean / 4.0, "theta {theta}: registered {} nominal {}", s.mean, s.nom_mean);
        for o in &outcomes {
            let m = o.result.as_ref().unwrap();
            assert!(m.est.0 < 1.5 * m.predicted, "theta {theta}: error {:?} beyond predicted {}", m.est, m.predicted);
        }
    }
}

#[test]
fn half_the_markers_hidden() {
    let bench = Bench::new("lacquered-wood");
    // Every other marker, and one contiguous half of the ring (two sides).
    let patterns: [(&str, [u32; 6]); 2] = [("alternate", [0, 2, 4, 6, 8, 10]), ("contiguous", [0, 1, 2, 3, 4, 5])];
    let views = [(0.0, 0.0), (45.0, 90.0), (60.0, 200.0), (75.0, 300.0)].map(|(t, p)| Direction::from_degrees(t, p));
    for (name, hidden) in patterns {
        let outcomes: Vec<Outcome> = views
            .par_iter()
            .enumerate()
            .map(|(k, v)| bench.run(*v, 1.0, 6000 + k as u64, &|shot, frame| bench.hide_markers(shot, frame, &hidden)))
            .collect();
        for o in &outcomes {
            print_view(name, o);
        }
        let s = summarise(&format!("half hidden ({name} {hidden:?})"), &outcomes);
        assert_eq!(s.views, views.len(), "{name}: every view registers");
        for o in &outcomes {
            let m = o.result.as_ref().unwrap();
            let expect: Vec<u32> = (0..12).filter(|i| !hidden.contains(i)).collect();
            assert_eq!(m.reg.detected, expect, "{name}: exactly the visible markers are found");
        }
        assert!(s.mean < 0.05 && s.max < 0.2, "{name}: mean {} max {}", s.mean, s.max);
    }
}

#[test]
fn strong_noise_low_light_registers_or_refuses() {
    let bench = Bench::new("lacquered-wood");
    let views = [(0.0, 0.0), (45.0, 90.0), (75.0, 300.0)].map(|(t, p)| Direction::from_degrees(t, p));
    println!(
        "default exposure {:.4} s (white at {} of full scale)",
        bench.default_exposure(),
        frames_common::WHITE_FRACTION
    );
    // White at a fraction of the sensor's full scale at gain 1 (in electrons) (the shot noise of
    // low light); then low light at gain 16 (what an auto exposure does when the time is
    // capped: same electrons and shot noise, amplified; read noise is in electrons).
    let levels: Vec<(f64, f64)> = vec![
        (0.05, 1.0),
        (0.01, 1.0),
        (0.003, 1.0),
        (0.002, 1.0),
        (0.0015, 1.0),
        (0.001, 1.0),
        (0.0003, 1.0),
        (0.003, 16.0),
        (0.0015, 16.0),
    ];
    let exposures: Vec<(f64, f64)> =
        levels.iter().map(|&(f, g)| (bench.scene.exposure_for_white(f, 1e-7, 30.0), g)).collect();
    // One render per view, captured at every level.
    let per_view: Vec<Vec<Outcome>> = views
        .par_iter()
        .enumerate()
        .map(|(k, v)| {
            let shot = bench.shot(*v, 1.0, 7000 + k as u64);
            bench
                .capture_levels(&shot, &exposures, 7100 + k as u64)
                .into_iter()
                .map(|frame| Outcome {
                    shot: shot.clone(),
                    result: bench.measure(&bench.registrar, &shot, &frame),
                    render_s: frame.render_s,
                    corners: Vec::new(),
                })
                .collect()
        })
        .collect();
    let mut refused = 0;
    for (i, &(fraction, gain)) in levels.iter().enumerate() {
        let outcomes: Vec<Outcome> = per_view
            .iter()
            .map(|v| Outcome {
                shot: v[i].shot.clone(),
                result: v[i].result.clone(),
                render_s: 0.0,
                corners: Vec::new(),
            })
            .collect();
        let label = format!("white at {:.2}% of full scale (gain 1), gain {gain}", 100.0 * fraction);
        for o in &outcomes {
            print_view(&label, o);
        }
        summarise(&label, &outcomes);
        for o in &outcomes {
            match &o.result {
                // Never a silent wrong pose: what registers is within its predicted uncertainty.
                Ok(m) => assert!(
                    m.est.0 < 3.0 * m.predicted + 0.01 && m.est.1 < 6.0 * m.predicted + 0.02,
                    "{label}: a pose outside its predicted uncertainty: {:?} predicted {}",
                    m.est,
                    m.predicted
                ),
                Err(e) => {
                    refused += 1;
                    let text = e.to_string();
                    assert!(text.contains("registration needs at least 3 good markers"), "{label}: {text}");
                }
            }
        }
        if fraction >= 0.003 {
            assert!(outcomes.iter().all(|o| o.result.is_ok()), "{label}: every view registers");
        }
        if fraction <= 0.0003 {
            assert!(outcomes.iter().all(|o| o.result.is_err()), "{label}: nothing to see, every view refuses");
        }
    }
    println!("low light: {refused} of {} frames refused", levels.len() * views.len());
}

#[test]
fn three_times_the_robot_error() {
    let bench = Bench::new("corduroy");
    let views: Vec<Direction> = common::bonn_views().into_iter().step_by(8).collect();
    let outcomes: Vec<Outcome> =
        views.par_iter().enumerate().map(|(k, v)| bench.run(*v, 3.0, 8000 + k as u64, &no_edit)).collect();
    for o in &outcomes {
        print_view("3x", o);
    }
    let s = summarise("3x robot and rail error", &outcomes);
    assert_eq!(s.views, views.len(), "every view registers");
    assert!(s.mean < 0.05 && s.max < 0.2, "mean {} max {}", s.mean, s.max);
    assert!(s.nom_mean > 10.0 * s.mean && s.nom_max > 1.0, "nominal {} / {}", s.nom_mean, s.nom_max);
}

#[test]
fn degenerate_marker_sets_fail_clearly() {
    let bench = Bench::new("lacquered-wood");
    let view = Direction::from_degrees(45.0, 90.0);
    for (label, visible) in [("two markers", vec![0u32, 1]), ("one marker", vec![7]), ("no marker", vec![])] {
        let hidden: Vec<u32> = (0..12).filter(|i| !visible.contains(i)).collect();
        let o = bench.run(view, 1.0, 9000, &|shot, frame| bench.hide_markers(shot, frame, &hidden));
        print_view(label, &o);
        match &o.result {
            Err(
                e @ btfrig_registration::FrameError::Register {
                    detected,
                    source: btfrig_registration::RegisterError::TooFewMarkers { found, needed: 3, .. },
                    ..
                },
            ) => {
                assert_eq!(*found, visible.len(), "{label}");
                assert_eq!(detected, &visible, "{label}");
                let text = e.to_string();
                assert!(
                    text.contains(&format!("registration needs at least 3 good markers, found {}", visible.len())),
                    "{label}: {text}"
                );
            }
            Err(e) => panic!("{label}: expected TooFewMarkers, got {e}"),
            Ok(m) => panic!("{label}: expected a refusal, got a pose ({:?})", m.est),
        }
    }
    // One row of the ring only (four markers along one side, spread ratio about 6): weakly
    // conditioned (tilt about the row is seen only across the 2 cm markers). Accepted, it
    // registered worse than the nominal pose (0.29 / 0.52 texel against 0.13 / 0.33) with a
    // predicted sigma that did not warn (0.076), so the estimator refuses it.
    let hidden: Vec<u32> = (4..12).collect();
    let o = bench.run(view, 1.0, 9001, &|shot, frame| bench.hide_markers(shot, frame, &hidden));
    print_view("one row (0-3)", &o);
    match &o.result {
        Err(e) => {
            let text = e.to_string();
            assert!(text.contains("degenerate marker geometry") && text.contains("collinear"), "one row: {text}");
        }
        Ok(m) => panic!("one row: expected a refusal, got a pose ({:?}, predicted {})", m.est, m.predicted),
    }
}

#[test]
fn a_marker_cut_by_the_image_border_is_rejected() {
    let bench = Bench::new("lacquered-wood");
    // Views where one marker sticks out to the left of all others, so a sensor cropped on the
    // left (a smaller sensor, the plate shifted in the frame) cuts exactly that marker.
    let mut done = 0;
    for (k, view) in common::bonn_views().into_iter().enumerate().step_by(3) {
        if done == 3 {
            break;
        }
        let shot = bench.shot(view, 1.0, 10_000 + k as u64);
        let quads: Vec<(u32, f64, f64)> = (0..12)
            .map(|id| {
                let q = bench.marker_quad(&shot, id, 1.0);
                (id, q.iter().map(|p| p.x).fold(f64::MAX, f64::min), q.iter().map(|p| p.x).fold(f64::MIN, f64::max))
            })
            .collect();
        let first = *quads.iter().min_by(|a, b| a.1.total_cmp(&b.1)).unwrap();
        let second = quads.iter().filter(|q| q.0 != first.0).map(|q| q.1).fold(f64::MAX, f64::min);
        // The cut keeps a quarter of the marker in the frame; it must leave every other marker
        // 5 px clear of the border.
        let x0 = (first.1 + 0.75 * (first.2 - first.1)).round();
        if x0 < 1.0 || second < x0 + 5.0 {
            continue;
        }
        done += 1;
        let frame = bench.capture(&shot, bench.default_exposure(), 1.0, 10_100 + k as u64);
        for fraction in [0.25, 0.5, 0.75] {
            let x0 = (first.1 + fraction * (first.2 - first.1)).round() as usize;
            let registrar = bench.cropped_registrar(x0);
            let cropped = frames_common::crop_left(&frame, x0);
            let o = Outcome {
                shot: shot.clone(),
                result: bench.measure(&registrar, &shot, &cropped),
                render_s: frame.render_s,
                corners: Vec::new(),
            };
            print_view(&format!("marker {} cut at {:.0}% of its width (x0 {x0})", first.0, 100.0 * fraction), &o);
            let m = o.result.as_ref().expect("the rest registers");
            let expect: Vec<u32> = (0..12).filter(|i| *i != first.0).collect();
            assert_eq!(m.reg.detected, expect, "the cut marker is rejected, the rest found");
            assert!(m.est.0 < 0.05 && m.est.1 < 0.2, "error {:?}", m.est);
        }
    }
    assert_eq!(done, 3, "three views with a marker alone at the left");
}
