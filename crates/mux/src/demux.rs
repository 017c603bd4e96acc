//! Demultiplexing `x = S⁻¹ m` per column of a pattern-major stack, three ways.
//!
//! With `N = n + 1` and the closed form `S⁻¹ = 2/N (2 Sᵀ − J)`:
//!
//! * **Fast Walsh–Hadamard** (Sylvester orders, `O(n log n)` per column). With
//!   `H[a][b] = (−1)^popcount(a & b)` of order `N` and `x = (0, m_0, …, m_{n−1})`,
//!   `(H x)_{j+1} = Σm − 2 (Sᵀ m)_j`, so
//!   `S⁻¹ m = −(2/N) · (H x)_{1..N}` and `S m = ((H x)_0 − (H x)_{1..N}) / 2`.
//!   By default (f32) `crate::vwht` runs it on blocks of 16 columns, every butterfly level of
//!   a block in two or three register passes, reading and writing the rows once; the generic
//!   code ([`Engine::Generic`], f64) runs radix-4 passes (one radix-2 pass when `log₂ N` is
//!   odd) over the tile's rows in place, each butterfly an element-wise add/subtract of two
//!   runs of `tile` values. Both vectorise over pixels and never transpose.
//! * **FFT circular convolution** (cyclic Paley and twin-prime orders, `O(n log n)` per column).
//!   `S[i][j] = s[(j − i) mod n]`, so `Sᵀ m = s ⊛ m` (circular convolution) and
//!   `S m = s ⋆ m` (circular correlation). With the DFT `K = F s` and `M = F m`:
//!   `F(S⁻¹ m) = G · M` with `G_k = 2/N · (2 K_k − n δ_k)` (the `J` term only touches bin 0,
//!   where `M_0 = Σm`), and `F(S m) = conj(K) · M`. Two real columns ride in one complex
//!   FFT (real and imaginary part; `G` and `K` are the spectra of real sequences, so the two
//!   stay apart). For a Paley order `p` the length-`p` circulant becomes one forward and one
//!   inverse FFT of length `p − 1` (Rader, `crate::rader`); by default (f32, `p − 1` twice a
//!   product of 3 … 13: 151, 199) that runs on the pixel-vectorised transform of
//!   `crate::vfft`, straight from and to the rows. The generic code ([`Engine::Generic`], f64,
//!   other orders) is rustfft with the tile transposed into its buffer and back; prime lengths
//!   are slow there, so other cyclic orders are zero-padded to a 5-smooth length `L >= 2n − 1`
//!   and convolved with the code extended periodically over `−(n−1)..(n−1)` ([`fft_len`]);
//!   the first `n` outputs of that length-`L` circular convolution are the length-`n` ones.
//! * **Dense** (any order, `O(n²)` per column): `Y = S⁻¹ X` as a matrix product
//!   (nalgebra → matrixmultiply) on the gathered tile, either pattern-major (`X` is
//!   `tile × n` column-major: a plain copy of the tile's runs, `Y = X S⁻ᵀ`) or pixel-major
//!   (`X` is `n × tile`: a transposing gather, `Y = S⁻¹ X`).
//!
//! Accumulation is f32 (the data type) or f64 ([`Accumulate`]); the f64 variants gather the
//! tile into an f64 scratch and round once at the end. `tests/demux.rs` measures f32 against
//! f64 and both against the dense f64 closed form.

use std::sync::Arc;

use nalgebra::{DMatrix, DMatrixView, DMatrixViewMut};
use rustfft::num_complex::Complex;
use rustfft::{Fft, FftNum, FftPlanner};

use crate::error::MuxError;
use crate::kernel::{Dir, Real};
use crate::rader::Rader;
use crate::smatrix::{is_prime, Construction, SMatrix};
use crate::tile::{check_shape, for_each_tile, Par};
use crate::vfft::VecRader;
use crate::vwht::VecWht;

/// Which algorithm applies `S⁻¹` (or `S`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    /// Fast Walsh–Hadamard transform (Sylvester orders only).
    Fwht,
    /// FFT circular convolution (cyclic orders only).
    Fft,
    /// Dense matrix product with the closed-form inverse, in the given tile layout.
    Dense(DenseLayout),
}

impl Method {
    /// Short name for tables: `fwht`, `fft`, `dense-pattern`, `dense-pixel`.
    pub fn name(&self) -> &'static str {
        match self {
            Method::Fwht => "fwht",
            Method::Fft => "fft",
            Method::Dense(DenseLayout::PatternMajor) => "dense-pattern",
            Method::Dense(DenseLayout::PixelMajor) => "dense-pixel",
        }
    }

    /// The fast method for a construction: FWHT for Sylvester, FFT for the cyclic ones.
    pub fn fast_for(c: Construction) -> Method {
        if c.is_cyclic() {
            Method::Fft
        } else {
            Method::Fwht
        }
    }
}

/// Memory layout of a tile handed to the dense matrix product.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DenseLayout {
    /// The tile's runs copied as they are: `X` is `tile × n` column-major, `Y = X S⁻ᵀ`.
    PatternMajor,
    /// Transposed on gather: `X` is `n × tile` column-major (each pixel's vector
    /// contiguous), `Y = S⁻¹ X`.
    PixelMajor,
}

/// Floating-point type the arithmetic runs in (data are always f32).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Accumulate {
    /// f32 throughout.
    #[default]
    F32,
    /// Gather the tile to f64, round once at the end.
    F64,
}

/// Tuning of a [`Demuxer`]; `Default` picks the fast method for the construction and a tile
/// size that keeps a tile within about 256 KiB.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DemuxParams {
    /// The method; `None` = [`Method::fast_for`] the construction.
    pub method: Option<Method>,
    /// Columns per tile; 0 = automatic.
    pub tile: usize,
    /// Accumulation precision.
    pub accumulate: Accumulate,
    /// FFT length of the cyclic path: 0 = automatic ([`fft_len`]), else `n` or `>= 2n − 1`.
    pub fft_len: usize,
    /// The code that runs the fast transform (FWHT or FFT).
    pub engine: Engine,
}

/// Which code runs the fast transform.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Engine {
    /// Pixel-vectorised, one block of columns through every pass with explicit vector
    /// arithmetic, in f32: the Walsh–Hadamard transform (`crate::vwht`) for the Sylvester
    /// orders, the Rader-domain transform (`crate::vfft`) for the Paley orders with `p − 1`
    /// twice a product of 3 … 13; AVX-512 where the CPU has it, else AVX2, else portable code.
    /// Elsewhere (other orders, f64) the generic code.
    #[default]
    Vector,
    /// The same, but never AVX-512 (to compare the two on one CPU).
    VectorAvx2,
    /// The generic code: FWHT passes of radix 4 over a whole tile (vectorised by the
    /// compiler); FFTs by rustfft, one column pair at a time, the tile transposed into its
    /// buffer and back.
    Generic,
}

/// A plan that applies `S⁻¹` (demultiplex) or `S` (multiplex) to every column of a
/// pattern-major stack. Build once per S-matrix, reuse for every view.
pub struct Demuxer {
    n: usize,
    construction: Construction,
    method: Method,
    tile: usize,
    accumulate: Accumulate,
    kernel: Kernel,
}

impl std::fmt::Debug for Demuxer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Demuxer")
            .field("n", &self.n)
            .field("construction", &self.construction)
            .field("method", &self.method)
            .field("tile", &self.tile)
            .field("accumulate", &self.accumulate)
            .finish_non_exhaustive()
    }
}

enum Kernel {
    Fwht,
    FwhtVec(VecWht),
    Fft32(FftKernel<f32>),
    Fft64(FftKernel<f64>),
    FftVec(VecRader),
    /// `inv`/`fwd` are `S⁻¹`/`S`, transposed for the pattern-major layout.
    Dense {
        layout: DenseLayout,
        inv: DMatrix<f64>,
        fwd: DMatrix<f64>,
        inv32: DMatrix<f32>,
        fwd32: DMatrix<f32>,
    },
}

struct FftKernel<F: FftNum> {
    n: usize,
    /// Transform length: `n` (circular directly) or `L >= 2n − 1` (linear convolution of the
    /// zero-padded column with the periodically extended code).
    len: usize,
    fwd: Arc<dyn Fft<F>>,
    inv: Arc<dyn Fft<F>>,
    /// Spectrum multiplier of the demultiplex.
    g_demux: Vec<Complex<F>>,
    /// Spectrum multiplier of the multiplex `S m`.
    g_mux: Vec<Complex<F>>,
    scratch_len: usize,
    /// The Rader-domain plan (`len = n − 1`, prime `n`); the fields above are then unused
    /// except `n` and `len`.
    rader: Option<Rader<F>>,
}

/// The FFT length for a cyclic order `n` (0 = automatic): for a prime (Paley) order whose
/// `n − 1` has no prime factor above 13, `n − 1` (the Rader-domain path, `crate::rader`, on
/// the pixel-vectorised transform of `crate::vfft` in f32: 151 → 150, 199 → 198); else `n`
/// itself when it is 5-smooth (rustfft's fast radices), else the smallest 5-smooth
/// `L >= 2n − 1`. Prime lengths are 3-4x slower in rustfft than such an `L` (1.19 µs for 151
/// against 0.38 µs for 320, f32, `examples/fft_lengths.rs`).
pub fn fft_len(n: usize, requested: usize) -> usize {
    if requested > 0 {
        return requested;
    }
    if n > 2 && is_prime(n) && smooth13(n - 1) {
        return n - 1;
    }
    if smooth(n) {
        return n;
    }
    padded_len(n)
}

fn smooth(mut x: usize) -> bool {
    for f in [2, 3, 5] {
        while x % f == 0 {
            x /= f;
        }
    }
    x == 1
}

/// No prime factor above 13 (the radices of `crate::vfft`).
fn smooth13(mut x: usize) -> bool {
    for f in [2, 3, 5, 7, 11, 13] {
        while x % f == 0 {
            x /= f;
        }
    }
    x == 1
}

/// The smallest 5-smooth length `>= 2n − 1`.
pub fn padded_len(n: usize) -> usize {
    (2 * n - 1..).find(|&l| smooth(l)).unwrap_or(2 * n - 1)
}

/// Per-thread workspace of a [`Demuxer`] (one block per thread of the [`Par`] it was made
/// for). Make it with [`Demuxer::scratch`]; reuse across calls.
#[derive(Debug, Default)]
pub struct DemuxScratch {
    blocks: Vec<BlockScratch>,
}

#[derive(Debug, Default)]
struct BlockScratch {
    r32: Vec<f32>,
    r64: Vec<f64>,
    c32: Vec<Complex<f32>>,
    c64: Vec<Complex<f64>>,
    f32s: Vec<Complex<f32>>,
    f64s: Vec<Complex<f64>>,
    x32: Vec<f32>,
    y32: Vec<f32>,
    x64: Vec<f64>,
    y64: Vec<f64>,
    v: Vec<pulp::f32x16>,
}

impl DemuxScratch {
    /// Number of per-thread blocks.
    pub fn blocks(&self) -> usize {
        self.blocks.len()
    }
}

impl Demuxer {
    /// Plans the demultiplexing of `s` with `params`; [`MuxError::MethodUnsupported`] when
    /// the method does not fit the construction (FWHT needs Sylvester, FFT a cyclic order).
    pub fn new(s: &SMatrix, params: &DemuxParams) -> Result<Demuxer, MuxError> {
        let c = s.construction();
        let n = s.order();
        let method = params.method.unwrap_or(Method::fast_for(c));
        let kernel = match method {
            Method::Fwht => {
                if c.is_cyclic() {
                    return Err(MuxError::MethodUnsupported {
                        method: "fwht",
                        construction: c.name(),
                        order: n,
                        allowed: "Sylvester orders 2^k - 1",
                    });
                }
                match (params.accumulate, params.engine) {
                    (Accumulate::F32, Engine::Vector | Engine::VectorAvx2) => {
                        match VecWht::new(n, params.engine == Engine::Vector) {
                            Some(v) => Kernel::FwhtVec(v),
                            None => Kernel::Fwht,
                        }
                    }
                    _ => Kernel::Fwht,
                }
            }
            Method::Fft => {
                let Some(row) = s.first_row() else {
                    return Err(MuxError::MethodUnsupported {
                        method: "fft",
                        construction: c.name(),
                        order: n,
                        allowed: "cyclic constructions (Paley, twin prime)",
                    });
                };
                let len = fft_len(n, params.fft_len);
                let rader_ok = matches!(c, Construction::Paley { .. }) && len + 1 == n;
                if len != n && len < 2 * n - 1 && !rader_ok {
                    return Err(MuxError::BadParameter {
                        construction: "fft demultiplex",
                        what: "fft_len",
                        value: len.to_string(),
                        allowed: format!("the order {n} or at least 2n - 1 = {}", 2 * n - 1),
                    });
                }
                match params.accumulate {
                    Accumulate::F32 if matches!(params.engine, Engine::Vector | Engine::VectorAvx2) && rader_ok => {
                        let wide = params.engine == Engine::Vector;
                        match rader_f64(row).and_then(|r| VecRader::new(r, wide)) {
                            Some(v) => Kernel::FftVec(v),
                            None => Kernel::Fft32(FftKernel::new(row, len)),
                        }
                    }
                    Accumulate::F32 => Kernel::Fft32(FftKernel::new(row, len)),
                    Accumulate::F64 => Kernel::Fft64(FftKernel::new(row, len)),
                }
            }
            Method::Dense(layout) => {
                let mut inv = DMatrix::from_row_slice(n, n, &s.inverse_dense());
                let dense: Vec<f64> = s.to_dense().into_iter().map(f64::from).collect();
                let mut fwd = DMatrix::from_row_slice(n, n, &dense);
                if layout == DenseLayout::PatternMajor {
                    // Y = X Aᵀ: keep the transposes.
                    inv = inv.transpose();
                    fwd = fwd.transpose();
                }
                let inv32 = inv.map(|v| v as f32);
                let fwd32 = fwd.map(|v| v as f32);
                Kernel::Dense { layout, inv, fwd, inv32, fwd32 }
            }
        };
        let tile = if params.tile > 0 {
            params.tile
        } else {
            match method {
                // The vector paths' unit is their block of 16 or 32 columns read straight from
                // the rows; a tile only bounds how far ahead they prefetch (not across tiles),
                // so it is long: 1 MP RGB is 46 tiles per thread.
                _ if matches!(kernel, Kernel::FftVec(_) | Kernel::FwhtVec(_)) => 1 << 15,
                // About 256 KiB of f32 per tile (the rows of N = n + 1 runs).
                Method::Fwht => ((65536 / (n + 1)).clamp(16, 1024) / 16) * 16,
                // The Rader path copies the tile and transforms it in batches of 16 column
                // pairs; 64 columns measured 5 % faster than 256 at n = 151 (noisy).
                Method::Fft if matches!(c, Construction::Paley { .. }) && fft_len(n, params.fft_len) + 1 == n => 64,
                Method::Fft => 256,
                Method::Dense(_) => 512,
            }
        };
        Ok(Demuxer { n, construction: c, method, tile, accumulate: params.accumulate, kernel })
    }

    /// The order.
    pub fn order(&self) -> usize {
        self.n
    }

    /// The method in use.
    pub fn method(&self) -> Method {
        self.method
    }

    /// The code that runs the fast transform (`None` for the dense method).
    pub fn engine(&self) -> Option<Engine> {
        match self.kernel {
            Kernel::FftVec(ref k) if k.wide() => Some(Engine::Vector),
            Kernel::FwhtVec(ref k) if k.wide() => Some(Engine::Vector),
            Kernel::FftVec(_) | Kernel::FwhtVec(_) => Some(Engine::VectorAvx2),
            Kernel::Fwht | Kernel::Fft32(_) | Kernel::Fft64(_) => Some(Engine::Generic),
            Kernel::Dense { .. } => None,
        }
    }

    /// The instruction set the pixel-vectorised transform runs on this CPU ("avx512", "avx2"
    /// or "portable"); `None` off those paths.
    pub fn vector_isa(&self) -> Option<&'static str> {
        match &self.kernel {
            Kernel::FftVec(k) => Some(k.isa()),
            Kernel::FwhtVec(k) => Some(k.isa()),
            _ => None,
        }
    }

    /// Columns per tile.
    pub fn tile(&self) -> usize {
        self.tile
    }

    /// The accumulation precision.
    pub fn accumulate(&self) -> Accumulate {
        self.accumulate
    }

    /// A workspace for calls with `par`.
    pub fn scratch(&self, par: Par) -> DemuxScratch {
        let (n, t) = (self.n, self.tile);
        let blocks = (0..par.blocks())
            .map(|_| {
                let mut b = BlockScratch::default();
                match (&self.kernel, self.accumulate) {
                    (Kernel::Fwht, Accumulate::F32) => b.r32 = vec![0.0; t],
                    (Kernel::Fwht, Accumulate::F64) => b.r64 = vec![0.0; (n + 1) * t],
                    (Kernel::Fft32(k), _) => {
                        b.c32 = vec![Complex::default(); t.div_ceil(2) * k.len];
                        b.f32s = vec![Complex::default(); k.scratch_len];
                        if k.rader.is_some() {
                            b.x32 = vec![0.0; n * t];
                        }
                    }
                    (Kernel::FwhtVec(k), _) => {
                        b.r32 = vec![0.0; t];
                        b.v = vec![<pulp::f32x16 as pulp::bytemuck::Zeroable>::zeroed(); k.scratch_len()];
                    }
                    (Kernel::FftVec(k), _) => {
                        b.v = vec![<pulp::f32x16 as pulp::bytemuck::Zeroable>::zeroed(); k.scratch_len()];
                    }
                    (Kernel::Fft64(k), _) => {
                        b.c64 = vec![Complex::default(); t.div_ceil(2) * k.len];
                        b.f64s = vec![Complex::default(); k.scratch_len];
                        if k.rader.is_some() {
                            b.x32 = vec![0.0; n * t];
                        }
                    }
                    (Kernel::Dense { .. }, Accumulate::F32) => {
                        b.x32 = vec![0.0; t * n];
                        b.y32 = vec![0.0; t * n];
                    }
                    (Kernel::Dense { .. }, Accumulate::F64) => {
                        b.x64 = vec![0.0; t * n];
                        b.y64 = vec![0.0; t * n];
                    }
                }
                b
            })
            .collect();
        DemuxScratch { blocks }
    }

    /// Demultiplexes in place: `data` holds `n` frames of `cols` values (pattern-major) and
    /// afterwards `n` single-source images of `cols` values, image `j` where frame `j` was.
    pub fn demux_in_place(
        &self,
        data: &mut [f32],
        cols: usize,
        scratch: &mut DemuxScratch,
        par: Par,
    ) -> Result<(), MuxError> {
        self.run(data, cols, scratch, par, Dir::Demux)
    }

    /// Multiplexes in place: `n` single-source images in, the `n` pattern frames `S x` out
    /// (for simulation and tests).
    pub fn multiplex_in_place(
        &self,
        data: &mut [f32],
        cols: usize,
        scratch: &mut DemuxScratch,
        par: Par,
    ) -> Result<(), MuxError> {
        self.run(data, cols, scratch, par, Dir::Mux)
    }

    /// Demultiplexes a copy of `frames` (owning convenience; sequential).
    pub fn demux(&self, frames: &[f32], cols: usize) -> Result<Vec<f32>, MuxError> {
        let mut out = frames.to_vec();
        let mut scratch = self.scratch(Par::Seq);
        self.demux_in_place(&mut out, cols, &mut scratch, Par::Seq)?;
        Ok(out)
    }

    /// Multiplexes a copy of `images` (owning convenience; sequential).
    pub fn multiplex(&self, images: &[f32], cols: usize) -> Result<Vec<f32>, MuxError> {
        let mut out = images.to_vec();
        let mut scratch = self.scratch(Par::Seq);
        self.multiplex_in_place(&mut out, cols, &mut scratch, Par::Seq)?;
        Ok(out)
    }

    fn run(
        &self,
        data: &mut [f32],
        cols: usize,
        scratch: &mut DemuxScratch,
        par: Par,
        dir: Dir,
    ) -> Result<(), MuxError> {
        check_shape("demux stack", data.len(), self.n, cols)?;
        if scratch.blocks.len() != par.blocks() {
            *scratch = self.scratch(par);
        }
        let (n, acc) = (self.n, self.accumulate);
        let blocks = &mut scratch.blocks[..];
        match &self.kernel {
            Kernel::Fwht => for_each_tile(data, n, cols, self.tile, blocks, |rows, s| match acc {
                Accumulate::F32 => fwht_tile_f32(rows, &mut s.r32, dir),
                Accumulate::F64 => fwht_tile_f64(rows, &mut s.r64, dir),
            }),
            Kernel::Fft32(k) => for_each_tile(data, n, cols, self.tile, blocks, |rows, s| {
                k.tile(rows, &mut s.c32, &mut s.f32s, &mut s.x32, dir)
            }),
            Kernel::FwhtVec(k) => {
                for_each_tile(data, n, cols, self.tile, blocks, |rows, s| k.tile(rows, &mut s.r32, &mut s.v, dir))
            }
            Kernel::FftVec(k) => for_each_tile(data, n, cols, self.tile, blocks, |rows, s| k.tile(rows, &mut s.v, dir)),
            Kernel::Fft64(k) => for_each_tile(data, n, cols, self.tile, blocks, |rows, s| {
                k.tile(rows, &mut s.c64, &mut s.f64s, &mut s.x32, dir)
            }),
            Kernel::Dense { layout, inv, fwd, inv32, fwd32 } => {
                let layout = *layout;
                for_each_tile(data, n, cols, self.tile, blocks, |rows, s| match acc {
                    Accumulate::F32 => {
                        let a = if dir == Dir::Demux { inv32 } else { fwd32 };
                        dense_tile(rows, a, layout, &mut s.x32, &mut s.y32)
                    }
                    Accumulate::F64 => {
                        let a = if dir == Dir::Demux { inv } else { fwd };
                        dense_tile(rows, a, layout, &mut s.x64, &mut s.y64)
                    }
                })
            }
        }
        Ok(())
    }
}

/// In-place unnormalised Walsh–Hadamard transform across the rows `v` (`v.len()` a power of
/// two), element-wise along the runs.
pub(crate) fn wht_rows<T: Real>(v: &mut [&mut [T]]) {
    let n = v.len();
    debug_assert!(n.is_power_of_two());
    let mut h = 1;
    while 4 * h <= n {
        for start in (0..n).step_by(4 * h) {
            for i in start..start + h {
                let (lo, rest) = v.split_at_mut(i + h);
                let (b, rest) = rest.split_at_mut(h);
                let (c, d) = rest.split_at_mut(h);
                radix4(lo[i], b[0], c[0], d[0]);
            }
        }
        h *= 4;
    }
    if 2 * h <= n {
        for i in 0..h {
            let (lo, hi) = v.split_at_mut(i + h);
            radix2(lo[i], hi[0]);
        }
    }
}

#[inline(always)]
fn radix2<T: Real>(a: &mut [T], b: &mut [T]) {
    let len = a.len();
    let b = &mut b[..len];
    for k in 0..len {
        let (x, y) = (a[k], b[k]);
        a[k] = x + y;
        b[k] = x - y;
    }
}

#[inline(always)]
fn radix4<T: Real>(a: &mut [T], b: &mut [T], c: &mut [T], d: &mut [T]) {
    let len = a.len();
    let (b, c, d) = (&mut b[..len], &mut c[..len], &mut d[..len]);
    for k in 0..len {
        let (w, x, y, z) = (a[k], b[k], c[k], d[k]);
        let (s0, d0, s1, d1) = (w + x, w - x, y + z, y - z);
        a[k] = s0 + s1;
        b[k] = d0 + d1;
        c[k] = s0 - s1;
        d[k] = d0 - d1;
    }
}

fn fwht_tile_f32(rows: &mut [&mut [f32]], zero: &mut [f32], dir: Dir) {
    let t = rows[0].len();
    let big = rows.len() + 1;
    let zero = &mut zero[..t];
    zero.fill(0.0);
    let mut v: Vec<&mut [f32]> = Vec::with_capacity(big);
    v.push(zero);
    for r in rows.iter_mut() {
        v.push(&mut r[..]);
    }
    wht_rows(&mut v);
    let (head, tail) = v.split_at_mut(1);
    match dir {
        Dir::Demux => {
            let c = -2.0 / big as f32;
            for r in tail.iter_mut() {
                r.iter_mut().for_each(|x| *x *= c);
            }
        }
        Dir::Mux => {
            let h0 = &head[0];
            for r in tail.iter_mut() {
                r.iter_mut().zip(h0.iter()).for_each(|(x, s)| *x = 0.5 * (*s - *x));
            }
        }
    }
}

fn fwht_tile_f64(rows: &mut [&mut [f32]], buf: &mut [f64], dir: Dir) {
    let t = rows[0].len();
    let big = rows.len() + 1;
    let buf = &mut buf[..big * t];
    buf[..t].fill(0.0);
    for (dst, src) in buf[t..].chunks_mut(t).zip(rows.iter()) {
        dst.iter_mut().zip(src.iter()).for_each(|(d, s)| *d = f64::from(*s));
    }
    let mut v: Vec<&mut [f64]> = buf.chunks_mut(t).collect();
    wht_rows(&mut v);
    let h0: Vec<f64> = v[0].to_vec();
    for (dst, src) in rows.iter_mut().zip(v[1..].iter()) {
        match dir {
            Dir::Demux => {
                let c = -2.0 / big as f64;
                dst.iter_mut().zip(src.iter()).for_each(|(d, s)| *d = (c * s) as f32);
            }
            Dir::Mux => {
                dst.iter_mut().zip(src.iter().zip(&h0)).for_each(|(d, (s, z))| *d = (0.5 * (z - s)) as f32);
            }
        }
    }
}

/// The Rader-domain plan of a prime cyclic order in f64 (its spectra feed the vector
/// path's fused coefficients); `None` for other orders.
pub(crate) fn rader_f64(first_row: &[u8]) -> Option<Rader<f64>> {
    let n = first_row.len();
    if n < 3 {
        return None;
    }
    FftKernel::<f64>::new(first_row, n - 1).rader
}

impl<F: Real> FftKernel<F> {
    fn new(first_row: &[u8], mut len: usize) -> FftKernel<F> {
        let n = first_row.len();
        if len + 1 == n {
            // Rader: the length-n spectra of the two circulants, in f64.
            let (kd, km) = (Self::kernel_spectrum(first_row, n, 1), Self::kernel_spectrum(first_row, n, -1));
            let big = n as f64 + 1.0;
            let mut gd: Vec<Complex<f64>> = kd.iter().map(|v| v * (4.0 / big)).collect();
            gd[0].re -= 2.0 * n as f64 / big;
            if let Some(r) = Rader::new(&gd, &km) {
                let scratch_len = r.scratch_len();
                let (fwd, inv) = (Arc::clone(&r.fwd), Arc::clone(&r.inv));
                return FftKernel {
                    n,
                    len,
                    fwd,
                    inv,
                    g_demux: Vec::new(),
                    g_mux: Vec::new(),
                    scratch_len,
                    rader: Some(r),
                };
            }
            // Not a quadratic-residue spectrum (not reached for the constructions here).
            len = padded_len(n);
        }
        let mut planner = FftPlanner::<F>::new();
        let fwd = planner.plan_fft_forward(len);
        let inv = planner.plan_fft_inverse(len);
        let (kd, km) = (Self::kernel_spectrum(first_row, len, 1), Self::kernel_spectrum(first_row, len, -1));
        let lf = len as f64;
        let c = 4.0 / (n as f64 + 1.0) / lf;
        // Demultiplex: y = 2/N (2 s⊛m − Σm); the 2/N·2/len factor here, −2/N Σm after the inverse.
        let g_demux = kd.iter().map(|v| Complex::new(F::of_f64(c * v.re), F::of_f64(c * v.im))).collect();
        let g_mux = km.iter().map(|v| Complex::new(F::of_f64(v.re / lf), F::of_f64(v.im / lf))).collect();
        let scratch_len = fwd.get_inplace_scratch_len().max(inv.get_inplace_scratch_len());
        FftKernel { n, len, fwd, inv, g_demux, g_mux, scratch_len, rader: None }
    }

    /// Spectrum (f64, length `len`) of the kernel of `Sᵀm = s ⊛ m` (`sign` 1: convolution
    /// with s) or `S m = r ⊛ m` (`sign` −1: `r_d = s_{−d}`). For `len > n` the code is
    /// extended periodically over `d = −(n−1)..(n−1)` and the column zero-padded, so the
    /// first n outputs of the length-`len` circular convolution are the length-n circular ones.
    fn kernel_spectrum(first_row: &[u8], len: usize, sign: isize) -> Vec<Complex<f64>> {
        let n = first_row.len();
        let mut k = vec![Complex::new(0.0, 0.0); len];
        let (ni, li) = (n as isize, len as isize);
        let range = if len == n { 0..ni } else { -(ni - 1)..ni };
        for d in range {
            let v = f64::from(first_row[((sign * d) % ni + ni) as usize % n]);
            k[((d % li + li) % li) as usize] = Complex::new(v, 0.0);
        }
        FftPlanner::<f64>::new().plan_fft_forward(len).process(&mut k);
        k
    }

    fn tile(
        &self,
        rows: &mut [&mut [f32]],
        buf: &mut [Complex<F>],
        scratch: &mut [Complex<F>],
        local: &mut [f32],
        dir: Dir,
    ) {
        if let Some(r) = &self.rader {
            return r.tile(rows, buf, scratch, local, dir);
        }
        let (n, len) = (self.n, self.len);
        let t = rows[0].len();
        let h = t.div_ceil(2);
        let buf = &mut buf[..h * len];
        // Gather: column q in the real part, column q + h in the imaginary part, zero-padded.
        if len > n {
            for col in buf.chunks_mut(len) {
                col[n..].fill(Complex::new(F::zero(), F::zero()));
            }
        }
        // Blocks of 8 rows: each write is a run of 8 consecutive complex values (whole cache
        // lines) instead of one value per column 8·len bytes apart.
        let hi = t - h; // columns in the imaginary parts (h or h − 1)
        for (b, block) in rows.chunks(8).enumerate() {
            let p0 = 8 * b;
            for q in 0..h {
                let dst = &mut buf[q * len + p0..q * len + p0 + block.len()];
                if q < hi {
                    for (d, r) in dst.iter_mut().zip(block) {
                        *d = Complex::new(F::of_f32(r[q]), F::of_f32(r[q + h]));
                    }
                } else {
                    for (d, r) in dst.iter_mut().zip(block) {
                        *d = Complex::new(F::of_f32(r[q]), F::zero());
                    }
                }
            }
        }
        self.fwd.process_with_scratch(buf, scratch);
        let g = if dir == Dir::Demux { &self.g_demux } else { &self.g_mux };
        // Σm of both packed columns is bin 0 (before the multiply).
        let sums: Vec<Complex<F>> = buf.chunks(len).map(|c| c[0]).collect();
        for chunk in buf.chunks_mut(len) {
            chunk.iter_mut().zip(g.iter()).for_each(|(x, g)| *x = *x * *g);
        }
        self.inv.process_with_scratch(buf, scratch);
        let c = F::of_f64(if dir == Dir::Demux { 2.0 / (n as f64 + 1.0) } else { 0.0 });
        for (b, block) in rows.chunks_mut(8).enumerate() {
            let p0 = 8 * b;
            for q in 0..h {
                let (sr, si) = (c * sums[q].re, c * sums[q].im);
                let src = &buf[q * len + p0..q * len + p0 + block.len()];
                if q < hi {
                    for (v, r) in src.iter().zip(block.iter_mut()) {
                        r[q] = (v.re - sr).to_f32();
                        r[q + h] = (v.im - si).to_f32();
                    }
                } else {
                    for (v, r) in src.iter().zip(block.iter_mut()) {
                        r[q] = (v.re - sr).to_f32();
                    }
                }
            }
        }
    }
}

/// Dense tile product `Y = A X` per column, in the given layout.
fn dense_tile<T>(rows: &mut [&mut [f32]], a: &DMatrix<T>, layout: DenseLayout, x: &mut [T], y: &mut [T])
where
    T: Real + nalgebra::RealField,
{
    let n = rows.len();
    let t = rows[0].len();
    let (x, y) = (&mut x[..t * n], &mut y[..t * n]);
    match layout {
        DenseLayout::PatternMajor => {
            for (dst, src) in x.chunks_mut(t).zip(rows.iter()) {
                dst.iter_mut().zip(src.iter()).for_each(|(d, s)| *d = T::of_f32(*s));
            }
            let xm = DMatrixView::from_slice(x, t, n);
            let mut ym = DMatrixViewMut::from_slice(y, t, n);
            // Y (t x n) = X (t x n) · Aᵀ; `a` holds Aᵀ for this layout.
            ym.gemm(T::one(), &xm, a, T::zero());
            for (dst, src) in rows.iter_mut().zip(y.chunks(t)) {
                dst.iter_mut().zip(src.iter()).for_each(|(d, s)| *d = s.to_f32());
            }
        }
        DenseLayout::PixelMajor => {
            for (p, src) in rows.iter().enumerate() {
                for (q, v) in src.iter().enumerate() {
                    x[q * n + p] = T::of_f32(*v);
                }
            }
            let xm = DMatrixView::from_slice(x, n, t);
            let mut ym = DMatrixViewMut::from_slice(y, n, t);
            ym.gemm(T::one(), a, &xm, T::zero());
            for (p, dst) in rows.iter_mut().enumerate() {
                for (q, d) in dst.iter_mut().enumerate() {
                    *d = y[q * n + p].to_f32();
                }
            }
        }
    }
}
