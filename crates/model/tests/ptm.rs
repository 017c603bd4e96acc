//! Scaled Lafortune lobes and per-view polynomial texture maps against data generated from
//! known models (seeded): fitted back exactly, finite at grazing angles and on degenerate
//! light sets, and a dataset with too few lights per view is refused with the view named.

use btfrig_model::lafortune::{fit as fit_plain, BtfInput, LafortuneParams, Lobe};
use btfrig_model::ptm::{basis, fit as fit_ptm, PtmInput, PtmParams};
use btfrig_model::scaled_lafortune::{fit as fit_scaled, ScaledParams};
use rand::{Rng, SeedableRng};

fn dir(theta_deg: f64, phi_deg: f64) -> [f64; 3] {
    let (t, p) = (theta_deg.to_radians(), phi_deg.to_radians());
    [t.sin() * p.cos(), t.sin() * p.sin(), t.cos()]
}

fn lobe(lb: &Lobe, l: &[f64; 3], v: &[f64; 3]) -> f64 {
    let b = lb.cxy * (l[0] * v[0] + l[1] * v[1]) + lb.cz * l[2] * v[2];
    if b > 0.0 {
        b.powf(lb.n)
    } else {
        0.0
    }
}

/// Relative RMSE of `model` against `images` over every texel and capture.
fn rel_rmse(model: impl Fn(usize, usize) -> [f32; 3], images: &[Vec<[f32; 3]>]) -> f64 {
    let (mut e, mut s) = (0.0, 0.0);
    for (i, img) in images.iter().enumerate() {
        for (t, p) in img.iter().enumerate() {
            let m = model(i, t);
            for c in 0..3 {
                assert!(m[c].is_finite(), "capture {i}, texel {t}: {m:?}");
                e += (f64::from(m[c]) - f64::from(p[c])).powi(2);
                s += f64::from(p[c]).powi(2);
            }
        }
    }
    (e / s).sqrt()
}

#[test]
fn scaled_lobes_are_fitted_back_and_beat_plain_lobes() {
    // Six views with their occlusion factors, lights from the zenith to grazing.
    let view_t = [(10.0, 0.0, 1.0), (30.0, 90.0, 0.8), (50.0, 200.0, 0.55), (70.0, 300.0, 0.35), (89.9, 45.0, 0.7)];
    let truth = [Lobe { cxy: -1.0, cz: 1.0, n: 20.0 }, Lobe { cxy: -0.9, cz: 0.9, n: 8.0 }];
    let rho = [[0.3f64, 0.2, 0.1], [0.5, 0.5, 0.4]];
    let (mut lights, mut views, mut scales) = (Vec::new(), Vec::new(), Vec::new());
    for &(vt, vp, s) in &view_t {
        for lt in [0.0, 20.0, 40.0, 60.0, 89.9] {
            for lp in [0.0, 90.0, 200.0, 290.0] {
                lights.push(dir(lt, lp));
                views.push(dir(vt, vp));
                scales.push(s);
            }
        }
    }
    let images: Vec<Vec<[f32; 3]>> = (0..lights.len())
        .map(|i| {
            (0..2)
                .map(|t| {
                    let (l, v) = (&lights[i], &views[i]);
                    rho[t].map(|r| (scales[i] * l[2] * (r + lobe(&truth[t], l, v))) as f32)
                })
                .collect()
        })
        .collect();
    let refs: Vec<&[[f32; 3]]> = images.iter().map(|v| v.as_slice()).collect();
    let input = BtfInput { texels: 2, lights: &lights, views: &views, images: &refs, normals: None };
    let scaled = fit_scaled(&input, &ScaledParams::new(1)).unwrap();
    let e_scaled = rel_rmse(|i, t| scaled.eval(t, &lights[i], &views[i]), &images);
    let plain = fit_plain(&input, &LafortuneParams::new(1)).unwrap();
    let e_plain = rel_rmse(|i, t| plain.eval(t, &lights[i], &views[i]), &images);
    assert!(e_scaled < 1e-5, "scaled: relative RMSE {e_scaled}");
    assert!(e_plain > 10.0 * e_scaled, "plain {e_plain} against scaled {e_scaled}");
    // T is the truth's, normalised to a largest value of 1 (it is 1 already).
    assert_eq!(scaled.view_dirs.len(), view_t.len());
    for (j, &(_, _, s)) in view_t.iter().enumerate() {
        for t in 0..2 {
            let got = f64::from(scaled.scale[t * view_t.len() + j]);
            assert!((got - s).abs() < 0.01, "texel {t}, view {j}: T {got}, truth {s}");
        }
    }
    assert!((scaled.lafortune.albedo[0][0] - 0.3).abs() < 0.01, "{:?}", scaled.lafortune.albedo[0]);
    assert_eq!(scaled.values_per_texel(), 3 + 3 + view_t.len());

    // Black and constant texels stay finite.
    let flat: Vec<Vec<[f32; 3]>> = (0..lights.len()).map(|i| vec![[0.0; 3], [0.4; 3], [(i % 3) as f32; 3]]).collect();
    let refs: Vec<&[[f32; 3]]> = flat.iter().map(|v| v.as_slice()).collect();
    let input = BtfInput { texels: 3, lights: &lights, views: &views, images: &refs, normals: None };
    let m = fit_scaled(&input, &ScaledParams::new(2)).unwrap();
    assert!(m.scale.iter().all(|s| s.is_finite() && (0.0..=1.0).contains(s)), "{:?}", m.scale);
    rel_rmse(|i, t| m.eval(t, &lights[i], &views[i]), &flat);
}

/// A biquadratic per texel and view, positive over the hemisphere, with a chroma.
fn random_ptm(rng: &mut rand_chacha::ChaCha8Rng) -> ([f64; 6], [f64; 3]) {
    let a = [
        rng.gen_range(-0.2..0.2),
        rng.gen_range(-0.2..0.2),
        rng.gen_range(-0.1..0.1),
        rng.gen_range(-0.2..0.2),
        rng.gen_range(-0.2..0.2),
        rng.gen_range(0.8..1.2),
    ];
    (a, [rng.gen_range(0.5..1.5), rng.gen_range(0.5..1.5), rng.gen_range(0.5..1.5)])
}

#[test]
fn polynomial_texture_maps_are_fitted_back_exactly_up_to_grazing_lights() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(29);
    let view_dirs = [dir(0.0, 0.0), dir(45.0, 120.0), dir(75.0, 250.0), dir(30.0, 10.0)];
    let texels = 5;
    let truth: Vec<Vec<([f64; 6], [f64; 3])>> =
        view_dirs.iter().map(|_| (0..texels).map(|_| random_ptm(&mut rng)).collect()).collect();
    let (mut lights, mut views, mut images) = (Vec::new(), Vec::new(), Vec::new());
    for (j, v) in view_dirs.iter().enumerate() {
        // The last view's lights are within 15 deg of the zenith (|l_u|, |l_v| <= 0.26).
        let thetas = if j == 3 { [0.0, 4.0, 8.0, 12.0, 15.0] } else { [0.0, 15.0, 30.0, 60.0, 89.9] };
        for lt in thetas {
            for lp in [0.0, 72.0, 144.0, 216.0, 288.0] {
                let l = dir(lt, lp);
                let phi = basis(l[0], l[1]);
                lights.push(l);
                views.push(*v);
                images.push(
                    truth[j]
                        .iter()
                        .map(|(a, c)| {
                            let lum: f64 = a.iter().zip(&phi).map(|(a, p)| a * p).sum();
                            c.map(|c| (c * lum) as f32)
                        })
                        .collect::<Vec<_>>(),
                );
            }
        }
    }
    let refs: Vec<&[[f32; 3]]> = images.iter().map(|v| v.as_slice()).collect();
    let input = PtmInput { texels, lights: &lights, views: &views, images: &refs };
    let map = fit_ptm(&input, &PtmParams::default()).unwrap();
    assert_eq!(map.views.len(), 4);
    assert_eq!(map.values_per_texel(), 36);
    let e = rel_rmse(|i, t| map.eval(t, &lights[i], &views[i]), &images);
    assert!(e < 1e-5, "relative RMSE {e}");
    // The luminance polynomial is the truth's times the mean chroma.
    for (j, tv) in truth.iter().enumerate() {
        for (t, (a, c)) in tv.iter().enumerate() {
            let mean = (c[0] + c[1] + c[2]) / 3.0;
            for (k, (got, want)) in map.coeffs[j * texels + t].iter().zip(a).enumerate() {
                let (got, want) = (f64::from(*got), want * mean);
                assert!((got - want).abs() < 1e-4, "view {j} texel {t} a_{k}: {got} against {want}");
            }
        }
        assert!(map.views[j].rcond > 1e-4, "{:?}", map.views[j]);
    }
}

#[test]
fn lights_on_one_ring_are_reported_ill_conditioned_and_stay_finite() {
    // Six grazing lights on one ring lie on a conic (l_u² + l_v² is constant): the
    // biquadratic is not determined; the ridge picks one that still fits the data.
    let v = dir(20.0, 0.0);
    let lights: Vec<[f64; 3]> = (0..8).map(|k| dir(89.9, 45.0 * f64::from(k))).collect();
    let views = vec![v; lights.len()];
    let images: Vec<Vec<[f32; 3]>> =
        lights.iter().map(|l| vec![[1.0, 0.7, 0.4].map(|c| (c * (0.3 + 0.1 * l[0])) as f32), [0.0; 3]]).collect();
    let refs: Vec<&[[f32; 3]]> = images.iter().map(|v| v.as_slice()).collect();
    let map =
        fit_ptm(&PtmInput { texels: 2, lights: &lights, views: &views, images: &refs }, &PtmParams::default()).unwrap();
    assert!(map.views[0].rcond < 1e-9, "{:?}", map.views[0]);
    assert!(map.coeffs.iter().flatten().chain(map.chroma.iter().flatten()).all(|x| x.is_finite()));
    let e = rel_rmse(|i, t| map.eval(t, &lights[i], &views[i]), &images);
    assert!(e < 1e-3, "relative RMSE {e}");
    // At the zenith, never measured: finite.
    assert!(map.eval(0, &[0.0, 0.0, 1.0], &v).iter().all(|x| x.is_finite()));
}

#[test]
fn too_few_lights_per_view_are_refused_naming_the_view() {
    // A gonio demo's shape: many views, three lights each.
    let (mut lights, mut views) = (Vec::new(), Vec::new());
    for vp in [0.0, 90.0, 180.0] {
        for lp in [0.0, 120.0, 240.0] {
            lights.push(dir(15.0, lp + vp));
            views.push(dir(30.0, vp));
        }
    }
    let images = vec![vec![[0.5f32; 3]; 4]; lights.len()];
    let refs: Vec<&[[f32; 3]]> = images.iter().map(|v| v.as_slice()).collect();
    let e = fit_ptm(&PtmInput { texels: 4, lights: &lights, views: &views, images: &refs }, &PtmParams::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("view 0 (theta 30.0 deg, phi 0.0 deg) = 3 distinct light direction(s)"), "{e}");
    assert!(e.contains("at least 6 distinct light directions in every view") && e.contains("3 of the 3 views"), "{e}");
    // A NaN is named too.
    let mut bad = images.clone();
    bad[4][2][1] = f32::NAN;
    let refs: Vec<&[[f32; 3]]> = bad.iter().map(|v| v.as_slice()).collect();
    let e = fit_ptm(&PtmInput { texels: 4, lights: &lights, views: &views, images: &refs }, &PtmParams::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("image 4 = NaN: finite values"), "{e}");
}
