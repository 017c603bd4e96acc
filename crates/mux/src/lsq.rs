//! Least squares with calibrated intensities, dead and stuck LEDs, and the high-level
//! demultiplexer.
//!
//! **Model.** The measured pattern matrix is `W = S diag(a)` (`a_j` = calibrated intensity of
//! LED `j`, 0 for an always-off slot) or any measured `frames × sources` matrix. Per column
//! the frames are `m = W i + ν` and the solution is the least-squares `î = W⁺ m`, computed
//! once per fault configuration as the pseudo-inverse by SVD,
//! `W⁺ = V Σ⁻¹ Uᵀ`, in f64, and applied to tiles as a matrix product. The condition number
//! `σ_max/σ_min` is checked against [`LsParams::max_condition`]: an ill-conditioned
//! calibration is a [`MuxError::IllConditioned`] naming the weakest source, never NaN.
//! Sources whose column norm is below `min_relative_intensity` of the largest are excluded
//! (image 0, reported) before the solve.
//!
//! **Faults** change the columns: a *dead* LED's column is removed (its image is 0); a *stuck*
//! LED is lit in every frame, so its column becomes `a_j · 1` (its image is still an unknown;
//! a second stuck LED is indistinguishable from the first and is merged into it). With the
//! nominal `S⁻¹`, a stuck LED `j` leaves `c_j = 2/(n+1) a_j i_j` and adds the same
//! `2/(n+1) a_j i_j` to every other image and to every always-off slot; a dead LED leaves
//! `c_j ≈ 0` and touches nothing else.
//!
//! **Detection** ([`detect_faults`], from the nominal demultiplexed images on a sample of
//! columns): per source the mean `μ_j` of `c_j / a_j`, its standard error and `z = μ/se`, and
//! `μ_j / median(μ)`. A source darker than `suspect_ratio` of the median, and significantly so
//! (`median − μ_j >= z_zero · se_j`, so noise alone never makes a suspect), is *dead* when `|z|` is
//! below `z_zero` (statistically no light), *stuck* when rescaling by `(n+1)/2` brings it back
//! into the plausible range of the others and (if the code has always-off slots) the slots'
//! mean is consistent with the matching offset `c_v ≈ c_j`, else *dim* (reported, left alone).
//!
//! **Solving around**: [`Demultiplexer::run`] demultiplexes with the fast path, detects, and
//! if there are faults re-solves in the demultiplexed domain: `î = W_f⁺ m = (W_f⁺ S) c`.
//! Without a fault the fast path's `c_j / a_j` is already the exact solution.

use nalgebra::{DMatrix, DMatrixView, DMatrixViewMut};
use rayon::prelude::*;

use crate::demux::{Accumulate, DemuxParams, Demuxer, Method};
use crate::error::MuxError;
use crate::kernel::Real;
use crate::smatrix::SMatrix;
use crate::tile::{check_shape, for_each_tile, for_each_tile_io, Par};

/// The role of a source in a solve.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SourceState {
    /// Lit as the pattern matrix says.
    Nominal,
    /// Never lights: column removed, image 0.
    Dead,
    /// Lit in every frame: column `a_j · 1`.
    Stuck,
    /// Not solved for (always-off slot, too dim, or a merged second stuck LED): image 0.
    Excluded,
}

/// A measured pattern matrix `W` (`frames × sources`, f64).
#[derive(Debug, Clone, PartialEq)]
pub struct PatternModel {
    w: DMatrix<f64>,
}

impl PatternModel {
    /// `W = S diag(intensities)`; `intensities.len()` must be the order, each finite and
    /// `>= 0` (0 = never lit, e.g. an always-off slot).
    pub fn from_smatrix(s: &SMatrix, intensities: &[f64]) -> Result<PatternModel, MuxError> {
        let n = s.order();
        check_intensities(intensities, n)?;
        let w = DMatrix::from_fn(n, n, |i, j| f64::from(s.get(i, j)) * intensities[j]);
        Ok(PatternModel { w })
    }

    /// Any measured `frames × sources` matrix, row-major.
    pub fn from_rows(frames: usize, sources: usize, w: &[f64]) -> Result<PatternModel, MuxError> {
        check_shape("pattern matrix", w.len(), frames, sources)?;
        if let Some(i) = w.iter().position(|v| !v.is_finite()) {
            return Err(MuxError::BadPattern { frame: i / sources, source_index: i % sources, value: w[i] });
        }
        Ok(PatternModel { w: DMatrix::from_row_slice(frames, sources, w) })
    }

    /// Frames (rows).
    pub fn frames(&self) -> usize {
        self.w.nrows()
    }

    /// Sources (columns).
    pub fn sources(&self) -> usize {
        self.w.ncols()
    }

    /// The matrix `W`.
    pub fn W(&self) -> &DMatrix<f64> {
        &self.w
    }
}

fn check_intensities(a: &[f64], n: usize) -> Result<(), MuxError> {
    check_shape("LED intensities", a.len(), n, 1)?;
    if let Some(i) = a.iter().position(|v| !(v.is_finite() && *v >= 0.0)) {
        return Err(MuxError::BadIntensity { index: i, value: a[i] });
    }
    Ok(())
}

/// Tuning of [`LeastSquares`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LsParams {
    /// Sources whose column norm is below this fraction of the largest are excluded
    /// (default 1e-3: such an LED's image would carry 1000x the noise).
    pub min_relative_intensity: f64,
    /// Largest condition number accepted (default 1e6).
    pub max_condition: f64,
    /// Columns per tile of the apply (default 256).
    pub tile: usize,
    /// Accumulation precision of the apply (the factorisation is always f64).
    pub accumulate: Accumulate,
}

impl Default for LsParams {
    fn default() -> Self {
        LsParams { min_relative_intensity: 1e-3, max_condition: 1e6, tile: 256, accumulate: Accumulate::F32 }
    }
}

/// Per-thread buffers of a tile product: (x f64, y f64, x f32, y f32).
type ApplyScratch = (Vec<f64>, Vec<f64>, Vec<f32>, Vec<f32>);
/// [`ApplyScratch`] plus the copy of the tile's input runs.
type InPlaceScratch = (Vec<f64>, Vec<f64>, Vec<f32>, Vec<f32>, Vec<f32>);

/// A factored least-squares solve `î = W⁺ m` for a pattern matrix and source states.
#[derive(Debug, Clone)]
pub struct LeastSquares {
    frames: usize,
    sources: usize,
    /// Per source: its index among the unknowns.
    unknown: Vec<Option<usize>>,
    /// `W⁺` (unknowns × frames).
    pinv: DMatrix<f64>,
    states: Vec<SourceState>,
    condition: f64,
    tile: usize,
    accumulate: Accumulate,
}

impl LeastSquares {
    /// Factors `model` with `states` (one per source; `Nominal` sources below
    /// `min_relative_intensity` become `Excluded`).
    pub fn new(model: &PatternModel, states: &[SourceState], params: &LsParams) -> Result<LeastSquares, MuxError> {
        let (f, n) = (model.frames(), model.sources());
        check_shape("source states", states.len(), n, 1)?;
        let w = model.W();
        let norms: Vec<f64> = (0..n).map(|j| w.column(j).norm()).collect();
        let max_norm = norms.iter().cloned().fold(0.0, f64::max);
        let mut states = states.to_vec();
        let mut stuck_seen = false;
        for j in 0..n {
            match states[j] {
                SourceState::Nominal if norms[j] <= params.min_relative_intensity * max_norm => {
                    states[j] = SourceState::Excluded;
                }
                SourceState::Stuck if stuck_seen => states[j] = SourceState::Excluded,
                SourceState::Stuck => stuck_seen = true,
                _ => {}
            }
        }
        let cols: Vec<usize> =
            (0..n).filter(|&j| matches!(states[j], SourceState::Nominal | SourceState::Stuck)).collect();
        let u = cols.len();
        if u > f || u == 0 {
            return Err(MuxError::Underdetermined { frames: f, unknowns: u, excluded: n - u });
        }
        let weff = DMatrix::from_fn(f, u, |i, k| {
            let j = cols[k];
            if states[j] == SourceState::Stuck {
                // Lit in every frame at its usual level (the largest entry of its column).
                w.column(j).amax().max(f64::MIN_POSITIVE)
            } else {
                w[(i, j)]
            }
        });
        let svd = nalgebra::SVD::new(weff, true, true);
        let sv = &svd.singular_values;
        let (mut smax, mut smin, mut imin) = (0.0f64, f64::INFINITY, 0);
        for (k, &s) in sv.iter().enumerate() {
            smax = smax.max(s);
            if s < smin {
                smin = s;
                imin = k;
            }
        }
        let condition = if smin > 0.0 { smax / smin } else { f64::INFINITY };
        let (Some(uu), Some(vt)) = (svd.u.as_ref(), svd.v_t.as_ref()) else {
            unreachable!("SVD computed with U and V");
        };
        if condition.is_nan() || condition > params.max_condition {
            let weakest =
                vt.row(imin).iter().enumerate().max_by(|a, b| a.1.abs().total_cmp(&b.1.abs())).map_or(0, |x| x.0);
            return Err(MuxError::IllConditioned {
                condition,
                max_condition: params.max_condition,
                weakest_source: cols[weakest],
            });
        }
        // W⁺ = V Σ⁻¹ Uᵀ.
        let mut sinv_ut = uu.transpose();
        for (k, mut row) in sinv_ut.row_iter_mut().enumerate() {
            row /= sv[k];
        }
        let pinv = vt.transpose() * sinv_ut;
        let mut unknown = vec![None; n];
        for (k, &j) in cols.iter().enumerate() {
            unknown[j] = Some(k);
        }
        Ok(LeastSquares {
            frames: f,
            sources: n,
            unknown,
            pinv,
            states,
            condition,
            tile: params.tile.max(1),
            accumulate: params.accumulate,
        })
    }

    /// Condition number of the solved system.
    pub fn condition(&self) -> f64 {
        self.condition
    }

    /// The states after automatic exclusion.
    pub fn states(&self) -> &[SourceState] {
        &self.states
    }

    /// The pseudo-inverse `W⁺` (unknowns × frames).
    pub fn pinv(&self) -> &DMatrix<f64> {
        &self.pinv
    }

    /// Per source, the standard deviation of its estimate for unit noise per frame
    /// (`‖row of W⁺‖`), 0 for sources not solved for.
    pub fn noise_gain(&self) -> Vec<f64> {
        self.unknown.iter().map(|u| u.map_or(0.0, |k| self.pinv.row(k).norm())).collect()
    }

    /// Solves every column of `frames` (`frames × cols`, pattern-major) into `out`
    /// (`sources × cols`); excluded, dead and merged sources get 0.
    pub fn solve_into(&self, frames: &[f32], cols: usize, out: &mut [f32], par: Par) -> Result<(), MuxError> {
        check_shape("least-squares frames", frames.len(), self.frames, cols)?;
        check_shape("least-squares output", out.len(), self.sources, cols)?;
        let pt = self.pinv.transpose();
        let pt32 = pt.map(|v| v as f32);
        let (f, u, t) = (self.frames, self.pinv.nrows(), self.tile);
        let mut scratch: Vec<ApplyScratch> = (0..par.blocks())
            .map(|_| match self.accumulate {
                Accumulate::F64 => (vec![0.0; t * f], vec![0.0; t * u], Vec::new(), Vec::new()),
                Accumulate::F32 => (Vec::new(), Vec::new(), vec![0.0; t * f], vec![0.0; t * u]),
            })
            .collect();
        let unknown = &self.unknown;
        for_each_tile_io(frames, f, out, self.sources, cols, t, &mut scratch, |tin, tout, s| match self.accumulate {
            Accumulate::F64 => apply_tile(tin, tout, unknown, &pt, &mut s.0, &mut s.1),
            Accumulate::F32 => apply_tile(tin, tout, unknown, &pt32, &mut s.2, &mut s.3),
        });
        Ok(())
    }

    /// Solves in place when frames and sources are as many (`data` is `n × cols`): each tile
    /// is copied to scratch and overwritten with the images, so no second stack is needed.
    pub fn solve_in_place(&self, data: &mut [f32], cols: usize, par: Par) -> Result<(), MuxError> {
        if self.frames != self.sources {
            return Err(MuxError::Shape {
                what: "in-place least squares",
                len: self.frames,
                expected: self.sources,
                shape: "frames must equal sources to solve in place".into(),
            });
        }
        check_shape("least-squares stack", data.len(), self.frames, cols)?;
        let pt = self.pinv.transpose();
        let pt32 = pt.map(|v| v as f32);
        let (f, u, t, acc) = (self.frames, self.pinv.nrows(), self.tile, self.accumulate);
        let mut scratch: Vec<InPlaceScratch> = (0..par.blocks())
            .map(|_| match acc {
                Accumulate::F64 => (vec![0.0; t * f], vec![0.0; t * u], Vec::new(), Vec::new(), vec![0.0; t * f]),
                Accumulate::F32 => (Vec::new(), Vec::new(), vec![0.0; t * f], vec![0.0; t * u], vec![0.0; t * f]),
            })
            .collect();
        let unknown = &self.unknown;
        for_each_tile(data, f, cols, t, &mut scratch, |rows, s| {
            let tt = rows[0].len();
            let copy = &mut s.4[..tt * f];
            for (dst, src) in copy.chunks_mut(tt).zip(rows.iter()) {
                dst.copy_from_slice(src);
            }
            let tin: Vec<&[f32]> = copy.chunks(tt).collect();
            match acc {
                Accumulate::F64 => apply_tile(&tin, rows, unknown, &pt, &mut s.0, &mut s.1),
                Accumulate::F32 => apply_tile(&tin, rows, unknown, &pt32, &mut s.2, &mut s.3),
            }
        });
        Ok(())
    }

    /// Owning [`LeastSquares::solve_into`] (sequential).
    pub fn solve(&self, frames: &[f32], cols: usize) -> Result<Vec<f32>, MuxError> {
        let mut out = vec![0.0; self.sources * cols];
        self.solve_into(frames, cols, &mut out, Par::Seq)?;
        Ok(out)
    }
}

/// `Y = X Mᵀ` on a tile: `X` the input runs (`t × in_rows`), `mt = Mᵀ` (`in_rows × u`), output
/// row `j` = column `unknown[j]` of `Y`, or 0.
fn apply_tile<T: Real + nalgebra::RealField>(
    tin: &[&[f32]],
    tout: &mut [&mut [f32]],
    unknown: &[Option<usize>],
    mt: &DMatrix<T>,
    x: &mut [T],
    y: &mut [T],
) {
    let t = tin[0].len();
    let (fi, u) = (mt.nrows(), mt.ncols());
    let (x, y) = (&mut x[..t * fi], &mut y[..t * u]);
    for (dst, src) in x.chunks_mut(t).zip(tin.iter()) {
        dst.iter_mut().zip(src.iter()).for_each(|(d, s)| *d = T::of_f32(*s));
    }
    let xm = DMatrixView::from_slice(x, t, fi);
    let mut ym = DMatrixViewMut::from_slice(y, t, u);
    ym.gemm(T::one(), &xm, mt, T::zero());
    for (j, dst) in tout.iter_mut().enumerate() {
        match unknown[j] {
            Some(k) => dst.iter_mut().zip(&y[k * t..(k + 1) * t]).for_each(|(d, s)| *d = s.to_f32()),
            None => dst.fill(0.0),
        }
    }
}

/// What a fault is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum FaultKind {
    /// Never lights.
    Dead,
    /// Lit in every frame.
    Stuck,
    /// Much darker than the others but neither dead nor stuck: reported, not corrected.
    Dim,
}

impl FaultKind {
    /// `dead`, `stuck`, `dim`.
    pub fn name(&self) -> &'static str {
        match self {
            FaultKind::Dead => "dead",
            FaultKind::Stuck => "stuck",
            FaultKind::Dim => "dim",
        }
    }
}

/// The numbers a fault was decided on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FaultEvidence {
    /// Mean of the source's nominal image (divided by its intensity) over the median of all
    /// sources' means.
    pub relative_brightness: f64,
    /// `mean / standard error` of the nominal image over the sampled columns.
    pub z: f64,
    /// `relative_brightness · (n+1)/2`: the brightness if it is stuck.
    pub stuck_brightness: f64,
    /// Mean of the always-off slots' images over the mean of this source's nominal image (both
    /// before dividing by intensities): about 1 for a stuck LED, if the code has slots.
    pub off_slot_ratio: Option<f64>,
    /// `mean / standard error` of the always-off slots' mean image, if any.
    pub off_slot_z: Option<f64>,
    /// `(slot mean − source mean) / standard error of the difference`: within `z_zero` when
    /// the slots show the offset a stuck LED leaves, if any.
    pub off_slot_consistency_z: Option<f64>,
    /// Several LEDs showed only the common offset a stuck LED leaves: a stuck LED and dead
    /// LEDs cannot be told apart by the data (the stuck light is the same constant in every
    /// frame whichever LED emits it), so the most plausible one (restored brightness closest
    /// to the median) is called stuck and the others dead. The other LEDs' images are the same
    /// whichever is chosen.
    pub ambiguous: bool,
}

/// A detected fault.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fault {
    /// The source (column).
    pub source: usize,
    /// What it is.
    pub kind: FaultKind,
    /// Why.
    pub evidence: FaultEvidence,
}

impl std::fmt::Display for Fault {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let e = &self.evidence;
        write!(
            f,
            "LED {} {}: brightness {:.4} of the median (z = {:.1}), {:.3} if stuck",
            self.source,
            self.kind.name(),
            e.relative_brightness,
            e.z,
            e.stuck_brightness
        )?;
        if let (Some(c), Some(z)) = (e.off_slot_ratio, e.off_slot_z) {
            write!(f, ", always-off slots: {c:.2} of its level (z = {z:.1})")?;
        }
        if e.ambiguous {
            write!(f, " (ambiguous: several LEDs show only the stuck offset; which one is stuck cannot be told)")?;
        }
        Ok(())
    }
}

/// Tuning of [`detect_faults`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FaultParams {
    /// Columns sampled (runs of 256 contiguous columns, evenly spread; default 65536: the stuck signature is small, 2/(n+1)
    /// of the LED's image, and needs many columns to stand out of the noise).
    pub sample_cols: usize,
    /// `|z|` below this = statistically no light (default 5).
    pub z_zero: f64,
    /// Brightness below this fraction of the median makes a source a suspect (default 0.1;
    /// the stuck signature is `2/(n+1)`, so orders below about 31 need the always-off slots).
    pub suspect_ratio: f64,
    /// Range of brightness relative to the median a restored stuck LED must fall in
    /// (default 0.1..10).
    pub plausible: (f64, f64),
}

impl Default for FaultParams {
    fn default() -> Self {
        FaultParams { sample_cols: 65536, z_zero: 5.0, suspect_ratio: 0.1, plausible: (0.1, 10.0) }
    }
}

fn mean_sd(x: &[f64]) -> (f64, f64) {
    let n = x.len().max(1) as f64;
    let m = x.iter().sum::<f64>() / n;
    let v = x.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / (n - 1.0).max(1.0);
    (m, v.sqrt())
}

fn z_of(m: f64, sd: f64, count: usize) -> f64 {
    let se = sd / (count as f64).sqrt();
    if se > 0.0 {
        m / se
    } else if m == 0.0 {
        0.0
    } else {
        m.signum() * f64::INFINITY
    }
}

/// Finds dead, stuck and dim LEDs in the nominal demultiplexed images `c = S⁻¹ m`
/// (`n × cols`, pattern-major, *not* divided by the intensities). Sources with intensity 0
/// are the always-off slots. Returns the faults, sorted by source.
pub fn detect_faults(
    s: &SMatrix,
    intensities: &[f64],
    demuxed: &[f32],
    cols: usize,
    params: &FaultParams,
) -> Result<Vec<Fault>, MuxError> {
    let n = s.order();
    check_intensities(intensities, n)?;
    check_shape("demultiplexed images", demuxed.len(), n, cols)?;
    if cols == 0 {
        return Ok(Vec::new());
    }
    let count = params.sample_cols.clamp(2, cols.max(2)).min(cols);
    // Runs of 256 contiguous columns, evenly spread (whole cache lines, not one value each).
    let run = 256.min(count);
    let runs = count / run;
    let starts: Vec<usize> = (0..runs).map(|b| b * (cols / runs)).collect();
    let count = runs * run;
    // Mean and standard deviation of image `j` over the sampled columns, two passes, no copy.
    let raw_stats = |j: usize| -> (f64, f64) {
        let img = &demuxed[j * cols..(j + 1) * cols];
        let runs = || starts.iter().flat_map(|&c| &img[c..c + run]);
        let m = runs().map(|&v| f64::from(v)).sum::<f64>() / count as f64;
        let v = runs().map(|&v| (f64::from(v) - m).powi(2)).sum::<f64>() / (count as f64 - 1.0).max(1.0);
        (m, v.sqrt())
    };
    let max_a = intensities.iter().cloned().fold(0.0, f64::max);
    let physical: Vec<usize> = (0..n).filter(|&j| intensities[j] > 0.0).collect();
    let slots: Vec<usize> = (0..n).filter(|&j| intensities[j] == 0.0).collect();
    if physical.is_empty() || max_a <= 0.0 {
        return Ok(Vec::new());
    }
    // Mean of the always-off slots' images, per sampled column.
    let slot_img: Option<Vec<f64>> = (!slots.is_empty()).then(|| {
        let mut acc = vec![0.0; count];
        for &v in &slots {
            let img = &demuxed[v * cols..(v + 1) * cols];
            let sample = starts.iter().flat_map(|&c| &img[c..c + run]);
            acc.iter_mut().zip(sample).for_each(|(a, x)| *a += f64::from(*x) / slots.len() as f64);
        }
        acc
    });
    let slot_stats = slot_img.as_ref().map(|x| mean_sd(x));
    // (source, mean, z, standard error, raw mean, raw sd), the sources in parallel (a fault
    // check of 65536 columns of 199 images took 200 ms on one thread with copies).
    let stats: Vec<(usize, f64, f64, f64, f64, f64)> = physical
        .par_iter()
        .map(|&j| {
            let (raw_m, raw_sd) = raw_stats(j);
            let (m, sd) = (raw_m / intensities[j], raw_sd / intensities[j]);
            (j, m, z_of(m, sd, count), sd / (count as f64).sqrt(), raw_m, raw_sd)
        })
        .collect();
    let mut means: Vec<f64> = stats.iter().map(|s| s.1).collect();
    means.sort_by(f64::total_cmp);
    let median = means[means.len() / 2];
    if median.is_nan() || median <= 0.0 {
        return Ok(Vec::new());
    }
    let half = (n as f64 + 1.0) / 2.0;
    let mut faults = Vec::new();
    for &(j, m, z, se, raw_m, raw_sd) in &stats {
        let rel = m / median;
        // A suspect is darker than suspect_ratio of the median, and significantly so (noise
        // alone must not make a source look dark).
        if rel >= params.suspect_ratio || (median - m) < params.z_zero * se {
            continue;
        }
        let slot = slot_stats.map(|(sm, ssd)| {
            let se_diff = ((ssd * ssd + raw_sd * raw_sd) / count as f64).sqrt();
            let cz = if se_diff > 0.0 { (sm - raw_m) / se_diff } else { 0.0 };
            (sm / raw_m, z_of(sm, ssd, count), cz)
        });
        let evidence = FaultEvidence {
            relative_brightness: rel,
            z,
            stuck_brightness: rel * half,
            off_slot_ratio: slot.map(|s| s.0),
            off_slot_z: slot.map(|s| s.1),
            off_slot_consistency_z: slot.map(|s| s.2),
            ambiguous: false,
        };
        let plausible = (params.plausible.0..=params.plausible.1).contains(&(rel * half));
        // A stuck LED leaves the same offset in the always-off slots as in its own image.
        let slots_agree = slot.is_none_or(|s| s.2.abs() < params.z_zero);
        let kind = if z.abs() < params.z_zero {
            FaultKind::Dead
        } else if plausible && slots_agree {
            FaultKind::Stuck
        } else {
            FaultKind::Dim
        };
        faults.push(Fault { source: j, kind, evidence });
    }
    // At most one stuck LED is identifiable: keep the most plausible, call the rest dead.
    let stuck: Vec<usize> = (0..faults.len()).filter(|&k| faults[k].kind == FaultKind::Stuck).collect();
    if stuck.len() > 1 {
        let best = stuck
            .iter()
            .copied()
            .min_by(|&a, &b| {
                let la = faults[a].evidence.stuck_brightness.ln().abs();
                let lb = faults[b].evidence.stuck_brightness.ln().abs();
                la.total_cmp(&lb)
            })
            .unwrap_or(stuck[0]);
        for &k in &stuck {
            faults[k].evidence.ambiguous = true;
            if k != best {
                faults[k].kind = FaultKind::Dead;
            }
        }
    }
    Ok(faults)
}

/// Tuning of the [`Demultiplexer`].
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct DemultiplexerParams {
    /// The fast path.
    pub demux: DemuxParams,
    /// The least-squares re-solve.
    pub ls: LsParams,
    /// Fault detection.
    pub faults: FaultParams,
    /// Skip fault detection (the fast path's result, scaled by the intensities, is returned).
    pub skip_detection: bool,
    /// Threads.
    pub par: Par,
}

/// The owning high-level demultiplexer: an S-matrix, the calibrated intensities and the
/// plans, reused for every view group.
#[derive(Debug)]
pub struct Demultiplexer {
    s: SMatrix,
    intensities: Vec<f64>,
    demuxer: Demuxer,
    params: DemultiplexerParams,
}

/// What [`Demultiplexer::run`] did.
#[derive(Debug, Clone, PartialEq)]
pub struct DemuxReport {
    /// The fast method used for the nominal solve.
    pub method: Method,
    /// Faults found (dead, stuck, dim).
    pub faults: Vec<Fault>,
    /// Sources whose image is 0 and not an estimate: always-off slots, dead LEDs, LEDs below
    /// `min_relative_intensity`, merged second stuck LEDs.
    pub excluded: Vec<usize>,
    /// True when the images come from the least-squares re-solve around faults.
    pub re_solved: bool,
    /// Condition number of the least-squares system when one was solved (the fast path needs
    /// none: `cond(S) = √(n+1)`).
    pub condition: Option<f64>,
    /// Per source, the standard deviation of its image for unit noise per frame.
    pub noise_gain: Vec<f64>,
}

/// Demultiplexed images (`sources × cols`, pattern-major: image `j` at `j*cols..`) and the
/// report.
#[derive(Debug, Clone, PartialEq)]
pub struct Demultiplexed {
    images: Vec<f32>,
    cols: usize,
    report: DemuxReport,
}

impl Demultiplexed {
    /// All images, source-major.
    pub fn images(&self) -> &[f32] {
        &self.images
    }

    /// Image of source `j`.
    pub fn image(&self, j: usize) -> &[f32] {
        &self.images[j * self.cols..(j + 1) * self.cols]
    }

    /// The report.
    pub fn report(&self) -> &DemuxReport {
        &self.report
    }

    /// Images and report.
    pub fn into_parts(self) -> (Vec<f32>, DemuxReport) {
        (self.images, self.report)
    }
}

impl Demultiplexer {
    /// A demultiplexer for `s` with calibrated `intensities` (one per column; 0 marks an
    /// always-off slot).
    pub fn new(s: SMatrix, intensities: Vec<f64>, params: DemultiplexerParams) -> Result<Demultiplexer, MuxError> {
        check_intensities(&intensities, s.order())?;
        let demuxer = Demuxer::new(&s, &params.demux)?;
        Ok(Demultiplexer { s, intensities, demuxer, params })
    }

    /// The S-matrix.
    pub fn s(&self) -> &SMatrix {
        &self.s
    }

    /// Demultiplexes one view group: `frames` holds the `n` pattern frames (pattern-major,
    /// `cols` values each) and is reused for the images.
    pub fn run(&self, mut frames: Vec<f32>, cols: usize) -> Result<Demultiplexed, MuxError> {
        let n = self.s.order();
        check_shape("frames", frames.len(), n, cols)?;
        let par = self.params.par;
        let mut scratch = self.demuxer.scratch(par);
        self.demuxer.demux_in_place(&mut frames, cols, &mut scratch, par)?;
        let faults = if self.params.skip_detection {
            Vec::new()
        } else {
            detect_faults(&self.s, &self.intensities, &frames, cols, &self.params.faults)?
        };
        let mut states: Vec<SourceState> = self
            .intensities
            .iter()
            .map(|&a| if a > 0.0 { SourceState::Nominal } else { SourceState::Excluded })
            .collect();
        for f in &faults {
            match f.kind {
                FaultKind::Dead => states[f.source] = SourceState::Dead,
                FaultKind::Stuck => states[f.source] = SourceState::Stuck,
                FaultKind::Dim => {}
            }
        }
        let re_solved = states.iter().any(|s| matches!(s, SourceState::Dead | SourceState::Stuck));
        let max_a = self.intensities.iter().cloned().fold(0.0, f64::max);
        let report = if re_solved {
            let model = PatternModel::from_smatrix(&self.s, &self.intensities)?;
            let ls = LeastSquares::new(&model, &states, &self.params.ls)?;
            // î = W⁺ m = (W⁺ S) c with c the nominal images.
            let dense: Vec<f64> = self.s.to_dense().into_iter().map(f64::from).collect();
            let q = ls.pinv() * DMatrix::from_row_slice(n, n, &dense);
            let qt = q.transpose();
            let qt32 = qt.map(|v| v as f32);
            let (u, t, acc) = (q.nrows(), self.params.ls.tile.max(1), self.params.ls.accumulate);
            let unknown = &ls.unknown;
            let mut sc: Vec<ApplyScratch> = (0..par.blocks())
                .map(|_| match acc {
                    Accumulate::F64 => (vec![0.0; t * n], vec![0.0; t * u], Vec::new(), Vec::new()),
                    Accumulate::F32 => (Vec::new(), Vec::new(), vec![0.0; t * n], vec![0.0; t * u]),
                })
                .collect();
            for_each_tile(&mut frames, n, cols, t, &mut sc, |rows, s| {
                let tin: Vec<Vec<f32>> = rows.iter().map(|r| r.to_vec()).collect();
                let tin: Vec<&[f32]> = tin.iter().map(|r| &r[..]).collect();
                match acc {
                    Accumulate::F64 => apply_tile(&tin, rows, unknown, &qt, &mut s.0, &mut s.1),
                    Accumulate::F32 => apply_tile(&tin, rows, unknown, &qt32, &mut s.2, &mut s.3),
                }
            });
            let excluded =
                (0..n).filter(|&j| !matches!(ls.states()[j], SourceState::Nominal | SourceState::Stuck)).collect();
            DemuxReport {
                method: self.demuxer.method(),
                faults,
                excluded,
                re_solved,
                condition: Some(ls.condition()),
                noise_gain: ls.noise_gain(),
            }
        } else {
            // The fast path is exact: î_j = c_j / a_j; std of c_j per unit frame noise 2√n/(n+1).
            let base = 2.0 * (n as f64).sqrt() / (n as f64 + 1.0);
            let keep = |a: f64| a > self.params.ls.min_relative_intensity * max_a;
            let excluded: Vec<usize> = (0..n).filter(|&j| !keep(self.intensities[j])).collect();
            let noise_gain: Vec<f64> = self.intensities.iter().map(|&a| if keep(a) { base / a } else { 0.0 }).collect();
            let scale = |(j, img): (usize, &mut [f32])| {
                let a = self.intensities[j];
                if !keep(a) {
                    img.fill(0.0);
                } else if a != 1.0 {
                    let inv = (1.0 / a) as f32;
                    img.iter_mut().for_each(|v| *v *= inv);
                }
            };
            if par.blocks() > 1 {
                use rayon::prelude::*;
                frames.par_chunks_mut(cols.max(1)).enumerate().for_each(scale);
            } else {
                frames.chunks_mut(cols.max(1)).enumerate().for_each(scale);
            }
            DemuxReport { method: self.demuxer.method(), faults, excluded, re_solved, condition: None, noise_gain }
        };
        Ok(Demultiplexed { images: frames, cols, report })
    }
}
