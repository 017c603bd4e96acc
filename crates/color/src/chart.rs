//! Colour charts as the calibration sees them: the patch layout (rows, columns, pitch, gap)
//! and each patch's published reference (name, CIE L*a*b* under ICC D50). A real rig's
//! colour calibration needs only this; the simulator's renderer (`btfrig_render::chart`)
//! adds a reflectance spectrum per patch to draw the chart.
//!
//! Patch `k` sits at row `k / cols`, column `k % cols`; row 0 is at `+y` (the top edge seen
//! by a frontal camera, like a texture) and column 0 at `-x`; the chart is centred on the
//! sample frame's origin. Two charts are built in ([`CHART_NAMES`]): the ColorChecker Classic
//! 24 and the ColorChecker SG (140 patches), both with X-Rite's data after November 2014
//! (`sim/spectra/colorchecker24_lab_d50.csv`, `sim/spectra/colorcheckersg140_lab_d50.csv`).

use std::sync::LazyLock;

/// The names of the built-in charts.
pub const CHART_NAMES: [&str; 2] = ["colorchecker24", "colorchecker-sg140"];

/// One patch's published reference.
#[derive(Debug, Clone, PartialEq)]
pub struct PatchReference {
    /// Name, e.g. `dark skin` or `A1`.
    pub name: String,
    /// Published CIE L*a*b* under ICC D50 (the chart maker's values).
    pub lab_d50: [f64; 3],
}

/// A colour chart's layout and published patch references.
#[derive(Debug, Clone, PartialEq)]
pub struct ChartLayout {
    /// Name, e.g. `colorchecker24`.
    pub name: String,
    /// Which published data (edition) the patches' Lab come from.
    pub edition: String,
    /// Patch rows.
    pub rows: usize,
    /// Patch columns.
    pub cols: usize,
    /// Distance between neighbouring patch centres, metres.
    pub pitch_m: f64,
    /// Black gap between neighbouring patches, metres (patch side = pitch - gap).
    pub gap_m: f64,
    /// `rows * cols` patches, row-major.
    pub patches: Vec<PatchReference>,
}

/// Patches of an embedded CSV file: `name` and `L`, `a`, `b` columns found by header name.
fn read_lab_csv(file: &str, text: &str) -> Vec<PatchReference> {
    let mut lines = text.lines().filter(|l| !l.starts_with('#') && !l.trim().is_empty());
    let header: Vec<&str> = lines.next().unwrap_or_else(|| panic!("{file}: no header")).split(',').collect();
    let idx = |n: &str| header.iter().position(|c| c.trim() == n).unwrap_or_else(|| panic!("{file}: no column {n}"));
    let (name, l, a, b) = (idx("name"), idx("L"), idx("a"), idx("b"));
    lines
        .map(|line| {
            let f: Vec<&str> = line.split(',').collect();
            let num = |i: usize| -> f64 { f[i].trim().parse().unwrap_or_else(|e| panic!("{file}: {line}: {e}")) };
            PatchReference { name: f[name].trim().to_string(), lab_d50: [num(l), num(a), num(b)] }
        })
        .collect()
}

static CC24: LazyLock<Vec<PatchReference>> = LazyLock::new(|| {
    read_lab_csv("colorchecker24_lab_d50.csv", include_str!("../../../sim/spectra/colorchecker24_lab_d50.csv"))
});

static SG140: LazyLock<Vec<PatchReference>> = LazyLock::new(|| {
    read_lab_csv("colorcheckersg140_lab_d50.csv", include_str!("../../../sim/spectra/colorcheckersg140_lab_d50.csv"))
});

impl ChartLayout {
    /// ColorChecker Classic 24 (4 x 6), 16 mm pitch and 3 mm gaps: 96 x 64 mm in the default
    /// 100 mm sample region.
    pub fn colorchecker24() -> ChartLayout {
        ChartLayout {
            name: "colorchecker24".into(),
            edition: "ColorChecker Classic, X-Rite data after November 2014 (Lab D50); spectra Ohta 1997 / ISO 17321-1"
                .into(),
            rows: 4,
            cols: 6,
            pitch_m: 0.016,
            gap_m: 0.003,
            patches: CC24.clone(),
        }
    }

    /// ColorChecker SG (10 x 14), 7 mm pitch and 1.5 mm gaps: 98 x 70 mm.
    pub fn colorchecker_sg140() -> ChartLayout {
        ChartLayout {
            name: "colorchecker-sg140".into(),
            edition: "ColorChecker SG, X-Rite data after November 2014 (Lab D50); spectra synthesised".into(),
            rows: 10,
            cols: 14,
            pitch_m: 0.007,
            gap_m: 0.0015,
            patches: SG140.clone(),
        }
    }

    /// A built-in chart by name ([`CHART_NAMES`]).
    pub fn by_name(name: &str) -> Result<ChartLayout, String> {
        match name {
            "colorchecker24" => Ok(Self::colorchecker24()),
            "colorchecker-sg140" => Ok(Self::colorchecker_sg140()),
            _ => Err(format!("unknown colour chart {name:?}: built in are {}", CHART_NAMES.join(", "))),
        }
    }

    /// Side of a patch, metres.
    pub fn patch_side_m(&self) -> f64 {
        self.pitch_m - self.gap_m
    }

    /// Width and height of the patch grid (outer patch edges), metres.
    pub fn extent_m(&self) -> (f64, f64) {
        (self.cols as f64 * self.pitch_m - self.gap_m, self.rows as f64 * self.pitch_m - self.gap_m)
    }

    /// Centre of patch `k` in the sample frame (metres, chart centred on the origin).
    pub fn patch_centre_m(&self, k: usize) -> [f64; 2] {
        let (r, c) = ((k / self.cols) as f64, (k % self.cols) as f64);
        [(c - (self.cols as f64 - 1.0) / 2.0) * self.pitch_m, ((self.rows as f64 - 1.0) / 2.0 - r) * self.pitch_m]
    }

    /// The patch under sample point `(x, y)`, or `None` on a gap or off the chart.
    pub fn patch_at(&self, x: f64, y: f64) -> Option<usize> {
        let c = (x / self.pitch_m + (self.cols as f64 - 1.0) / 2.0).round();
        let r = ((self.rows as f64 - 1.0) / 2.0 - y / self.pitch_m).round();
        if c < 0.0 || r < 0.0 || c >= self.cols as f64 || r >= self.rows as f64 {
            return None;
        }
        let k = r as usize * self.cols + c as usize;
        let [cx, cy] = self.patch_centre_m(k);
        let h = self.patch_side_m() / 2.0;
        ((x - cx).abs() <= h && (y - cy).abs() <= h).then_some(k)
    }

    /// Every problem of the layout on a sample region of side `sample_side_m`.
    pub fn problems(&self, sample_side_m: f64) -> Vec<String> {
        let mut out = Vec::new();
        if self.patches.len() != self.rows * self.cols {
            out.push(format!("chart {}: {} patches for {} x {}", self.name, self.patches.len(), self.rows, self.cols));
        }
        if !(self.pitch_m > 0.0 && self.gap_m >= 0.0 && self.gap_m < self.pitch_m) {
            out.push(format!(
                "chart {}: pitch {} m, gap {} m: need 0 <= gap < pitch",
                self.name, self.pitch_m, self.gap_m
            ));
        }
        let (w, h) = self.extent_m();
        if w > sample_side_m || h > sample_side_m {
            out.push(format!(
                "chart {} is {:.1} x {:.1} mm, larger than the {:.1} mm sample region",
                self.name,
                w * 1e3,
                h * 1e3,
                sample_side_m * 1e3
            ));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layouts_fit_the_default_sample_region_and_patches_are_found_at_their_centres() {
        for name in CHART_NAMES {
            let c = ChartLayout::by_name(name).unwrap();
            assert!(c.problems(0.1).is_empty(), "{:?}", c.problems(0.1));
            for k in 0..c.patches.len() {
                let [x, y] = c.patch_centre_m(k);
                assert_eq!(c.patch_at(x, y), Some(k));
                // Half a gap beyond the patch edge: black.
                let h = c.patch_side_m() / 2.0 + c.gap_m / 4.0;
                assert_eq!(c.patch_at(x + h, y), None);
            }
        }
        // Row 0 at +y, column 0 at -x.
        let c = ChartLayout::colorchecker24();
        let [x0, y0] = c.patch_centre_m(0);
        assert!(x0 < 0.0 && y0 > 0.0);
        assert!(ChartLayout::by_name("it8").unwrap_err().contains("colorchecker24"));
    }

    #[test]
    fn published_references_are_read_in_chart_order() {
        let c = ChartLayout::colorchecker24();
        assert_eq!(c.patches.len(), 24);
        assert_eq!(c.patches[0].name, "dark skin");
        // The white patch (19) is near L* 96, neutral; the black one (24) near L* 20.
        assert!(c.patches[18].lab_d50[0] > 94.0 && c.patches[18].lab_d50[1].abs() < 1.5, "{:?}", c.patches[18]);
        assert!(c.patches[23].lab_d50[0] < 25.0, "{:?}", c.patches[23]);
        let sg = ChartLayout::colorchecker_sg140();
        assert_eq!((sg.patches.len(), sg.patches[0].name.as_str(), sg.patches[139].name.as_str()), (140, "A1", "N10"));
        assert_eq!(sg.patches[0].lab_d50, [96.71, -0.62, 2.06]);
    }
}
