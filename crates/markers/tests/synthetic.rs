//! The detector on analytically drawn images: markers drawn by exact-ish area sampling
//! (32 x 32 points per pixel) through a known homography, so the true corners are known
//! without the renderer; images without markers; a marker cut by the image border.

use btfrig_markers::{detect, detect_in_windows, DetectParams, Dictionary, GrayImage, Window};
use nalgebra::{Matrix3, Point2, Vector2, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

const W: usize = 400;
const H: usize = 300;

/// Homography from the unit square (corner order 0..3 = (0,0), (1,0), (1,1), (0,1)) to `q`.
fn square_to_quad(q: &[Point2<f64>; 4]) -> Matrix3<f64> {
    let src = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)];
    let mut a = nalgebra::SMatrix::<f64, 8, 8>::zeros();
    let mut b = nalgebra::SVector::<f64, 8>::zeros();
    for k in 0..4 {
        let (x, y) = src[k];
        let (u, v) = (q[k].x, q[k].y);
        let r1 = [x, y, 1.0, 0.0, 0.0, 0.0, -u * x, -u * y];
        let r2 = [0.0, 0.0, 0.0, x, y, 1.0, -v * x, -v * y];
        for j in 0..8 {
            a[(2 * k, j)] = r1[j];
            a[(2 * k + 1, j)] = r2[j];
        }
        b[2 * k] = u;
        b[2 * k + 1] = v;
    }
    let h = a.lu().solve(&b).unwrap();
    Matrix3::new(h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], 1.0)
}

/// Draws marker `id` with outer corners `q` (canonical order) onto a white (1.0) image with
/// black 0.05, by area sampling (integer coordinates = pixel centres).
fn draw(img: &mut [f32], dict: &Dictionary, id: usize, q: &[Point2<f64>; 4]) {
    let hinv = square_to_quad(q).try_inverse().unwrap();
    let n = dict.size + 2;
    let (x0, x1) = (q.iter().map(|p| p.x).fold(f64::MAX, f64::min), q.iter().map(|p| p.x).fold(f64::MIN, f64::max));
    let (y0, y1) = (q.iter().map(|p| p.y).fold(f64::MAX, f64::min), q.iter().map(|p| p.y).fold(f64::MIN, f64::max));
    let ss = 32;
    for py in (y0.floor() as i64 - 1).max(0)..=(y1.ceil() as i64 + 1).min(H as i64 - 1) {
        for px in (x0.floor() as i64 - 1).max(0)..=(x1.ceil() as i64 + 1).min(W as i64 - 1) {
            let mut acc = 0.0;
            for sy in 0..ss {
                for sx in 0..ss {
                    let x = px as f64 - 0.5 + (sx as f64 + 0.5) / ss as f64;
                    let y = py as f64 - 0.5 + (sy as f64 + 0.5) / ss as f64;
                    let m = hinv * Vector3::new(x, y, 1.0);
                    let (u, v) = (m.x / m.z, m.y / m.z);
                    let white = if (0.0..1.0).contains(&u) && (0.0..1.0).contains(&v) {
                        let (c, r) = ((u * n as f64) as usize, (v * n as f64) as usize);
                        r > 0 && c > 0 && r < n - 1 && c < n - 1 && dict.is_white(id, r - 1, c - 1)
                    } else {
                        true
                    };
                    acc += if white { 1.0 } else { 0.05 };
                }
            }
            img[py as usize * W + px as usize] = (acc / (ss * ss) as f64) as f32;
        }
    }
}

fn add_noise(img: &mut [f32], sigma: f64, seed: u64) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let n = Normal::new(0.0, sigma).unwrap();
    for v in img.iter_mut() {
        *v += n.sample(&mut rng) as f32;
    }
}

/// Corners of a square of side `s` centred at `c`, turned by `angle` (and, optionally, in
/// perspective by squeezing one side).
fn quad(c: (f64, f64), s: f64, angle: f64, squeeze: f64) -> [Point2<f64>; 4] {
    let h = s / 2.0;
    let pts = [(-h, -h), (h, -h * (1.0 - squeeze)), (h, h * (1.0 - squeeze)), (-h, h)];
    let (sn, cs) = angle.sin_cos();
    pts.map(|(x, y)| Point2::new(c.0 + cs * x - sn * y, c.1 + sn * x + cs * y))
}

#[test]
fn drawn_markers_in_every_rotation_give_ids_and_corners_in_canonical_order() {
    let dict = Dictionary::dict_4x4_50();
    let mut worst: f64 = 0.0;
    for (k, angle_deg) in [3.0f64, 93.0, 183.0, 273.0, 37.0, -61.0].iter().enumerate() {
        let mut img = vec![1.0f32; W * H];
        let id = 7 * k + 3;
        let q = quad((200.3, 148.7), 90.0 + 5.0 * k as f64, angle_deg.to_radians(), 0.15 * (k % 2) as f64);
        draw(&mut img, &dict, id, &q);
        add_noise(&mut img, 0.01, 100 + k as u64);
        let g = GrayImage::new(W, H, &img).unwrap();
        let d = detect(&g, &dict, &DetectParams::default()).unwrap();
        assert_eq!(d.len(), 1, "angle {angle_deg}: {d:?}");
        assert_eq!(d[0].id as usize, id, "angle {angle_deg}");
        assert_eq!(d[0].hamming, 0);
        for (j, (found, truth)) in d[0].corners.iter().zip(&q).enumerate() {
            let e = (found - truth).norm();
            worst = worst.max(e);
            // Pins the pixel-centre convention too: a half-pixel shift would fail here.
            assert!(e < 0.08, "angle {angle_deg} corner {j}: {found} vs {truth} ({e} px)");
        }
    }
    println!("drawn markers: worst corner error {worst:.4} px");
}

#[test]
fn a_flipped_bit_is_corrected_and_two_are_not_accepted_as_another_id() {
    // Redraw marker 5 with data modules flipped by drawing a tiny dictionary of its own.
    let dict = Dictionary::dict_4x4_50();
    for (flips, expect) in [(1u32, Some(5u32)), (2, None)] {
        let mut code = dict.codes[5];
        for b in 0..flips {
            code ^= 1 << (5 * b + 1);
        }
        let one = Dictionary { name: "one".into(), size: 4, codes: vec![code] };
        let mut img = vec![1.0f32; W * H];
        let q = quad((200.0, 150.0), 100.0, 0.2, 0.0);
        draw(&mut img, &one, 0, &q);
        let d = detect(&GrayImage::new(W, H, &img).unwrap(), &dict, &DetectParams::default()).unwrap();
        // With two flips the code may be within one bit of another id only if the dictionary's
        // distance allowed it; DICT_4X4_50's minimum distance is 3 or more, so nothing decodes
        // unless exactly this code is 1 bit from another (checked here explicitly).
        let near_other = (0..50).filter(|&i| i != 5).any(|i| {
            let mut c = code;
            (0..4).any(|_| {
                let hit = (c ^ dict.codes[i]).count_ones() <= 1;
                c = dict.rotate(c);
                hit
            })
        });
        match expect {
            Some(id) => {
                assert_eq!(d.len(), 1, "{d:?}");
                assert_eq!(d[0].id, id);
                assert_eq!(d[0].hamming, 1);
                assert!(d[0].quality.flags & btfrig_markers::Quality::CORRECTED != 0);
            }
            None if !near_other => assert!(d.is_empty(), "two flipped bits decoded as {d:?}"),
            None => {}
        }
    }
}

#[test]
fn images_without_markers_give_no_detection() {
    let dict = Dictionary::dict_4x4_50();
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    // A lit gradient with noise, black squares (solid, hollow, with a 4x4 random pattern
    // that is not a code), a checkerboard and random dark blobs.
    let mut img: Vec<f32> =
        (0..W * H).map(|i| 0.6 + 0.3 * (i % W) as f32 / W as f32 + 0.1 * (i / W) as f32 / H as f32).collect();
    let mut fill = |x0: usize, y0: usize, s: usize, f: &dyn Fn(usize, usize) -> bool| {
        for y in y0..y0 + s {
            for x in x0..x0 + s {
                if f(x - x0, y - y0) {
                    img[y * W + x] = 0.05;
                }
            }
        }
    };
    fill(20, 20, 60, &|_, _| true);
    fill(100, 20, 60, &|x, y| x < 10 || y < 10 || x >= 50 || y >= 50);
    fill(180, 20, 80, &|x, y| ((x / 10) + (y / 10)) % 2 == 0);
    fill(280, 20, 60, &|x, y| !(10..50).contains(&x) || !(10..50).contains(&y) || (x / 10 + 2 * (y / 10)) % 3 == 0);
    for _ in 0..40 {
        let (cx, cy, r) = (rng.gen_range(20.0..380.0), rng.gen_range(120.0..280.0), rng.gen_range(3.0..20.0));
        for y in 0..H {
            for x in 0..W {
                if (x as f64 - cx).hypot(y as f64 - cy) < r {
                    img[y * W + x] = 0.1;
                }
            }
        }
    }
    add_noise(&mut img, 0.02, 8);
    let d = detect(&GrayImage::new(W, H, &img).unwrap(), &dict, &DetectParams::default()).unwrap();
    assert!(d.is_empty(), "false detections {d:?}");
    // Pure noise around zero (black velvet) and a flat image.
    let mut dark = vec![0.0f32; W * H];
    add_noise(&mut dark, 0.01, 9);
    assert!(detect(&GrayImage::new(W, H, &dark).unwrap(), &dict, &DetectParams::default()).unwrap().is_empty());
    let flat = vec![0.5f32; W * H];
    assert!(detect(&GrayImage::new(W, H, &flat).unwrap(), &dict, &DetectParams::default()).unwrap().is_empty());
}

#[test]
fn a_marker_cut_by_the_image_border_is_rejected() {
    let dict = Dictionary::dict_4x4_50();
    let mut img = vec![1.0f32; W * H];
    // Marker 1 hangs 20 px over the left border; marker 2 is whole, 6 px from the right one.
    draw(&mut img, &dict, 1, &quad((20.0, 150.0), 80.0, 0.1, 0.0));
    let whole = quad((W as f64 - 50.0, 150.0), 80.0, 0.0, 0.0);
    draw(&mut img, &dict, 2, &whole);
    add_noise(&mut img, 0.01, 3);
    let d = detect(&GrayImage::new(W, H, &img).unwrap(), &dict, &DetectParams::default()).unwrap();
    assert_eq!(d.iter().map(|d| d.id).collect::<Vec<_>>(), vec![2], "{d:?}");
}

#[test]
fn partly_covered_marker_is_rejected() {
    // A dark object (the sample's edge, a shadow) covering a corner of the marker joins its
    // region: the region is no quad, or the edges do not fit lines.
    let dict = Dictionary::dict_4x4_50();
    let mut img = vec![1.0f32; W * H];
    draw(&mut img, &dict, 9, &quad((200.0, 150.0), 100.0, 0.05, 0.0));
    for y in 80..135 {
        for x in 120..175 {
            img[y * W + x] = 0.05;
        }
    }
    let d = detect(&GrayImage::new(W, H, &img).unwrap(), &dict, &DetectParams::default()).unwrap();
    assert!(d.is_empty(), "{d:?}");
}

#[test]
fn bad_inputs_are_named() {
    let dict = Dictionary::dict_4x4_50();
    let e = GrayImage::new(10, 10, &[0.0; 99]).unwrap_err();
    assert!(e.to_string().contains("99"), "{e}");
    let img = vec![0.0f32; 100];
    let bad = GrayImage { width: 11, height: 10, data: &img };
    assert!(matches!(detect(&bad, &dict, &DetectParams::default()), Err(btfrig_markers::DetectError::BadImage { .. })));
    let g = GrayImage::new(10, 10, &img).unwrap();
    let p = DetectParams { threshold_window_px: 4, ..DetectParams::default() };
    let e = detect(&g, &dict, &p).unwrap_err();
    assert!(e.to_string().contains("threshold_window_px"), "{e}");
    let cam = btfrig_core::camera::CameraModel::pinhole(20, 10, 100.0).unwrap();
    let e = detect(&g, &dict, &DetectParams { camera: Some(cam), ..DetectParams::default() }).unwrap_err();
    assert!(e.to_string().contains("20 x 10"), "{e}");
}

#[test]
fn dictionary_agrees_with_the_renderers_copy() {
    let ours = Dictionary::dict_4x4_50();
    let theirs = btfrig_render::markers::MarkerDictionary::by_name("DICT_4X4_50").unwrap();
    assert_eq!(ours.codes.len(), theirs.bits.len());
    for id in 0..ours.codes.len() {
        for r in 0..4 {
            for c in 0..4 {
                assert_eq!(ours.is_white(id, r, c), theirs.is_white(id, r + 1, c + 1), "id {id} ({r}, {c})");
            }
        }
    }
}

#[test]
fn windows_find_what_the_whole_frame_finds_and_drop_what_they_cut() {
    // Two markers and a dark bar on a noisy, shaded image; windows around each marker give
    // exactly the whole-frame detections; a window through a marker finds nothing there and
    // counts the cut region; a window on the bar only finds nothing.
    let dict = Dictionary::dict_4x4_50();
    let mut img: Vec<f32> = (0..W * H).map(|i| 0.7 + 0.3 * (i % W) as f32 / W as f32).collect();
    let qa = quad((100.4, 120.2), 70.0, 0.3, 0.1);
    let qb = quad((290.7, 160.1), 80.0, -0.5, 0.0);
    draw(&mut img, &dict, 11, &qa);
    draw(&mut img, &dict, 23, &qb);
    for y in 250..270 {
        for x in 150..380 {
            img[y * W + x] = 0.05;
        }
    }
    add_noise(&mut img, 0.01, 77);
    let g = GrayImage::new(W, H, &img).unwrap();
    let p = DetectParams::default();
    let whole = detect(&g, &dict, &p).unwrap();
    assert_eq!(whole.iter().map(|d| d.id).collect::<Vec<_>>(), vec![11, 23]);
    let around = [Window::new(40, 60, 165, 185), Window::new(220, 90, 370, 235)];
    let found = detect_in_windows(&g, &dict, &p, &around).unwrap();
    assert_eq!(found.detections.len(), 2);
    for (a, b) in whole.iter().zip(&found.detections) {
        assert_eq!(a.id, b.id);
        for k in 0..4 {
            // Same pixels, same fits: only the threshold's integral starts elsewhere.
            assert!((a.corners[k] - b.corners[k]).norm() < 1e-9, "{a:?} vs {b:?}");
            assert!((a.corner_sigma_px[k] - b.corner_sigma_px[k]).abs() < 1e-12);
        }
    }
    assert_eq!(found.pixels, around.iter().map(Window::area).sum::<usize>());
    // A window ending in the middle of marker 23, and one over the bar's middle.
    let cut =
        detect_in_windows(&g, &dict, &p, &[Window::new(220, 90, 290, 235), Window::new(200, 240, 300, 290)]).unwrap();
    assert!(cut.detections.is_empty(), "{:?}", cut.detections);
    assert!(cut.cut_by_window >= 2, "cut regions counted: {}", cut.cut_by_window);
    // Windows past the image are clipped; a window covering the frame is the whole frame.
    let all = detect_in_windows(&g, &dict, &p, &[Window::new(0, 0, W + 50, H + 50)]).unwrap();
    assert_eq!(all.detections, whole);
    assert_eq!((all.pixels, all.cut_by_window), (W * H, 0));
}

#[test]
fn regions_searched_on_binned_pixels_give_the_same_corners_and_still_drop_cut_and_covered_markers() {
    // The scene of the windows test plus a partly covered marker, searched with the regions
    // on 2 x 2 and 3 x 3 means: the corner fits read the full image, so the corners are the
    // full-resolution search's to well under their accuracy (~0.01 px); what the regions
    // decide (a cut region, a marker merged with a dark patch) is decided the same way.
    let dict = Dictionary::dict_4x4_50();
    let mut img: Vec<f32> = (0..W * H).map(|i| 0.7 + 0.3 * (i % W) as f32 / W as f32).collect();
    draw(&mut img, &dict, 11, &quad((100.4, 120.2), 70.0, 0.3, 0.1));
    draw(&mut img, &dict, 23, &quad((290.7, 160.1), 80.0, -0.5, 0.0));
    draw(&mut img, &dict, 9, &quad((330.0, 60.0), 60.0, 0.05, 0.0));
    for y in 250..270 {
        for x in 150..380 {
            img[y * W + x] = 0.05;
        }
    }
    // Covers a corner of marker 9.
    for y in 15..45 {
        for x in 280..310 {
            img[y * W + x] = 0.05;
        }
    }
    add_noise(&mut img, 0.01, 77);
    let g = GrayImage::new(W, H, &img).unwrap();
    let full = detect(&g, &dict, &DetectParams::default()).unwrap();
    assert_eq!(full.iter().map(|d| d.id).collect::<Vec<_>>(), vec![11, 23]);
    for bin in [2, 3] {
        let p = DetectParams { region_bin: bin, ..DetectParams::default() };
        let binned = detect(&g, &dict, &p).unwrap();
        assert_eq!(binned.iter().map(|d| d.id).collect::<Vec<_>>(), vec![11, 23], "bin {bin}");
        for (a, b) in full.iter().zip(&binned) {
            for k in 0..4 {
                let d = (a.corners[k] - b.corners[k]).norm();
                assert!(d < 1e-6, "bin {bin}, marker {} corner {k}: {d} px from the full search", a.id);
                assert!((a.corner_sigma_px[k] - b.corner_sigma_px[k]).abs() < 1e-3);
            }
        }
        let around = [Window::new(40, 60, 165, 185), Window::new(220, 90, 370, 235)];
        let found = detect_in_windows(&g, &dict, &p, &around).unwrap();
        assert_eq!(found.detections.iter().map(|d| d.id).collect::<Vec<_>>(), vec![11, 23], "bin {bin}");
        let cut = detect_in_windows(&g, &dict, &p, &[Window::new(220, 90, 290, 235), Window::new(200, 240, 300, 290)])
            .unwrap();
        assert!(cut.detections.is_empty(), "bin {bin}: {:?}", cut.detections);
        assert!(cut.cut_by_window >= 2, "bin {bin}: cut regions counted: {}", cut.cut_by_window);
    }
    let e = detect(&g, &dict, &DetectParams { region_bin: 5, ..DetectParams::default() }).unwrap_err();
    assert!(e.to_string().contains("region_bin"), "{e}");
}

#[test]
fn a_thin_marker_gets_its_corners_from_the_module_grid_unless_a_bit_was_corrected() {
    // A marker foreshortened 6 times (90 x 15 px, modules 2.5 px across its long sides) along
    // the pixel diagonal, as at 80 degrees: the module grid fit applies (modules under
    // `module_grid_below_px`). It needs the true bits: with a corrected bit the edge model's
    // corners stay, exactly.
    let dict = Dictionary::dict_4x4_50();
    let (c, a) = (Point2::new(200.2, 150.4), 45f64.to_radians());
    let (u, v) = (Vector2::new(a.cos(), a.sin()) * 90.0, Vector2::new(-a.sin(), a.cos()) * 15.0);
    let q = [c - u / 2.0 - v / 2.0, c + u / 2.0 - v / 2.0, c + u / 2.0 + v / 2.0, c - u / 2.0 + v / 2.0];
    let grid = DetectParams::default();
    assert_eq!(grid.module_grid_below_px, 4.0);
    let edges_only = DetectParams { module_grid_below_px: 0.0, ..grid.clone() };
    // Error across the long sides (what a foreshortened texel is sensitive to), worst corner.
    let across = |d: &btfrig_markers::Detection| -> f64 {
        let n = v.normalize();
        d.corners.iter().zip(&q).map(|(f, t)| (f - t).dot(&n).abs()).fold(0.0, f64::max)
    };
    let (mut worst_grid, mut worst_edges) = (0.0f64, 0.0f64);
    for seed in 0..4 {
        let id = 11 + seed as usize;
        let mut img = vec![1.0f32; W * H];
        draw(&mut img, &dict, id, &q);
        add_noise(&mut img, 0.01, 300 + seed);
        let g = GrayImage::new(W, H, &img).unwrap();
        let (dg, de) = (detect(&g, &dict, &grid).unwrap(), detect(&g, &dict, &edges_only).unwrap());
        assert_eq!((dg.len(), de.len()), (1, 1), "seed {seed}: {dg:?} / {de:?}");
        assert_eq!((dg[0].id as usize, dg[0].hamming), (id, 0));
        assert_ne!(dg[0].corners, de[0].corners, "seed {seed}: the grid fit did not run");
        worst_grid = worst_grid.max(across(&dg[0]));
        worst_edges = worst_edges.max(across(&de[0]));
        // Below the marker's modules the setting changes nothing.
        let off = DetectParams { module_grid_below_px: 2.0, ..grid.clone() };
        assert_eq!(detect(&g, &dict, &off).unwrap(), de, "seed {seed}: modules of 2.5 px are not under 2 px");
    }
    println!("thin marker, worst error across the long sides: {worst_grid:.4} px grid, {worst_edges:.4} px edges only");
    assert!(worst_grid < 0.015 && worst_grid < worst_edges, "grid: {worst_grid} px, edges only {worst_edges} px");
    // A corrected bit: the same corners as the edge model alone.
    let mut code = dict.codes[5];
    code ^= 1 << 6;
    let one = Dictionary { name: "one".into(), size: 4, codes: vec![code] };
    let mut img = vec![1.0f32; W * H];
    draw(&mut img, &one, 0, &q);
    add_noise(&mut img, 0.01, 310);
    let g = GrayImage::new(W, H, &img).unwrap();
    let (dg, de) = (detect(&g, &dict, &grid).unwrap(), detect(&g, &dict, &edges_only).unwrap());
    assert_eq!(dg.len(), 1, "{dg:?}");
    assert_eq!((dg[0].id, dg[0].hamming), (5, 1));
    assert_eq!(dg, de, "a marker with a corrected bit must keep the edge model's corners");
    // The setting is checked.
    let bad = DetectParams { module_grid_below_px: -1.0, ..grid };
    let e = detect(&g, &dict, &bad).unwrap_err().to_string();
    assert!(e.contains("module_grid_below_px"), "{e}");
}
