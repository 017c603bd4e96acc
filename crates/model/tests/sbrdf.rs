//! Seed 003's shadow and occlusion maps on analytic cases: a known SBRDF times known factors
//! is recovered; constant, zero and rank-deficient input stay finite; bad sizes are named.

use btfrig_model::sbrdf::{fit, ShadowInput, ShadowParams};
use btfrig_model::ModelError;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn unit(theta_deg: f64, phi_deg: f64) -> [f64; 3] {
    let (t, p) = (theta_deg.to_radians(), phi_deg.to_radians());
    [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()]
}

/// Light and view direction of each capture, and its (light, view) index.
type Pairs = (Vec<[f64; 3]>, Vec<[f64; 3]>, Vec<(usize, usize)>);

/// 5 light directions × 4 view directions, every pair measured.
fn pairs() -> Pairs {
    let ls: Vec<_> = (0..5).map(|k| unit(10.0 * k as f64, 70.0 * k as f64)).collect();
    let vs: Vec<_> = (0..4).map(|k| unit(15.0 * k as f64, 100.0 * k as f64 + 20.0)).collect();
    let mut lights = Vec::new();
    let mut views = Vec::new();
    let mut idx = Vec::new();
    for (a, l) in ls.iter().enumerate() {
        for (b, v) in vs.iter().enumerate() {
            lights.push(*l);
            views.push(*v);
            idx.push((a, b));
        }
    }
    (lights, views, idx)
}

#[test]
fn known_shadow_and_occlusion_factors_are_recovered() {
    let texels = 30;
    let (lights, views, idx) = pairs();
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    // True factors: each texel has one unshadowed light and one unoccluded view (max 1), so the
    // product's scale is fixed and the split is unique.
    let mut s_true = vec![vec![0.0f64; 5]; texels];
    let mut o_true = vec![vec![0.0f64; 4]; texels];
    for t in 0..texels {
        for (j, x) in s_true[t].iter_mut().enumerate() {
            *x = if j == t % 5 { 1.0 } else { rng.gen_range(0.1..1.0) };
        }
        for (j, x) in o_true[t].iter_mut().enumerate() {
            *x = if j == t % 4 { 1.0 } else { rng.gen_range(0.2..1.0) };
        }
    }
    // The SBRDF's brightness is off by a per-texel gain (it was fitted to shadowed data).
    let g_true: Vec<f64> = (0..texels).map(|_| rng.gen_range(0.5..2.0)).collect();
    let base: Vec<Vec<[f32; 3]>> =
        idx.iter().map(|_| (0..texels).map(|_| [0, 1, 2].map(|_| rng.gen_range(0.05..0.9f32))).collect()).collect();
    let images: Vec<Vec<[f32; 3]>> = idx
        .iter()
        .enumerate()
        .map(|(i, &(a, b))| {
            (0..texels).map(|t| base[i][t].map(|x| x * (g_true[t] * s_true[t][a] * o_true[t][b]) as f32)).collect()
        })
        .collect();
    let ir: Vec<&[[f32; 3]]> = images.iter().map(|v| v.as_slice()).collect();
    let br: Vec<&[[f32; 3]]> = base.iter().map(|v| v.as_slice()).collect();
    let input = ShadowInput { texels, lights: &lights, views: &views, images: &ir, base: &br };
    let maps = fit(&input, &ShadowParams { iterations: 400 }).unwrap();
    assert_eq!((maps.light_dirs.len(), maps.view_dirs.len(), maps.values_per_texel()), (5, 4, 10));
    let mut worst = 0.0f64;
    for t in 0..texels {
        worst = worst.max((f64::from(maps.gain[t]) - g_true[t]).abs() / g_true[t]);
        for (a, s) in s_true[t].iter().enumerate() {
            worst = worst.max((f64::from(maps.shadow[t * 5 + a]) - s).abs());
        }
        for (b, o) in o_true[t].iter().enumerate() {
            worst = worst.max((f64::from(maps.occlusion[t * 4 + b]) - o).abs());
        }
    }
    assert!(worst < 1e-3, "largest factor error {worst}");
    // The combined model reproduces the images.
    for (i, (l, v)) in lights.iter().zip(&views).enumerate() {
        let m = maps.apply(l, v, &base[i]);
        for t in 0..texels {
            for c in 0..3 {
                assert!((m[t][c] - images[i][t][c]).abs() < 2e-3, "image {i} texel {t}");
            }
        }
    }
}

#[test]
fn constant_zero_and_rank_deficient_input_stay_finite() {
    let texels = 4;
    let (lights, views, idx) = pairs();
    // Texel 0: data equals the SBRDF (factors 1). Texel 1: the SBRDF predicts 0 everywhere
    // (nothing to learn: factors stay 1). Texel 2: the data is 0 (factors 0, product 0).
    // Texel 3: data 3x the SBRDF (factors 1, gain 3).
    let base: Vec<Vec<[f32; 3]>> = idx.iter().map(|_| vec![[0.5; 3], [0.0; 3], [0.5; 3], [0.2; 3]]).collect();
    let images: Vec<Vec<[f32; 3]>> = idx.iter().map(|_| vec![[0.5; 3], [0.3; 3], [0.0; 3], [0.6; 3]]).collect();
    let ir: Vec<&[[f32; 3]]> = images.iter().map(|v| v.as_slice()).collect();
    let br: Vec<&[[f32; 3]]> = base.iter().map(|v| v.as_slice()).collect();
    let input = ShadowInput { texels, lights: &lights, views: &views, images: &ir, base: &br };
    let maps = fit(&input, &ShadowParams::default()).unwrap();
    assert!(maps.shadow.iter().chain(&maps.occlusion).all(|x| x.is_finite() && (0.0..=1.0).contains(x)));
    let f = |t: usize| maps.factor(t, &lights[7], &views[7]);
    assert!((f(0) - 1.0).abs() < 1e-6 && (f(1) - 1.0).abs() < 1e-6 && f(2) == 0.0 && (f(3) - 3.0).abs() < 1e-5);
    assert!((maps.gain[3] - 3.0).abs() < 1e-5 && maps.shadow[3 * 5..].iter().all(|&x| (x - 1.0).abs() < 1e-6));
    // One light and one view only (rank 1 in both): still finite.
    let one = [ir[0]];
    let oneb = [br[0]];
    let input = ShadowInput { texels, lights: &lights[..1], views: &views[..1], images: &one, base: &oneb };
    let maps = fit(&input, &ShadowParams::default()).unwrap();
    assert!(maps.shadow.iter().chain(&maps.occlusion).chain(&maps.gain).all(|x| x.is_finite()));
    // Bad input is named.
    let input = ShadowInput { texels, lights: &lights[..2], views: &views, images: &ir, base: &br };
    let e = fit(&input, &ShadowParams::default()).unwrap_err();
    assert!(matches!(e, ModelError::WrongSize { .. }) && e.to_string().contains("light directions"), "{e}");
    let nan = vec![[f32::NAN; 3]; texels];
    let mut ir2 = ir.clone();
    ir2[3] = &nan;
    let input = ShadowInput { texels, lights: &lights, views: &views, images: &ir2, base: &br };
    let e = fit(&input, &ShadowParams::default()).unwrap_err();
    assert!(e.to_string().contains("finite"), "{e}");
}
