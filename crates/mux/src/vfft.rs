//! A pixel-vectorised FFT along the pattern axis, and the Rader-domain demultiplex on it.
//!
//! rustfft transforms one column at a time, so the pattern-major tile has to be transposed
//! into its buffer and back, and the dense product (matrixmultiply, AVX2 + FMA picked at run
//! time) beat that path at the domes' orders 151 and 199. Here every element of the
//! transform is a vector of [`W`] columns in split-complex form ([`V`]: `W` columns as the
//! real part, the next `W` as the imaginary part, which the map keeps apart because it
//! sends real columns to real columns). A butterfly is then element-wise arithmetic on whole
//! vectors: nothing is transposed, the gather is the Rader reordering of the tile's rows, and
//! one block of `2W` columns (`q · 64` bytes, 9.6 KB at `q = 150`) stays in L1 through both
//! transforms.
//!
//! The transform is a mixed-radix Stockham autosort FFT (natural order in and out, two
//! buffers): radix 4 and 2, and odd radices 3 … 13 through the symmetric form
//! `y_k = x_0 + Σ_j cos(2πjk/r) (x_j + x_{r−j}) ± i sin(2πjk/r) (x_j − x_{r−j})`, which needs
//! `(r − 1)²` real multiply-adds per `r` outputs instead of the `4 r²` of a plain DFT.
//!
//! The workspace forbids unsafe code; the tile function is run through
//! [`pulp::Arch::dispatch`], which calls it inside a function compiled for AVX2 + FMA when
//! the CPU has them (checked at run time), so the loops over the `W` lanes compile to 256-bit
//! vector instructions without `target-cpu` flags.

use crate::demux::Dir;
use crate::rader::{Rader, Spec};
use rustfft::num_complex::Complex;

/// Columns per part of a vector element (one 256-bit register of f32 each for the real and
/// the imaginary part).
pub(crate) const W: usize = 8;

/// One transform element: `W` complex lanes, split.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct V {
    re: [f32; W],
    im: [f32; W],
}

impl V {
    const ZERO: V = V { re: [0.0; W], im: [0.0; W] };

    #[inline(always)]
    fn add(self, o: V) -> V {
        let mut r = V::ZERO;
        for i in 0..W {
            r.re[i] = self.re[i] + o.re[i];
            r.im[i] = self.im[i] + o.im[i];
        }
        r
    }

    #[inline(always)]
    fn sub(self, o: V) -> V {
        let mut r = V::ZERO;
        for i in 0..W {
            r.re[i] = self.re[i] - o.re[i];
            r.im[i] = self.im[i] - o.im[i];
        }
        r
    }

    /// `self + o · c` for a real scalar `c`.
    #[inline(always)]
    fn add_scaled<const F: bool>(self, o: V, c: f32) -> V {
        let mut r = V::ZERO;
        for i in 0..W {
            r.re[i] = fmadd::<F>(o.re[i], c, self.re[i]);
            r.im[i] = fmadd::<F>(o.im[i], c, self.im[i]);
        }
        r
    }

    /// `self · c` for a complex scalar `c`.
    #[inline(always)]
    fn cmul<const F: bool>(self, c: Complex<f32>) -> V {
        let mut r = V::ZERO;
        for i in 0..W {
            r.re[i] = fmadd::<F>(self.re[i], c.re, -(self.im[i] * c.im));
            r.im[i] = fmadd::<F>(self.re[i], c.im, self.im[i] * c.re);
        }
        r
    }

    /// `self · i · s` for a real `s`.
    #[inline(always)]
    fn mul_i(self, s: f32) -> V {
        let mut r = V::ZERO;
        for i in 0..W {
            r.re[i] = -s * self.im[i];
            r.im[i] = s * self.re[i];
        }
        r
    }

    /// The first `W` values of `run` as the real part, the next `W` as the imaginary part
    /// (zeros where `run` is shorter than `2W`).
    #[inline(always)]
    fn load(run: &[f32]) -> V {
        let mut v = V::ZERO;
        if let Ok(full) = <&[f32; 2 * W]>::try_from(run) {
            // Fixed-size copies: register moves, not library calls.
            for i in 0..W {
                v.re[i] = full[i];
                v.im[i] = full[W + i];
            }
        } else {
            let k = run.len().min(W);
            v.re[..k].copy_from_slice(&run[..k]);
            if run.len() > W {
                v.im[..run.len() - W].copy_from_slice(&run[W..]);
            }
        }
        v
    }

    /// The inverse of [`V::load`].
    #[inline(always)]
    fn store(self, run: &mut [f32]) {
        if let Ok(full) = <&mut [f32; 2 * W]>::try_from(&mut *run) {
            for i in 0..W {
                full[i] = self.re[i];
                full[W + i] = self.im[i];
            }
        } else {
            let k = run.len().min(W);
            run[..k].copy_from_slice(&self.re[..k]);
            if run.len() > W {
                let m = run.len() - W;
                run[W..].copy_from_slice(&self.im[..m]);
            }
        }
    }
}

/// `a · b + c`, fused when `F` (the caller runs where the CPU has FMA: `f32::mul_add` is
/// then one instruction, elsewhere a slow library call).
#[inline(always)]
fn fmadd<const F: bool>(a: f32, b: f32, c: f32) -> f32 {
    if F {
        a.mul_add(b, c)
    } else {
        a * b + c
    }
}

/// Blocks ahead that the gather prefetches.
const PREFETCH_BLOCKS: usize = 2;

/// Asks for the cache line holding `x` (a hint; no-op off x86_64).
#[inline(always)]
fn prefetch(x: &f32) {
    #[cfg(target_arch = "x86_64")]
    safe_arch::prefetch_t0(x);
    #[cfg(not(target_arch = "x86_64"))]
    let _ = x;
}

/// One Stockham pass.
#[derive(Debug)]
struct Stage {
    radix: usize,
    /// Length of the sub-transforms already done (product of the earlier radices).
    ns: usize,
    /// `tw[k·radix + s] = e^{sign·2πi·s·k/(ns·radix)}`.
    tw: Vec<Complex<f32>>,
    /// Odd radices: `cos[(j−1)·m + k−1] = cos(2πjk/r)`, `sin[…] = sign · sin(2πjk/r)`.
    cos: Vec<f32>,
    sin: Vec<f32>,
    /// −1 forward, +1 inverse.
    sign: f32,
}

/// A planned unnormalised complex FFT of one length on [`V`] elements, both directions
/// (forward `e^{−2πi jk/n}`, inverse `e^{+2πi jk/n}`, as rustfft).
#[derive(Debug)]
pub(crate) struct VecFft {
    n: usize,
    fwd: Vec<Stage>,
    inv: Vec<Stage>,
}

/// Radices the passes implement.
const RADICES: [usize; 7] = [4, 2, 3, 5, 7, 11, 13];

impl VecFft {
    /// Plans length `n`; `None` when `n` has a prime factor above 13.
    pub(crate) fn new(n: usize) -> Option<VecFft> {
        if n < 2 {
            return None;
        }
        let mut radices = Vec::new();
        let mut x = n;
        for r in RADICES {
            while x % r == 0 {
                radices.push(r);
                x /= r;
            }
        }
        if x != 1 {
            return None;
        }
        // The largest radix first: the first pass has no twiddles.
        radices.sort_unstable_by(|a, b| b.cmp(a));
        let stages = |sign: f64| {
            let mut ns = 1;
            radices
                .iter()
                .map(|&r| {
                    let tw = (0..ns * r)
                        .map(|i| {
                            let (k, s) = (i / r, i % r);
                            let a = sign * 2.0 * std::f64::consts::PI * (s * k) as f64 / (ns * r) as f64;
                            Complex::new(a.cos() as f32, a.sin() as f32)
                        })
                        .collect();
                    let m = r / 2;
                    let (mut cos, mut sin) = (Vec::new(), Vec::new());
                    if r % 2 == 1 {
                        for j in 1..=m {
                            for k in 1..=m {
                                let a = 2.0 * std::f64::consts::PI * (j * k) as f64 / r as f64;
                                cos.push(a.cos() as f32);
                                sin.push((sign * a.sin()) as f32);
                            }
                        }
                    }
                    let st = Stage { radix: r, ns, tw, cos, sin, sign: sign as f32 };
                    ns *= r;
                    st
                })
                .collect::<Vec<_>>()
        };
        Some(VecFft { n, fwd: stages(-1.0), inv: stages(1.0) })
    }

    /// Transforms `a` (length `n`); `b` is the second buffer. Returns true when the result is
    /// in `b`.
    #[inline(always)]
    fn run<const F: bool>(&self, inverse: bool, a: &mut [V], b: &mut [V]) -> bool {
        let stages = if inverse { &self.inv } else { &self.fwd };
        let (a, b) = (&mut a[..self.n], &mut b[..self.n]);
        let mut in_b = false;
        for st in stages {
            let (src, dst) = if in_b { (&*b, &mut *a) } else { (&*a, &mut *b) };
            match st.radix {
                2 => pass::<2, F>(st, src, dst),
                3 => pass::<3, F>(st, src, dst),
                4 => pass::<4, F>(st, src, dst),
                5 => pass::<5, F>(st, src, dst),
                7 => pass::<7, F>(st, src, dst),
                11 => pass::<11, F>(st, src, dst),
                13 => pass::<13, F>(st, src, dst),
                _ => unreachable!("radix {} is not planned", st.radix),
            }
            in_b = !in_b;
        }
        in_b
    }

    /// Transforms a plain slice (tests): returns the result.
    #[cfg(test)]
    fn transform(&self, inverse: bool, x: &[V]) -> Vec<V> {
        let mut a = x.to_vec();
        let mut b = vec![V::ZERO; self.n];
        if self.run::<false>(inverse, &mut a, &mut b) {
            b
        } else {
            a
        }
    }
}

/// One Stockham pass of radix `R` from `src` to `dst`: butterfly `j = g·ns + k` reads
/// `src[j + s·n/R]` (`s < R`) and writes `dst[g·ns·R + k + t·ns]` (`t < R`).
#[inline(always)]
fn pass<const R: usize, const F: bool>(st: &Stage, src: &[V], dst: &mut [V]) {
    let n = src.len();
    let stride = n / R;
    let ns = st.ns;
    let parts: [&[V]; R] = std::array::from_fn(|s| &src[s * stride..(s + 1) * stride]);
    for (g, out) in dst[..n].chunks_exact_mut(ns * R).enumerate() {
        for k in 0..ns {
            let j = g * ns + k;
            let mut v = [V::ZERO; R];
            for (vs, part) in v.iter_mut().zip(&parts) {
                *vs = part[j];
            }
            if k > 0 {
                let tw = &st.tw[k * R..(k + 1) * R];
                for s in 1..R {
                    v[s] = v[s].cmul::<F>(tw[s]);
                }
            }
            let y = butterfly::<R, F>(st, &v);
            for (t, yt) in y.iter().enumerate() {
                out[k + t * ns] = *yt;
            }
        }
    }
}

/// The length-`R` DFT of `x` in the stage's direction.
#[inline(always)]
fn butterfly<const R: usize, const F: bool>(st: &Stage, x: &[V; R]) -> [V; R] {
    let mut y = [V::ZERO; R];
    if R == 2 {
        y[0] = x[0].add(x[1]);
        y[1] = x[0].sub(x[1]);
    } else if R == 4 {
        let (s0, d0) = (x[0].add(x[2]), x[0].sub(x[2]));
        let (s1, d1) = (x[1].add(x[3]), x[1].sub(x[3]));
        let r = d1.mul_i(st.sign);
        y[0] = s0.add(s1);
        y[2] = s0.sub(s1);
        y[1] = d0.add(r);
        y[3] = d0.sub(r);
    } else {
        // Odd R: sums and differences of the mirrored pairs.
        let m = R / 2;
        let mut p = [V::ZERO; R];
        let mut d = [V::ZERO; R];
        let mut y0 = x[0];
        for j in 1..=m {
            p[j] = x[j].add(x[R - j]);
            d[j] = x[j].sub(x[R - j]);
            y0 = y0.add(p[j]);
        }
        y[0] = y0;
        for k in 1..=m {
            let mut c = x[0];
            let mut s = V::ZERO;
            for j in 1..=m {
                let i = (j - 1) * m + (k - 1);
                c = c.add_scaled::<F>(p[j], st.cos[i]);
                s = s.add_scaled::<F>(d[j], st.sin[i]);
            }
            let is = s.mul_i(1.0);
            y[k] = c.add(is);
            y[R - k] = c.sub(is);
        }
    }
    y
}

/// The Rader-domain demultiplex (see `crate::rader` for the algebra) with [`VecFft`]
/// transforms of length `q = p − 1`.
pub(crate) struct VecRader {
    pub(crate) rader: Rader<f32>,
    plan: VecFft,
}

impl VecRader {
    /// `None` when `p − 1` has a prime factor the passes do not implement.
    pub(crate) fn new(rader: Rader<f32>) -> Option<VecRader> {
        let plan = VecFft::new(rader.q)?;
        Some(VecRader { rader, plan })
    }

    /// Scratch elements per thread.
    pub(crate) fn scratch_len(&self) -> usize {
        2 * self.rader.q
    }

    /// Applies the circulant to every column of the tile `rows` (`p` runs), in place, in
    /// blocks of `2W` columns gathered straight from the rows in Rader order; `vb` holds
    /// [`VecRader::scratch_len`] elements.
    pub(crate) fn tile(&self, rows: &mut [&mut [f32]], vb: &mut [V], dir: Dir) {
        let arch = pulp::Arch::new();
        // pulp picks its AVX2 + FMA level only when the CPU has FMA.
        if matches!(arch, pulp::Arch::Scalar) {
            arch.dispatch(TileOp::<false> { k: self, rows, vb, dir });
        } else {
            arch.dispatch(TileOp::<true> { k: self, rows, vb, dir });
        }
    }
}

struct TileOp<'a, 'b, const F: bool> {
    k: &'a VecRader,
    rows: &'a mut [&'b mut [f32]],
    vb: &'a mut [V],
    dir: Dir,
}

impl<const F: bool> pulp::WithSimd for TileOp<'_, '_, F> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        let TileOp { k, rows, vb, dir } = self;
        let r = &k.rader;
        let sp = if dir == Dir::Demux { &r.demux } else { &r.mux };
        tile_impl::<F>(r, sp, &k.plan, rows, vb);
    }
}

#[inline(always)]
fn tile_impl<const F: bool>(r: &Rader<f32>, sp: &Spec<f32>, plan: &VecFft, rows: &mut [&mut [f32]], vb: &mut [V]) {
    let q = r.q;
    debug_assert_eq!(rows.len(), r.p);
    let half = q / 2;
    let t = rows[0].len();
    let (mut a, mut b) = vb[..2 * q].split_at_mut(q);
    let g0 = sp.g0;
    let mut c0 = 0;
    while c0 < t {
        let c1 = (c0 + 2 * W).min(t);
        // The block after next asked for now: a block reads p rows of the stack at once, more
        // streams than the hardware prefetcher follows (10-20 % faster at tile 256, noisy).
        let cp = c0 + PREFETCH_BLOCKS * 2 * W;
        if cp < t {
            let last = (cp + 2 * W - 1).min(t - 1);
            for row in rows.iter() {
                prefetch(&row[cp]);
                prefetch(&row[last]);
            }
        }
        for (dst, &row) in a.iter_mut().zip(&r.perm) {
            *dst = V::load(&rows[row][c0..c1]);
        }
        let m0 = V::load(&rows[0][c0..c1]);
        if plan.run::<F>(false, a, b) {
            std::mem::swap(&mut a, &mut b);
        }
        let (u0, uh) = (a[0], a[half]);
        let sum = u0.add(m0);
        let mut y0 = u0.cmul::<F>(sp.z0).add(uh.cmul::<F>(sp.zh)).add(m0.cmul::<F>(sp.zm));
        {
            let (lo, hi) = a.split_at_mut(half);
            let (alo, ahi) = sp.a.split_at(half);
            let (blo, bhi) = sp.b.split_at(half);
            for l in 0..half {
                let (x, y) = (lo[l], hi[l]);
                lo[l] = x.cmul::<F>(alo[l]).add(y.cmul::<F>(blo[l]));
                hi[l] = y.cmul::<F>(ahi[l]).add(x.cmul::<F>(bhi[l]));
            }
        }
        a[0] = a[0].add(m0.cmul::<F>(sp.t0));
        a[half] = a[half].add(m0.cmul::<F>(sp.th));
        if plan.run::<F>(true, a, b) {
            std::mem::swap(&mut a, &mut b);
        }
        let s = V::ZERO.add_scaled::<F>(sum, g0);
        y0 = y0.add(s);
        for (e, &row) in r.perm.iter().enumerate() {
            a[e].add(s).store(&mut rows[row][c0..c1]);
        }
        y0.store(&mut rows[0][c0..c1]);
        c0 = c1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rustfft::FftPlanner;

    /// Every lane of the vector transform equals rustfft's transform of that lane, both
    /// directions, for lengths with every radix.
    #[test]
    fn lanes_match_rustfft() {
        let mut planner = FftPlanner::<f64>::new();
        for n in [2usize, 3, 4, 5, 6, 7, 8, 11, 12, 13, 16, 30, 60, 150, 198, 2 * 3 * 5 * 7 * 11, 169, 1024] {
            let plan = VecFft::new(n).unwrap();
            let x: Vec<V> = (0..n)
                .map(|i| {
                    let mut v = V::ZERO;
                    for l in 0..W {
                        v.re[l] = (((i * 7 + l * 13) % 17) as f32 - 8.0) / 8.0;
                        v.im[l] = (((i * 5 + l * 3) % 11) as f32 - 5.0) / 5.0;
                    }
                    v
                })
                .collect();
            for inverse in [false, true] {
                let y = plan.transform(inverse, &x);
                let f = if inverse { planner.plan_fft_inverse(n) } else { planner.plan_fft_forward(n) };
                for l in 0..W {
                    let mut c: Vec<Complex<f64>> =
                        x.iter().map(|v| Complex::new(f64::from(v.re[l]), f64::from(v.im[l]))).collect();
                    f.process(&mut c);
                    let scale = c.iter().map(|z| z.norm()).fold(0.0, f64::max);
                    for (i, z) in c.iter().enumerate() {
                        let e = (Complex::new(f64::from(y[i].re[l]), f64::from(y[i].im[l])) - z).norm();
                        assert!(e <= 2e-6 * scale.max(1.0), "n {n} inverse {inverse} lane {l} bin {i}: error {e}");
                    }
                }
            }
        }
        assert!(VecFft::new(17).is_none(), "17 is not a planned radix");
        assert!(VecFft::new(2 * 23).is_none());
    }

    #[test]
    fn load_and_store_round_trip_short_runs() {
        for len in 1..=2 * W {
            let run: Vec<f32> = (0..len).map(|i| i as f32 + 1.0).collect();
            let v = V::load(&run);
            let mut out = vec![0.0; len];
            v.store(&mut out);
            assert_eq!(out, run, "len {len}");
        }
    }
}

