//! The Rader-domain demultiplex of the Paley orders on a pixel-vectorised FFT, with the
//! gather, the spectrum multiply and the scatter fused into the transform's stages.
//!
//! rustfft transforms one column at a time, so the pattern-major tile would have to be
//! transposed into its buffer and back. Here every element of the transform is a pair of
//! vectors of `W` columns in split-complex form (`W` columns of the tile as the real part,
//! the next `W` as the imaginary part, which the map keeps apart because it sends real
//! columns to real columns), so a butterfly is element-wise arithmetic on whole vectors and
//! nothing is transposed. One block of `2W` columns (`q` elements in one buffer, `q · 8W`
//! bytes: 19 KB at `q = 150`, `W = 16`) stays in L1 through every stage.
//!
//! The map of one block (see `crate::rader` for the algebra) is a forward FFT of length
//! `q = p − 1`, the two-valued spectrum multiply `T̂_f = A_f Û_f + B_f Û_{f+q/2}`, and an
//! inverse FFT. `q = 2m` with `m` odd (`p ≡ 3 mod 4`), and the FFT is a Good–Thomas
//! prime-factor transform: `m`'s prime powers (150 = 2 · 3 · 25, 198 = 2 · 9 · 11) are axes of
//! a multidimensional layout with the halves of `q` outermost, and a DFT of length `q` is
//! one DFT along each axis with no twiddles between axes (the input index map is Ruritanian,
//! the output map the Chinese remainder one). Inside a prime power `r^e` the stages are
//! in-place radix-`r` decimation in frequency (twiddles after the butterfly, digit-reversed
//! output); the inverse runs the same stages transposed in reverse order with conjugate
//! factors (`F = Fᵀ`), so it reads the forward's output layout and ends in the input layout.
//! Every stage works in place on the one buffer. Little but arithmetic is left between the
//! stack and the result:
//!
//! * the forward transform's first stage reads its inputs straight from the tile's rows (the
//!   position → row map combines the Rader order and the PFA input map): the gather is that
//!   stage's loads; the inverse's last stage writes the rows: the scatter is its stores;
//! * the innermost axis's lowest digit (radix 3 at both orders, stride 1, no twiddles), the
//!   radix-2 stage over the halves (which pairs exactly the frequencies `f`, `f + q/2` the
//!   spectrum multiply pairs) and their inverses are one step on `2r` elements in registers,
//!   the multiply in between a precomputed 2 × 2 complex matrix per pair; the rank-one terms
//!   of row 0 (`crate::rader`) enter at frequency 0, the common term `s` as a constant added
//!   to bin 0 of the inverse's input.
//!
//! So a block costs two sweeps over the buffer per stage outside the fused step: four at
//! q = 150 and 198 (measured in `docs/benchmarks.md`). Odd radices use the symmetric form
//! `y_k = x_0 + Σ_j cos(2πjk/r) (x_j + x_{r−j}) ± i sin(2πjk/r) (x_j − x_{r−j})`.
//!
//! The workspace forbids unsafe code; the tile function runs through
//! [`pulp::Simd::vectorize`] inside a function compiled for AVX-512 ([`pulp::x86::V4`], 16
//! lanes, 32 registers: radix 11 without spills) or AVX2 + FMA ([`pulp::x86::V3`], 8 lanes),
//! whichever the CPU has (checked at run time), and its arithmetic is pulp's explicit vector
//! operations ([`Lanes`]); no `target-cpu` flags. Elsewhere the portable [`Portable`] lanes
//! run the same code.

use rustfft::num_complex::Complex;

use crate::kernel::Dir;
use crate::lanes::{prefetch_run, tick, Lanes, Portable, Prefetch};
use crate::rader::{Rader, Spec};

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

/// One pass of an odd radix along one digit of one PFA axis, in place (see the module docs):
/// butterflies over `radix` elements `stride` apart, at every other digit value.
#[derive(Debug, Clone)]
struct Stage {
    radix: usize,
    /// Distance between a butterfly's elements: `axis_stride · lows`.
    stride: usize,
    /// The axis's lowest digit's stride.
    axis_stride: usize,
    /// Values of the axis's digits below this one (`r^d`); the twiddle of a butterfly
    /// depends on them. 1: no twiddles.
    lows: usize,
    /// Forward: `tw[2(low·radix + t)], …+1` = re, im of `e^{−2πi·low·t/(lows·radix)}`, applied
    /// after the butterfly; the inverse applies the conjugates before its butterfly.
    tw: Vec<f32>,
    tw_inv: Vec<f32>,
    /// `cos[(j−1)·h + k−1] = cos(2πjk/r)`, `sin[…] = −sin(2πjk/r)` (forward), `sin_inv = −sin`.
    cos: Vec<f32>,
    sin: Vec<f32>,
    sin_inv: Vec<f32>,
}

impl Stage {
    fn new(radix: usize, axis_stride: usize, lows: usize) -> Stage {
        let tau = 2.0 * std::f64::consts::PI;
        let (mut tw, mut tw_inv) = (Vec::new(), Vec::new());
        if lows > 1 {
            for low in 0..lows {
                for t in 0..radix {
                    let a = -tau * (low * t) as f64 / (lows * radix) as f64;
                    tw.extend([a.cos() as f32, a.sin() as f32]);
                    tw_inv.extend([a.cos() as f32, -a.sin() as f32]);
                }
            }
        }
        let h = radix / 2;
        let (mut cos, mut sin) = (Vec::new(), Vec::new());
        for j in 1..=h {
            for k in 1..=h {
                let a = tau * (j * k) as f64 / radix as f64;
                cos.push(a.cos() as f32);
                sin.push(-a.sin() as f32);
            }
        }
        let sin_inv = sin.iter().map(|v| -v).collect();
        Stage { radix, stride: axis_stride * lows, axis_stride, lows, tw, tw_inv, cos, sin, sin_inv }
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

/// Output `t` into `y[t]` (registers: used at R = 3, whose one output pair unrolls).
struct ArraySink<'a, L, const R: usize> {
    y: &'a mut [C<L>; R],
}

impl<M: Lanes, const R: usize> Sink<M> for ArraySink<'_, M::L, R> {
    #[inline(always)]
    fn put(&mut self, _o: Ops<M>, t: usize, v: C<M::L>) {
        self.y[t] = v;
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
fn dft_odd<const R: usize, M: Lanes, S: Sink<M>>(
    o: Ops<M>,
    cos: &[f32],
    sin: &[f32],
    x: &mut [C<M::L>; R],
    out: &mut S,
) {
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

/// Multiplies `x[t]` (`t >= 1`) by the twiddles `tw[2t], tw[2t + 1]` of one butterfly.
#[inline(always)]
fn twiddle<const R: usize, M: Lanes>(o: Ops<M>, tw: &[f32], x: &mut [C<M::L>; R]) {
    let tw = &tw[..2 * R];
    for t in 1..R {
        x[t] = o.cmul(x[t], tw[2 * t], tw[2 * t + 1]);
    }
}

// The stages take `q` and the stage's shape (`stride`, `axis_stride`, `lows`) as arguments and
// are `inline(always)`: called with constants (the plans of `block` for q = 150 and 198) every
// loop bound and index is known, the loops unroll and the bounds checks fold away; called
// with a stage's values they are the general code. Butterfly `(hi, low, inner)` works on the
// positions `hi·stride·R + low·axis_stride + inner + t·stride`.

/// The first stage's input: the rows by position and the block's first column.
type RowsIn<'a, 'b> = (&'a [&'b mut [f32]], usize);

/// A forward stage in place (butterfly, then twiddles); `rows` (positions' rows, this block's
/// columns at `c0`) instead of `buf` as input for the first stage.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn stage_fwd<const R: usize, M: Lanes>(
    o: Ops<M>,
    st: &Stage,
    q: usize,
    (axis_stride, lows): (usize, usize),
    rows: Option<RowsIn<'_, '_>>,
    buf: &mut [E<M>],
    pf: &mut Option<Prefetch<'_, '_>>,
) {
    debug_assert_eq!((st.radix, st.axis_stride, st.lows), (R, axis_stride, lows));
    let buf = &mut buf[..q];
    let stride = axis_stride * lows;
    let tw = &st.tw[..if lows > 1 { 2 * lows * R } else { 0 }];
    for hi in 0..q / (stride * R) {
        for low in 0..lows {
            let tw = if low > 0 { &tw[2 * low * R..2 * (low + 1) * R] } else { &[] };
            for inner in 0..axis_stride {
                let base = hi * stride * R + low * axis_stride + inner;
                let mut x = o.zeros::<R>();
                match rows {
                    Some((rows, c0)) => {
                        let rows = &rows[..q];
                        for t in 0..R {
                            x[t] = o.load_row(&*rows[base + t * stride], c0);
                        }
                    }
                    None => {
                        for t in 0..R {
                            x[t] = unpack(buf[base + t * stride]);
                        }
                    }
                }
                let mut out = TwiddledSink { dst: &mut *buf, base, step: stride, tw };
                dft_odd::<R, M, _>(o, &st.cos, &st.sin, &mut x, &mut out);
                tick(pf);
            }
        }
    }
}

/// An inverse stage in place, the transpose of [`stage_fwd`] with conjugate factors
/// (conjugate twiddles, then the butterfly); to `rows` instead of `buf` for the last stage.
#[inline(always)]
fn stage_inv<const R: usize, M: Lanes>(
    o: Ops<M>,
    st: &Stage,
    q: usize,
    (axis_stride, lows): (usize, usize),
    rows: Option<(&mut [&mut [f32]], usize)>,
    buf: &mut [E<M>],
    pf: &mut Option<Prefetch<'_, '_>>,
) {
    debug_assert_eq!((st.radix, st.axis_stride, st.lows), (R, axis_stride, lows));
    let buf = &mut buf[..q];
    let stride = axis_stride * lows;
    let tw = &st.tw_inv[..if lows > 1 { 2 * lows * R } else { 0 }];
    let mut rows = rows;
    for hi in 0..q / (stride * R) {
        for low in 0..lows {
            for inner in 0..axis_stride {
                let base = hi * stride * R + low * axis_stride + inner;
                let mut x = o.zeros::<R>();
                for t in 0..R {
                    x[t] = unpack(buf[base + t * stride]);
                }
                if low > 0 {
                    twiddle::<R, M>(o, &tw[2 * low * R..], &mut x);
                }
                match rows {
                    Some((ref mut rows, c0)) => {
                        let mut out = RowSink { rows: &mut rows[..q], base, step: stride, c0 };
                        dft_odd::<R, M, _>(o, &st.cos, &st.sin_inv, &mut x, &mut out);
                    }
                    None => {
                        let mut out = BufSink { dst: &mut *buf, base, step: stride };
                        dft_odd::<R, M, _>(o, &st.cos, &st.sin_inv, &mut x, &mut out);
                        tick(pf);
                    }
                }
            }
        }
    }
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

/// One direction's fused middle per pair of positions `(p, p + q/2)` (`p` in the lower half,
/// frequencies `f` and `f + q/2`): `[P, Q]`, `[R, S]` (re, im each) with
/// `out_p = P a + Q b`, `out_{p+q/2} = R a + S b` (`a`, `b` the pair's forward values before
/// the radix-2 butterfly); and the row-0 terms at frequency 0 (position 0).
struct Middle {
    coef: Vec<[[f32; 4]; 2]>,
    /// `lo = A₀ X + B₀ Y + t0 m₀ + s`, `hi = A_h Y + B_h X + th m₀` (`X = a + b`,
    /// `Y = a − b`), `y_row0 = z0 X + zh Y + zm m₀ + s`, `s = g0 (X + m₀)`.
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
    /// `freq[p]`: the frequency at lower-half position `p` after the forward stages.
    fn new(sp: &Spec<f64>, q: usize, freq: &[usize]) -> Middle {
        let h = q / 2;
        let coef = freq
            .iter()
            .map(|&f| {
                let g = (f + h) % q;
                // U_f = a + b, U_g = a − b; T_f = A_f U_f + B_f U_g, T_g = A_g U_g + B_g U_f;
                // out_p = T_f + T_g, out_{p+h} = T_f − T_g.
                let (xe, ye) = (sp.a[f] + sp.b[g], sp.b[f] + sp.a[g]);
                let (xo, yo) = (sp.a[f] - sp.b[g], sp.b[f] - sp.a[g]);
                let c = |p: Complex<f64>, q: Complex<f64>| [p.re as f32, p.im as f32, q.re as f32, q.im as f32];
                [c(xe + ye, xe - ye), c(xo + yo, xo - yo)]
            })
            .collect();
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

/// The last forward stage (radix `R`, the lowest digit of the innermost axis: stride 1, no
/// twiddles), the radix-2 stage over the halves, the spectrum multiply, and their inverses,
/// fused: one group of `2R` elements in registers at a time. Returns row 0's output.
#[inline(always)]
fn fused_middle<const R: usize, M: Lanes>(
    o: Ops<M>,
    st: &Stage,
    md: &Middle,
    q: usize,
    buf: &mut [E<M>],
    m0: C<M::L>,
    pf: &mut Option<Prefetch<'_, '_>>,
) -> C<M::L> {
    debug_assert_eq!((st.radix, st.stride), (R, 1));
    let m = o.0;
    let h = q / 2;
    let (lo_half, hi_half) = buf[..q].split_at_mut(h);
    let coef = &md.coef[..h];
    let mut y0 = m0;
    for g in 0..h / R {
        let base = g * R;
        let (mut a, mut b) = (o.zeros::<R>(), o.zeros::<R>());
        for t in 0..R {
            a[t] = unpack(lo_half[base + t]);
            b[t] = unpack(hi_half[base + t]);
        }
        let (mut fa, mut fb) = (o.zeros::<R>(), o.zeros::<R>());
        dft_odd::<R, M, _>(o, &st.cos, &st.sin, &mut a, &mut ArraySink { y: &mut fa });
        dft_odd::<R, M, _>(o, &st.cos, &st.sin, &mut b, &mut ArraySink { y: &mut fb });
        let (mut ta, mut tb) = (o.zeros::<R>(), o.zeros::<R>());
        for t in 0..R {
            let c = &coef[base + t];
            ta[t] = o.cmul2(fa[t], fb[t], &c[0]);
            tb[t] = o.cmul2(fa[t], fb[t], &c[1]);
        }
        if g == 0 {
            // Frequency 0 (position 0) and q/2: the rank-one terms of row 0 and the common term.
            let (x, y) = (o.add(fa[0], fb[0]), o.sub(fa[0], fb[0]));
            let xm = o.add(x, m0);
            let s = C { re: m.mul(xm.re, m.splat(md.g0)), im: m.mul(xm.im, m.splat(md.g0)) };
            let lo = o.add(o.add(o.add(o.cscale(x, md.a0), o.cscale(y, md.b0)), o.cscale(m0, md.t0)), s);
            let hi = o.add(o.add(o.cscale(y, md.ah), o.cscale(x, md.bh)), o.cscale(m0, md.th));
            ta[0] = o.add(lo, hi);
            tb[0] = o.sub(lo, hi);
            y0 = o.add(o.add(o.add(o.cscale(x, md.z0), o.cscale(y, md.zh)), o.cscale(m0, md.zm)), s);
        }
        let mut out = BufSink { dst: &mut *lo_half, base, step: 1 };
        dft_odd::<R, M, _>(o, &st.cos, &st.sin_inv, &mut ta, &mut out);
        let mut out = BufSink { dst: &mut *hi_half, base, step: 1 };
        dft_odd::<R, M, _>(o, &st.cos, &st.sin_inv, &mut tb, &mut out);
        tick(pf);
    }
    y0
}

/// Blocks ahead that the first stage prefetches: a block reads one run from each of the `p`
/// rows, more streams than the hardware prefetcher follows. 2 to 4 measured alike; 1 and 6
/// slower.
const PREFETCH_BLOCKS: usize = 4;

/// The Rader-domain demultiplex (see `crate::rader` for the algebra) on in-place PFA stages of
/// length `q = p − 1`.
pub(crate) struct VecRader {
    p: usize,
    q: usize,
    /// The row (of the tile's `p`) whose column values go to / come from each position.
    row_of: Vec<usize>,
    /// Forward stages before the fused one; the inverse runs them transposed in reverse order.
    stages: Vec<Stage>,
    /// The fused stage (stride 1, no twiddles).
    fused: Stage,
    /// Butterflies before the last stage: the prefetches' schedule (at least 1).
    ticks: usize,
    demux: Middle,
    mux: Middle,
    /// Use AVX-512 (blocks of 32 columns) where the CPU has it; else AVX2 (16 columns).
    wide: bool,
}

/// The PFA layout of `q = 2m` (`m` odd): prime-power axes of `m` (radix, exponent), largest
/// first, each one's digits from high to low, the halves of `q` outermost; `None` when `m`
/// has a prime factor the butterflies do not implement (above 13) or is 1.
fn plan_axes(q: usize) -> Option<Vec<(usize, u32)>> {
    if q % 2 != 0 || q % 4 == 0 || q < 6 {
        return None;
    }
    let mut x = q / 2;
    let mut axes = Vec::new();
    for r in [3usize, 5, 7, 11, 13] {
        let mut e = 0;
        while x % r == 0 {
            x /= r;
            e += 1;
        }
        if e > 0 {
            axes.push((r, e));
        }
    }
    if x != 1 {
        return None;
    }
    // The largest axis outermost; the smallest innermost, its lowest digit fused with the
    // middle (12 vectors at r = 3).
    axes.sort_by_key(|&(r, e)| std::cmp::Reverse(r.pow(e)));
    Some(axes)
}

impl VecRader {
    /// `None` when `p − 1` is not twice a product of the odd radices 3 … 13 (at least one);
    /// `wide`: AVX-512 where the CPU has it.
    pub(crate) fn new(rader: Rader<f64>, wide: bool) -> Option<VecRader> {
        let q = rader.q;
        let m = q / 2;
        let axes = plan_axes(q)?;
        // Axis strides: the innermost 1.
        let lens: Vec<usize> = axes.iter().map(|&(r, e)| r.pow(e)).collect();
        let mut strides = vec![1; axes.len()];
        for i in (0..axes.len().saturating_sub(1)).rev() {
            strides[i] = strides[i + 1] * lens[i + 1];
        }
        let mut stages = Vec::new();
        for (i, &(r, e)) in axes.iter().enumerate() {
            for d in (0..e).rev() {
                stages.push(Stage::new(r, strides[i], r.pow(d)));
            }
        }
        let fused = stages.pop()?;
        // Position p = half·m + Σ digits; time index (Ruritanian map) n = half·m +
        // Σ n_i·(q/N_i) mod q with n_i the axis's digits read naturally; frequency (CRT map)
        // the f ≡ k_i (mod N_i), f ≡ half (mod 2), k_i the axis's digits read reversed.
        let digits = |p: usize, i: usize| -> Vec<usize> {
            let (r, e) = axes[i];
            let v = (p / strides[i]) % lens[i];
            (0..e).map(|d| (v / r.pow(d)) % r).collect() // place d
        };
        let mut row_of = vec![0; q];
        for (p, row) in row_of.iter_mut().enumerate() {
            let (half, rest) = (p / m, p % m);
            let mut n = half * m;
            for (i, &(r, _)) in axes.iter().enumerate() {
                let ds = digits(rest, i);
                let ni: usize = ds.iter().enumerate().map(|(d, &v)| v * r.pow(d as u32)).sum();
                n += ni * (q / lens[i]);
            }
            *row = rader.perm[n % q];
        }
        let mut freq = vec![0; m];
        for (p, f) in freq.iter_mut().enumerate() {
            let ks: Vec<usize> = (0..axes.len())
                .map(|i| {
                    let (r, e) = axes[i];
                    let ds = digits(p, i);
                    (0..e as usize).map(|j| ds[e as usize - 1 - j] * r.pow(j as u32)).sum()
                })
                .collect();
            *f = (0..q).step_by(2).find(|f| ks.iter().zip(&lens).all(|(k, n)| f % n == *k))?;
        }
        let demux = Middle::new(&rader.demux, q, &freq);
        let mux = Middle::new(&rader.mux, q, &freq);
        let ticks = (stages.iter().map(|s| q / s.radix).sum::<usize>()
            + m / fused.radix
            + stages.iter().skip(1).map(|s| q / s.radix).sum::<usize>())
        .max(1);
        Some(VecRader { p: rader.p, q, row_of, stages, fused, demux, mux, wide, ticks })
    }

    /// Scratch vectors per thread ([`pulp::f32x16`] units): one buffer of `q` elements of up
    /// to 16 complex lanes.
    pub(crate) fn scratch_len(&self) -> usize {
        2 * self.q
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
        crate::lanes::isa(self.wide)
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

/// The whole map of one block of `2W` columns at `c0`: `row0` is row 0, `rows` the others by
/// position.
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
    buf: &mut [E<M>],
) {
    let m0 = o.load_row(row0, c0);
    if let Some((cp, n)) = pf {
        prefetch_run(row0, cp, n);
    }
    let (st, fu) = (&k.stages, &k.fused);
    let mut pfs = pf.map(|(col, len)| Prefetch::new(&*rows, col, len, k.ticks));
    let pfs = &mut pfs;
    // The domes' orders with every radix and stride a constant (see the stages' note); any
    // other order through the stages' values.
    let y0 = match k.q {
        150 => {
            let q = 150;
            // Axes 25 (stride 3: digits 15, 3) and 3 (stride 1, fused).
            stage_fwd::<5, M>(o, &st[0], q, (3, 5), Some((&*rows, c0)), buf, pfs);
            stage_fwd::<5, M>(o, &st[1], q, (3, 1), None, buf, pfs);
            let y0 = fused_middle::<3, M>(o, fu, md, q, buf, m0, pfs);
            stage_inv::<5, M>(o, &st[1], q, (3, 1), None, buf, pfs);
            stage_inv::<5, M>(o, &st[0], q, (3, 5), Some((rows, c0)), buf, &mut None);
            y0
        }
        198 => {
            let q = 198;
            // Axes 11 (stride 9) and 9 (stride 1: digits 3, 1 fused).
            stage_fwd::<11, M>(o, &st[0], q, (9, 1), Some((&*rows, c0)), buf, pfs);
            stage_fwd::<3, M>(o, &st[1], q, (1, 3), None, buf, pfs);
            let y0 = fused_middle::<3, M>(o, fu, md, q, buf, m0, pfs);
            stage_inv::<3, M>(o, &st[1], q, (1, 3), None, buf, pfs);
            stage_inv::<11, M>(o, &st[0], q, (9, 1), Some((rows, c0)), buf, &mut None);
            y0
        }
        q => {
            let shape = |s: &Stage| (s.axis_stride, s.lows);
            match st.first() {
                Some(s0) => {
                    by_radix!(s0.radix, stage_fwd::<M>(o, s0, q, shape(s0), Some((&*rows, c0)), &mut *buf, pfs))
                }
                None => {
                    // The fused stage is the only one: the rows straight into the buffer.
                    for (e, row) in buf[..q].iter_mut().zip(rows.iter()) {
                        *e = pack(o.load_row(row, c0));
                    }
                }
            }
            for s in st.iter().skip(1) {
                by_radix!(s.radix, stage_fwd::<M>(o, s, q, shape(s), None, &mut *buf, pfs));
            }
            let y0 = by_radix!(fu.radix, fused_middle::<M>(o, fu, md, q, &mut *buf, m0, pfs));
            for s in st.iter().skip(1).rev() {
                by_radix!(s.radix, stage_inv::<M>(o, s, q, shape(s), None, &mut *buf, pfs));
            }
            match st.first() {
                Some(s0) => {
                    by_radix!(
                        s0.radix,
                        stage_inv::<M>(o, s0, q, shape(s0), Some((&mut *rows, c0)), &mut *buf, &mut None)
                    )
                }
                None => {
                    for (e, row) in buf[..q].iter().zip(rows.iter_mut()) {
                        o.store_row(row, c0, unpack(*e));
                    }
                }
            }
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
    let buf = &mut vb[..q];
    let full = t / bw * bw;
    // The rows by position once per tile (`row_of` is a bijection onto 1..p).
    if full > 0 {
        let mut slots: Vec<Option<&mut [f32]>> = rows.iter_mut().map(|r| Some(&mut **r)).collect();
        let row0 = slots[0].take().expect("row 0");
        let mut prows: Vec<&mut [f32]> = k.row_of.iter().map(|&r| slots[r].take().expect("a permutation")).collect();
        let mut c0 = 0;
        while c0 < full {
            let cp = c0 + PREFETCH_BLOCKS * bw;
            let pf = (cp + bw <= t).then_some((cp, bw));
            block(o, k, md, row0, &mut prows, c0, pf, buf);
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
            let mut prows: Vec<&mut [f32]> =
                k.row_of.iter().map(|&r| slots[r].take().expect("a permutation")).collect();
            block(o, k, md, row0, &mut prows, 0, None, buf);
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
            println!(
                "p {p}: {:.1} ns per column, {:.0} cycles per 16-column block at 3.6 GHz",
                per_col * 1e9,
                per_col * 16.0 * 3.6e9
            );
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
        reps: usize,
    }
    impl<M: Lanes> pulp::WithSimd for Op<'_, M> {
        type Output = ();
        #[inline(always)]
        fn with_simd<S: pulp::Simd>(self, _s: S) {
            let Op { m, k, which, rows, a, reps } = self;
            let o = Ops(m);
            let (st, fu) = (&k.stages, &k.fused);
            let m0 = o.zeros::<1>()[0];
            for _ in 0..reps {
                match (k.q, which) {
                    (150, 0) => stage_fwd::<5, _>(o, &st[0], 150, (3, 5), Some((&*rows, 0)), a, &mut None),
                    (150, 1) => stage_fwd::<5, _>(o, &st[1], 150, (3, 1), None, a, &mut None),
                    (150, 2) => {
                        std::hint::black_box(fused_middle::<3, _>(o, fu, &k.demux, 150, a, m0, &mut None));
                    }
                    (150, 3) => stage_inv::<5, _>(o, &st[1], 150, (3, 1), None, a, &mut None),
                    (150, 4) => stage_inv::<5, _>(o, &st[0], 150, (3, 5), Some((&mut *rows, 0)), a, &mut None),
                    (198, 0) => stage_fwd::<11, _>(o, &st[0], 198, (9, 1), Some((&*rows, 0)), a, &mut None),
                    (198, 1) => stage_fwd::<3, _>(o, &st[1], 198, (1, 3), None, a, &mut None),
                    (198, 2) => {
                        std::hint::black_box(fused_middle::<3, _>(o, fu, &k.demux, 198, a, m0, &mut None));
                    }
                    (198, 3) => stage_inv::<3, _>(o, &st[1], 198, (1, 3), None, a, &mut None),
                    (198, 4) => stage_inv::<11, _>(o, &st[0], 198, (9, 1), Some((&mut *rows, 0)), a, &mut None),
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
            for which in 0..5 {
                let mut data: Vec<f32> = (0..q * 2 * M::W).map(|i| (i % 7) as f32 * 1e-3).collect();
                let zero = <M::L as pulp::bytemuck::Zeroable>::zeroed();
                let mut a = vec![[zero; 2]; q];
                let reps = 20_000;
                let mut best = f64::INFINITY;
                // Min of many short wall-clock runs: robust to the VM's other load, which also
                // takes a thread's on-CPU time (and that is counted in 4 ms ticks here).
                for _ in 0..41 {
                    let mut rows: Vec<&mut [f32]> = data.chunks_exact_mut(2 * M::W).collect();
                    let t = std::time::Instant::now();
                    let v4 = pulp::x86::V4::try_new().unwrap();
                    pulp::Simd::vectorize(v4, Op { m, k: &k, which, rows: &mut rows, a: &mut a, reps });
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
