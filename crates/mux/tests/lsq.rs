//! Least squares: residual checks over sizes for square and over-determined pattern
//! matrices, calibrated intensities, and named regression tests for dim, zero, singular and
//! ill-conditioned calibrations (a clear error or graceful degradation, never NaN).

mod common;

use btfrig_mux::{
    Accumulate, Demultiplexer, DemultiplexerParams, LeastSquares, LsParams, MuxError, PatternModel, SMatrix,
    SourceState,
};
use rand::Rng;

fn nominal(n: usize) -> Vec<SourceState> {
    vec![SourceState::Nominal; n]
}

#[test]
fn calibrated_s_matrix_solve_recovers_the_images_over_orders() {
    for (seed, n) in [7usize, 31, 83, 151, 199, 255].into_iter().enumerate() {
        let s = SMatrix::of_order(n).unwrap();
        let mut r = common::rng(seed as u64);
        let a: Vec<f64> = (0..n).map(|_| r.gen_range(0.5..1.5)).collect();
        let model = PatternModel::from_smatrix(&s, &a).unwrap();
        let cols = 17;
        let truth = common::uniform(n, cols, 0.0, 10.0, 3 + seed as u64);
        // m = W x in f64.
        let mut frames = vec![0.0f32; n * cols];
        for c in 0..cols {
            for i in 0..n {
                let v: f64 = (0..n).map(|j| model.W()[(i, j)] * f64::from(truth[j * cols + c])).sum();
                frames[i * cols + c] = v as f32;
            }
        }
        for acc in [Accumulate::F32, Accumulate::F64] {
            let ls =
                LeastSquares::new(&model, &nominal(n), &LsParams { accumulate: acc, ..Default::default() }).unwrap();
            // cond(S diag(a)) <= cond(S) · max(a)/min(a).
            assert!(ls.condition() <= ((n + 1) as f64).sqrt() * 3.0 * 1.0001, "order {n}: {}", ls.condition());
            let got = ls.solve(&frames, cols).unwrap();
            let worst = got.iter().zip(&truth).map(|(g, t)| (g - t).abs()).fold(0.0f32, f32::max);
            assert!(worst < 2e-5 * (n as f32).sqrt() * 10.0, "order {n} {acc:?}: {worst}");
            // In place (square system), any thread count: the same numbers.
            for par in [btfrig_mux::Par::Seq, btfrig_mux::Par::Rayon(2)] {
                let mut inplace = frames.clone();
                ls.solve_in_place(&mut inplace, cols, par).unwrap();
                assert_eq!(inplace, got, "order {n} {acc:?} {par:?}");
            }
        }
        // The high-level path (fast demux, then divide by a) gives the same.
        let dm = Demultiplexer::new(s, a.clone(), DemultiplexerParams::default()).unwrap();
        let out = dm.run(frames, cols).unwrap();
        let worst = out.images().iter().zip(&truth).map(|(g, t)| (g - t).abs()).fold(0.0f32, f32::max);
        assert!(worst < 2e-5 * (n as f32).sqrt() * 10.0, "order {n} fast: {worst}");
        assert!(out.report().faults.is_empty());
    }
}

#[test]
fn overdetermined_solve_satisfies_the_normal_equations() {
    // Random 0/1 patterns with more frames than sources, noisy data: Wᵀ(m − W î) = 0.
    for (seed, (f, n)) in [(12usize, 7usize), (40, 31), (90, 63), (300, 127)].into_iter().enumerate() {
        let mut r = common::rng(20 + seed as u64);
        let w: Vec<f64> = (0..f * n).map(|_| if r.gen_bool(0.5) { r.gen_range(0.8..1.2) } else { 0.0 }).collect();
        let model = PatternModel::from_rows(f, n, &w).unwrap();
        let ls =
            LeastSquares::new(&model, &nominal(n), &LsParams { accumulate: Accumulate::F64, ..Default::default() })
                .unwrap();
        let cols = 5;
        let m = common::uniform(f, cols, 0.0, 100.0, 30 + seed as u64);
        let x = ls.solve(&m, cols).unwrap();
        let scale = 100.0 * f as f64;
        for c in 0..cols {
            let resid: Vec<f64> = (0..f)
                .map(|i| {
                    f64::from(m[i * cols + c]) - (0..n).map(|j| w[i * n + j] * f64::from(x[j * cols + c])).sum::<f64>()
                })
                .collect();
            for j in 0..n {
                let g: f64 = (0..f).map(|i| w[i * n + j] * resid[i]).sum();
                assert!(g.abs() < 1e-5 * scale, "{f}x{n} column {c}: (Wᵀr)[{j}] = {g}");
            }
        }
    }
}

#[test]
fn regression_dim_led_is_excluded_and_reported_never_nan() {
    let n = 63;
    let s = SMatrix::of_order(n).unwrap();
    let mut a = vec![1.0; n];
    a[5] = 1e-9; // a practically dead calibration
    a[9] = 0.02; // dim but usable: 50x the noise, reported
    let cols = 50;
    let truth = common::uniform(n, cols, 1.0, 2.0, 1);
    let lit: Vec<f32> = truth.iter().enumerate().map(|(k, v)| v * a[k / cols] as f32).collect();
    let frames = btfrig_mux::Demuxer::new(&s, &Default::default()).unwrap().multiplex(&lit, cols).unwrap();
    let dm = Demultiplexer::new(s.clone(), a.clone(), DemultiplexerParams::default()).unwrap();
    let out = dm.run(frames.clone(), cols).unwrap();
    let r = out.report();
    assert!(out.images().iter().all(|v| v.is_finite()));
    assert_eq!(r.excluded, vec![5], "{r:?}");
    assert!(out.image(5).iter().all(|&v| v == 0.0));
    assert!(r.noise_gain[9] > 40.0 * r.noise_gain[0], "{:?}", &r.noise_gain[..10]);
    let worst = (0..n)
        .filter(|&j| j != 5)
        .flat_map(|j| (0..cols).map(move |c| (j, c)))
        .map(|(j, c)| (out.images()[j * cols + c] - truth[j * cols + c]).abs())
        .fold(0.0f32, f32::max);
    assert!(worst < 2e-3, "{worst}");
    // Least squares with no dim threshold: a clear error naming the LED.
    let model = PatternModel::from_smatrix(&s, &a).unwrap();
    let e = LeastSquares::new(&model, &nominal(n), &LsParams { min_relative_intensity: 0.0, ..Default::default() })
        .unwrap_err();
    match &e {
        MuxError::IllConditioned { weakest_source, condition, .. } => {
            assert_eq!(*weakest_source, 5);
            assert!(*condition > 1e8, "{condition}");
        }
        other => panic!("{other:?}"),
    }
    assert!(e.to_string().contains("source 5"), "{e}");
}

#[test]
fn regression_zero_and_bad_intensities() {
    let s = SMatrix::of_order(7).unwrap();
    let e = Demultiplexer::new(s.clone(), vec![1.0, 1.0, -0.5, 1.0, 1.0, 1.0, 1.0], Default::default()).unwrap_err();
    assert_eq!(e, MuxError::BadIntensity { index: 2, value: -0.5 });
    let e = Demultiplexer::new(s.clone(), vec![f64::NAN; 7], Default::default()).unwrap_err();
    assert!(e.to_string().contains("LED 0"), "{e}");
    let e = Demultiplexer::new(s.clone(), vec![1.0; 6], Default::default()).unwrap_err();
    assert!(e.to_string().contains("6 values, expected 7"), "{e}");
    // All zero: nothing to solve for.
    let model = PatternModel::from_smatrix(&s, &[0.0; 7]).unwrap();
    let e = LeastSquares::new(&model, &nominal(7), &LsParams::default()).unwrap_err();
    assert!(matches!(e, MuxError::Underdetermined { unknowns: 0, .. }), "{e}");
    // All zero through the fast path: zeros out, every LED excluded, no NaN.
    let dm = Demultiplexer::new(s, vec![0.0; 7], Default::default()).unwrap();
    let out = dm.run(vec![1.0; 7 * 3], 3).unwrap();
    assert!(out.images().iter().all(|&v| v == 0.0));
    assert_eq!(out.report().excluded.len(), 7);
}

#[test]
fn regression_singular_and_underdetermined_pattern_matrices() {
    // Two identical columns: rank deficient.
    let w = [1.0, 1.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.0];
    let model = PatternModel::from_rows(4, 3, &w).unwrap();
    let e = LeastSquares::new(&model, &nominal(3), &LsParams::default()).unwrap_err();
    assert!(matches!(e, MuxError::IllConditioned { .. }), "{e}");
    // Fewer frames than sources.
    let model = PatternModel::from_rows(2, 3, &[1.0, 0.0, 1.0, 0.0, 1.0, 1.0]).unwrap();
    let e = LeastSquares::new(&model, &nominal(3), &LsParams::default()).unwrap_err();
    assert!(e.to_string().contains("2 frames, 3 unknowns"), "{e}");
    // A dead column makes the square system over-determined and well posed again.
    let s = SMatrix::of_order(15).unwrap();
    let model = PatternModel::from_smatrix(&s, &[1.0; 15]).unwrap();
    let mut st = nominal(15);
    st[4] = SourceState::Dead;
    let ls = LeastSquares::new(&model, &st, &LsParams::default()).unwrap();
    assert!(ls.condition() < 10.0 && ls.noise_gain()[4] == 0.0);
    // Non-finite entries are named.
    let e = PatternModel::from_rows(1, 2, &[1.0, f64::INFINITY]).unwrap_err();
    assert!(e.to_string().contains("frame 0, source 1"), "{e}");
}

#[test]
fn regression_gradually_dimmer_led_degrades_gracefully() {
    // As one LED's calibrated intensity falls from 1 to 1e-12, its noise gain grows as 1/a
    // until it is excluded; every output stays finite and the others are unaffected.
    let n = 31;
    let s = SMatrix::of_order(n).unwrap();
    let cols = 8;
    let truth = common::uniform(n, cols, 1.0, 2.0, 9);
    for k in 0..13 {
        let dim = 10f64.powi(-k);
        let mut a = vec![1.0; n];
        a[3] = dim;
        let lit: Vec<f32> = truth.iter().enumerate().map(|(i, v)| v * a[i / cols] as f32).collect();
        let frames = btfrig_mux::Demuxer::new(&s, &Default::default()).unwrap().multiplex(&lit, cols).unwrap();
        let out = Demultiplexer::new(s.clone(), a, DemultiplexerParams::default()).unwrap().run(frames, cols).unwrap();
        assert!(out.images().iter().all(|v| v.is_finite()), "a = {dim:e}");
        let excluded = out.report().excluded.contains(&3);
        assert_eq!(excluded, dim <= 1e-3, "a = {dim:e}");
        let worst = (0..n)
            .filter(|&j| j != 3)
            .flat_map(|j| (0..cols).map(move |c| (j, c)))
            .map(|(j, c)| (out.images()[j * cols + c] - truth[j * cols + c]).abs())
            .fold(0.0f32, f32::max);
        // Excluding a 1e-3 LED leaves its light (1e-3 of an image) in the others: 2/(n+1)·1e-3·2.
        assert!(worst < 2e-4, "a = {dim:e}: others off by {worst}");
    }
}

#[test]
fn large_order_least_squares_with_a_dead_led() {
    // Numerical stress of the SVD path: order 511 with calibrated intensities and a dead LED.
    let n = 511;
    let s = SMatrix::of_order(n).unwrap();
    let mut r = common::rng(4);
    let a: Vec<f64> = (0..n).map(|_| r.gen_range(0.7..1.3)).collect();
    let model = PatternModel::from_smatrix(&s, &a).unwrap();
    let mut st = nominal(n);
    st[100] = SourceState::Dead;
    let ls = LeastSquares::new(&model, &st, &LsParams::default()).unwrap();
    assert!(ls.condition() < 2.0 * ((n + 1) as f64).sqrt() * 1.3 / 0.7);
    let cols = 4;
    let mut truth = common::uniform(n, cols, 0.0, 1.0, 5);
    truth[100 * cols..101 * cols].iter_mut().for_each(|v| *v = 0.0);
    let lit: Vec<f32> = truth.iter().enumerate().map(|(k, v)| v * a[k / cols] as f32).collect();
    let frames = btfrig_mux::Demuxer::new(&s, &Default::default()).unwrap().multiplex(&lit, cols).unwrap();
    let x = ls.solve(&frames, cols).unwrap();
    let worst = x.iter().zip(&truth).map(|(g, t)| (g - t).abs()).fold(0.0f32, f32::max);
    assert!(worst < 1e-4, "{worst}");
}
