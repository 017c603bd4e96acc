//! `btfrig bench demux`: demultiplexing one view group of S-matrix captures (pattern-major,
//! one f32 image per pattern, `megapixels` × `channels` values each) by the fast transform
//! (FWHT for Sylvester orders, FFT circular convolution for the cyclic ones, f32 and f64
//! accumulation), by the dense closed-form inverse as a matrix product in several tile
//! layouts, by least squares with calibrated intensities (SVD pseudo-inverse applied as a
//! matrix product), and by the high-level demultiplexer (fast path plus fault check); time
//! (median of `repeat`) and error against the known single-light images side by side, with
//! one plain read-and-write pass over the same stack as the memory-bandwidth floor. The
//! machine's memory bandwidth drifts with other load (the pass alone varied 46–128 ms here),
//! so a memory pass runs right before every timed repetition and "x floor" is the median of
//! the ratios to it.
//!
//! The single-light images are a hash of (LED, column) in [0, 1), so nothing but the one
//! stack is held in memory (n × megapixels × channels × 4 bytes: 3.1 GB at n = 255, 1 MP RGB);
//! before each method the stack is refilled with the images and multiplexed by the fast
//! forward transform (not timed).

use std::time::Instant;

use btfrig_mux::{
    Accumulate, Demultiplexer, DemultiplexerParams, DemuxParams, Demuxer, DenseLayout, Engine, LeastSquares, LsParams,
    Method, Par, PatternModel, SMatrix, SourceState,
};
use rayon::prelude::*;

/// One method's measurements.
#[derive(Debug, Clone)]
pub struct Row {
    /// Method name.
    pub method: String,
    /// Layout and tile.
    pub layout: String,
    /// Accumulation.
    pub accumulate: &'static str,
    /// Median time, ms.
    pub ms: f64,
    /// Median over the repetitions of the time over that of the memory pass run just before
    /// it (1 for the memory pass itself).
    pub x_floor: f64,
    /// Extra one-off time (factorisation), ms.
    pub setup_ms: f64,
    /// Largest |result − truth| (truth in [0, 1)); `None` for the memory pass.
    pub max_err: Option<f64>,
    /// RMS of result − truth.
    pub rms_err: Option<f64>,
    /// Is it a dense matrix product (for the "best dense" comparison)?
    pub dense: bool,
}

/// The result for one order.
#[derive(Debug, Clone)]
pub struct OrderResult {
    /// The order.
    pub n: usize,
    /// Its construction.
    pub construction: &'static str,
    /// Values per image.
    pub cols: usize,
    /// Rows, memory pass first.
    pub rows: Vec<Row>,
}

impl OrderResult {
    /// The memory-pass time (median of the passes run before every timed repetition).
    pub fn floor_ms(&self) -> f64 {
        self.rows[0].ms
    }

    /// The fastest dense row.
    pub fn best_dense(&self) -> Option<&Row> {
        self.rows.iter().filter(|r| r.dense).min_by(|a, b| a.ms.total_cmp(&b.ms))
    }

    /// The fast path, f32.
    pub fn fast(&self) -> Option<&Row> {
        self.rows.iter().find(|r| (r.method == "fwht" || r.method == "fft") && r.accumulate == "f32")
    }
}

fn splitmix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The known single-light value of LED `j` at column `c`, in [0, 1).
fn truth(j: usize, c: usize) -> f32 {
    ((splitmix64(((j as u64) << 40) ^ c as u64) >> 40) as f32) / 16_777_216.0
}

fn fill_truth(data: &mut [f32], cols: usize, scale: &[f64]) {
    data.par_chunks_mut(cols).enumerate().for_each(|(j, row)| {
        let a = scale[j] as f32;
        row.iter_mut().enumerate().for_each(|(c, v)| *v = a * truth(j, c));
    });
}

fn errors(data: &[f32], cols: usize) -> (f64, f64) {
    let (max, sum) = data
        .par_chunks(cols)
        .enumerate()
        .map(|(j, row)| {
            row.iter().enumerate().fold((0.0f64, 0.0f64), |(m, s), (c, v)| {
                let d = f64::from(*v) - f64::from(truth(j, c));
                (m.max(d.abs()), s + d * d)
            })
        })
        .reduce(|| (0.0, 0.0), |a, b| (a.0.max(b.0), a.1 + b.1));
    (max, (sum / data.len().max(1) as f64).sqrt())
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// One plain read-modify-write pass over the stack (the memory-bandwidth floor), ms.
fn memory_pass(data: &mut [f32]) -> f64 {
    let k = std::hint::black_box(1.0f32);
    let t = Instant::now();
    data.par_chunks_mut(1 << 16).for_each(|c| c.iter_mut().for_each(|v| *v *= k));
    t.elapsed().as_secs_f64() * 1e3
}

/// Times `repeat` runs of `run`, each right after a timed memory pass over the same data (the
/// machine's memory bandwidth drifts with other load, so every ratio is taken against the pass
/// just before it); `check` (untimed) after each run. Returns the median time and the median
/// ratio; the memory passes go to `floors`.
fn time_against_floor(
    data: &mut Vec<f32>,
    repeat: usize,
    floors: &mut Vec<f64>,
    mut run: impl FnMut(&mut Vec<f32>) -> anyhow::Result<()>,
    mut check: impl FnMut(usize, &[f32]) -> anyhow::Result<()>,
) -> anyhow::Result<(f64, f64)> {
    let (mut times, mut ratios) = (Vec::new(), Vec::new());
    for rep in 0..repeat {
        let floor = memory_pass(data);
        floors.push(floor);
        let t = Instant::now();
        run(data)?;
        let ms = t.elapsed().as_secs_f64() * 1e3;
        times.push(ms);
        ratios.push(ms / floor);
        check(rep, data)?;
    }
    Ok((median(times), median(ratios)))
}

/// Runs the benchmark for one order.
pub fn run_order(n: usize, cols: usize, repeat: usize, fast_only: bool) -> anyhow::Result<OrderResult> {
    let s = SMatrix::of_order(n)?;
    let par = Par::Rayon(0);
    let fast = Demuxer::new(&s, &DemuxParams::default())?;
    let mut fast_scratch = fast.scratch(par);
    let ones = vec![1.0; n];
    let mut data = vec![0.0f32; n * cols];
    // Refill with the (scaled) truth and multiplex: the captures.
    let mut prepare = |data: &mut [f32], scale: &[f64]| -> anyhow::Result<()> {
        fill_truth(data, cols, scale);
        fast.multiplex_in_place(data, cols, &mut fast_scratch, par)?;
        Ok(())
    };
    let mut rows = Vec::new();

    // The floor: one read-modify-write pass over the whole stack before every timed
    // repetition (pages touched first, one untimed pass to warm up); its row is filled in at
    // the end.
    prepare(&mut data, &ones)?;
    memory_pass(&mut data);
    let mut floors = Vec::new();

    let fast_method = Method::fast_for(s.construction());
    let mut configs: Vec<(DemuxParams, bool)> = vec![
        (DemuxParams { method: Some(fast_method), accumulate: Accumulate::F32, ..Default::default() }, false),
        (DemuxParams { method: Some(fast_method), accumulate: Accumulate::F64, ..Default::default() }, false),
    ];
    if fast_method == Method::Fft {
        // The other FFT lengths, for comparison with the default: the prime length itself,
        // zero-padded to a 5-smooth length >= 2n - 1, and (Paley) the Rader length n - 1.
        let auto = btfrig_mux::demux::fft_len(n, 0);
        let mut others = vec![n, btfrig_mux::demux::padded_len(n)];
        if matches!(s.construction(), btfrig_mux::Construction::Paley { .. }) {
            others.push(n - 1);
        }
        others.sort_unstable();
        others.dedup();
        for len in others.into_iter().filter(|&l| l != auto) {
            configs.push((DemuxParams { method: Some(Method::Fft), fft_len: len, ..Default::default() }, false));
        }
    }
    // The vector transform without AVX-512, where the default uses it.
    let dflt = Demuxer::new(&s, &DemuxParams { method: Some(fast_method), ..Default::default() })?;
    if dflt.vector_isa() == Some("avx512") {
        configs
            .push((DemuxParams { method: Some(fast_method), engine: Engine::VectorAvx2, ..Default::default() }, false));
    }
    // The generic code the pixel-vectorised transforms replaced: radix-4 FWHT passes over
    // whole tiles; rustfft at the same Rader length, the tile transposed per column pair.
    if dflt.vector_isa().is_some() {
        configs.push((DemuxParams { method: Some(fast_method), engine: Engine::Generic, ..Default::default() }, false));
    }
    if !fast_only {
        for (layout, tile) in [
            (DenseLayout::PatternMajor, 256),
            (DenseLayout::PatternMajor, 1024),
            (DenseLayout::PixelMajor, 256),
            (DenseLayout::PixelMajor, 1024),
        ] {
            configs.push((DemuxParams { method: Some(Method::Dense(layout)), tile, ..Default::default() }, true));
        }
    }
    for (p, dense) in configs {
        let d = Demuxer::new(&s, &p)?;
        let mut sc = d.scratch(par);
        prepare(&mut data, &ones)?;
        let mut err = (0.0, 0.0);
        let (ms, x_floor) = time_against_floor(
            &mut data,
            repeat,
            &mut floors,
            |data| Ok(d.demux_in_place(data, cols, &mut sc, par)?),
            |rep, data| {
                if rep == 0 {
                    err = errors(data, cols);
                }
                Ok(())
            },
        )?;
        let layout = match d.method() {
            Method::Dense(DenseLayout::PatternMajor) => format!("pattern-major tile {}", d.tile()),
            Method::Dense(DenseLayout::PixelMajor) => format!("pixel-major tile {}", d.tile()),
            Method::Fft => {
                let len = btfrig_mux::demux::fft_len(n, p.fft_len);
                let how = if len + 1 == n {
                    " (Rader)"
                } else if len > n {
                    " (padded)"
                } else {
                    ""
                };
                let engine = match d.vector_isa() {
                    Some(isa) => format!("vector {isa}"),
                    None => "rustfft".to_string(),
                };
                format!("{engine}, tile {}, length {len}{how}", d.tile())
            }
            _ => match d.vector_isa() {
                Some(isa) => format!("vector {isa}, tile {}", d.tile()),
                None => format!("radix-4 passes, tile {}", d.tile()),
            },
        };
        rows.push(Row {
            method: if dense { "dense S^-1".into() } else { d.method().name().into() },
            layout,
            accumulate: if p.accumulate == Accumulate::F32 { "f32" } else { "f64" },
            ms,
            x_floor,
            setup_ms: 0.0,
            max_err: Some(err.0),
            rms_err: Some(err.1),
            dense,
        });
    }

    // The high-level path: fast demultiplex, fault check on 65536 columns, scaling.
    {
        let dm = Demultiplexer::new(s.clone(), ones.clone(), DemultiplexerParams { par, ..Default::default() })?;
        prepare(&mut data, &ones)?;
        let mut err = (0.0, 0.0);
        let (ms, x_floor) = time_against_floor(
            &mut data,
            repeat,
            &mut floors,
            |data| {
                let out = dm.run(std::mem::take(data), cols)?;
                anyhow::ensure!(out.report().faults.is_empty(), "order {n}: false fault {:?}", out.report().faults);
                *data = out.into_parts().0;
                Ok(())
            },
            |rep, data| {
                if rep == 0 {
                    err = errors(data, cols);
                }
                Ok(())
            },
        )?;
        rows.push(Row {
            method: "demultiplexer".into(),
            layout: format!("{} + fault check", fast_method.name()),
            accumulate: "f32",
            ms,
            x_floor,
            setup_ms: 0.0,
            max_err: Some(err.0),
            rms_err: Some(err.1),
            dense: false,
        });
    }

    if !fast_only {
        // Least squares with calibrated intensities 0.8..1.2: W = S diag(a), SVD pseudo-inverse.
        let a: Vec<f64> =
            (0..n).map(|j| 0.8 + 0.4 * (splitmix64(j as u64 ^ 0xA5A5) >> 11) as f64 / (1u64 << 53) as f64).collect();
        let t = Instant::now();
        let model = PatternModel::from_smatrix(&s, &a)?;
        let ls = LeastSquares::new(&model, &vec![SourceState::Nominal; n], &LsParams::default())?;
        let setup_ms = t.elapsed().as_secs_f64() * 1e3;
        prepare(&mut data, &a)?;
        let mut err = (0.0, 0.0);
        let (ms, x_floor) = time_against_floor(
            &mut data,
            repeat,
            &mut floors,
            |data| Ok(ls.solve_in_place(data, cols, par)?),
            |rep, data| {
                if rep == 0 {
                    err = errors(data, cols);
                }
                Ok(())
            },
        )?;
        rows.push(Row {
            method: "least squares".into(),
            layout: format!("pattern-major tile {}, cond {:.1}", LsParams::default().tile, ls.condition()),
            accumulate: "f32",
            ms,
            x_floor,
            setup_ms,
            max_err: Some(err.0),
            rms_err: Some(err.1),
            dense: false,
        });
    }
    let floor = Row {
        method: "memory pass".into(),
        layout: "read+write".into(),
        accumulate: "-",
        ms: median(floors),
        x_floor: 1.0,
        setup_ms: 0.0,
        max_err: None,
        rms_err: None,
        dense: false,
    };
    rows.insert(0, floor);
    Ok(OrderResult { n, construction: s.construction().name(), cols, rows })
}

pub fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .ok()
        .and_then(|s| s.split_whitespace().next().map(str::to_string))
        .unwrap_or_else(|| "?".into())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiny_bench_measures_every_method_and_errors_are_small() {
        for n in [7, 11, 19] {
            let r = run_order(n, 3000, 1, false).unwrap();
            assert!(r.rows.len() >= 9, "{:?}", r.rows);
            for w in &r.rows[1..] {
                let e = w.max_err.unwrap();
                assert!(e < 1e-5, "order {n} {} {}: {e}", w.method, w.layout);
                assert!(w.ms >= 0.0);
            }
            assert!(r.best_dense().is_some() && r.fast().is_some());
        }
    }
}
