//! Spectra on the 380–780 nm, 10 nm grid, and the published spectral data the simulator
//! uses, embedded in the binary (no file I/O at run time).
//!
//! Brief overview: [`Spectrum`] holds 41 samples, one per 10 nm from 380 to 780 nm. The data
//! files in `sim/spectra/` (each with `#` lines naming its source) are compiled in with
//! `include_str!` and parsed once on first use: [`cie1931_cmf`], [`lamp_spectrum`] (columns of
//! `illuminants_10nm.csv`), [`camera_sensitivity`] (Nikon D5100, Canon 5D Mark II),
//! [`colorchecker24`] (Ohta / ISO 17321-1 reflectances), [`colorchecker24_babelcolor`]
//! (380–730 nm, extended to 780 nm by holding the last value, CIE 15's recommendation for
//! missing ends) and [`colorchecker24_reference`] (published L*a*b*, XYZ and sRGB values).

use std::sync::LazyLock;

/// First wavelength of the grid, nm.
pub const START_NM: f64 = 380.0;
/// Grid step, nm.
pub const STEP_NM: f64 = 10.0;
/// Number of samples (380..=780 nm).
pub const LEN: usize = 41;

/// Errors of the spectral data: bad embedded text (a build-time bug) or unknown names.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum SpectralError {
    /// A data file does not parse.
    #[error("{origin} line {line}: {message}")]
    Parse {
        /// File name.
        origin: String,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// A spectrum name that is not in the data.
    #[error("unknown {kind} {name:?}: known names are {known}")]
    Unknown {
        /// What was looked up ("lamp spectrum", "camera sensitivity").
        kind: &'static str,
        /// The name asked for.
        name: String,
        /// The names that exist.
        known: String,
    },
    /// Samples given on a grid that cannot be resampled (unsorted, mismatched lengths, empty).
    #[error("cannot resample: {0}")]
    BadGrid(String),
}

/// A spectral quantity sampled at 380, 390, ..., 780 nm.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Spectrum(pub [f64; LEN]);

impl Spectrum {
    /// The same value at every wavelength (e.g. 1 = perfect white reflector).
    pub const fn constant(v: f64) -> Self {
        Spectrum([v; LEN])
    }

    /// Wavelength of sample `i`, nm.
    pub fn wavelength(i: usize) -> f64 {
        START_NM + STEP_NM * i as f64
    }

    /// Resamples values given at increasing `wavelengths_nm` onto the grid: linear
    /// interpolation inside, the end values held constant outside (CIE 15 practice).
    pub fn from_samples(wavelengths_nm: &[f64], values: &[f64]) -> Result<Self, SpectralError> {
        if wavelengths_nm.len() != values.len() || values.is_empty() {
            return Err(SpectralError::BadGrid(format!(
                "{} wavelengths for {} values",
                wavelengths_nm.len(),
                values.len()
            )));
        }
        if wavelengths_nm.windows(2).any(|w| !(w[1] > w[0])) {
            return Err(SpectralError::BadGrid("wavelengths must increase strictly".into()));
        }
        let mut out = [0.0; LEN];
        for (i, o) in out.iter_mut().enumerate() {
            let l = Self::wavelength(i);
            let j = wavelengths_nm.partition_point(|&w| w <= l);
            *o = if j == 0 {
                values[0]
            } else if j == values.len() {
                values[values.len() - 1]
            } else {
                let (l0, l1) = (wavelengths_nm[j - 1], wavelengths_nm[j]);
                let t = (l - l0) / (l1 - l0);
                values[j - 1] * (1.0 - t) + values[j] * t
            };
        }
        Ok(Spectrum(out))
    }

    /// Sum over the grid of `self · other` (a Riemann sum without the 10 nm step; every use
    /// in this crate is a ratio, where the step cancels).
    pub fn dot(&self, other: &Spectrum) -> f64 {
        self.0.iter().zip(&other.0).map(|(a, b)| a * b).sum()
    }

    /// Sample-wise product.
    pub fn mul(&self, other: &Spectrum) -> Spectrum {
        let mut out = self.0;
        for (o, b) in out.iter_mut().zip(&other.0) {
            *o *= b;
        }
        Spectrum(out)
    }

    /// Every sample times `k`.
    pub fn scale(&self, k: f64) -> Spectrum {
        Spectrum(self.0.map(|v| v * k))
    }

    /// Sum of the samples.
    pub fn sum(&self) -> f64 {
        self.0.iter().sum()
    }

    /// Largest sample and its wavelength (nm).
    pub fn peak(&self) -> (f64, f64) {
        let (i, v) =
            self.0.iter().enumerate().fold((0, f64::NEG_INFINITY), |acc, (i, &v)| if v > acc.1 { (i, v) } else { acc });
        (v, Self::wavelength(i))
    }

    /// A smooth reflectance spectrum for an RGB reflectance triple: `r·B_r + g·B_g + b·B_b`
    /// with three fixed smooth band functions that sum to 1 at every wavelength (so equal
    /// triples give flat, neutral spectra). Blue covers below ~490 nm, green ~490–590 nm, red
    /// above; transitions are logistic with a 15 nm scale. A convenience for materials given
    /// in RGB: their colour then passes through the spectral camera and observer like any
    /// measured spectrum.
    pub fn from_rgb_reflectance(rgb: [f64; 3]) -> Spectrum {
        let mut out = [0.0; LEN];
        for (i, o) in out.iter_mut().enumerate() {
            let [br, bg, bb] = rgb_band_weights(Self::wavelength(i));
            *o = rgb[0] * br + rgb[1] * bg + rgb[2] * bb;
        }
        Spectrum(out)
    }
}

/// Weights of the red, green and blue bands of [`Spectrum::from_rgb_reflectance`] at `l` nm.
fn rgb_band_weights(l: f64) -> [f64; 3] {
    let logistic = |x: f64| 1.0 / (1.0 + (-x).exp());
    let above_490 = logistic((l - 490.0) / 15.0);
    let above_590 = logistic((l - 590.0) / 15.0);
    [above_590, above_490 - above_590, 1.0 - above_490]
}

/// A parsed CSV table: `#` comment lines, one header line, then numeric rows whose first
/// column is the wavelength.
#[derive(Debug, Clone)]
struct Table {
    columns: Vec<String>,
    rows: Vec<Vec<f64>>,
}

impl Table {
    fn parse(text: &str, origin: &str) -> Result<Table, SpectralError> {
        let err = |line: usize, message: String| SpectralError::Parse { origin: origin.into(), line, message };
        let mut columns: Option<Vec<String>> = None;
        let mut rows = Vec::new();
        for (i, line) in text.lines().enumerate() {
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let fields: Vec<&str> = line.split(',').map(str::trim).collect();
            match &columns {
                None => columns = Some(fields.iter().map(|s| s.to_string()).collect()),
                Some(cols) => {
                    if fields.len() != cols.len() {
                        return Err(err(i + 1, format!("{} fields, header has {}", fields.len(), cols.len())));
                    }
                    let row = fields
                        .iter()
                        .map(|f| f.parse::<f64>().map_err(|e| err(i + 1, format!("{f:?}: {e}"))))
                        .collect::<Result<Vec<_>, _>>()?;
                    rows.push(row);
                }
            }
        }
        let columns = columns.ok_or_else(|| err(0, "no header line".into()))?;
        Ok(Table { columns, rows })
    }

    fn column_index(&self, name: &str) -> Option<usize> {
        self.columns.iter().position(|c| c == name)
    }

    /// Column `name` resampled onto the grid (first column = wavelength).
    fn spectrum(&self, col: usize) -> Spectrum {
        let wl: Vec<f64> = self.rows.iter().map(|r| r[0]).collect();
        let v: Vec<f64> = self.rows.iter().map(|r| r[col]).collect();
        Spectrum::from_samples(&wl, &v).expect("embedded spectral tables have increasing wavelengths")
    }
}

macro_rules! embedded {
    ($name:literal) => {
        ($name, include_str!(concat!("../../../sim/spectra/", $name)))
    };
}

static CMF_CSV: (&str, &str) = embedded!("cie1931_2deg_cmf_10nm.csv");
static ILLUMINANTS_CSV: (&str, &str) = embedded!("illuminants_10nm.csv");
static NIKON_CSV: (&str, &str) = embedded!("camera_nikon_d5100_npl_10nm.csv");
static CANON_CSV: (&str, &str) = embedded!("camera_canon_5dmkii_rawtoaces_10nm.csv");
static CC24_CSV: (&str, &str) = embedded!("colorchecker24_reflectance_10nm.csv");
static CC24_BABEL_CSV: (&str, &str) = embedded!("colorchecker24_reflectance_babelcolor_10nm.csv");
static CC24_LAB_CSV: (&str, &str) = embedded!("colorchecker24_lab_d50.csv");

/// Camera sensitivity names and their files (names match
/// `btfrig_core::config::sensor::KNOWN_CAMERA_SENSITIVITIES`).
const CAMERAS: [(&str, &(&str, &str)); 2] = [("nikon_d5100", &NIKON_CSV), ("canon_5d_mk2", &CANON_CSV)];

fn parse_embedded(file: &(&str, &str)) -> Table {
    // The files are part of the source tree; a parse failure is a build bug, caught by the
    // tests below, so panicking with the file and line is the right report.
    Table::parse(file.1, file.0).unwrap_or_else(|e| panic!("embedded spectral data: {e}"))
}

static CMF: LazyLock<[Spectrum; 3]> = LazyLock::new(|| {
    let t = parse_embedded(&CMF_CSV);
    [1, 2, 3].map(|c| t.spectrum(c))
});
static ILLUMINANTS: LazyLock<Table> = LazyLock::new(|| parse_embedded(&ILLUMINANTS_CSV));
static CAMERA_TABLES: LazyLock<Vec<[Spectrum; 3]>> = LazyLock::new(|| {
    CAMERAS
        .iter()
        .map(|(_, file)| {
            let t = parse_embedded(file);
            ["R", "G", "B"].map(|c| t.spectrum(t.column_index(c).expect("camera files have R, G, B columns")))
        })
        .collect()
});
static CC24: LazyLock<[Spectrum; 24]> = LazyLock::new(|| chart_spectra(&CC24_CSV));
static CC24_BABEL: LazyLock<[Spectrum; 24]> = LazyLock::new(|| chart_spectra(&CC24_BABEL_CSV));

fn chart_spectra(file: &(&str, &str)) -> [Spectrum; 24] {
    let t = parse_embedded(file);
    std::array::from_fn(|i| t.spectrum(t.column_index(&format!("p{:02}", i + 1)).expect("columns p01..p24")))
}

/// CIE 1931 2° colour-matching functions `[x̄, ȳ, z̄]`.
pub fn cie1931_cmf() -> &'static [Spectrum; 3] {
    &CMF
}

/// Names of the lamp spectra (columns of `illuminants_10nm.csv`).
pub fn lamp_spectrum_names() -> Vec<&'static str> {
    ILLUMINANTS.columns[1..].iter().map(String::as_str).collect()
}

/// The relative spectral power distribution of lamp `name` (as published; scale arbitrary).
pub fn lamp_spectrum(name: &str) -> Result<Spectrum, SpectralError> {
    match ILLUMINANTS.column_index(name) {
        Some(c) if c > 0 => Ok(ILLUMINANTS.spectrum(c)),
        _ => Err(SpectralError::Unknown {
            kind: "lamp spectrum",
            name: name.into(),
            known: lamp_spectrum_names().join(", "),
        }),
    }
}

/// Names of the camera sensitivity sets.
pub fn camera_names() -> Vec<&'static str> {
    CAMERAS.iter().map(|(n, _)| *n).collect()
}

/// The relative spectral sensitivities `[R, G, B]` of camera `name` (as published; scale
/// arbitrary; read as responsivity per unit radiant energy).
pub fn camera_sensitivity(name: &str) -> Result<[Spectrum; 3], SpectralError> {
    CAMERAS.iter().position(|(n, _)| *n == name).map(|i| CAMERA_TABLES[i]).ok_or_else(|| SpectralError::Unknown {
        kind: "camera sensitivity",
        name: name.into(),
        known: camera_names().join(", "),
    })
}

/// Spectral reflectances of the 24 ColorChecker Classic patches in chart order (Ohta 1997,
/// ISO 17321-1): patch 1 dark skin ... 19 white, 24 black.
pub fn colorchecker24() -> &'static [Spectrum; 24] {
    &CC24
}

/// The BabelColor average of 30 measured charts (380–730 nm, held constant to 780 nm).
pub fn colorchecker24_babelcolor() -> &'static [Spectrum; 24] {
    &CC24_BABEL
}

/// Published reference values of one ColorChecker patch (X-Rite, after November 2014).
#[derive(Debug, Clone, PartialEq)]
pub struct ChartPatch {
    /// Patch name, e.g. "dark skin".
    pub name: String,
    /// CIE L*a*b* under ICC D50.
    pub lab_d50: [f64; 3],
    /// XYZ under ICC D50, Y of the perfect diffuser = 1.
    pub xyz_d50: [f64; 3],
    /// Linear sRGB (Bradford D50 -> D65), before the transfer function.
    pub srgb_linear: [f64; 3],
}

static CC24_REF: LazyLock<Vec<ChartPatch>> = LazyLock::new(|| {
    let file = &CC24_LAB_CSV;
    let body: String = file.1.lines().filter(|l| !l.starts_with('#')).skip(1).collect::<Vec<_>>().join("\n");
    let header = file.1.lines().find(|l| !l.starts_with('#')).expect("header");
    let cols: Vec<&str> = header.split(',').collect();
    let idx = |n: &str| cols.iter().position(|c| *c == n).unwrap_or_else(|| panic!("{}: no column {n}", file.0));
    body.lines()
        .map(|line| {
            let f: Vec<&str> = line.split(',').collect();
            let num = |n: &str| -> f64 { f[idx(n)].parse().unwrap_or_else(|e| panic!("{}: {line}: {e}", file.0)) };
            ChartPatch {
                name: f[idx("name")].to_string(),
                lab_d50: [num("L"), num("a"), num("b")],
                xyz_d50: [num("X_D50"), num("Y_D50"), num("Z_D50")],
                srgb_linear: [num("sRGB_lin_R"), num("sRGB_lin_G"), num("sRGB_lin_B")],
            }
        })
        .collect()
});

/// Published reference values of the 24 patches, chart order.
pub fn colorchecker24_reference() -> &'static [ChartPatch] {
    &CC24_REF
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embedded_data_parses_with_known_values() {
        let cmf = cie1931_cmf();
        // ȳ peaks at 1.0 at 560 nm (10 nm samples of the 1 nm table, peak 555 nm ~ 1.0).
        assert!((cmf[1].0[18] - 0.995).abs() < 0.01, "{}", cmf[1].0[18]);
        assert!((cmf[0].0[0] - 1.368e-3).abs() < 1e-9);
        let d65 = lamp_spectrum("D65").unwrap();
        assert!((d65.0[0] - 49.9755).abs() < 1e-9);
        assert!((d65.0[18] - 100.0).abs() < 0.01); // normalised to 100 at 560 nm
        assert_eq!(colorchecker24()[18].0[4], 0.84); // white patch at 420 nm
        assert_eq!(colorchecker24_reference().len(), 24);
        assert_eq!(colorchecker24_reference()[18].name, "white 9.5 (.05 D)");
        for name in camera_names() {
            let s = camera_sensitivity(name).unwrap();
            assert!(s.iter().all(|c| c.0.iter().all(|v| *v >= 0.0) && c.sum() > 0.0));
        }
    }

    #[test]
    fn core_config_name_lists_match_the_data() {
        assert_eq!(lamp_spectrum_names(), btfrig_core::config::lamp::KNOWN_LAMP_SPECTRA);
        assert_eq!(camera_names(), btfrig_core::config::sensor::KNOWN_CAMERA_SENSITIVITIES);
    }

    #[test]
    fn unknown_names_list_the_known_ones() {
        let e = lamp_spectrum("HMI").unwrap_err().to_string();
        assert!(e.contains("\"HMI\"") && e.contains("LS_Metal_Halide"), "{e}");
        let e = camera_sensitivity("sony").unwrap_err().to_string();
        assert!(e.contains("nikon_d5100"), "{e}");
    }

    #[test]
    fn babelcolor_is_extended_by_holding_the_last_value() {
        let b = colorchecker24_babelcolor();
        // 730 nm is index 35; 740..780 hold it.
        for p in b.iter() {
            assert!(p.0[36..].iter().all(|v| *v == p.0[35]));
        }
        assert_eq!(b[0].0[0], 0.055);
    }

    #[test]
    fn resampling_interpolates_linearly_and_holds_ends() {
        let s = Spectrum::from_samples(&[400.0, 500.0, 700.0], &[1.0, 2.0, 0.0]).unwrap();
        assert_eq!(s.0[0], 1.0); // 380 held
        assert!((s.0[5] - 1.3).abs() < 1e-12); // 430 nm
        assert!((s.0[22] - 1.0).abs() < 1e-12); // 600 nm, midway 2 -> 0
        assert_eq!(s.0[40], 0.0);
        assert!(Spectrum::from_samples(&[500.0, 400.0], &[1.0, 2.0]).is_err());
        assert!(Spectrum::from_samples(&[500.0], &[1.0, 2.0]).is_err());
    }

    #[test]
    fn parse_errors_name_file_and_line() {
        let e = Table::parse("# c\nwl,a\n380,1\n390,x\n", "t.csv").unwrap_err().to_string();
        assert!(e.starts_with("t.csv line 4"), "{e}");
        let e = Table::parse("wl,a\n380,1,2\n", "t.csv").unwrap_err().to_string();
        assert!(e.contains("line 2"), "{e}");
    }

    #[test]
    fn rgb_bands_partition_unity() {
        let grey = Spectrum::from_rgb_reflectance([0.4, 0.4, 0.4]);
        assert!(grey.0.iter().all(|v| (v - 0.4).abs() < 1e-12));
        let red = Spectrum::from_rgb_reflectance([1.0, 0.0, 0.0]);
        assert!(red.0[40] > 0.99 && red.0[0] < 0.01);
    }
}
