//! Colour-correction models: analytic cases, exposure invariance, constraints, errors.

mod common;

use btfrig_color::space::mat3_apply;
use btfrig_color::{ColorError, ColorModel, FitOptions, ModelKind, WhiteConstraint};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const M: [[f64; 3]; 3] = [[1.6, -0.4, -0.2], [-0.3, 1.5, -0.2], [0.05, -0.45, 1.4]];

fn random_rgb(n: usize, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n).map(|_| [rng.gen_range(0.02..0.9), rng.gen_range(0.02..0.9), rng.gen_range(0.02..0.9)]).collect()
}

fn max_abs_diff(a: [f64; 3], b: [f64; 3]) -> f64 {
    (0..3).map(|i| (a[i] - b[i]).abs()).fold(0.0, f64::max)
}

#[test]
fn every_model_recovers_an_exact_linear_map() {
    // Every model contains r, g, b as terms, so linear data is fitted exactly (other terms 0).
    let cam = random_rgb(60, 1);
    let tgt: Vec<[f64; 3]> = cam.iter().map(|c| mat3_apply(&M, *c)).collect();
    for kind in ModelKind::ALL {
        let m = ColorModel::fit(kind, &cam, &tgt, None, &FitOptions::default()).unwrap();
        let probe = [0.3, 0.5, 0.1];
        let err = max_abs_diff(m.apply(probe), mat3_apply(&M, probe));
        assert!(err < 1e-8, "{kind}: {err}");
        assert!(m.rms_residual().iter().all(|r| *r < 1e-9), "{kind}: {:?}", m.rms_residual());
        assert_eq!(m.coefficients().len(), kind.terms());
        assert_eq!(kind.term_names().len(), kind.terms());
        for (j, row) in m.coefficients().iter().enumerate().skip(3) {
            assert!(row.iter().all(|v| v.abs() < 1e-6), "{kind} term {j}: {row:?}");
        }
    }
}

#[test]
fn polynomial_and_root_polynomial_fit_their_own_functions_exactly() {
    // Target = a known combination of each model's terms: the fit must find it.
    let cam = random_rgb(80, 2);
    for kind in ModelKind::ALL {
        let mut rng = ChaCha8Rng::seed_from_u64(kind.terms() as u64);
        let truth: Vec<[f64; 3]> = (0..kind.terms())
            .map(|_| [rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0)])
            .collect();
        let truth_model = ColorModel::from_coefficients(kind, truth.clone()).unwrap();
        let tgt: Vec<[f64; 3]> = cam.iter().map(|c| truth_model.apply(*c)).collect();
        let m = ColorModel::fit(kind, &cam, &tgt, None, &FitOptions::default()).unwrap();
        for (a, b) in m.coefficients().iter().zip(&truth) {
            assert!(max_abs_diff(*a, *b) < 1e-6 * m.condition().max(1.0), "{kind}: {a:?} vs {b:?}");
        }
    }
}

#[test]
fn root_polynomial_and_linear_are_exposure_invariant_polynomial_is_not() {
    let cam = random_rgb(40, 3);
    // A non-linear target so the extra terms are used.
    let tgt: Vec<[f64; 3]> = cam.iter().map(|c| [c[0] * 0.9 + (c[0] * c[1]).sqrt() * 0.2, c[1], c[2] * 1.1]).collect();
    for kind in ModelKind::ALL {
        let m = ColorModel::fit(kind, &cam, &tgt, None, &FitOptions::default()).unwrap();
        let mut worst: f64 = 0.0;
        for c in random_rgb(50, 4) {
            for k in [0.1, 0.5, 2.0, 7.0] {
                let a = m.apply(c.map(|v| v * k));
                let b = m.apply(c).map(|v| v * k);
                worst = worst.max(max_abs_diff(a, b) / (k * 1.0));
            }
        }
        if kind.exposure_invariant() {
            assert!(worst < 1e-12, "{kind}: {worst}");
        } else {
            assert!(worst > 1e-3, "{kind} should not be exposure invariant: {worst}");
        }
    }
}

#[test]
fn negative_camera_values_stay_finite_and_continuous() {
    let cam = random_rgb(40, 5);
    let tgt: Vec<[f64; 3]> = cam.iter().map(|c| mat3_apply(&M, *c)).collect();
    for kind in ModelKind::ALL {
        let m = ColorModel::fit(kind, &cam, &tgt, None, &FitOptions::default()).unwrap();
        for p in [[-0.001, 0.002, 0.0005], [-0.01, -0.02, 0.003], [0.0, 0.0, 0.0], [-1e-6, 1e-6, -1e-6]] {
            let o = m.apply(p);
            assert!(o.iter().all(|v| v.is_finite()), "{kind} {p:?}: {o:?}");
            // Continuity through zero: a tiny input gives a tiny output.
            assert!(o.iter().all(|v| v.abs() < 0.2), "{kind} {p:?}: {o:?}");
        }
        assert_eq!(m.apply([0.0; 3]), [0.0; 3]);
    }
}

#[test]
fn white_constraint_holds_exactly_and_costs_little() {
    let cam = random_rgb(30, 6);
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    // Slightly non-linear, noisy target: the unconstrained fit misses white a little.
    let tgt: Vec<[f64; 3]> = cam
        .iter()
        .map(|c| {
            let t = mat3_apply(&M, *c);
            [t[0] + 0.01 * c[0] * c[0] + rng.gen_range(-0.002..0.002), t[1], t[2] + rng.gen_range(-0.002..0.002)]
        })
        .collect();
    // A white reference whose target is a little off the data's map (as a real chart's white is).
    let wc = [0.8, 0.9, 0.7];
    let wt = mat3_apply(&M, wc);
    let white = WhiteConstraint { camera: wc, target: [wt[0] + 0.004, wt[1] - 0.003, wt[2] + 0.002] };
    for kind in ModelKind::ALL {
        let free = ColorModel::fit(kind, &cam, &tgt, None, &FitOptions::default()).unwrap();
        let opts = FitOptions { white: Some(white), ..FitOptions::default() };
        let fixed = ColorModel::fit(kind, &cam, &tgt, None, &opts).unwrap();
        let w = fixed.apply(white.camera);
        assert!(max_abs_diff(w, white.target) < 1e-12, "{kind}: {w:?}");
        assert!(max_abs_diff(free.apply(white.camera), white.target) > 1e-6, "{kind}: test needs a miss");
        // The constrained optimum's residual is at least the free one's, but close.
        let (rf, rc) = (free.rms_residual(), fixed.rms_residual());
        for c in 0..3 {
            assert!(rc[c] >= rf[c] - 1e-12 && rc[c] < rf[c] + 0.02, "{kind} ch {c}: {rf:?} {rc:?}");
        }
    }
}

#[test]
fn weights_exclude_samples_and_weighted_equals_repeated() {
    let mut cam = random_rgb(30, 8);
    let mut tgt: Vec<[f64; 3]> = cam.iter().map(|c| mat3_apply(&M, *c)).collect();
    // Two outliers with weight 0 do not move the fit.
    cam.push([0.5, 0.5, 0.5]);
    tgt.push([9.0, -9.0, 9.0]);
    cam.push([0.2, 0.7, 0.1]);
    tgt.push([f64::MAX / 1e300, 0.0, 0.0]);
    let mut w = vec![1.0; cam.len()];
    w[30] = 0.0;
    w[31] = 0.0;
    let m = ColorModel::fit(ModelKind::RootPolynomial2, &cam, &tgt, Some(&w), &FitOptions::default()).unwrap();
    assert!(max_abs_diff(m.apply([0.4, 0.3, 0.2]), mat3_apply(&M, [0.4, 0.3, 0.2])) < 1e-9);
    // Weight 2 equals the sample listed twice.
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let cam = random_rgb(20, 10);
    let tgt: Vec<[f64; 3]> = cam.iter().map(|c| mat3_apply(&M, *c).map(|v| v + rng.gen_range(-0.05..0.05))).collect();
    let mut w = vec![1.0; 20];
    w[3] = 2.0;
    let a = ColorModel::fit(ModelKind::Linear, &cam, &tgt, Some(&w), &FitOptions::default()).unwrap();
    let (mut cam2, mut tgt2) = (cam.clone(), tgt.clone());
    cam2.push(cam[3]);
    tgt2.push(tgt[3]);
    let b = ColorModel::fit(ModelKind::Linear, &cam2, &tgt2, None, &FitOptions::default()).unwrap();
    for (x, y) in a.coefficients().iter().zip(b.coefficients()) {
        assert!(max_abs_diff(*x, *y) < 1e-12);
    }
}

#[test]
fn grey_only_and_few_colours_are_ill_conditioned_not_nan() {
    // Every patch grey: r = g = b, the design matrix has rank 1.
    let grey: Vec<[f64; 3]> = (1..=24).map(|i| [i as f64 / 25.0; 3]).collect();
    let tgt: Vec<[f64; 3]> = grey.clone();
    // The same with sensor-like noise (0.1 % of the signal): the fit would succeed and reproduce
    // the greys, but its colour response is noise.
    let mut rng = ChaCha8Rng::seed_from_u64(14);
    let noisy: Vec<[f64; 3]> = grey.iter().map(|g| g.map(|v| v * (1.0 + rng.gen_range(-1e-3..1e-3)))).collect();
    for kind in ModelKind::ALL {
        for (cam, min_condition) in [(&grey, 1e13), (&noisy, 100.0)] {
            match ColorModel::fit(kind, cam, &tgt, None, &FitOptions::default()) {
                Err(ColorError::FewColours { model, condition, limit }) => {
                    assert_eq!(model, kind);
                    assert!(
                        condition > min_condition && limit == FitOptions::DEFAULT_MAX_COLOUR_CONDITION,
                        "{condition}"
                    );
                }
                other => panic!("{kind}: {other:?}"),
            }
        }
    }
    // Three distinct colours at several exposures: enough for the linear map (rank 3), not for
    // the 6- and 13-term root-polynomials (exposure only scales their terms: rank 3 too).
    let base = [[0.6, 0.3, 0.1], [0.2, 0.5, 0.3], [0.1, 0.2, 0.7]];
    let cam: Vec<[f64; 3]> = (0..24).map(|i| base[i % 3].map(|v| v * (0.2 + 0.1 * (i / 3) as f64))).collect();
    let tgt: Vec<[f64; 3]> = cam.iter().map(|c| mat3_apply(&M, *c)).collect();
    assert!(ColorModel::fit(ModelKind::Linear, &cam, &tgt, None, &FitOptions::default()).is_ok());
    for kind in [ModelKind::RootPolynomial2, ModelKind::RootPolynomial3] {
        let e = ColorModel::fit(kind, &cam, &tgt, None, &FitOptions::default()).unwrap_err();
        assert!(matches!(e, ColorError::IllConditioned { .. }), "{kind}: {e}");
        assert!(e.to_string().contains(kind.name()) && e.to_string().contains("condition number"), "{e}");
    }
    // A ridge term makes the near-singular fit well posed (and reports the regularised condition).
    let opts = FitOptions { ridge: 1e-6, ..FitOptions::default() };
    let m = ColorModel::fit(ModelKind::RootPolynomial3, &cam, &tgt, None, &opts).unwrap();
    // Unit-norm columns: σ_max² ≤ terms, so the regularised condition is at most √((13 + λ)/λ).
    assert!(m.condition() <= ((13.0 + 1e-6) / 1e-6f64).sqrt(), "{}", m.condition());
    assert!(m.coefficients().iter().flatten().all(|v| v.is_finite()));
    assert!(max_abs_diff(m.apply(cam[5]), tgt[5]) < 1e-3);
}

#[test]
fn bad_inputs_give_named_errors() {
    let cam = random_rgb(20, 11);
    let tgt: Vec<[f64; 3]> = cam.iter().map(|c| mat3_apply(&M, *c)).collect();
    let o = FitOptions::default();
    let fit = |k, c: &[[f64; 3]], t: &[[f64; 3]], w: Option<&[f64]>, o: &FitOptions| ColorModel::fit(k, c, t, w, o);
    // Too few samples for 19 terms.
    assert_eq!(
        fit(ModelKind::Polynomial3, &cam[..10], &tgt[..10], None, &o),
        Err(ColorError::TooFewSamples { model: ModelKind::Polynomial3, samples: 10, needed: 19 })
    );
    assert!(fit(ModelKind::Linear, &cam[..3], &tgt[..3], None, &o).is_ok());
    assert!(matches!(fit(ModelKind::Linear, &cam, &tgt[..5], None, &o), Err(ColorError::LengthMismatch { .. })));
    let mut bad = cam.clone();
    bad[7][1] = f64::NAN;
    assert!(matches!(
        fit(ModelKind::Linear, &bad, &tgt, None, &o),
        Err(ColorError::NonFinite { what: "camera", index: 7, .. })
    ));
    let mut badt = tgt.clone();
    badt[2][0] = f64::INFINITY;
    assert!(matches!(
        fit(ModelKind::Linear, &cam, &badt, None, &o),
        Err(ColorError::NonFinite { what: "target", index: 2, .. })
    ));
    let mut w = vec![1.0; 20];
    w[4] = -1.0;
    assert_eq!(
        fit(ModelKind::Linear, &cam, &tgt, Some(&w), &o),
        Err(ColorError::InvalidWeight { index: 4, value: -1.0 })
    );
    let o2 = FitOptions { ridge: -1.0, ..o };
    assert!(matches!(
        fit(ModelKind::Linear, &cam, &tgt, None, &o2),
        Err(ColorError::InvalidOption { what: "ridge", .. })
    ));
    assert!(matches!(
        ColorModel::from_coefficients(ModelKind::RootPolynomial2, vec![[0.0; 3]; 3]),
        Err(ColorError::WrongTermCount { expected: 6, got: 3, .. })
    ));
    assert_eq!("rootpoly3".parse::<ModelKind>(), Ok(ModelKind::RootPolynomial3));
    assert!(matches!("cubic".parse::<ModelKind>(), Err(ColorError::UnknownModel(_))));
    for k in ModelKind::ALL {
        assert_eq!(k.name().parse::<ModelKind>(), Ok(k));
    }
}

#[test]
fn f32_batch_apply_agrees_with_f64() {
    let cam = random_rgb(50, 12);
    let tgt: Vec<[f64; 3]> = cam.iter().map(|c| mat3_apply(&M, *c).map(|v| v + 0.05 * (v * 7.0).sin())).collect();
    for kind in ModelKind::ALL {
        let m = ColorModel::fit(kind, &cam, &tgt, None, &FitOptions::default()).unwrap();
        let px: Vec<[f32; 3]> = random_rgb(5000, 13).iter().map(|c| c.map(|v| v as f32)).collect();
        let mut out = px.clone();
        m.apply_f32(&mut out);
        let mut worst: f64 = 0.0;
        for (p, o) in px.iter().zip(&out) {
            let r = m.apply(p.map(|v| v as f64));
            let scale = r.iter().map(|v| v.abs()).fold(0.0, f64::max).max(1e-3);
            worst = worst.max(max_abs_diff(r, o.map(|v| v as f64)) / scale);
        }
        assert!(worst < 1e-6, "{kind}: {worst}");
    }
}
