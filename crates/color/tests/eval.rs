//! Statistics, cross-validation plumbing and the reported fallback of model selection.

use btfrig_color::eval::percentile_sorted;
use btfrig_color::space::mat3_apply;
use btfrig_color::{
    cross_validate, evaluate, select_model, ColorError, ColorModel, DeltaEStats, FitOptions, ModelKind, TargetSpace,
};

#[test]
fn statistics_follow_the_documented_percentile_definition() {
    let s = DeltaEStats::from_values(vec![4.0, 1.0, 3.0, 2.0, 10.0]).unwrap();
    assert_eq!(s.mean, 4.0);
    assert_eq!(s.median, 3.0);
    // h = 4 * 0.95 = 3.8: 4 + 0.8 * (10 - 4).
    assert!((s.p95 - 8.8).abs() < 1e-12);
    assert_eq!(s.max, 10.0);
    assert_eq!(s.per_patch, vec![4.0, 1.0, 3.0, 2.0, 10.0]);
    // Even count: median between the middle two.
    assert_eq!(percentile_sorted(&[1.0, 2.0, 3.0, 4.0], 0.5), 2.5);
    assert_eq!(percentile_sorted(&[7.0], 0.95), 7.0);
    assert_eq!(DeltaEStats::from_values(vec![]), Err(ColorError::Empty));
    assert!(matches!(DeltaEStats::from_values(vec![1.0, f64::NAN]), Err(ColorError::NonFinite { index: 1, .. })));
}

fn data(n: usize) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let m = [[1.3, -0.2, -0.1], [-0.2, 1.4, -0.2], [0.0, -0.3, 1.3]];
    let cam: Vec<[f64; 3]> = (0..n)
        .map(|i| {
            let t = i as f64;
            [0.1 + 0.8 * (t * 0.37).sin().abs(), 0.1 + 0.8 * (t * 0.91).cos().abs(), 0.05 + 0.7 * (t * 1.7).sin().abs()]
        })
        .collect();
    let tgt = cam.iter().map(|c| mat3_apply(&m, *c).map(|v| v + 0.01 * (v * 13.0).sin())).collect();
    (cam, tgt)
}

#[test]
fn cross_validation_is_leave_one_out_at_n_folds() {
    let (cam, tgt) = data(15);
    let o = FitOptions::default();
    let sp = TargetSpace::LinearSrgb;
    let cv = cross_validate(ModelKind::Linear, &cam, &tgt, None, &o, sp, 15).unwrap();
    // Leave-one-out by hand.
    for i in 0..15 {
        let mut w = vec![1.0; 15];
        w[i] = 0.0;
        let m = ColorModel::fit(ModelKind::Linear, &cam, &tgt, Some(&w), &o).unwrap();
        let e = evaluate(&m, &cam[i..=i], &tgt[i..=i], sp).unwrap().mean;
        assert!((cv.per_patch[i] - e).abs() < 1e-12);
    }
    assert!(matches!(
        cross_validate(ModelKind::Linear, &cam, &tgt, None, &o, sp, 1),
        Err(ColorError::InvalidOption { what: "folds", .. })
    ));
    assert!(matches!(
        cross_validate(ModelKind::Linear, &cam, &tgt, None, &o, sp, 16),
        Err(ColorError::InvalidOption { what: "folds", .. })
    ));
    // XYZ targets: Lab relative to the given white.
    let white = btfrig_color::space::d65_white();
    let xyz: Vec<[f64; 3]> = tgt.iter().map(|t| btfrig_color::space::linear_srgb_to_xyz(*t)).collect();
    let cx = cross_validate(ModelKind::Linear, &cam, &xyz, None, &o, TargetSpace::Xyz { white }, 5).unwrap();
    let cs = cross_validate(ModelKind::Linear, &cam, &tgt, None, &o, sp, 5).unwrap();
    // A linear model commutes with the linear sRGB -> XYZ map: identical errors.
    assert!((cx.mean - cs.mean).abs() < 1e-9, "{} {}", cx.mean, cs.mean);
}

#[test]
fn selection_reports_models_that_cannot_be_fitted_and_falls_back() {
    // 12 patches: 10-fold CV leaves 10-11 for fitting, too few for the 13- and 19-term models.
    let (cam, tgt) = data(12);
    let sel = select_model(&ModelKind::ALL, &cam, &tgt, None, &FitOptions::default(), TargetSpace::LinearSrgb, 10);
    let r3 = sel.reports.iter().find(|r| r.kind == ModelKind::Polynomial3).unwrap();
    assert!(matches!(r3.model, Err(ColorError::TooFewSamples { samples: 12, needed: 19, .. })));
    assert!(matches!(r3.cv, Err(ColorError::TooFewSamples { .. })));
    let rr3 = sel.reports.iter().find(|r| r.kind == ModelKind::RootPolynomial3).unwrap();
    assert!(rr3.cv.is_err());
    let (best, _) = sel.best().unwrap();
    assert!(best.kind.terms() <= 9, "{}", best.kind);
    // Nothing fits: a clear error naming the cause.
    let grey: Vec<[f64; 3]> = (1..=20).map(|i| [i as f64 / 21.0; 3]).collect();
    let sel = select_model(&ModelKind::ALL, &grey, &grey, None, &FitOptions::default(), TargetSpace::LinearSrgb, 5);
    assert_eq!(sel.chosen, None);
    match sel.best() {
        Err(ColorError::NoUsableModel { first_error }) => {
            assert!(first_error.contains("distinct colours"), "{first_error}")
        }
        other => panic!("{other:?}"),
    }
}
