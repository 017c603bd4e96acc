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
//! The workspace forbids unsafe code; when the CPU has AVX2 + FMA (checked at run time) the
//! tile function runs through [`pulp::Simd::vectorize`] on [`pulp::x86::V3`], inside a
//! function compiled for those features, and its arithmetic is pulp's explicit 256-bit
//! operations ([`Lanes`]); no `target-cpu` flags. Against loops over the lanes of plain
//! arrays left to LLVM's vectoriser (which mixed in 128-bit pieces), the explicit operations
//! measured 5 % faster at 151 and 20 % at 199 (`examples/demux_probe.rs`, one thread, a
//! stack that fits in L3).

use crate::demux::Dir;
use crate::rader::{Rader, Spec};
use rustfft::num_complex::Complex;

/// Columns per part of a vector element (one 256-bit register of f32 each for the real and
/// the imaginary part).
pub(crate) const W: usize = 8;

/// `W` lanes of f32.
type L = [f32; W];

/// Element-wise arithmetic on [`L`]: through explicit AVX2 + FMA vector operations where the
/// CPU has them ([`pulp::x86::V3`]), else portable loops. (Loops over the lanes of plain
/// arrays left the vectorising to LLVM, which split them into 128-bit pieces.)
pub(crate) trait Lanes: Copy {
    fn add(self, a: L, b: L) -> L;
    fn sub(self, a: L, b: L) -> L;
    /// `a · c`.
    fn scale(self, a: L, c: f32) -> L;
    /// `a · c + b`.
    fn fma(self, a: L, c: f32, b: L) -> L;
    /// `b − a · c`.
    fn fnma(self, a: L, c: f32, b: L) -> L;
}

/// The fallback: plain loops, no fused multiply-add (a library call where the CPU lacks it).
#[derive(Clone, Copy)]
pub(crate) struct Portable;

impl Lanes for Portable {
    #[inline(always)]
    fn add(self, a: L, b: L) -> L {
        std::array::from_fn(|i| a[i] + b[i])
    }
    #[inline(always)]
    fn sub(self, a: L, b: L) -> L {
        std::array::from_fn(|i| a[i] - b[i])
    }
    #[inline(always)]
    fn scale(self, a: L, c: f32) -> L {
        std::array::from_fn(|i| a[i] * c)
    }
    #[inline(always)]
    fn fma(self, a: L, c: f32, b: L) -> L {
        std::array::from_fn(|i| a[i] * c + b[i])
    }
    #[inline(always)]
    fn fnma(self, a: L, c: f32, b: L) -> L {
        std::array::from_fn(|i| b[i] - a[i] * c)
    }
}

#[cfg(target_arch = "x86_64")]
impl Lanes for pulp::x86::V3 {
    #[inline(always)]
    fn add(self, a: L, b: L) -> L {
        use pulp::Simd;
        cast(self.add_f32s(cast(a), cast(b)))
    }
    #[inline(always)]
    fn sub(self, a: L, b: L) -> L {
        use pulp::Simd;
        cast(self.sub_f32s(cast(a), cast(b)))
    }
    #[inline(always)]
    fn scale(self, a: L, c: f32) -> L {
        use pulp::Simd;
        cast(self.mul_f32s(cast(a), self.splat_f32s(c)))
    }
    #[inline(always)]
    fn fma(self, a: L, c: f32, b: L) -> L {
        use pulp::Simd;
        cast(self.mul_add_f32s(cast(a), self.splat_f32s(c), cast(b)))
    }
    #[inline(always)]
    fn fnma(self, a: L, c: f32, b: L) -> L {
        use pulp::Simd;
        cast(self.negate_mul_add_f32x8(cast(a), self.splat_f32s(c), cast(b)))
    }
}

#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn cast<A: pulp::bytemuck::Pod, B: pulp::bytemuck::Pod>(a: A) -> B {
    pulp::bytemuck::cast(a)
}

/// One transform element: `W` complex lanes, split.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct V {
    re: L,
    im: L,
}

impl V {
    const ZERO: V = V { re: [0.0; W], im: [0.0; W] };

    #[inline(always)]
    fn add<M: Lanes>(self, o: V, m: M) -> V {
        V { re: m.add(self.re, o.re), im: m.add(self.im, o.im) }
    }

    #[inline(always)]
    fn sub<M: Lanes>(self, o: V, m: M) -> V {
        V { re: m.sub(self.re, o.re), im: m.sub(self.im, o.im) }
    }

    /// `self + o · c` for a real scalar `c`.
    #[inline(always)]
    fn add_scaled<M: Lanes>(self, o: V, c: f32, m: M) -> V {
        V { re: m.fma(o.re, c, self.re), im: m.fma(o.im, c, self.im) }
    }

    /// `o · c` for a real scalar `c`.
    #[inline(always)]
    fn scaled<M: Lanes>(self, c: f32, m: M) -> V {
        V { re: m.scale(self.re, c), im: m.scale(self.im, c) }
    }

    /// `self · c` for a complex scalar `c`.
    #[inline(always)]
    fn cmul<M: Lanes>(self, c: Complex<f32>, m: M) -> V {
        V { re: m.fnma(self.im, c.im, m.scale(self.re, c.re)), im: m.fma(self.re, c.im, m.scale(self.im, c.re)) }
    }

    /// `self + i · o`.
    #[inline(always)]
    fn add_i<M: Lanes>(self, o: V, m: M) -> V {
        V { re: m.sub(self.re, o.im), im: m.add(self.im, o.re) }
    }

    /// `self − i · o`.
    #[inline(always)]
    fn sub_i<M: Lanes>(self, o: V, m: M) -> V {
        V { re: m.add(self.re, o.im), im: m.sub(self.im, o.re) }
    }

    /// The first `W` values of `run` as the real part, the next `W` as the imaginary part
    /// (zeros where `run` is shorter than `2W`).
    #[inline(always)]
    fn load(run: &[f32]) -> V {
        match <&[f32; 2 * W]>::try_from(run) {
            // Fixed-size moves straight into the result: two vector loads.
            Ok(full) => V { re: std::array::from_fn(|i| full[i]), im: std::array::from_fn(|i| full[W + i]) },
            Err(_) => V::load_partial(run),
        }
    }

    #[cold]
    #[inline(never)]
    fn load_partial(run: &[f32]) -> V {
        let mut v = V::ZERO;
        let k = run.len().min(W);
        v.re[..k].copy_from_slice(&run[..k]);
        if run.len() > W {
            v.im[..run.len() - W].copy_from_slice(&run[W..]);
        }
        v
    }

    /// The inverse of [`V::load`].
    #[inline(always)]
    fn store(self, run: &mut [f32]) {
        match <&mut [f32; 2 * W]>::try_from(&mut *run) {
            Ok(full) => {
                full[..W].copy_from_slice(&self.re);
                full[W..].copy_from_slice(&self.im);
            }
            Err(_) => self.store_partial(run),
        }
    }

    #[cold]
    #[inline(never)]
    fn store_partial(self, run: &mut [f32]) {
        let k = run.len().min(W);
        run[..k].copy_from_slice(&self.re[..k]);
        if run.len() > W {
            let m = run.len() - W;
            run[W..].copy_from_slice(&self.im[..m]);
        }
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
    fn run<M: Lanes>(&self, m: M, inverse: bool, a: &mut [V], b: &mut [V]) -> bool {
        let stages = if inverse { &self.inv } else { &self.fwd };
        let (a, b) = (&mut a[..self.n], &mut b[..self.n]);
        let mut in_b = false;
        for st in stages {
            let (src, dst) = if in_b { (&*b, &mut *a) } else { (&*a, &mut *b) };
            match st.radix {
                2 => pass::<2, M>(m, st, src, dst),
                3 => pass::<3, M>(m, st, src, dst),
                4 => pass::<4, M>(m, st, src, dst),
                5 => pass::<5, M>(m, st, src, dst),
                7 => pass::<7, M>(m, st, src, dst),
                11 => pass::<11, M>(m, st, src, dst),
                13 => pass::<13, M>(m, st, src, dst),
                _ => unreachable!("radix {} is not planned", st.radix),
            }
            in_b = !in_b;
        }
        in_b
    }

    /// Transforms a plain slice (tests): returns the result.
    #[cfg(test)]
    fn transform<M: Lanes>(&self, m: M, inverse: bool, x: &[V]) -> Vec<V> {
        let mut a = x.to_vec();
        let mut b = vec![V::ZERO; self.n];
        if self.run(m, inverse, &mut a, &mut b) {
            b
        } else {
            a
        }
    }
}

/// One Stockham pass of radix `R` from `src` to `dst`: butterfly `j = g·ns + k` reads
/// `src[j + s·n/R]` (`s < R`) and writes `dst[g·ns·R + k + t·ns]` (`t < R`).
#[inline(always)]
fn pass<const R: usize, M: Lanes>(m: M, st: &Stage, src: &[V], dst: &mut [V]) {
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
                    v[s] = v[s].cmul(tw[s], m);
                }
            }
            let y = butterfly::<R, M>(m, st, &v);
            for (t, yt) in y.iter().enumerate() {
                out[k + t * ns] = *yt;
            }
        }
    }
}

/// The length-`R` DFT of `x` in the stage's direction.
#[inline(always)]
fn butterfly<const R: usize, M: Lanes>(m: M, st: &Stage, x: &[V; R]) -> [V; R] {
    let mut y = [V::ZERO; R];
    if R == 2 {
        y[0] = x[0].add(x[1], m);
        y[1] = x[0].sub(x[1], m);
    } else if R == 4 {
        let (s0, d0) = (x[0].add(x[2], m), x[0].sub(x[2], m));
        let (s1, d1) = (x[1].add(x[3], m), x[1].sub(x[3], m));
        y[0] = s0.add(s1, m);
        y[2] = s0.sub(s1, m);
        // y1 = d0 + sign · i · d1, y3 = d0 − sign · i · d1.
        if st.sign < 0.0 {
            y[1] = d0.sub_i(d1, m);
            y[3] = d0.add_i(d1, m);
        } else {
            y[1] = d0.add_i(d1, m);
            y[3] = d0.sub_i(d1, m);
        }
    } else {
        // Odd R: sums and differences of the mirrored pairs.
        let h = R / 2;
        let mut p = [V::ZERO; R];
        let mut d = [V::ZERO; R];
        let mut y0 = x[0];
        for j in 1..=h {
            p[j] = x[j].add(x[R - j], m);
            d[j] = x[j].sub(x[R - j], m);
            y0 = y0.add(p[j], m);
        }
        y[0] = y0;
        for k in 1..=h {
            let mut c = x[0].add_scaled(p[1], st.cos[k - 1], m);
            let mut s = d[1].scaled(st.sin[k - 1], m);
            for j in 2..=h {
                let i = (j - 1) * h + (k - 1);
                c = c.add_scaled(p[j], st.cos[i], m);
                s = s.add_scaled(d[j], st.sin[i], m);
            }
            y[k] = c.add_i(s, m);
            y[R - k] = c.sub_i(s, m);
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
    /// blocks of `2W` columns; `vb` holds [`VecRader::scratch_len`] elements.
    pub(crate) fn tile(&self, rows: &mut [&mut [f32]], vb: &mut [V], dir: Dir) {
        #[cfg(target_arch = "x86_64")]
        if let Some(v3) = pulp::x86::V3::try_new() {
            // The body compiled for AVX2 + FMA (checked at run time above).
            return pulp::Simd::vectorize(v3, TileOp { m: v3, k: self, rows, vb, dir });
        }
        TileOp { m: Portable, k: self, rows, vb, dir }.body();
    }
}

struct TileOp<'a, 'b, M> {
    m: M,
    k: &'a VecRader,
    rows: &'a mut [&'b mut [f32]],
    vb: &'a mut [V],
    dir: Dir,
}

impl<M: Lanes> TileOp<'_, '_, M> {
    #[inline(always)]
    fn body(self) {
        let TileOp { m, k, rows, vb, dir } = self;
        let r = &k.rader;
        let sp = if dir == Dir::Demux { &r.demux } else { &r.mux };
        tile_impl(m, r, sp, &k.plan, rows, vb);
    }
}

// Everything below `with_simd` is `inline(always)`, so it is compiled inside pulp's AVX2 + FMA
// function (a closure there would not be, and every vector operation would become a call).
impl<M: Lanes> pulp::WithSimd for TileOp<'_, '_, M> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        self.body()
    }
}

/// The Rader-domain map of one block `a` (`q` elements in Rader order; `m0` is the row-0
/// element); `b` is the second buffer. Returns the buffer holding the result (before the
/// common term `s` is added), the row-0 output, and `s`.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn block<'x, M: Lanes>(
    m: M,
    r: &Rader<f32>,
    sp: &Spec<f32>,
    plan: &VecFft,
    a: &'x mut [V],
    b: &'x mut [V],
    m0: V,
) -> (&'x mut [V], V, V) {
    let half = r.q / 2;
    let (mut a, mut b) = (a, b);
    if plan.run(m, false, a, b) {
        std::mem::swap(&mut a, &mut b);
    }
    let (u0, uh) = (a[0], a[half]);
    let sum = u0.add(m0, m);
    let y0 = u0.cmul(sp.z0, m).add(uh.cmul(sp.zh, m), m).add(m0.cmul(sp.zm, m), m);
    {
        let (lo, hi) = a.split_at_mut(half);
        let (alo, ahi) = sp.a.split_at(half);
        let (blo, bhi) = sp.b.split_at(half);
        for l in 0..half {
            let (x, y) = (lo[l], hi[l]);
            lo[l] = x.cmul(alo[l], m).add(y.cmul(blo[l], m), m);
            hi[l] = y.cmul(ahi[l], m).add(x.cmul(bhi[l], m), m);
        }
    }
    a[0] = a[0].add(m0.cmul(sp.t0, m), m);
    a[half] = a[half].add(m0.cmul(sp.th, m), m);
    if plan.run(m, true, a, b) {
        std::mem::swap(&mut a, &mut b);
    }
    let s = sum.scaled(sp.g0, m);
    (a, y0.add(s, m), s)
}

/// Blocks of `2W` columns gathered straight from the rows in Rader order.
#[inline(always)]
fn tile_impl<M: Lanes>(m: M, r: &Rader<f32>, sp: &Spec<f32>, plan: &VecFft, rows: &mut [&mut [f32]], vb: &mut [V]) {
    let q = r.q;
    debug_assert_eq!(rows.len(), r.p);
    let t = rows[0].len();
    let (a, b) = vb[..2 * q].split_at_mut(q);
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
        let (res, y0, s) = block(m, r, sp, plan, &mut *a, &mut *b, m0);
        for (e, &row) in r.perm.iter().enumerate() {
            res[e].add(s, m).store(&mut rows[row][c0..c1]);
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
                let y = plan.transform(Portable, inverse, &x);
                // The AVX2 + FMA arithmetic gives the same transform (up to rounding).
                #[cfg(target_arch = "x86_64")]
                if let Some(v3) = pulp::x86::V3::try_new() {
                    let yv = plan.transform(v3, inverse, &x);
                    for (a, b) in y.iter().zip(&yv) {
                        for l in 0..W {
                            let e = (a.re[l] - b.re[l]).abs().max((a.im[l] - b.im[l]).abs());
                            assert!(e <= 1e-5 * (1.0 + a.re[l].abs() + a.im[l].abs()) * n as f32, "n {n}: V3 lane {l} off by {e}");
                        }
                    }
                }
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

