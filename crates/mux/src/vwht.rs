//! The Walsh–Hadamard demultiplex of the Sylvester orders on pixel vectors, one block of
//! columns at a time through every pass, with the gather and the scatter fused into the
//! first and the last pass.
//!
//! The generic path (`demux::wht_rows`) runs each radix-4 pass over a whole tile of the rows
//! (256 columns, 256 KB at N = 256): four passes through L2 plus a scaling pass, and the
//! first touch of each tile's runs is a cache miss the hardware prefetcher only partly hides.
//! Here every element of the transform is one vector of `W` columns (one 64-byte line at
//! `W = 16`), and a block of `W` columns of all `N = n + 1` rows (16 KB at N = 256) stays
//! in L1 while radix-`R` butterflies, `R = 2^b` vectors held in registers, run the `log₂ N`
//! butterfly levels `b` at a time: two passes at N = 256 on AVX-512 (`R = 16`, 32 registers),
//! three on AVX2 (`R` up to 8, 16 registers). The first pass loads its inputs straight from
//! the rows (element 0 is the zero that extends `m` to length `N`), the last pass scales and
//! stores straight to them (`S⁻¹ m = −(2/N) (H x)_{1..N}`, `S m = ((H x)_0 − (H x)_{1..N})/2`,
//! see `crate::demux`), so the rows are read once and written once. The passes before the
//! last prefetch a later block's lines ([`Prefetch`]), as in `crate::vfft`.
//!
//! The Walsh–Hadamard transform of order `2^k` is the Kronecker product of `k` butterflies,
//! one per index bit, and they commute: a pass takes `b` consecutive bits, its butterflies
//! are over the `2^b` elements that differ only there, in natural order (no bit reversal).

use crate::kernel::Dir;
use crate::lanes::{prefetch_run, tick, Lanes, Portable, Prefetch};

/// Blocks ahead that the passes prefetch, in groups: every block prefetches `1/GROUP` of the
/// rows, `GROUP` lines each (256 contiguous bytes of a row at a time rather than one line per
/// row per block: fewer, longer requests per DRAM page). 255 × 3 000 000 stack, 2 threads,
/// interleaved with the memory pass (`examples/demux_probe.rs`, `SWEEP`), medians of the
/// per-round ratios over three runs: group 4 at distance 8 2.2–3.1x the memory pass, group 1
/// (one line per row per block) 2.6–3.5x; the machine's noise is of the same order.
const PREFETCH_BLOCKS: usize = 8;
const PREFETCH_GROUP: usize = 4;

/// The Sylvester demultiplex of order `n = N − 1`, `N = 2^k`, on pixel vectors.
pub(crate) struct VecWht {
    n: usize,
    log2: u32,
    /// Use AVX-512 (16-lane vectors, radix 16) where the CPU has it; else AVX2.
    wide: bool,
}

impl VecWht {
    /// `None` unless `n + 1` is a power of two, at least 2.
    pub(crate) fn new(n: usize, wide: bool) -> Option<VecWht> {
        let big = n.checked_add(1)?;
        (big >= 2 && big.is_power_of_two()).then(|| VecWht { n, log2: big.trailing_zeros(), wide })
    }

    /// Scratch vectors per thread ([`pulp::f32x16`] units): the block's `N` elements.
    pub(crate) fn scratch_len(&self) -> usize {
        self.n + 1
    }

    /// Applies `S⁻¹` (or `S`) to every column of the tile `rows` (`n` runs), in place;
    /// `vb` holds [`VecWht::scratch_len`] vectors, `zero` at least the tile's width of zeros
    /// (and does again afterwards).
    pub(crate) fn tile(&self, rows: &mut [&mut [f32]], zero: &mut [f32], vb: &mut [pulp::f32x16], dir: Dir) {
        #[cfg(target_arch = "x86_64")]
        if self.wide {
            if let Some(v4) = pulp::x86::V4::try_new() {
                // The body compiled for AVX-512 (checked at run time above).
                return pulp::Simd::vectorize(v4, TileOp { m: v4, k: self, rows, zero, vb, dir });
            }
        }
        #[cfg(target_arch = "x86_64")]
        if let Some(v3) = pulp::x86::V3::try_new() {
            // The body compiled for AVX2 + FMA (checked at run time above).
            return pulp::Simd::vectorize(v3, TileOp { m: v3, k: self, rows, zero, vb, dir });
        }
        TileOp { m: Portable, k: self, rows, zero, vb, dir }.body();
    }

    /// AVX-512 allowed.
    pub(crate) fn wide(&self) -> bool {
        self.wide
    }

    /// The instruction set [`VecWht::tile`] runs on this CPU.
    pub(crate) fn isa(&self) -> &'static str {
        crate::lanes::isa(self.wide)
    }

    /// The same through the portable lanes (tests).
    #[cfg(test)]
    fn tile_portable(&self, rows: &mut [&mut [f32]], zero: &mut [f32], vb: &mut [pulp::f32x16], dir: Dir) {
        TileOp { m: Portable, k: self, rows, zero, vb, dir }.body();
    }
}

/// The passes over `log2` index bits, at most `bmax` bits each, as `(lowest bit, bits)`:
/// as few passes as possible, the bits spread evenly (8 bits, at most 3: 3 + 3 + 2).
fn plan_passes(log2: u32, bmax: u32) -> Vec<(u32, u32)> {
    let np = log2.div_ceil(bmax).max(1);
    let mut lo = 0;
    (0..np)
        .map(|j| {
            let bits = log2 / np + u32::from(j < log2 % np);
            let pass = (lo, bits);
            lo += bits;
            pass
        })
        .collect()
}

struct TileOp<'a, 'b, M> {
    m: M,
    k: &'a VecWht,
    rows: &'a mut [&'b mut [f32]],
    zero: &'a mut [f32],
    vb: &'a mut [pulp::f32x16],
    dir: Dir,
}

impl<M: Lanes> TileOp<'_, '_, M> {
    #[inline(always)]
    fn body(self) {
        let TileOp { m, k, rows, zero, vb, dir } = self;
        let vb: &mut [M::L] = pulp::bytemuck::cast_slice_mut(vb);
        tile_impl(m, k, rows, zero, vb, dir);
    }
}

// Everything below `with_simd` is `inline(always)`, so it is compiled inside pulp's
// target-feature function (see `crate::vfft`).
impl<M: Lanes> pulp::WithSimd for TileOp<'_, '_, M> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        self.body()
    }
}

/// The Walsh–Hadamard transform of `R` vectors in registers (`R` a power of two).
#[inline(always)]
fn wht_in_registers<const R: usize, M: Lanes>(m: M, x: &mut [M::L; R]) {
    let mut h = 1;
    while h < R {
        for i in 0..R {
            if i & h == 0 {
                let (a, b) = (x[i], x[i + h]);
                x[i] = m.add(a, b);
                x[i + h] = m.sub(a, b);
            }
        }
        h *= 2;
    }
}

/// Where a pass reads: the rows (element `i` is row `i`; row 0 is zeros, the rest are the
/// tile's) or the block's buffer.
#[derive(Clone, Copy)]
enum From<'a, 'b> {
    Rows(&'a [&'b mut [f32]]),
    Buf,
}

/// Where a pass writes: the buffer, or the rows as `α (H x)_0 + β (H x)_i` (row 0 too: the
/// caller zeroes it again).
enum To<'a, 'b> {
    Buf,
    Rows(&'a mut [&'b mut [f32]], f32, f32),
}

/// One pass of radix `R` over the bits `lo .. lo + log₂ R` of the `big` elements, for the
/// block at column `c0`.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn pass<const R: usize, M: Lanes>(
    m: M,
    big: usize,
    lo: u32,
    from: From<'_, '_>,
    to: To<'_, '_>,
    c0: usize,
    buf: &mut [M::L],
    pf: &mut Option<Prefetch<'_, '_>>,
) {
    let buf = &mut buf[..big];
    let s = 1usize << lo;
    let z = m.splat(0.0);
    let (mut to, alpha, beta) = match to {
        To::Buf => (None, z, z),
        To::Rows(rows, a, b) => (Some(rows), m.splat(a), m.splat(b)),
    };
    let mut h0 = z;
    // Branch-free loops over `t` (the zero row instead of a test for element 0), so they
    // unroll and `x` stays in registers.
    for hi in (0..big).step_by(s * R) {
        for inner in 0..s {
            let base = hi + inner;
            let mut x = [z; R];
            match from {
                From::Rows(rows) => {
                    let rows = &rows[..big];
                    for (t, x) in x.iter_mut().enumerate() {
                        *x = m.load(&rows[base + t * s][c0..]);
                    }
                }
                From::Buf => {
                    for (t, x) in x.iter_mut().enumerate() {
                        *x = buf[base + t * s];
                    }
                }
            }
            wht_in_registers::<R, M>(m, &mut x);
            match to {
                None => {
                    for (t, x) in x.iter().enumerate() {
                        buf[base + t * s] = *x;
                    }
                    tick(pf);
                }
                Some(ref mut rows) => {
                    // Element 0 is in the first butterfly (base 0, t 0).
                    if base == 0 {
                        h0 = m.mul(alpha, x[0]);
                    }
                    let rows = &mut rows[..big];
                    for (t, x) in x.iter().enumerate() {
                        m.store(m.fma(beta, *x, h0), &mut rows[base + t * s][c0..]);
                    }
                }
            }
        }
    }
}

/// Dispatches a pass over the radices 2 … 16.
macro_rules! by_bits {
    ($b:expr, pass::<$m:ty>($($a:expr),*)) => {
        match $b {
            1 => pass::<2, $m>($($a),*),
            2 => pass::<4, $m>($($a),*),
            3 => pass::<8, $m>($($a),*),
            4 => pass::<16, $m>($($a),*),
            b => unreachable!("{b} bits per pass are not planned"),
        }
    };
}

/// The whole transform of one block of `W` columns at `c0`, prefetching the block at `pf`;
/// `rows[0]` is zeros (and is again afterwards), `rows[1..]` the tile's.
#[inline(always)]
fn block<M: Lanes>(
    m: M,
    passes: &[(u32, u32)],
    (alpha, beta): (f32, f32),
    rows: &mut [&mut [f32]],
    c0: usize,
    pf: Option<(usize, usize, std::ops::Range<usize>)>,
    buf: &mut [M::L],
) {
    let big = rows.len();
    let Some((&(last_lo, last_bits), before)) = passes.split_last() else { return };
    if before.is_empty() {
        // One pass (N ≤ 16): the rows into the buffer first.
        if let Some((cp, len, range)) = pf {
            rows[range].iter().for_each(|r| prefetch_run(r, cp, len));
        }
        for (e, row) in buf[..big].iter_mut().zip(rows.iter()) {
            *e = m.load(&row[c0..]);
        }
    } else {
        // Butterflies before the last pass: the prefetches' schedule.
        let ticks: usize = before.iter().map(|&(_, b)| big >> b).sum();
        let mut pfs = pf.map(|(cp, len, range)| Prefetch::new(&rows[range], cp, len, ticks));
        for (j, &(lo, bits)) in before.iter().enumerate() {
            let from = if j == 0 { From::Rows(&*rows) } else { From::Buf };
            by_bits!(bits, pass::<M>(m, big, lo, from, To::Buf, c0, &mut *buf, &mut pfs));
        }
    }
    let to = To::Rows(&mut *rows, alpha, beta);
    by_bits!(last_bits, pass::<M>(m, big, last_lo, From::Buf, to, c0, &mut *buf, &mut None));
    m.store(m.splat(0.0), &mut rows[0][c0..]);
}

/// Blocks of `W` columns; a short last block through a zero-padded copy. `zero` holds at
/// least the tile's width of zeros (and does again afterwards).
#[inline(always)]
fn tile_impl<M: Lanes>(m: M, k: &VecWht, rows: &mut [&mut [f32]], zero: &mut [f32], vb: &mut [M::L], dir: Dir) {
    debug_assert_eq!(rows.len(), k.n);
    let big = k.n + 1;
    let w = M::W;
    let buf = &mut vb[..big];
    // 16 vectors of data in AVX-512's 32 registers, 8 in AVX2's 16.
    let passes = plan_passes(k.log2, if w >= 16 { 4 } else { 3 });
    let scale = match dir {
        Dir::Demux => (0.0, -2.0 / big as f32),
        Dir::Mux => (0.5, -0.5),
    };
    let t = rows.first().map_or(0, |r| r.len());
    let full = t / w * w;
    if full > 0 {
        let mut all: Vec<&mut [f32]> = Vec::with_capacity(big);
        all.push(&mut zero[..t]);
        all.extend(rows.iter_mut().map(|r| &mut **r));
        let g = PREFETCH_GROUP;
        let mut c0 = 0;
        while c0 < full {
            // Block b prefetches its share of the rows (j of g) for the group of g blocks
            // PREFETCH_BLOCKS ahead of the current group.
            let b = c0 / w;
            let j = b % g;
            let cp = (b - j + PREFETCH_BLOCKS) * w;
            let range = j * big / g..(j + 1) * big / g;
            block(m, &passes, scale, &mut all, c0, (cp + g * w <= t).then_some((cp, g * w, range)), buf);
            c0 += w;
        }
    }
    if full < t {
        let rest = t - full;
        let mut pad = vec![0.0f32; big * w];
        for (dst, row) in pad[w..].chunks_exact_mut(w).zip(rows.iter()) {
            dst[..rest].copy_from_slice(&row[full..]);
        }
        let mut prows: Vec<&mut [f32]> = pad.chunks_exact_mut(w).collect();
        block(m, &passes, scale, &mut prows, 0, None, buf);
        for (src, row) in pad[w..].chunks_exact(w).zip(rows.iter_mut()) {
            row[full..].copy_from_slice(&src[..rest]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::smatrix::SMatrix;

    #[test]
    fn passes_cover_every_bit_once() {
        for log2 in 1..=12 {
            for bmax in [3, 4] {
                let p = plan_passes(log2, bmax);
                assert_eq!(p.len() as u32, log2.div_ceil(bmax));
                let mut next = 0;
                for &(lo, bits) in &p {
                    assert_eq!(lo, next);
                    assert!((1..=bmax).contains(&bits), "{p:?}");
                    next += bits;
                }
                assert_eq!(next, log2);
            }
        }
    }

    /// Every lane width, both directions, against `S⁻¹ m` and `S x` in f64 from the dense
    /// matrix, for the orders 1 … 1023 (one to four passes) and column counts that leave a
    /// short block.
    #[test]
    fn vector_wht_matches_the_dense_matrix() {
        for k in 1..=10u32 {
            let n = (1usize << k) - 1;
            let s = SMatrix::sylvester(k).unwrap();
            let dense = s.to_dense();
            let inv = s.inverse_dense();
            let cols = 37;
            let data: Vec<f32> = (0..n * cols).map(|i| ((i * 2_654_435_761usize) % 1000) as f32 / 1000.0).collect();
            for wide in [false, true] {
                let v = VecWht::new(n, wide).unwrap();
                for portable in [false, true] {
                    for dir in [Dir::Demux, Dir::Mux] {
                        let mut out = data.clone();
                        let mut vb = vec![<pulp::f32x16 as pulp::bytemuck::Zeroable>::zeroed(); v.scratch_len()];
                        let mut zero = vec![0.0; cols];
                        {
                            let mut rows: Vec<&mut [f32]> = out.chunks_exact_mut(cols).collect();
                            if portable {
                                v.tile_portable(&mut rows, &mut zero, &mut vb, dir);
                            } else {
                                v.tile(&mut rows, &mut zero, &mut vb, dir);
                            }
                        }
                        assert!(zero.iter().all(|z| *z == 0.0));
                        let mut worst = 0.0f64;
                        for c in 0..cols {
                            for r in 0..n {
                                let want: f64 = (0..n)
                                    .map(|j| {
                                        let a = if dir == Dir::Demux {
                                            inv[r * n + j]
                                        } else {
                                            f64::from(dense[r * n + j])
                                        };
                                        a * f64::from(data[j * cols + c])
                                    })
                                    .sum();
                                worst = worst.max((f64::from(out[r * cols + c]) - want).abs());
                            }
                        }
                        // f32 sums of N terms of size ≤ 1 (the multiplex: up to N/2).
                        let tol = if dir == Dir::Demux { 2e-6 } else { 1e-6 * (n + 1) as f64 };
                        assert!(worst < tol, "n {n} wide {wide} portable {portable}: error {worst:e}");
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod probe {
    use super::*;

    /// Timing probe (not a test): one tile of `COLS` columns (default 16), in cache, many
    /// times: `cargo test --release -p btfrig-mux --lib vwht::probe -- --ignored --nocapture`.
    #[test]
    #[ignore]
    fn time_tile_in_cache() {
        let cols: usize = std::env::var("COLS").ok().and_then(|s| s.parse().ok()).unwrap_or(16);
        let only: Option<usize> = std::env::var("ORDER").ok().and_then(|s| s.parse().ok());
        for (n, wide) in [(255usize, true), (255, false), (1023, true)] {
            if only.is_some_and(|o| o != n) {
                continue;
            }
            let v = VecWht::new(n, wide).unwrap();
            let mut data: Vec<f32> = (0..n * cols).map(|i| ((i * 2_654_435_761usize) % 1000) as f32 / 1000.0).collect();
            let mut vb = vec![<pulp::f32x16 as pulp::bytemuck::Zeroable>::zeroed(); v.scratch_len()];
            let mut zero = vec![0.0; cols];
            let reps = 100_000 / cols;
            let mut best = f64::INFINITY;
            for _ in 0..41 {
                let t = std::time::Instant::now();
                for r in 0..reps {
                    let mut rows: Vec<&mut [f32]> = data.chunks_exact_mut(cols).collect();
                    v.tile(&mut rows, &mut zero, &mut vb, if r % 2 == 0 { Dir::Demux } else { Dir::Mux });
                }
                best = best.min(t.elapsed().as_secs_f64());
            }
            let per_col = best / (reps * cols) as f64;
            println!(
                "n {n} {}: {:.1} ns per column, {:.0} cycles per 16 columns at 3.6 GHz, {:.2} ns per value",
                v.isa(),
                per_col * 1e9,
                per_col * 16.0 * 3.6e9,
                per_col * 1e9 / n as f64
            );
        }
    }
}
