//! What the demultiplexing kernels share: the direction of the map and the arithmetic they
//! are generic over (`crate::demux` plans and runs them; `crate::rader`, `crate::vfft` and
//! `crate::vwht` are kernels).

use rustfft::FftNum;

/// Which map a kernel applies: `S⁻¹` (demultiplex) or `S` (multiplex, for simulation and
/// tests).
#[derive(Clone, Copy, PartialEq, Eq)]
pub(crate) enum Dir {
    Demux,
    Mux,
}

/// The arithmetic the kernels are generic over.
pub(crate) trait Real:
    FftNum + Copy + std::ops::Add<Output = Self> + std::ops::Sub<Output = Self> + std::ops::Mul<Output = Self>
{
    fn of_f32(x: f32) -> Self;
    fn of_f64(x: f64) -> Self;
    fn to_f32(self) -> f32;
}

impl Real for f32 {
    #[inline(always)]
    fn of_f32(x: f32) -> f32 {
        x
    }
    #[inline(always)]
    fn of_f64(x: f64) -> f32 {
        x as f32
    }
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self
    }
}

impl Real for f64 {
    #[inline(always)]
    fn of_f32(x: f32) -> f64 {
        f64::from(x)
    }
    #[inline(always)]
    fn of_f64(x: f64) -> f64 {
        x
    }
    #[inline(always)]
    fn to_f32(self) -> f32 {
        self as f32
    }
}
