//! Physics of the renderer against analytic cases; every test here can fail.

use btfrig_core::config::plate::PlateConfig;
use btfrig_core::pose::ScenePose;
use btfrig_core::Direction;
use btfrig_render::material::MaterialSpec;
use btfrig_render::radiance::RadianceImage;
use btfrig_render::renderer::{Pinhole, RenderOptions, Renderer};
use btfrig_render::scene::ColourSpace;
use nalgebra::Point3;

/// A toy colour system: `flat:x` is grey `x` in both spaces; chart names get distinct colours.
fn resolver(name: &str) -> Result<([f64; 3], [f64; 3]), String> {
    if let Some(v) = name.strip_prefix("flat:") {
        let x: f64 = v.parse().map_err(|e| format!("{e}"))?;
        return Ok(([x; 3], [x; 3]));
    }
    let h = name.bytes().fold(7u32, |a, b| a.wrapping_mul(31).wrapping_add(b as u32));
    let c =
        [(h % 97) as f64 / 120.0 + 0.05, (h / 97 % 89) as f64 / 110.0 + 0.05, (h / 8633 % 83) as f64 / 100.0 + 0.05];
    Ok((c, [c[2], c[1], c[0]]))
}

fn flat_material(albedo: f64, glossy: Option<(f64, f64)>) -> MaterialSpec {
    let spec = match glossy {
        Some((s, r)) => format!("[specular]\nstrength = {s}\nroughness = {r}\n"),
        None => String::new(),
    };
    MaterialSpec::from_toml(
        &format!(
            "name = \"flat\"\ntexels = 64\nseed = 1\nbasis = [\"flat:1\"]\n[albedo]\npattern = {{ kind = \"constant\", value = 0.0 }}\nstops = [[{albedo}]]\n{spec}"
        ),
        "test",
    )
    .unwrap()
}

fn renderer(spec: &MaterialSpec) -> Renderer {
    Renderer::new(&PlateConfig::default(), spec, 1000.0, &resolver).unwrap()
}

/// Odd-sized camera whose centre pixel looks exactly at the sample origin.
fn small_cam() -> Pinhole {
    Pinhole { width: 101, height: 81, fx: 2000.0, fy: 2000.0, cx: 50.0, cy: 40.0 }
}

fn centre(img: &RadianceImage) -> [f32; 3] {
    img.at(50, 40)
}

#[test]
fn flat_lambertian_follows_cosine_and_inverse_square() {
    let r = renderer(&flat_material(0.5, None));
    for dist in [1.0, 2.0, 3.5] {
        for theta in [0.0, 15.0, 30.0, 45.0, 60.0, 75.0, 85.0] {
            let pose = ScenePose::looking_at(
                Direction::from_degrees(theta, 40.0),
                Direction::from_degrees(20.0, 200.0),
                1.5,
                dist,
            );
            let v = centre(&r.render(&pose, &small_cam(), &RenderOptions::default()));
            let expect = 1000.0 * 0.5 * f64::cos(theta.to_radians()) / (dist * dist);
            for c in v {
                assert!(((c as f64) - expect).abs() <= 1e-5 * expect, "theta {theta} dist {dist}: {c} vs {expect}");
            }
        }
    }
}

#[test]
fn white_reflector_at_one_metre_gives_lamp_scale_in_ground_truth() {
    let r = renderer(&flat_material(1.0, None));
    let pose = ScenePose::looking_at(Direction::from_degrees(0.0, 0.0), Direction::from_degrees(30.0, 0.0), 1.5, 1.0);
    let gt = r.ground_truth(&pose, 9, 9, None);
    // Centre texel is the origin: lit normally from 1 m.
    for c in gt.data[4 * 9 + 4] {
        assert!((c as f64 - 1000.0).abs() < 1e-3, "{c}");
    }
}

#[test]
fn flat_glossy_radiance_over_cosine_is_symmetric_in_light_and_view() {
    let r = renderer(&flat_material(0.4, Some((0.3, 0.2))));
    let dirs = [(10.0, 0.0), (35.0, 80.0), (50.0, 190.0), (70.0, 300.0), (20.0, 150.0)];
    let mut checked = 0;
    for a in dirs {
        for b in dirs {
            let (da, db) = (Direction::from_degrees(a.0, a.1), Direction::from_degrees(b.0, b.1));
            let (tr_ab, _) = trace_origin(&r, da, db);
            let (tr_ba, _) = trace_origin(&r, db, da);
            let x = tr_ab / da.theta.cos();
            let y = tr_ba / db.theta.cos();
            assert!((x - y).abs() <= 1e-9 * x.abs().max(y.abs()), "{a:?} {b:?}: {x} vs {y}");
            checked += 1;
        }
    }
    assert_eq!(checked, 25);
}

/// Radiance (channel 0) at the origin, lamp and camera both 1.5 m away.
fn trace_origin(r: &Renderer, light: Direction, view: Direction) -> (f64, ()) {
    let pose = ScenePose::looking_at(light, view, 1.5, 1.5);
    let o = pose.camera_in_sample().coords;
    let d = -o.normalize();
    let (v, _) = r.trace(&pose, &o, &d, ColourSpace::Camera, true);
    (v[0], ())
}

#[test]
fn corduroy_shadowed_fraction_grows_with_light_zenith() {
    let spec = MaterialSpec::builtin("corduroy").unwrap();
    let r = renderer(&spec);
    for phi in [0.0, 30.0] {
        let mut prev = -1.0;
        let mut fr = Vec::new();
        for theta in (0..=75).step_by(5) {
            let lamp = Point3::from(Direction::from_degrees(theta as f64, phi).to_vector() * 2.0);
            let f = r.shadow_fraction(&lamp);
            fr.push((theta, f));
            assert!(f >= prev, "phi {phi}: not monotonic: {fr:?}");
            prev = f;
        }
        assert!(fr[0].1 < 0.01, "shadow at theta 0: {}", fr[0].1);
        assert!(fr.last().unwrap().1 > 0.3, "little shadow at 75 deg across the wales: {fr:?}");
        eprintln!("phi {phi}: {fr:?}");
    }
    // Along the wales (lamp azimuth 90 deg, wales run along y) the ridges cast little shadow.
    let along = r.shadow_fraction(&Point3::from(Direction::from_degrees(75.0, 90.0).to_vector() * 2.0));
    let across = r.shadow_fraction(&Point3::from(Direction::from_degrees(75.0, 0.0).to_vector() * 2.0));
    assert!(along < 0.5 * across, "along {along} across {across}");
}

#[test]
fn no_negative_or_nan_radiance_at_grazing_poses() {
    let cam = Pinhole { width: 320, height: 240, fx: 900.0, fy: 900.0, cx: 159.5, cy: 119.5 };
    for name in ["lacquered-wood", "corduroy", "glazed-tile", "leather"] {
        let r = renderer(&MaterialSpec::builtin(name).unwrap());
        let mut lit = 0;
        for (lt, lp, vt, vp) in [
            (80.0, 0.0, 75.0, 180.0),
            (89.0, 90.0, 60.0, 270.0),
            (85.0, 45.0, 85.0, 45.0),
            (0.0, 0.0, 88.0, 10.0),
            (75.0, 180.0, 80.0, 0.0),
            (60.0, 300.0, 89.5, 120.0),
        ] {
            let pose =
                ScenePose::looking_at(Direction::from_degrees(lt, lp), Direction::from_degrees(vt, vp), 0.8, 1.2);
            for skips in [true, false] {
                let img = r.render(&pose, &cam, &RenderOptions::with_skips(skips));
                for p in &img.data {
                    for c in p {
                        assert!(c.is_finite() && *c >= 0.0, "{name} {lt}/{lp} {vt}/{vp}: {c}");
                    }
                }
                lit += img.data.iter().filter(|p| p[1] > 0.0).count();
            }
            let gt = r.ground_truth(&pose, 64, 64, None);
            assert!(gt.data.iter().flatten().all(|c| c.is_finite() && *c >= 0.0), "{name}: ground truth");
        }
        assert!(lit > 1000, "{name}: nothing lit");
    }
}

#[test]
fn corduroy_ground_truth_shows_masking_at_grazing_view() {
    let r = renderer(&MaterialSpec::builtin("corduroy").unwrap());
    let light = Direction::from_degrees(30.0, 20.0);
    let diff = |view: Direction| {
        let pose = ScenePose::looking_at(light, view, 1.5, 2.0);
        let gt = r.ground_truth(&pose, 64, 64, None);
        let mut sum = 0.0;
        let mut norm = 0.0;
        for row in 0..64 {
            for col in 0..64 {
                let (x, y) = gt.texel_centre(col, row);
                let u = r.shade_unmasked(&pose, x, y, ColourSpace::Output);
                sum += (gt.data[row * 64 + col][1] as f64 - u[1]).abs();
                norm += u[1].abs();
            }
        }
        sum / norm
    };
    let grazing = diff(Direction::from_degrees(75.0, 180.0));
    let frontal = diff(Direction::from_degrees(0.0, 0.0));
    eprintln!("relative L1 difference, ground truth vs unmasked: grazing {grazing:.3}, frontal {frontal:.3}");
    assert!(grazing > 0.3, "masking barely changes the grazing view: {grazing}");
    assert!(frontal < 0.25 * grazing, "frontal {frontal} vs grazing {grazing}");
}
