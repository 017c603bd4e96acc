//! The skips are savings, not behaviour changes: images with and without them agree.

use btfrig_core::config::plate::PlateConfig;
use btfrig_core::pose::ScenePose;
use btfrig_core::Direction;
use btfrig_render::material::MaterialSpec;
use btfrig_render::renderer::{Pinhole, RenderOptions, Renderer};

fn resolver(name: &str) -> Result<([f64; 3], [f64; 3]), String> {
    let x = name.strip_prefix("flat:").and_then(|v| v.parse().ok()).unwrap_or(0.3 + (name.len() % 5) as f64 * 0.1);
    Ok(([x, 0.9 * x, 0.7 * x], [x; 3]))
}

const FLAT: &str = r#"
name = "flat-grey"
texels = 128
seed = 1
basis = ["flat:0.6", "flat:0.2"]
[albedo]
pattern = { kind = "noise", scale_m = 0.01 }
stops = [[1.0, 0.0], [0.0, 1.0]]
[specular]
strength = 0.1
roughness = 0.2
"#;

#[test]
fn skips_on_and_off_give_the_same_image() {
    let cam = Pinhole { width: 400, height: 300, fx: 1500.0, fy: 1500.0, cx: 199.5, cy: 149.5 };
    let mut specs: Vec<MaterialSpec> = ["lacquered-wood", "corduroy", "glazed-tile", "leather"]
        .iter()
        .map(|n| MaterialSpec::builtin(n).unwrap().with_texels(128))
        .collect();
    specs.push(MaterialSpec::from_toml(FLAT, "flat-grey").unwrap());
    let poses = [
        ((45.0, 0.0), (0.0, 0.0)),
        ((70.0, 10.0), (60.0, 180.0)),
        ((20.0, 100.0), (75.0, 280.0)),
        ((85.0, 180.0), (30.0, 45.0)),
    ];
    for spec in &specs {
        let r = Renderer::new(&PlateConfig::default(), spec, 1000.0, &resolver).unwrap();
        let mut identical = true;
        for ((lt, lp), (vt, vp)) in poses {
            let pose =
                ScenePose::looking_at(Direction::from_degrees(lt, lp), Direction::from_degrees(vt, vp), 1.0, 1.5);
            let (a, sa) = r.render_with_stats(&pose, &cam, &RenderOptions::with_skips(true));
            let (b, sb) = r.render_with_stats(&pose, &cam, &RenderOptions::with_skips(false));
            let max = a.max_value().max(b.max_value());
            assert!(max > 0.0);
            for (p, q) in a.data.iter().zip(&b.data) {
                for c in 0..3 {
                    if p[c] != q[c] {
                        identical = false;
                    }
                    // Relative to the pixel (1e-6) with a floor of 1e-9 of the image maximum.
                    assert!(
                        (p[c] - q[c]).abs() <= 1e-6 * p[c].abs().max(q[c].abs()) + 1e-9 * max,
                        "{}: {p:?} vs {q:?}",
                        spec.name
                    );
                }
            }
            // The skips really skip something.
            assert!(sa.pixels_traced < sb.pixels_traced);
            // Every lamp-visibility question was asked in both runs; the skips answered some
            // from the slope bound instead of a shadow ray.
            assert_eq!(sa.shadow_rays + sa.shadow_rays_skipped, sb.shadow_rays, "{}", spec.name);
            if spec.name == "flat-grey" || spec.name == "lacquered-wood" {
                assert!(sa.shadow_rays_skipped > 0, "{}: {sa:?}", spec.name);
            }
            if spec.name == "flat-grey" {
                assert_eq!((sa.shadow_rays, sa.marches), (0, 0));
            }
            assert_eq!(sa.sample_hits, sb.sample_hits, "{}", spec.name);
            assert_eq!(sa.plate_hits, sb.plate_hits, "{}", spec.name);
        }
        eprintln!("{}: bit-identical = {identical}", spec.name);
    }
}

/// A dome's camera keeps its marker-edge subsample rays between frames
/// (`CachedCamera::caching_subsamples`): a saving, so every LED's image is bit for bit the
/// uncached camera's, the first time (filling the cache) and again (from it).
#[test]
fn cached_subsample_rays_give_the_same_dome_images() {
    use btfrig_core::config::RigConfig;
    use btfrig_render::rig_scene::CachedCamera;
    let text = btfrig_core::plan::BUILTIN_RIGS.iter().find(|(n, _)| *n == "builtin:bonn-dome-sim").unwrap().1;
    let cfg = RigConfig::from_toml(text, "bonn-dome-sim").unwrap();
    let dome = cfg.require_dome("the test").unwrap();
    let spec = MaterialSpec::builtin("leather").unwrap().with_texels(128);
    let r = Renderer::new(&cfg.plate, &spec, 1000.0, &resolver).unwrap();
    let opts = RenderOptions::default();
    let plain = CachedCamera::new(cfg.camera.to_model().unwrap());
    let cached = plain.clone().caching_subsamples(opts.marker_supersampling as usize);
    for pass in ["filling the cache", "from the cache"] {
        for (c, turn, led) in [(4, 0.0, 0), (4, 0.0, 57), (4, 0.0, 197), (0, 1.2, 100), (9, 2.5, 23)] {
            let pose = dome.scene_pose(c, turn, led);
            let (a, _) = r.render_with_stats(&pose, &plain, &opts);
            let (b, _) = r.render_with_stats(&pose, &cached, &opts);
            assert!(a.max_value() > 0.0);
            assert!(a.data == b.data, "camera {c}, turntable {turn}, LED {led}, {pass}: images differ");
            // Marker edges were supersampled (the image differs from one ray per pixel), so
            // the cache was used.
            let one = r.render(&pose, &plain, &RenderOptions { marker_supersampling: 1, ..opts });
            assert!(one.data != a.data, "camera {c}, turntable {turn}, LED {led}: no marker edge supersampled");
        }
    }
}
