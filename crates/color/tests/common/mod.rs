//! Test helpers: the copied reference CSVs and spectral synthesis of chart patches.
#![allow(dead_code)]

use btfrig_color::space::{bradford, d65_white, mat3_apply, mat3_mul, xyz_to_srgb_matrix, Mat3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// Path of a file in tests/data.
pub fn data_path(name: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data").join(name)
}

/// A CSV file: header names and rows of numbers (`#` lines skipped).
pub struct Csv {
    pub header: Vec<String>,
    pub rows: Vec<Vec<f64>>,
}

impl Csv {
    pub fn read(name: &str) -> Csv {
        let text = std::fs::read_to_string(data_path(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
        let mut lines = text.lines().filter(|l| !l.starts_with('#') && !l.trim().is_empty());
        let header = lines.next().expect("header").split(',').map(|s| s.trim().to_string()).collect();
        let rows = lines.map(|l| l.split(',').map(|v| v.trim().parse::<f64>().expect(l)).collect()).collect();
        Csv { header, rows }
    }

    pub fn col(&self, name: &str) -> Vec<f64> {
        let i = self.header.iter().position(|h| h == name).unwrap_or_else(|| panic!("no column {name}"));
        self.rows.iter().map(|r| r[i]).collect()
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// The 24 Ohta ColorChecker spectra (380–780 nm, 10 nm).
pub fn chart_spectra() -> Vec<Vec<f64>> {
    let c = Csv::read("colorchecker24_reflectance_10nm.csv");
    (1..=24).map(|i| c.col(&format!("p{i:02}"))).collect()
}

/// Camera (Nikon D5100) and observer under one illuminant: camera RGB and target linear sRGB
/// (D65, Bradford-adapted from the lamp white), as btfrig-render's ColourSystem defines them.
pub struct Spectral {
    cam: [Vec<f64>; 3],
    xyz: [Vec<f64>; 3],
    to_srgb: Mat3,
}

impl Spectral {
    pub fn new(illuminant: &str) -> Spectral {
        let ill = Csv::read("illuminants_10nm.csv").col(illuminant);
        let cam = Csv::read("camera_nikon_d5100_npl_10nm.csv");
        let cmf = Csv::read("cie1931_2deg_cmf_10nm.csv");
        let weigh = |s: Vec<f64>| -> Vec<f64> { s.iter().zip(&ill).map(|(a, b)| a * b).collect() };
        let cam = ["R", "G", "B"].map(|k| weigh(cam.col(k)));
        let xyz = ["xbar", "ybar", "zbar"].map(|k| weigh(cmf.col(k)));
        assert_eq!(cam[0].len(), 41);
        let g: f64 = cam[1].iter().sum();
        let y: f64 = xyz[1].iter().sum();
        let cam = cam.map(|v| v.iter().map(|x| x / g).collect::<Vec<_>>());
        let xyz = xyz.map(|v| v.iter().map(|x| x / y).collect::<Vec<_>>());
        let white = [0, 1, 2].map(|k| xyz[k].iter().sum::<f64>());
        let to_srgb = mat3_mul(&xyz_to_srgb_matrix(), &bradford(white, d65_white()));
        Spectral { cam, xyz, to_srgb }
    }

    /// Camera RGB (white reflector: green = 1).
    pub fn camera(&self, r: &[f64]) -> [f64; 3] {
        [0, 1, 2].map(|k| dot(&self.cam[k], r))
    }

    /// Target linear sRGB (white reflector: (1, 1, 1)).
    pub fn target(&self, r: &[f64]) -> [f64; 3] {
        mat3_apply(&self.to_srgb, [0, 1, 2].map(|k| dot(&self.xyz[k], r)))
    }
}

/// `count` random plausible reflectances mixed from the chart's spectra: half additive
/// (convex) mixtures of 2–3 patches, half subtractive (weighted geometric) mixtures, each times
/// a brightness in [0.25, 1].
pub fn mixtures(base: &[Vec<f64>], count: usize, seed: u64) -> Vec<Vec<f64>> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..count)
        .map(|i| {
            let k = rng.gen_range(2..=3);
            let idx: Vec<usize> = (0..k).map(|_| rng.gen_range(0..base.len())).collect();
            let w: Vec<f64> = (0..k).map(|_| rng.gen_range(0.05..1.0)).collect();
            let ws: f64 = w.iter().sum();
            let bright = rng.gen_range(0.25..1.0);
            (0..base[0].len())
                .map(|l| {
                    let v = if i % 2 == 0 {
                        idx.iter().zip(&w).map(|(&j, wj)| wj / ws * base[j][l]).sum::<f64>()
                    } else {
                        idx.iter().zip(&w).map(|(&j, wj)| (wj / ws) * base[j][l].max(1e-4).ln()).sum::<f64>().exp()
                    };
                    bright * v
                })
                .collect()
        })
        .collect()
}

/// Sensor-like noise on patch means: shot noise (full well `full_well` electrons at 1.0) plus
/// read noise `read_e` electrons, averaged over `pixels` pixels.
pub fn add_noise(v: &mut [[f64; 3]], full_well: f64, read_e: f64, pixels: f64, seed: u64) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let n = Normal::new(0.0, 1.0).unwrap();
    for p in v.iter_mut() {
        for c in p.iter_mut() {
            let var_e = (*c * full_well).max(0.0) + read_e * read_e;
            *c += n.sample(&mut rng) * var_e.sqrt() / full_well / pixels.sqrt();
        }
    }
}

/// (camera RGB scaled by `exposure`, target) of spectra.
pub fn pairs(s: &Spectral, spectra: &[Vec<f64>], exposure: f64) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    (spectra.iter().map(|r| s.camera(r).map(|v| v * exposure)).collect(), spectra.iter().map(|r| s.target(r)).collect())
}
