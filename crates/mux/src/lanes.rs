//! Explicit vector arithmetic on lanes of f32 and software prefetch of the rows, shared by
//! the pixel-vectorised transforms ([`crate::vfft`], [`crate::vwht`]).
//!
//! A pattern-major tile is `n` runs far apart in memory, and a transform that works on a block
//! of a few columns at a time reads one short run from each of them: more streams than the
//! hardware prefetcher follows, so the kernels ask for a later block's lines themselves
//! ([`Prefetch`]).
use pulp::bytemuck::Pod;

/// The instruction set the vector kernels run on this CPU: "avx512" (if `wide` allows it),
/// "avx2" (with FMA) or "portable", the order in which their `tile` functions try them.
pub(crate) fn isa(wide: bool) -> &'static str {
    #[cfg(target_arch = "x86_64")]
    {
        if wide && pulp::x86::V4::try_new().is_some() {
            return "avx512";
        }
        if pulp::x86::V3::try_new().is_some() {
            return "avx2";
        }
    }
    let _ = wide;
    "portable"
}

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

/// Prefetches of a later block's runs of the rows, spread evenly over the butterflies of a
/// block's stages before the last (`ticks` of them): all at once in the first stage, 302 lines
/// of 151 rows, left the misses of the two threads bunched (see `docs/benchmarks.md`).
pub(crate) struct Prefetch<'a, 'b> {
    rows: &'a [&'b mut [f32]],
    /// First column and length of the runs.
    col: usize,
    len: usize,
    next: usize,
    /// `acc += rows`, one row per `ticks` subtracted.
    acc: usize,
    ticks: usize,
}

impl<'a, 'b> Prefetch<'a, 'b> {
    /// Prefetches `rows[..][col .. col + len]`, all of them over `ticks` calls of [`tick`].
    pub(crate) fn new(rows: &'a [&'b mut [f32]], col: usize, len: usize, ticks: usize) -> Prefetch<'a, 'b> {
        Prefetch { rows, col, len, next: 0, acc: 0, ticks: ticks.max(1) }
    }

    #[inline(always)]
    pub(crate) fn tick(&mut self) {
        self.acc += self.rows.len();
        while self.acc >= self.ticks && self.next < self.rows.len() {
            prefetch_run(self.rows[self.next], self.col, self.len);
            self.next += 1;
            self.acc -= self.ticks;
        }
    }
}

/// One butterfly's turn at the prefetches, if any.
#[inline(always)]
pub(crate) fn tick(pf: &mut Option<Prefetch<'_, '_>>) {
    if let Some(p) = pf {
        p.tick();
    }
}

/// Asks for the lines of `row[c0 .. c0 + n]` into L2 (a hint; no-op off x86_64). Into L2
/// rather than L1: the block's two buffers (up to 38 KB) already fill L1, and lines
/// prefetched there were evicted before use (single thread, 151 × 300 000 stack: 40 ms with
/// `prefetcht0`, 34.5 ms with `prefetcht2`, 36.5 ms with `prefetcht1`, 85 ms with none).
#[inline(always)]
pub(crate) fn prefetch_run(row: &[f32], c0: usize, n: usize) {
    #[cfg(target_arch = "x86_64")]
    for x in row[c0..c0 + n].iter().step_by(16) {
        safe_arch::prefetch_t2(x);
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = (row, c0, n);
}
