//! The cyclic demultiplex of a prime order `p` by FFTs of length `q = p − 1` (Rader's
//! reindexing), for the Paley S-matrices.
//!
//! A circulant `C` of order `p` with spectrum `G` (`C m = F⁻¹(G · F m)`, `F` the length-`p`
//! DFT) is applied without a length-`p` transform (prime: slow) and without zero-padding to a
//! 5-smooth length `>= 2p − 1` (twice the work). With a primitive root `g` of `p`, reorder the
//! column as `u_a = m_{g^a}` (`a = 0..q`) and the spectrum as `k = g^{−b}`; then
//!
//! * `F m` at `k = g^{−b}` is `m_0 + V_b` with `V = u ⊛ h` (a length-`q` cyclic convolution,
//!   `h_d = w_{−d}`, `w_c = e^{−2πi g^c / p}`), and `(F m)_0 = Σm`;
//! * the inverse, at `i = g^e`, is `(G_0 Σm + (w̄ ⊛ Z)_e) / p` with `Z_b = γ_b (V_b + m_0)`,
//!   `γ_b = G_{g^{−b}}`, and at `i = 0` it is `(G_0 Σm + Σ_b Z_b) / p`.
//!
//! For a quadratic-residue code `G_k` takes one value on the residues and another on the
//! non-residues (a Gauss sum), and `g^{−b}` is a residue exactly when `b` is even, so
//! `γ_b = α + β (−1)^b`. Multiplying by `(−1)^b` shifts a length-`q` spectrum by `q/2`, so in
//! the length-`q` Fourier domain the whole operation is
//!
//! `T̂_l = A_l Û_l + B_l Û_{l + q/2}` (indices mod `q`; `A`, `B` precomputed)
//!
//! plus rank-one corrections for `m_0` and `Σm`: one forward and one inverse FFT of length `q`
//! per column instead of two of length `>= 2p − 1`. The map is complex-linear, so two real
//! columns ride in one complex FFT (real and imaginary part) as in the padded path. The
//! two-valued property is checked on construction (to 1e-9 of the spectrum's size); a
//! construction without it gets `None` and the caller falls back to the padded transform.

use std::sync::Arc;

use rustfft::num_complex::Complex;
use rustfft::{Fft, FftPlanner};

use crate::kernel::{Dir, Real};

/// Packed column pairs transformed per batch: `BATCH · q` complex values (19 KB for
/// `q = 150` in f32) stay in L1 between the gather, the two transforms and the scatter.
const BATCH: usize = 16;

/// One direction's precomputed multipliers (all divided by `p q` where they enter the
/// unnormalised inverse).
pub(crate) struct Spec<F> {
    /// `A_l`.
    pub(crate) a: Vec<Complex<F>>,
    /// `B_l`.
    pub(crate) b: Vec<Complex<F>>,
    /// `T̂_0 += t0 · m_0` and `T̂_{q/2} += th · m_0`.
    pub(crate) t0: Complex<F>,
    pub(crate) th: Complex<F>,
    /// `y_0 = g0 Σm + z0 Û_0 + zh Û_{q/2} + zm m_0`.
    pub(crate) z0: Complex<F>,
    pub(crate) zh: Complex<F>,
    pub(crate) zm: Complex<F>,
    /// `G_0 / p` (real: `G_0` is the sum of a real kernel).
    pub(crate) g0: F,
}

/// The Rader-domain plan of one prime order.
pub(crate) struct Rader<F: rustfft::FftNum> {
    pub(crate) p: usize,
    pub(crate) q: usize,
    /// `perm[a] = g^a mod p`.
    pub(crate) perm: Vec<usize>,
    pub(crate) fwd: Arc<dyn Fft<F>>,
    pub(crate) inv: Arc<dyn Fft<F>>,
    pub(crate) demux: Spec<F>,
    pub(crate) mux: Spec<F>,
    scratch_len: usize,
}

fn c64_to<F: Real>(z: Complex<f64>) -> Complex<F> {
    Complex::new(F::of_f64(z.re), F::of_f64(z.im))
}

fn pow_mod(mut b: u64, mut e: u64, m: u64) -> u64 {
    let mut r = 1 % m;
    b %= m;
    while e > 0 {
        if e & 1 == 1 {
            r = r * b % m;
        }
        b = b * b % m;
        e >>= 1;
    }
    r
}

/// The smallest primitive root of the prime `p` (`p >= 3`, `p < 2^32`).
pub(crate) fn primitive_root(p: usize) -> usize {
    let q = (p - 1) as u64;
    let mut factors = Vec::new();
    let mut x = q;
    let mut f = 2;
    while f * f <= x {
        if x % f == 0 {
            factors.push(f);
            while x % f == 0 {
                x /= f;
            }
        }
        f += 1;
    }
    if x > 1 {
        factors.push(x);
    }
    (2..p as u64).find(|&g| factors.iter().all(|&f| pow_mod(g, q / f, p as u64) != 1)).map_or(1, |g| g as usize)
}

impl<F: Real> Rader<F> {
    /// Plans the circulants with length-`p` spectra `g_demux` and `g_mux` (f64, bin 0 first,
    /// `C m = F⁻¹(G · F m)`); `None` when `p` is not an odd prime or a spectrum is not
    /// two-valued on residues / non-residues.
    pub(crate) fn new(g_demux: &[Complex<f64>], g_mux: &[Complex<f64>]) -> Option<Rader<F>> {
        let p = g_demux.len();
        if p < 3 || p % 2 == 0 || !crate::smatrix::is_prime(p) || g_mux.len() != p {
            return None;
        }
        let q = p - 1;
        let g = primitive_root(p);
        let mut perm = Vec::with_capacity(q);
        let mut x = 1usize;
        for _ in 0..q {
            perm.push(x);
            x = x * g % p;
        }
        let pf = p as f64;
        let w: Vec<Complex<f64>> =
            perm.iter().map(|&e| Complex::from_polar(1.0, -2.0 * std::f64::consts::PI * e as f64 / pf)).collect();
        let mut planner = FftPlanner::<f64>::new();
        let f64fwd = planner.plan_fft_forward(q);
        let mut hh: Vec<Complex<f64>> = (0..q).map(|d| w[(q - d) % q]).collect();
        f64fwd.process(&mut hh);
        let mut wc: Vec<Complex<f64>> = w.iter().map(|z| z.conj()).collect();
        f64fwd.process(&mut wc);
        let half = q / 2;
        let spec = |gs: &[Complex<f64>]| -> Option<Spec<F>> {
            // γ_b = G at k = g^{−b} = perm[(q − b) mod q].
            let gamma: Vec<Complex<f64>> = (0..q).map(|b| gs[perm[(q - b) % q]]).collect();
            let alpha = (gamma[0] + gamma[1]) * 0.5;
            let beta = (gamma[0] - gamma[1]) * 0.5;
            let size = gs.iter().fold(0.0f64, |m, z| m.max(z.norm())).max(1e-300);
            let off = gamma
                .iter()
                .enumerate()
                .map(|(b, z)| (z - if b % 2 == 0 { alpha + beta } else { alpha - beta }).norm())
                .fold(0.0, f64::max);
            if off > 1e-9 * size {
                return None;
            }
            let s = 1.0 / (pf * q as f64);
            let c: Vec<Complex<f64>> = wc.iter().map(|z| z * alpha * s).collect();
            let d: Vec<Complex<f64>> = wc.iter().map(|z| z * beta * s).collect();
            let a = (0..q).map(|l| c64_to(c[l] * hh[l])).collect();
            let b = (0..q).map(|l| c64_to(d[l] * hh[(l + half) % q])).collect();
            let qf = q as f64;
            Some(Spec {
                a,
                b,
                t0: c64_to(c[0] * qf),
                th: c64_to(d[half] * qf),
                z0: c64_to(alpha * hh[0] / pf),
                zh: c64_to(beta * hh[half] / pf),
                zm: c64_to(alpha * qf / pf),
                g0: F::of_f64(gs[0].re / pf),
            })
        };
        let demux = spec(g_demux)?;
        let mux = spec(g_mux)?;
        let mut planner = FftPlanner::<F>::new();
        let fwd = planner.plan_fft_forward(q);
        let inv = planner.plan_fft_inverse(q);
        let scratch_len = fwd.get_inplace_scratch_len().max(inv.get_inplace_scratch_len());
        Some(Rader { p, q, perm, fwd, inv, demux, mux, scratch_len })
    }

    /// Scratch the transforms need (complex values).
    pub(crate) fn scratch_len(&self) -> usize {
        self.scratch_len
    }

    /// Applies the circulant to every column of the tile `rows` (`p` runs), in place;
    /// `local` holds `p × t` values.
    pub(crate) fn tile(
        &self,
        rows: &mut [&mut [f32]],
        buf: &mut [Complex<F>],
        scratch: &mut [Complex<F>],
        local: &mut [f32],
        dir: Dir,
    ) {
        let (p, q) = (self.p, self.q);
        debug_assert_eq!(rows.len(), p);
        let half = q / 2;
        let sp = if dir == Dir::Demux { &self.demux } else { &self.mux };
        let t = rows[0].len();
        let pairs = t.div_ceil(2);
        let zero = F::of_f64(0.0);
        let mut m0 = [Complex::new(zero, zero); BATCH];
        let mut y0 = [Complex::new(zero, zero); BATCH];
        let mut sum = [Complex::new(zero, zero); BATCH];
        // The tile's runs first copied whole, in Rader order (slot a = row g^a): each row is
        // read as one sequential run, so the batches below gather from cache instead of
        // missing to memory on every 2-line piece of a row taken in permuted order.
        let local = &mut local[..q * t];
        for (dst, &r) in local.chunks_exact_mut(t).zip(&self.perm) {
            dst.copy_from_slice(rows[r]);
        }
        let mut j0 = 0;
        while j0 < pairs {
            let nb = BATCH.min(pairs - j0);
            let (c0, c1) = (2 * j0, (2 * (j0 + nb)).min(t));
            let full = (c1 - c0) / 2; // pairs with both columns
            let buf = &mut buf[..nb * q];
            // Gather in Rader order: buf[j q + a] = column pair j at row g^a. The writes stride
            // q but the batch is in L1; each row contributes one contiguous run.
            for (a, src) in local.chunks_exact(t).enumerate() {
                let run = &src[c0..c1];
                for (j, v) in run.chunks_exact(2).enumerate() {
                    buf[j * q + a] = Complex::new(F::of_f32(v[0]), F::of_f32(v[1]));
                }
                if full < nb {
                    buf[full * q + a] = Complex::new(F::of_f32(run[2 * full]), zero);
                }
            }
            {
                let run = &rows[0][c0..c1];
                for (j, v) in run.chunks_exact(2).enumerate() {
                    m0[j] = Complex::new(F::of_f32(v[0]), F::of_f32(v[1]));
                }
                if full < nb {
                    m0[full] = Complex::new(F::of_f32(run[2 * full]), zero);
                }
            }
            self.fwd.process_with_scratch(buf, scratch);
            for (j, col) in buf.chunks_exact_mut(q).enumerate() {
                let (u0, uh, m) = (col[0], col[half], m0[j]);
                sum[j] = u0 + m;
                y0[j] = sp.z0 * u0 + sp.zh * uh + sp.zm * m;
                let (lo, hi) = col.split_at_mut(half);
                let (alo, ahi) = sp.a.split_at(half);
                let (blo, bhi) = sp.b.split_at(half);
                for l in 0..half {
                    let (x, y) = (lo[l], hi[l]);
                    lo[l] = alo[l] * x + blo[l] * y;
                    hi[l] = ahi[l] * y + bhi[l] * x;
                }
                col[0] = col[0] + sp.t0 * m;
                col[half] = col[half] + sp.th * m;
            }
            self.inv.process_with_scratch(buf, scratch);
            for j in 0..nb {
                let s = sum[j];
                sum[j] = Complex::new(sp.g0 * s.re, sp.g0 * s.im);
                y0[j] = y0[j] + sum[j];
            }
            for (e, &r) in self.perm.iter().enumerate() {
                let run = &mut rows[r][c0..c1];
                for (j, v) in run.chunks_exact_mut(2).enumerate() {
                    let z = buf[j * q + e] + sum[j];
                    v[0] = z.re.to_f32();
                    v[1] = z.im.to_f32();
                }
                if full < nb {
                    run[2 * full] = (buf[full * q + e].re + sum[full].re).to_f32();
                }
            }
            let run = &mut rows[0][c0..c1];
            for (j, v) in run.chunks_exact_mut(2).enumerate() {
                v[0] = y0[j].re.to_f32();
                v[1] = y0[j].im.to_f32();
            }
            if full < nb {
                run[2 * full] = y0[full].re.to_f32();
            }
            j0 += nb;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn primitive_roots_generate_the_whole_group() {
        for p in [3usize, 7, 11, 19, 151, 199, 1019, 2039] {
            let g = primitive_root(p);
            let mut seen = vec![false; p];
            let mut x = 1;
            for _ in 0..p - 1 {
                assert!(!seen[x], "p {p} g {g}: {x} repeats");
                seen[x] = true;
                x = x * g % p;
            }
            assert_eq!(x, 1, "p {p} g {g}");
        }
        assert_eq!(primitive_root(151), 6);
        assert_eq!(primitive_root(199), 3);
    }

    #[test]
    fn a_spectrum_that_is_not_two_valued_is_refused() {
        // A generic circulant (not a quadratic-residue code) has no Rader-domain shortcut.
        let p = 11;
        let g: Vec<Complex<f64>> = (0..p).map(|k| Complex::new(k as f64, 0.5 * k as f64)).collect();
        assert!(Rader::<f32>::new(&g, &g).is_none());
        assert!(Rader::<f32>::new(&g[..10], &g[..10]).is_none(), "even length");
    }
}
