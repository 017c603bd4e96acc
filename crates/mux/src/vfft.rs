//! The Rader-domain demultiplex of the Paley orders on a pixel-vectorised FFT, with the
//! gather, the spectrum multiply and the scatter fused into the transform passes.
//!
//! rustfft transforms one column at a time, so the pattern-major tile would have to be
//! transposed into its buffer and back. Here every element of the transform is a pair of
//! vectors of `W` columns in split-complex form (`W` columns of the tile as the real part,
//! the next `W` as the imaginary part, which the map keeps apart because it sends real
//! columns to real columns), so a butterfly is element-wise arithmetic on whole vectors and
//! nothing is transposed. One block of `2W` columns (`q` elements, `q · 8W` bytes per buffer)
//! stays in L1 through every pass.
//!
//! The map of one block (see `crate::rader` for the algebra) is a forward FFT of length
//! `q = p − 1`, the two-valued spectrum multiply `T̂_l = A_l Û_l + B_l Û_{l+q/2}`, and an
//! inverse FFT. Both transforms are mixed-radix Stockham passes (natural order in and out, two
//! buffers) over the odd radices 3 … 13 of `q` plus one radix 2 (`q = p − 1 ≡ 2 mod 4` for
//! a Paley prime `p ≡ 3 mod 4`). The passes are arranged so that little but arithmetic is
//! left between the stack and the result:
//!
//! * the forward transform's first pass (radix `r₀`, no twiddles) reads its inputs straight
//!   from the tile's rows in Rader order: the gather is that pass's loads;
//! * the forward transform ends with its radix-2 pass (pairs `l`, `l + q/2`), which is exactly
//!   the pairing of the spectrum multiply, and the inverse transform starts with a radix-2
//!   pass over the same pairs: the three are one 2 × 2 complex matrix per pair,
//!   `[out₂ⱼ, out₂ⱼ₊₁] = M_j [a_j, a_{j+q/2}]`, precomputed (four complex multiply-adds per
//!   pair instead of a twiddle, two butterflies and four complex products); the rank-one
//!   terms of row 0 (`crate::rader`) enter at `j = 0`, the common term `s` as a constant
//!   added to bin 0 of the inverse's input;
//! * the inverse transform's last pass writes its outputs straight to the tile's rows.
//!
//! So a block costs `2 · (number of odd radices)` passes plus the fused middle, against
//! gather + 2 transforms + multiply + scatter before (measured in `docs/benchmarks.md`).
//! Odd radices use the symmetric form
//! `y_k = x_0 + Σ_j cos(2πjk/r) (x_j + x_{r−j}) ± i sin(2πjk/r) (x_j − x_{r−j})`.
//!
//! The workspace forbids unsafe code; when the CPU has AVX2 + FMA (checked at run time) the
//! tile function runs through [`pulp::Simd::vectorize`] on [`pulp::x86::V3`], inside a
//! function compiled for those features, and its arithmetic is pulp's explicit 256-bit
//! operations ([`Lanes`]); no `target-cpu` flags. Elsewhere the portable [`Portable`] lanes
//! run the same code.

use pulp::bytemuck::Pod;
use rustfft::num_complex::Complex;

use crate::demux::Dir;
use crate::rader::{Rader, Spec};

/// Element-wise arithmetic on `W` lanes of f32: explicit vector operations where the CPU has
/// them, else portable loops.
pub(crate) trait Lanes: Copy {
    /// The vector type.
    type L: Copy + Pod;
    /// Lanes per vector.
    const W: usize;
    fn splat(self, c: f32) -> Self::L;
    fn add(self, a: Self::L, b: Self::L) -> Self::L;
    fn sub(self, a: Self::L, b: Self::L) -> Self::L;
    fn mul(self, a: Self::L, b: Self::L) -> Self::L;
    /// `a · b + c`.
    fn fma(self, a: Self::L, b: Self::L, c: Self::L) -> Self::L;
    /// `c − a · b`.
    fn fnma(self, a: Self::L, b: Self::L, c: Self::L) -> Self::L;
    /// The first `W` values of `s`.
    fn load(self, s: &[f32]) -> Self::L;
    /// Into the first `W` values of `d`.
    fn store(self, v: Self::L, d: &mut [f32]);
}

/// The fallback: plain loops over 8 lanes.
#[derive(Clone, Copy)]
pub(crate) struct Portable;

impl Lanes for Portable {
    type L = [f32; 8];
    const W: usize = 8;
    #[inline(always)]
    fn splat(self, c: f32) -> [f32; 8] {
        [c; 8]
    }
    #[inline(always)]
    fn add(self, a: [f32; 8], b: [f32; 8]) -> [f32; 8] {
        std::array::from_fn(|i| a[i] + b[i])
    }
    #[inline(always)]
    fn sub(self, a: [f32; 8], b: [f32; 8]) -> [f32; 8] {
        std::array::from_fn(|i| a[i] - b[i])
    }
    #[inline(always)]
    fn mul(self, a: [f32; 8], b: [f32; 8]) -> [f32; 8] {
        std::array::from_fn(|i| a[i] * b[i])
    }
    #[inline(always)]
    fn fma(self, a: [f32; 8], b: [f32; 8], c: [f32; 8]) -> [f32; 8] {
        std::array::from_fn(|i| a[i] * b[i] + c[i])
    }
    #[inline(always)]
    fn fnma(self, a: [f32; 8], b: [f32; 8], c: [f32; 8]) -> [f32; 8] {
        std::array::from_fn(|i| c[i] - a[i] * b[i])
    }
    #[inline(always)]
    fn load(self, s: &[f32]) -> [f32; 8] {
        s[..8].try_into().expect("8 values")
    }
    #[inline(always)]
    fn store(self, v: [f32; 8], d: &mut [f32]) {
        d[..8].copy_from_slice(&v);
    }
}

#[cfg(target_arch = "x86_64")]
impl Lanes for pulp::x86::V3 {
    type L = pulp::f32x8;
    const W: usize = 8;
    #[inline(always)]
    fn splat(self, c: f32) -> pulp::f32x8 {
        self.splat_f32x8(c)
    }
    #[inline(always)]
    fn add(self, a: pulp::f32x8, b: pulp::f32x8) -> pulp::f32x8 {
        self.add_f32x8(a, b)
    }
    #[inline(always)]
    fn sub(self, a: pulp::f32x8, b: pulp::f32x8) -> pulp::f32x8 {
        self.sub_f32x8(a, b)
    }
    #[inline(always)]
    fn mul(self, a: pulp::f32x8, b: pulp::f32x8) -> pulp::f32x8 {
        self.mul_f32x8(a, b)
    }
    #[inline(always)]
    fn fma(self, a: pulp::f32x8, b: pulp::f32x8, c: pulp::f32x8) -> pulp::f32x8 {
        self.mul_add_f32x8(a, b, c)
    }
    #[inline(always)]
    fn fnma(self, a: pulp::f32x8, b: pulp::f32x8, c: pulp::f32x8) -> pulp::f32x8 {
        self.negate_mul_add_f32x8(a, b, c)
    }
    #[inline(always)]
    fn load(self, s: &[f32]) -> pulp::f32x8 {
        let a: [f32; 8] = s[..8].try_into().expect("8 values");
        pulp::bytemuck::cast(a)
    }
    #[inline(always)]
    fn store(self, v: pulp::f32x8, d: &mut [f32]) {
        d[..8].copy_from_slice(&pulp::bytemuck::cast::<_, [f32; 8]>(v));
    }
}

#[cfg(target_arch = "x86_64")]
impl Lanes for pulp::x86::V4 {
    type L = pulp::f32x16;
    const W: usize = 16;
    #[inline(always)]
    fn splat(self, c: f32) -> pulp::f32x16 {
        self.splat_f32x16(c)
    }
    #[inline(always)]
    fn add(self, a: pulp::f32x16, b: pulp::f32x16) -> pulp::f32x16 {
        self.add_f32x16(a, b)
    }
    #[inline(always)]
    fn sub(self, a: pulp::f32x16, b: pulp::f32x16) -> pulp::f32x16 {
        self.sub_f32x16(a, b)
    }
    #[inline(always)]
    fn mul(self, a: pulp::f32x16, b: pulp::f32x16) -> pulp::f32x16 {
        self.mul_f32x16(a, b)
    }
    #[inline(always)]
    fn fma(self, a: pulp::f32x16, b: pulp::f32x16, c: pulp::f32x16) -> pulp::f32x16 {
        self.mul_add_f32x16(a, b, c)
    }
    #[inline(always)]
    fn fnma(self, a: pulp::f32x16, b: pulp::f32x16, c: pulp::f32x16) -> pulp::f32x16 {
        self.negate_mul_add_f32x16(a, b, c)
    }
    #[inline(always)]
    fn load(self, s: &[f32]) -> pulp::f32x16 {
        let a: [f32; 16] = s[..16].try_into().expect("16 values");
        pulp::bytemuck::cast(a)
    }
    #[inline(always)]
    fn store(self, v: pulp::f32x16, d: &mut [f32]) {
        d[..16].copy_from_slice(&pulp::bytemuck::cast::<_, [f32; 16]>(v));
    }
}

/// One transform element: `W` complex lanes, split (in registers).
#[derive(Clone, Copy)]
struct C<L> {
    re: L,
    im: L,
}

/// One transform element in a buffer: real part, imaginary part.
type E<M> = [<M as Lanes>::L; 2];

/// The arithmetic of [`C`] on a [`Lanes`].
#[derive(Clone, Copy)]
struct Ops<M>(M);

impl<M: Lanes> Ops<M> {
    #[inline(always)]
    fn add(self, a: C<M::L>, b: C<M::L>) -> C<M::L> {
        C { re: self.0.add(a.re, b.re), im: self.0.add(a.im, b.im) }
    }
    #[inline(always)]
    fn sub(self, a: C<M::L>, b: C<M::L>) -> C<M::L> {
        C { re: self.0.sub(a.re, b.re), im: self.0.sub(a.im, b.im) }
    }
    /// `x · (wr + i wi)`.
    #[inline(always)]
    fn cmul(self, x: C<M::L>, wr: f32, wi: f32) -> C<M::L> {
        let m = self.0;
        let (r, i) = (m.splat(wr), m.splat(wi));
        C { re: m.fnma(x.im, i, m.mul(x.re, r)), im: m.fma(x.re, i, m.mul(x.im, r)) }
    }
    /// `a · pc + b · qc` for complex scalars `pc = (c[0], c[1])`, `qc = (c[2], c[3])`.
    #[inline(always)]
    fn cmul2(self, a: C<M::L>, b: C<M::L>, c: &[f32; 4]) -> C<M::L> {
        let m = self.0;
        let (pr, pi, qr, qi) = (m.splat(c[0]), m.splat(c[1]), m.splat(c[2]), m.splat(c[3]));
        let re = m.fnma(b.im, qi, m.fma(b.re, qr, m.fnma(a.im, pi, m.mul(a.re, pr))));
        let im = m.fma(b.re, qi, m.fma(b.im, qr, m.fma(a.re, pi, m.mul(a.im, pr))));
        C { re, im }
    }
    /// `x · c` for a complex scalar.
    #[inline(always)]
    fn cscale(self, x: C<M::L>, c: Complex<f32>) -> C<M::L> {
        self.cmul(x, c.re, c.im)
    }
    /// `R` zero elements (explicit: `std::array::from_fn` is not inlined into the
    /// vectorised function, and every vector operation in its closure became a call).
    #[inline(always)]
    fn zeros<const R: usize>(self) -> [C<M::L>; R] {
        let z = self.0.splat(0.0);
        [C { re: z, im: z }; R]
    }
    /// Columns `c0 .. c0 + W` of `row` as the real part, the next `W` as the imaginary part.
    #[inline(always)]
    fn load_row(self, row: &[f32], c0: usize) -> C<M::L> {
        let run = &row[c0..c0 + 2 * M::W];
        C { re: self.0.load(&run[..M::W]), im: self.0.load(&run[M::W..]) }
    }
    #[inline(always)]
    fn store_row(self, row: &mut [f32], c0: usize, v: C<M::L>) {
        let run = &mut row[c0..c0 + 2 * M::W];
        let (a, b) = run.split_at_mut(M::W);
        self.0.store(v.re, a);
        self.0.store(v.im, b);
    }
}

#[inline(always)]
fn unpack<L: Copy>(e: [L; 2]) -> C<L> {
    C { re: e[0], im: e[1] }
}

#[inline(always)]
fn pack<L: Copy>(c: C<L>) -> [L; 2] {
    [c.re, c.im]
}

/// One Stockham pass of an odd radix.
#[derive(Debug)]
struct Stage {
    radix: usize,
    /// Length of the sub-transforms already done (product of the earlier radices).
    ns: usize,
    /// `tw[2(k·radix + s)], tw[2(k·radix + s) + 1]` = re, im of `e^{sign·2πi·s·k/(ns·radix)}`.
    tw: Vec<f32>,
    /// `cos[(j−1)·h + k−1] = cos(2πjk/r)`, `sin[…] = sign · sin(2πjk/r)` (`h = r / 2`).
    cos: Vec<f32>,
    sin: Vec<f32>,
}

impl Stage {
    fn new(radix: usize, ns: usize, sign: f64) -> Stage {
        let tau = 2.0 * std::f64::consts::PI;
        let mut tw = Vec::with_capacity(2 * ns * radix);
        for k in 0..ns {
            for s in 0..radix {
                let a = sign * tau * (s * k) as f64 / (ns * radix) as f64;
                tw.push(a.cos() as f32);
                tw.push(a.sin() as f32);
            }
        }
        let h = radix / 2;
        let (mut cos, mut sin) = (Vec::new(), Vec::new());
        for j in 1..=h {
            for k in 1..=h {
                let a = tau * (j * k) as f64 / radix as f64;
                cos.push(a.cos() as f32);
                sin.push((sign * a.sin()) as f32);
            }
        }
        Stage { radix, ns, tw, cos, sin }
    }
}

/// Where a butterfly's outputs go: `put(t, y_t)` for every `t < R`.
trait Sink<M: Lanes> {
    fn put(&mut self, o: Ops<M>, t: usize, v: C<M::L>);
}

/// Output `t` to `dst[base + t·step]`.
struct BufSink<'a, M: Lanes> {
    dst: &'a mut [E<M>],
    base: usize,
    step: usize,
}

impl<M: Lanes> Sink<M> for BufSink<'_, M> {
    #[inline(always)]
    fn put(&mut self, _o: Ops<M>, t: usize, v: C<M::L>) {
        self.dst[self.base + t * self.step] = pack(v);
    }
}

/// Output `t` times the twiddle `tw[2t], tw[2t + 1]` (none when `tw` is empty) to
/// `dst[base + t·step]`: the decimation-in-frequency passes.
struct TwiddledSink<'a, M: Lanes> {
    dst: &'a mut [E<M>],
    base: usize,
    step: usize,
    tw: &'a [f32],
}

impl<M: Lanes> Sink<M> for TwiddledSink<'_, M> {
    #[inline(always)]
    fn put(&mut self, o: Ops<M>, t: usize, v: C<M::L>) {
        let v = if t > 0 && !self.tw.is_empty() { o.cmul(v, self.tw[2 * t], self.tw[2 * t + 1]) } else { v };
        self.dst[self.base + t * self.step] = pack(v);
    }
}

/// Output `t` to row `rows[base + t·step]`, columns `c0 .. c0 + 2W`.
struct RowSink<'a, 'b> {
    rows: &'a mut [&'b mut [f32]],
    base: usize,
    step: usize,
    c0: usize,
}

impl<M: Lanes> Sink<M> for RowSink<'_, '_> {
    #[inline(always)]
    fn put(&mut self, o: Ops<M>, t: usize, v: C<M::L>) {
        o.store_row(self.rows[self.base + t * self.step], self.c0, v);
    }
}

/// The length-`R` DFT of `x` (odd `R`), symmetric form, outputs to `out`; `cos`, `sin` as in
/// [`Stage`]. The outputs go out as they are made: with `k` a loop (R = 11 is not unrolled)
/// an output array indexed by `k` went through the stack; the inputs' indices are constants
/// (the inner loop unrolls), so `x` stays in registers.
#[inline(always)]
fn dft_odd<const R: usize, M: Lanes, S: Sink<M>>(o: Ops<M>, cos: &[f32], sin: &[f32], x: &mut [C<M::L>; R], out: &mut S) {
    let m = o.0;
    let h = R / 2;
    let (cos, sin) = (&cos[..h * h], &sin[..h * h]);
    // p_j in x[j], d_j in x[R − j].
    let mut y0 = x[0];
    for j in 1..=h {
        let (a, b) = (x[j], x[R - j]);
        x[j] = o.add(a, b);
        x[R - j] = o.sub(a, b);
        y0 = o.add(y0, x[j]);
    }
    out.put(o, 0, y0);
    for k in 1..=h {
        let c0 = m.splat(cos[k - 1]);
        let s0 = m.splat(sin[k - 1]);
        let mut cre = m.fma(x[1].re, c0, x[0].re);
        let mut cim = m.fma(x[1].im, c0, x[0].im);
        let mut sre = m.mul(x[R - 1].re, s0);
        let mut sim = m.mul(x[R - 1].im, s0);
        for j in 2..=h {
            let i = (j - 1) * h + (k - 1);
            let (c, s) = (m.splat(cos[i]), m.splat(sin[i]));
            cre = m.fma(x[j].re, c, cre);
            cim = m.fma(x[j].im, c, cim);
            sre = m.fma(x[R - j].re, s, sre);
            sim = m.fma(x[R - j].im, s, sim);
        }
        // y_k = c + i s, y_{R−k} = c − i s.
        out.put(o, k, C { re: m.sub(cre, sim), im: m.add(cim, sre) });
        out.put(o, R - k, C { re: m.add(cre, sim), im: m.sub(cim, sre) });
    }
}

/// Multiplies `x[s]` (`s >= 1`) by the twiddles `tw[2s], tw[2s + 1]` of one butterfly.
#[inline(always)]
fn twiddle<const R: usize, M: Lanes>(o: Ops<M>, tw: &[f32], x: &mut [C<M::L>; R]) {
    let tw = &tw[..2 * R];
    for s in 1..R {
        x[s] = o.cmul(x[s], tw[2 * s], tw[2 * s + 1]);
    }
}

// The passes take the transform length `q` and the stage's `ns` as arguments and are
// `inline(always)`: called with constants (the plans of `block` for q = 150 and 198) every
// loop bound and index is known, the loops unroll and the bounds checks fold away; called
// with a stage's values they are the general code.

/// The forward transform's first pass (`ns = 1`, no twiddles): inputs straight from the
/// tile's rows in Rader order (`rows[e]` is element `e`), outputs to `dst`; asks for the
/// lines of the block at `pf` (if any) on the way.
#[inline(always)]
fn first_pass<const R: usize, M: Lanes>(
    o: Ops<M>,
    st: &Stage,
    q: usize,
    rows: &[&mut [f32]],
    c0: usize,
    pf: Option<(usize, usize)>,
    dst: &mut [E<M>],
) {
    let (rows, dst) = (&rows[..q], &mut dst[..q]);
    let stride = q / R;
    for j in 0..stride {
        let mut x = o.zeros::<R>();
        for s in 0..R {
            x[s] = o.load_row(&*rows[j + s * stride], c0);
        }
        if let Some((cp, n)) = pf {
            for s in 0..R {
                prefetch_run(&*rows[j + s * stride], cp, n);
            }
        }
        dft_odd::<R, M, _>(o, &st.cos, &st.sin, &mut x, &mut BufSink { dst: &mut *dst, base: j * R, step: 1 });
    }
}

/// A twiddled Stockham pass of odd radix `R` from `src` to `dst`: butterfly `(g, k)` reads
/// elements `g·ns + k + s·q/R` and writes `g·ns·R + k + t·ns`.
#[inline(always)]
fn pass<const R: usize, M: Lanes>(o: Ops<M>, st: &Stage, q: usize, ns: usize, src: &[E<M>], dst: &mut [E<M>]) {
    debug_assert_eq!((st.radix, st.ns), (R, ns));
    let (src, dst) = (&src[..q], &mut dst[..q]);
    let tw = &st.tw[..2 * ns * R];
    let stride = q / R;
    for g in 0..stride / ns {
        for k in 0..ns {
            let j = g * ns + k;
            let mut x = o.zeros::<R>();
            for s in 0..R {
                x[s] = unpack(src[j + s * stride]);
            }
            if k > 0 {
                twiddle::<R, M>(o, &tw[2 * k * R..], &mut x);
            }
            let base = g * ns * R + k;
            dft_odd::<R, M, _>(o, &st.cos, &st.sin, &mut x, &mut BufSink { dst: &mut *dst, base, step: ns });
        }
    }
}

/// The transpose of [`pass`] (decimation in frequency, twiddles after the butterfly): the
/// inverse transform runs the forward plan's passes transposed in reverse order (`F = Fᵀ`),
/// so its last pass is the untwiddled `ns = 1` one. Butterfly `(g, k)` reads elements
/// `g·ns·R + k + t·ns` and writes `g·ns + k + s·q/R`.
#[inline(always)]
fn pass_dif<const R: usize, M: Lanes>(o: Ops<M>, st: &Stage, q: usize, ns: usize, src: &[E<M>], dst: &mut [E<M>]) {
    debug_assert_eq!((st.radix, st.ns), (R, ns));
    let (src, dst) = (&src[..q], &mut dst[..q]);
    let tw = &st.tw[..2 * ns * R];
    let stride = q / R;
    for g in 0..stride / ns {
        for k in 0..ns {
            let base = g * ns * R + k;
            let mut x = o.zeros::<R>();
            for t in 0..R {
                x[t] = unpack(src[base + t * ns]);
            }
            let tw = if k > 0 { &tw[2 * k * R..2 * (k + 1) * R] } else { &[] };
            let mut out = TwiddledSink { dst: &mut *dst, base: g * ns + k, step: stride, tw };
            dft_odd::<R, M, _>(o, &st.cos, &st.sin, &mut x, &mut out);
        }
    }
}

/// The inverse transform's last pass: [`pass_dif`] at `ns = 1` (no twiddles), outputs
/// straight to the tile's rows in Rader order.
#[inline(always)]
fn last_pass<const R: usize, M: Lanes>(
    o: Ops<M>,
    st: &Stage,
    q: usize,
    src: &[E<M>],
    rows: &mut [&mut [f32]],
    c0: usize,
) {
    debug_assert_eq!((st.radix, st.ns), (R, 1));
    let (src, rows) = (&src[..q], &mut rows[..q]);
    let stride = q / R;
    for g in 0..stride {
        let mut x = o.zeros::<R>();
        for t in 0..R {
            x[t] = unpack(src[g * R + t]);
        }
        dft_odd::<R, M, _>(o, &st.cos, &st.sin, &mut x, &mut RowSink { rows: &mut *rows, base: g, step: stride, c0 });
    }
}

/// Asks for the lines of `row[c0 .. c0 + n]` into L2 (a hint; no-op off x86_64). Into L2
/// rather than L1: the block's two buffers (up to 38 KB) already fill L1, and lines
/// prefetched there were evicted before use (single thread, 151 × 300 000 stack: 40 ms with
/// `prefetcht0`, 34.5 ms with `prefetcht2`, 36.5 ms with `prefetcht1`, 85 ms with none).
#[inline(always)]
fn prefetch_run(row: &[f32], c0: usize, n: usize) {
    #[cfg(target_arch = "x86_64")]
    for x in row[c0..c0 + n].iter().step_by(16) {
        safe_arch::prefetch_t2(x);
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (row, c0, n);
}

/// Dispatches a pass over the planned radices.
macro_rules! by_radix {
    ($r:expr, $f:ident::<$m:ty>($($a:expr),*)) => {
        match $r {
            3 => $f::<3, $m>($($a),*),
            5 => $f::<5, $m>($($a),*),
            7 => $f::<7, $m>($($a),*),
            11 => $f::<11, $m>($($a),*),
            13 => $f::<13, $m>($($a),*),
            r => unreachable!("radix {r} is not planned"),
        }
    };
}

/// One direction's fused middle: per pair `j >= 1`, `[P, Q, R, S]` (re, im each) with
/// `out₂ⱼ = P a_j + Q a_{j+h}`, `out₂ⱼ₊₁ = R a_j + S a_{j+h}`; and the row-0 terms at `j = 0`.
struct Middle {
    coef: Vec<[[f32; 4]; 2]>,
    /// `lo_0 = A₀ X + B₀ Y + t0 m₀ + s`, `hi_0 = A'₀ Y + B'₀ X + th m₀` (`X = a₀ + a_h`,
    /// `Y = a₀ − a_h`), `y_row0 = z0 X + zh Y + zm m₀ + s`, `s = g0 (X + m₀)`.
    a0: Complex<f32>,
    b0: Complex<f32>,
    ah: Complex<f32>,
    bh: Complex<f32>,
    t0: Complex<f32>,
    th: Complex<f32>,
    z0: Complex<f32>,
    zh: Complex<f32>,
    zm: Complex<f32>,
    g0: f32,
}

fn c32(z: Complex<f64>) -> Complex<f32> {
    Complex::new(z.re as f32, z.im as f32)
}

impl Middle {
    fn new(sp: &Spec<f64>, q: usize) -> Middle {
        let h = q / 2;
        let mut coef = Vec::with_capacity(h);
        for j in 0..h {
            let (a, b, a2, b2) = (sp.a[j], sp.b[j], sp.a[j + h], sp.b[j + h]);
            // The forward radix-2 pass at ns = h: X = a_j + w a_{j+h}, Y = a_j − w a_{j+h}.
            let w = Complex::from_polar(1.0, -2.0 * std::f64::consts::PI * j as f64 / q as f64);
            // lo = A X + B Y, hi = A' Y + B' X; out = lo ± hi.
            let (xe, ye) = (a + b2, b + a2);
            let (xo, yo) = (a - b2, b - a2);
            // The inverse's radix-2 pass transposed: out_j = lo + hi, out_{j+h} = (lo − hi) w̄.
            let wb = w.conj();
            let f = |p: Complex<f64>, q: Complex<f64>| [p.re as f32, p.im as f32, q.re as f32, q.im as f32];
            coef.push([f(xe + ye, (xe - ye) * w), f((xo + yo) * wb, (xo - yo) * w * wb)]);
        }
        Middle {
            coef,
            a0: c32(sp.a[0]),
            b0: c32(sp.b[0]),
            ah: c32(sp.a[h]),
            bh: c32(sp.b[h]),
            t0: c32(sp.t0),
            th: c32(sp.th),
            z0: c32(sp.z0),
            zh: c32(sp.zh),
            zm: c32(sp.zm),
            g0: sp.g0 as f32,
        }
    }
}

/// The forward radix-2 pass, the spectrum multiply and the inverse radix-2 pass, fused;
/// returns row 0's output.
#[inline(always)]
fn middle<M: Lanes>(o: Ops<M>, md: &Middle, q: usize, src: &[E<M>], dst: &mut [E<M>], m0: C<M::L>) -> C<M::L> {
    let m = o.0;
    let h = q / 2;
    let (lo_in, hi_in) = src[..q].split_at(h);
    let dst = &mut dst[..q];
    let (a, b) = (unpack(lo_in[0]), unpack(hi_in[0]));
    let (x, y) = (o.add(a, b), o.sub(a, b));
    let xm = o.add(x, m0);
    let s = C { re: m.mul(xm.re, m.splat(md.g0)), im: m.mul(xm.im, m.splat(md.g0)) };
    let t0m = o.cscale(m0, md.t0);
    let lo = o.add(o.add(o.add(o.cscale(x, md.a0), o.cscale(y, md.b0)), t0m), s);
    let hi = o.add(o.add(o.cscale(y, md.ah), o.cscale(x, md.bh)), o.cscale(m0, md.th));
    dst[0] = pack(o.add(lo, hi));
    dst[h] = pack(o.sub(lo, hi));
    let y0 = o.add(o.add(o.add(o.cscale(x, md.z0), o.cscale(y, md.zh)), o.cscale(m0, md.zm)), s);
    let coef = &md.coef[..h];
    for j in 1..h {
        let (a, b) = (unpack(lo_in[j]), unpack(hi_in[j]));
        let c = &coef[j];
        dst[j] = pack(o.cmul2(a, b, &c[0]));
        dst[j + h] = pack(o.cmul2(a, b, &c[1]));
    }
    y0
}

/// Blocks ahead that the first pass prefetches: a block reads one run from each of the `p`
/// rows, more streams than the hardware prefetcher follows. 2 to 4 measured alike; 1 and 6
/// slower.
const PREFETCH_BLOCKS: usize = 4;

/// The Rader-domain demultiplex (see `crate::rader` for the algebra), fused passes of length
/// `q = p − 1`.
pub(crate) struct VecRader {
    p: usize,
    q: usize,
    /// `perm[a] = g^a mod p`.
    perm: Vec<usize>,
    /// Forward odd-radix passes, then (after the middle) the inverse ones.
    fwd: Vec<Stage>,
    inv: Vec<Stage>,
    demux: Middle,
    mux: Middle,
    /// Use AVX-512 (blocks of 32 columns) where the CPU has it; else AVX2 (16 columns).
    wide: bool,
}

impl VecRader {
    /// `None` when `p − 1` is not twice a product of the odd radices 3 … 13 (at least one);
    /// `wide`: AVX-512 where the CPU has it.
    pub(crate) fn new(rader: Rader<f64>, wide: bool) -> Option<VecRader> {
        let q = rader.q;
        if q % 2 != 0 || q % 4 == 0 {
            return None;
        }
        let mut radices = Vec::new();
        let mut x = q / 2;
        for r in [3, 5, 7, 11, 13] {
            while x % r == 0 {
                radices.push(r);
                x /= r;
            }
        }
        if x != 1 || radices.is_empty() {
            return None;
        }
        // The largest radix first (its pass has no twiddles and reads the rows).
        radices.sort_unstable_by(|a, b| b.cmp(a));
        let mut ns = 1;
        let fwd = radices
            .iter()
            .map(|&r| {
                let st = Stage::new(r, ns, -1.0);
                ns *= r;
                st
            })
            .collect();
        // The inverse: the same plan with the opposite sign, run transposed in reverse order
        // (`pass_dif`), after the radix-2 pass the middle holds.
        let mut ns = 1;
        let inv = radices
            .iter()
            .map(|&r| {
                let st = Stage::new(r, ns, 1.0);
                ns *= r;
                st
            })
            .collect();
        let demux = Middle::new(&rader.demux, q);
        let mux = Middle::new(&rader.mux, q);
        Some(VecRader { p: rader.p, q, perm: rader.perm, fwd, inv, demux, mux, wide })
    }

    /// Scratch vectors per thread ([`pulp::f32x16`] units): two buffers of `q` elements of up to
    /// 16 complex lanes.
    pub(crate) fn scratch_len(&self) -> usize {
        4 * self.q
    }

    /// Applies the circulant to every column of the tile `rows` (`p` runs), in place, in
    /// blocks of `2W` columns; `vb` holds [`VecRader::scratch_len`] vectors.
    pub(crate) fn tile(&self, rows: &mut [&mut [f32]], vb: &mut [pulp::f32x16], dir: Dir) {
        #[cfg(target_arch = "x86_64")]
        if self.wide {
            if let Some(v4) = pulp::x86::V4::try_new() {
                // The body compiled for AVX-512 (checked at run time above).
                return pulp::Simd::vectorize(v4, TileOp { m: v4, k: self, rows, vb, dir });
            }
        }
        #[cfg(target_arch = "x86_64")]
        if let Some(v3) = pulp::x86::V3::try_new() {
            // The body compiled for AVX2 + FMA (checked at run time above).
            return pulp::Simd::vectorize(v3, TileOp { m: v3, k: self, rows, vb, dir });
        }
        TileOp { m: Portable, k: self, rows, vb, dir }.body();
    }

    /// AVX-512 allowed.
    pub(crate) fn wide(&self) -> bool {
        self.wide
    }

    /// The instruction set [`VecRader::tile`] runs on this CPU.
    pub(crate) fn isa(&self) -> &'static str {
        #[cfg(target_arch = "x86_64")]
        {
            if self.wide && pulp::x86::V4::try_new().is_some() {
                return "avx512";
            }
            if pulp::x86::V3::try_new().is_some() {
                return "avx2";
            }
        }
        "portable"
    }

    /// The same through the portable lanes (tests).
    #[cfg(test)]
    fn tile_portable(&self, rows: &mut [&mut [f32]], vb: &mut [pulp::f32x16], dir: Dir) {
        TileOp { m: Portable, k: self, rows, vb, dir }.body();
    }
}

struct TileOp<'a, 'b, M> {
    m: M,
    k: &'a VecRader,
    rows: &'a mut [&'b mut [f32]],
    vb: &'a mut [pulp::f32x16],
    dir: Dir,
}

impl<M: Lanes> TileOp<'_, '_, M> {
    #[inline(always)]
    fn body(self) {
        let TileOp { m, k, rows, vb, dir } = self;
        let md = if dir == Dir::Demux { &k.demux } else { &k.mux };
        let vb: &mut [E<M>] = pulp::bytemuck::cast_slice_mut(vb);
        tile_impl(Ops(m), k, md, rows, vb);
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

/// The whole map of one block of `2W` columns at `c0`: `row0` is row 0, `rows` the others in
/// Rader order.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn block<M: Lanes>(
    o: Ops<M>,
    k: &VecRader,
    md: &Middle,
    row0: &mut [f32],
    rows: &mut [&mut [f32]],
    c0: usize,
    pf: Option<(usize, usize)>,
    a: &mut [E<M>],
    b: &mut [E<M>],
) {
    let m0 = o.load_row(row0, c0);
    if let Some((cp, n)) = pf {
        prefetch_run(row0, cp, n);
    }
    let (f, i) = (&k.fwd, &k.inv);
    // The domes' orders with every radix and stride a constant (see the passes' note); any
    // other 13-smooth q through the stages' values.
    let y0 = match k.q {
        150 => {
            let q = 150;
            first_pass::<5, M>(o, &f[0], q, rows, c0, pf, a);
            pass::<5, M>(o, &f[1], q, 5, a, b);
            pass::<3, M>(o, &f[2], q, 25, b, a);
            let y0 = middle(o, md, q, a, b, m0);
            pass_dif::<3, M>(o, &i[2], q, 25, b, a);
            pass_dif::<5, M>(o, &i[1], q, 5, a, b);
            last_pass::<5, M>(o, &i[0], q, b, rows, c0);
            y0
        }
        198 => {
            let q = 198;
            first_pass::<11, M>(o, &f[0], q, rows, c0, pf, a);
            pass::<3, M>(o, &f[1], q, 11, a, b);
            pass::<3, M>(o, &f[2], q, 33, b, a);
            let y0 = middle(o, md, q, a, b, m0);
            pass_dif::<3, M>(o, &i[2], q, 33, b, a);
            pass_dif::<3, M>(o, &i[1], q, 11, a, b);
            last_pass::<11, M>(o, &i[0], q, b, rows, c0);
            y0
        }
        q => {
            let st = &f[0];
            by_radix!(st.radix, first_pass::<M>(o, st, q, rows, c0, pf, a));
            // `a` holds the data; ping-pong to the end of the forward passes.
            let (mut src, mut dst) = (a, b);
            for st in &f[1..] {
                by_radix!(st.radix, pass::<M>(o, st, q, st.ns, src, dst));
                std::mem::swap(&mut src, &mut dst);
            }
            let y0 = middle(o, md, q, src, dst, m0);
            std::mem::swap(&mut src, &mut dst);
            for st in i[1..].iter().rev() {
                by_radix!(st.radix, pass_dif::<M>(o, st, q, st.ns, src, dst));
                std::mem::swap(&mut src, &mut dst);
            }
            let st = &i[0];
            by_radix!(st.radix, last_pass::<M>(o, st, q, src, rows, c0));
            y0
        }
    };
    o.store_row(row0, c0, y0);
}

/// Blocks of `2W` columns; a short last block through a zero-padded copy.
#[inline(always)]
fn tile_impl<M: Lanes>(o: Ops<M>, k: &VecRader, md: &Middle, rows: &mut [&mut [f32]], vb: &mut [E<M>]) {
    let (p, q) = (k.p, k.q);
    debug_assert_eq!(rows.len(), p);
    let bw = 2 * M::W;
    let t = rows[0].len();
    let (a, rest) = vb[..2 * q].split_at_mut(q);
    let b = &mut rest[..q];
    let full = t / bw * bw;
    if full > 0 {
        // The rows in Rader order once per tile (the permutation is a bijection on 1..p).
        let mut slots: Vec<Option<&mut [f32]>> = rows.iter_mut().map(|r| Some(&mut **r)).collect();
        let row0 = slots[0].take().expect("row 0");
        let mut rrows: Vec<&mut [f32]> = k.perm.iter().map(|&r| slots[r].take().expect("a permutation")).collect();
        let mut c0 = 0;
        while c0 < full {
            let cp = c0 + PREFETCH_BLOCKS * bw;
            let pf = (cp + bw <= t).then_some((cp, bw));
            block(o, k, md, row0, &mut rrows, c0, pf, a, b);
            c0 += bw;
        }
    }
    if full < t {
        let w = t - full;
        let mut pad = vec![0.0f32; p * bw];
        for (dst, row) in pad.chunks_exact_mut(bw).zip(rows.iter()) {
            dst[..w].copy_from_slice(&row[full..]);
        }
        {
            let mut slots: Vec<Option<&mut [f32]>> = pad.chunks_exact_mut(bw).map(Some).collect();
            let row0 = slots[0].take().expect("row 0");
            let mut rrows: Vec<&mut [f32]> = k.perm.iter().map(|&r| slots[r].take().expect("a permutation")).collect();
            block(o, k, md, row0, &mut rrows, 0, None, a, b);
        }
        for (src, row) in pad.chunks_exact(bw).zip(rows.iter_mut()) {
            row[full..].copy_from_slice(&src[..w]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::smatrix::SMatrix;

    /// Every lane implementation this CPU has (portable, AVX2, AVX-512) against the dense f64
    /// closed form, both directions, for every
    /// Paley prime below 400 whose `p − 1` the passes take (one to three odd radices, every
    /// radix), over a tile with a short last block.
    #[test]
    fn fused_map_matches_the_dense_closed_form() {
        let mut tested = Vec::new();
        let mut worst = 0.0f64;
        for p in (7..400).filter(|&p| p % 4 == 3 && crate::smatrix::is_prime(p)) {
            let s = SMatrix::paley(p).unwrap();
            let row = s.first_row().unwrap();
            let Some(r) = crate::demux::rader_f64(row) else { continue };
            let Some(vr) = VecRader::new(r, true) else { continue };
            let narrow = VecRader::new(crate::demux::rader_f64(row).unwrap(), false).unwrap();
            tested.push(p);
            let t = 2 * 16 * 2 + 7;
            let data: Vec<f32> = (0..p * t).map(|i| ((i * 2_654_435_761usize) % 1000) as f32 / 1000.0).collect();
            for dir in [Dir::Demux, Dir::Mux] {
                let mut want = vec![0.0f64; p * t];
                for c in 0..t {
                    let v: Vec<f64> = (0..p).map(|r| f64::from(data[r * t + c])).collect();
                    let y = if dir == Dir::Demux { s.solve(&v) } else { s.apply(&v) };
                    for r in 0..p {
                        want[r * t + c] = y[r];
                    }
                }
                let scale = want.iter().fold(0.0f64, |m, v| m.max(v.abs()));
                let mut runs: Vec<(&str, Vec<f32>)> = Vec::new();
                let mut vb = vec![<pulp::f32x16 as pulp::bytemuck::Zeroable>::zeroed(); vr.scratch_len()];
                let mut got = data.clone();
                {
                    let mut rows: Vec<&mut [f32]> = got.chunks_exact_mut(t).collect();
                    vr.tile_portable(&mut rows, &mut vb, dir);
                }
                runs.push(("portable", got));
                let mut got = data.clone();
                {
                    let mut rows: Vec<&mut [f32]> = got.chunks_exact_mut(t).collect();
                    vr.tile(&mut rows, &mut vb, dir);
                }
                runs.push((vr.isa(), got));
                let mut got = data.clone();
                {
                    let mut rows: Vec<&mut [f32]> = got.chunks_exact_mut(t).collect();
                    narrow.tile(&mut rows, &mut vb, dir);
                }
                runs.push((narrow.isa(), got));
                for (name, got) in runs {
                    let err = got.iter().zip(&want).map(|(g, w)| (f64::from(*g) - w).abs()).fold(0.0, f64::max) / scale;
                    assert!(err < 2e-7 * (p as f64).log2(), "p {p} {name} dir {}: rel err {err:e}", dir == Dir::Demux);
                    worst = worst.max(err / (p as f64).log2());
                }
            }
        }
        eprintln!("largest rel. error / log2 p: {worst:.2e}");
        // Radices 3, 5, 7, 11, 13, alone and combined.
        for p in [7, 11, 23, 31, 43, 67, 79, 131, 151, 199, 211, 251] {
            assert!(tested.contains(&p), "p {p} not taken: {tested:?}");
        }
    }
}

#[cfg(test)]
mod probe {
    use super::*;
    use crate::smatrix::SMatrix;

    /// Timing probe (not a test): one tile of `cols` columns, in cache, many times:
    /// `cargo test --release -p btfrig-mux --lib vfft::probe -- --ignored --nocapture`.
    #[test]
    #[ignore]
    fn time_tile_in_cache() {
        let cols: usize = std::env::var("COLS").ok().and_then(|s| s.parse().ok()).unwrap_or(16);
        for p in [151usize, 199] {
            let s = SMatrix::paley(p).unwrap();
            let vr = VecRader::new(crate::demux::rader_f64(s.first_row().unwrap()).unwrap(), true).unwrap();
            let mut data: Vec<f32> = (0..p * cols).map(|i| ((i * 2_654_435_761usize) % 1000) as f32 / 1000.0).collect();
            let mut vb = vec![<pulp::f32x16 as pulp::bytemuck::Zeroable>::zeroed(); vr.scratch_len()];
            let reps = 100_000 / cols;
            let mut best = f64::INFINITY;
            for _ in 0..41 {
                let t = std::time::Instant::now();
                for r in 0..reps {
                    let mut rows: Vec<&mut [f32]> = data.chunks_exact_mut(cols).collect();
                    vr.tile(&mut rows, &mut vb, if r % 2 == 0 { Dir::Demux } else { Dir::Mux });
                }
                best = best.min(t.elapsed().as_secs_f64());
            }
            let per_col = best / (reps * cols) as f64;
            println!("p {p}: {:.1} ns per column, {:.0} cycles per 16-column block at 3.6 GHz", per_col * 1e9, per_col * 16.0 * 3.6e9);
        }
    }
}

#[cfg(test)]
mod pass_probe {
    use super::*;
    use crate::smatrix::SMatrix;

    struct Op<'a, M: Lanes> {
        m: M,
        k: &'a VecRader,
        which: usize,
        rows: &'a mut [&'a mut [f32]],
        a: &'a mut [E<M>],
        b: &'a mut [E<M>],
        reps: usize,
    }
    impl<M: Lanes> pulp::WithSimd for Op<'_, M> {
        type Output = ();
        #[inline(always)]
        fn with_simd<S: pulp::Simd>(self, _s: S) {
            let Op { m, k, which, rows, a, b, reps } = self;
            let o = Ops(m);
            let (f, i) = (&k.fwd, &k.inv);
            let m0 = o.zeros::<1>()[0];
            for _ in 0..reps {
                match (k.q, which) {
                    (150, 0) => first_pass::<5, _>(o, &f[0], 150, rows, 0, None, a),
                    (150, 1) => pass::<5, _>(o, &f[1], 150, 5, a, b),
                    (150, 2) => pass::<3, _>(o, &f[2], 150, 25, b, a),
                    (150, 3) => {
                        std::hint::black_box(middle(o, &k.demux, 150, a, b, m0));
                    }
                    (150, 4) => pass_dif::<3, _>(o, &i[2], 150, 25, b, a),
                    (150, 5) => pass_dif::<5, _>(o, &i[1], 150, 5, a, b),
                    (150, 6) => last_pass::<5, _>(o, &i[0], 150, b, rows, 0),
                    (198, 0) => first_pass::<11, _>(o, &f[0], 198, rows, 0, None, a),
                    (198, 1) => pass::<3, _>(o, &f[1], 198, 11, a, b),
                    (198, 2) => pass::<3, _>(o, &f[2], 198, 33, b, a),
                    (198, 3) => {
                        std::hint::black_box(middle(o, &k.demux, 198, a, b, m0));
                    }
                    (198, 4) => pass_dif::<3, _>(o, &i[2], 198, 33, b, a),
                    (198, 5) => pass_dif::<3, _>(o, &i[1], 198, 11, a, b),
                    (198, 6) => last_pass::<11, _>(o, &i[0], 198, b, rows, 0),
                    _ => unreachable!(),
                }
                std::hint::black_box(&mut *a);
            }
        }
    }

    fn time<M: Lanes>(m: M, name: &str) {
        for p in [151usize, 199] {
            let s = SMatrix::paley(p).unwrap();
            let k = VecRader::new(crate::demux::rader_f64(s.first_row().unwrap()).unwrap(), true).unwrap();
            let q = k.q;
            let mut line = format!("{name} p {p}:");
            let mut total = 0.0;
            for which in 0..7 {
                let mut data: Vec<f32> = (0..q * 2 * M::W).map(|i| (i % 7) as f32 * 1e-3).collect();
                let zero = <M::L as pulp::bytemuck::Zeroable>::zeroed();
                let mut a = vec![[zero; 2]; q];
                let mut b = vec![[zero; 2]; q];
                let reps = 20_000;
                let mut best = f64::INFINITY;
                // Min of many short wall-clock runs: robust to the VM's other load, which also
                // takes a thread's on-CPU time (and that is counted in 4 ms ticks here).
                for _ in 0..41 {
                    let mut rows: Vec<&mut [f32]> = data.chunks_exact_mut(2 * M::W).collect();
                    let t = std::time::Instant::now();
                    let v4 = pulp::x86::V4::try_new().unwrap();
                    pulp::Simd::vectorize(v4, Op { m, k: &k, which, rows: &mut rows, a: &mut a, b: &mut b, reps });
                    best = best.min(t.elapsed().as_secs_f64());
                }
                // Cycles per 16 columns.
                let cyc = best / reps as f64 * 3.6e9 * 8.0 / M::W as f64;
                total += cyc;
                line += &format!(" {which}:{cyc:.0}");
            }
            println!("{line}  total {total:.0} cycles per 16 columns");
        }
    }

    /// Per-pass timing (not a test): `cargo test --release -p btfrig-mux --lib vfft::pass_probe -- --ignored --nocapture`.
    #[test]
    #[ignore]
    fn time_passes() {
        time(pulp::x86::V3::try_new().unwrap(), "v3");
        if let Some(v4) = pulp::x86::V4::try_new() {
            time(v4, "v4");
        }
    }
}
