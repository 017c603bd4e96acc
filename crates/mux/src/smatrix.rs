//! S-matrices: the optimal 0/1 multiplexing codes for signal-independent noise.
//!
//! An S-matrix of order `n` (`n ≡ 3 mod 4`) is an `n × n` 0/1 matrix whose rows are the
//! illumination patterns (row = frame, column = source), with
//!
//! ```text
//! every row and column has (n+1)/2 ones,
//! Sᵀ S = (n+1)/4 · (I + J),                J = all-ones matrix,
//! S⁻¹  = 2/(n+1) · (2 Sᵀ − J),
//! singular values (n+1)/2 (once) and √(n+1)/2 (n−1 times), so cond(S) = √(n+1).
//! ```
//!
//! Constructions implemented (all checked in `tests/smatrix.rs` for the structural identity):
//!
//! * **Sylvester**, `n = 2^k − 1`, `1 <= k <= 16`: `S[i][j] = 1` iff `popcount((i+1) & (j+1))` is
//!   odd, i.e. the Sylvester Hadamard matrix `H[a][b] = (−1)^popcount(a & b)` of order `2^k`
//!   without its first row and column, with `+1 → 0`, `−1 → 1`. Symmetric. Demultiplexed by
//!   the fast Walsh–Hadamard transform.
//! * **Paley (quadratic residues)**, `n = p` prime, `p ≡ 3 mod 4`: cyclic, first row
//!   `s_0 = 1`, `s_j = 1` iff `j` is a quadratic non-residue mod `p`; row `i` is the first row
//!   rotated right by `i`: `S[i][j] = s[(j − i) mod n]`. Demultiplexed by FFT circular
//!   convolution.
//! * **Twin prime**, `n = p(p+2)` with `p` and `p+2` prime: cyclic, the complement of the
//!   Stanton–Sprott difference set `D = {x : x ≡ 0 mod (p+2)} ∪ {x : χ_p(x) χ_{p+2}(x) = 1}`
//!   (χ = Legendre symbol, 0 at multiples). Orders 15, 35, 143, 323, 899, 1763, ...
//!
//! [`SMatrix::of_order`] prefers Sylvester, then Paley, then twin prime, where an order has
//! several. An order with no construction is a [`MuxError::NoConstruction`] naming the
//! nearest available orders; [`SMatrix::for_sources`] instead picks the smallest available
//! order `>= sources` and reports the always-off slots it pads with (the dome's 198 LEDs use
//! Paley 199 with one always-off slot).
//!
//! The matrix is never stored densely (a Sylvester matrix is a formula, a cyclic one its first
//! row), so orders in the tens of thousands cost nothing until a dense path asks for
//! [`SMatrix::to_dense`].

use crate::error::MuxError;

/// Largest Sylvester exponent: `n = 2^16 − 1`.
pub const MAX_SYLVESTER_K: u32 = 16;
/// Largest order of the prime-based constructions.
pub const MAX_PRIME_ORDER: usize = 1 << 20;

/// How an S-matrix was built.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Construction {
    /// `n = 2^k − 1` from the Sylvester Hadamard matrix of order `2^k`.
    Sylvester {
        /// The exponent.
        k: u32,
    },
    /// `n = p`, prime, `p ≡ 3 mod 4` (quadratic residues; cyclic).
    Paley {
        /// The prime.
        p: usize,
    },
    /// `n = p(p+2)`, twin primes (cyclic).
    TwinPrime {
        /// The smaller prime.
        p: usize,
    },
}

impl Construction {
    /// Short name: `sylvester`, `paley`, `twin-prime`.
    pub fn name(&self) -> &'static str {
        match self {
            Construction::Sylvester { .. } => "sylvester",
            Construction::Paley { .. } => "paley",
            Construction::TwinPrime { .. } => "twin-prime",
        }
    }

    /// True for the cyclic constructions (every row a rotation of the first).
    pub fn is_cyclic(&self) -> bool {
        !matches!(self, Construction::Sylvester { .. })
    }
}

/// An S-matrix of order `n`: `n` patterns (rows, frames) over `n` sources (columns).
#[derive(Debug, Clone, PartialEq)]
pub struct SMatrix {
    n: usize,
    construction: Construction,
    /// First row of a cyclic construction (0/1); empty for Sylvester.
    first_row: Vec<u8>,
}

/// An S-matrix for a given number of physical sources, with the always-off slots it pads with.
#[derive(Debug, Clone, PartialEq)]
pub struct Padded {
    /// The matrix, of order `sources + padding`.
    pub s: SMatrix,
    /// Physical sources: columns `0..sources`.
    pub sources: usize,
    /// Always-off slots: columns `sources..s.order()` (their demultiplexed images are zero up
    /// to noise, a free consistency check used by fault detection).
    pub padding: usize,
}

impl SMatrix {
    /// The Sylvester-type S-matrix of order `2^k − 1`, `1 <= k <= 16`.
    pub fn sylvester(k: u32) -> Result<SMatrix, MuxError> {
        if !(1..=MAX_SYLVESTER_K).contains(&k) {
            return Err(MuxError::BadParameter {
                construction: "sylvester",
                what: "k",
                value: k.to_string(),
                allowed: format!("1..={MAX_SYLVESTER_K} (orders 1..=65535)"),
            });
        }
        Ok(SMatrix { n: (1usize << k) - 1, construction: Construction::Sylvester { k }, first_row: Vec::new() })
    }

    /// The cyclic quadratic-residue (Paley) S-matrix of prime order `p ≡ 3 mod 4`.
    pub fn paley(p: usize) -> Result<SMatrix, MuxError> {
        if !(p % 4 == 3 && is_prime(p) && p <= MAX_PRIME_ORDER) {
            return Err(MuxError::BadParameter {
                construction: "paley",
                what: "p",
                value: p.to_string(),
                allowed: format!("a prime p = 3 mod 4, p <= {MAX_PRIME_ORDER}"),
            });
        }
        let mut row = vec![1u8; p];
        // Quadratic residues get 0; 0 and the non-residues keep 1.
        for x in 1..p {
            row[(x * x) % p] = 0;
        }
        row[0] = 1;
        Ok(SMatrix { n: p, construction: Construction::Paley { p }, first_row: row })
    }

    /// The cyclic twin-prime S-matrix of order `p(p+2)`, `p` and `p+2` odd primes.
    pub fn twin_prime(p: usize) -> Result<SMatrix, MuxError> {
        let n = p.saturating_mul(p + 2);
        if !(p >= 3 && is_prime(p) && is_prime(p + 2) && n <= MAX_PRIME_ORDER) {
            return Err(MuxError::BadParameter {
                construction: "twin-prime",
                what: "p",
                value: p.to_string(),
                allowed: format!("p and p+2 both prime, p(p+2) <= {MAX_PRIME_ORDER}"),
            });
        }
        let q = p + 2;
        let (chi_p, chi_q) = (legendre_table(p), legendre_table(q));
        let row = (0..n)
            .map(|x| {
                let in_d = x % q == 0 || chi_p[x % p] * chi_q[x % q] == 1;
                u8::from(!in_d)
            })
            .collect();
        Ok(SMatrix { n, construction: Construction::TwinPrime { p }, first_row: row })
    }

    /// The S-matrix of order `n` (Sylvester, else Paley, else twin prime), or
    /// [`MuxError::NoConstruction`] naming the nearest available orders.
    pub fn of_order(n: usize) -> Result<SMatrix, MuxError> {
        match construction_of(n) {
            Some(Construction::Sylvester { k }) => SMatrix::sylvester(k),
            Some(Construction::Paley { p }) => SMatrix::paley(p),
            Some(Construction::TwinPrime { p }) => SMatrix::twin_prime(p),
            None => {
                let below = (1..n).rev().find(|&m| construction_of(m).is_some());
                let above = (n + 1..=MAX_PRIME_ORDER).find(|&m| construction_of(m).is_some());
                Err(MuxError::NoConstruction { order: n, below, above })
            }
        }
    }

    /// The smallest available S-matrix with at least `sources` columns; the extra columns
    /// are always-off slots.
    pub fn for_sources(sources: usize) -> Result<Padded, MuxError> {
        if sources == 0 || sources > MAX_PRIME_ORDER {
            return Err(MuxError::BadParameter {
                construction: "for_sources",
                what: "sources",
                value: sources.to_string(),
                allowed: format!("1..={MAX_PRIME_ORDER}"),
            });
        }
        let n = (sources..=MAX_PRIME_ORDER)
            .find(|&m| construction_of(m).is_some())
            .ok_or(MuxError::NoConstruction { order: sources, below: None, above: None })?;
        Ok(Padded { s: SMatrix::of_order(n)?, sources, padding: n - sources })
    }

    /// The order `n`.
    pub fn order(&self) -> usize {
        self.n
    }

    /// How it was built.
    pub fn construction(&self) -> Construction {
        self.construction
    }

    /// Lit sources per pattern (and patterns per source): `(n+1)/2`.
    pub fn lit_per_pattern(&self) -> usize {
        self.n.div_ceil(2)
    }

    /// The first row of a cyclic construction, `None` for Sylvester.
    pub fn first_row(&self) -> Option<&[u8]> {
        if self.construction.is_cyclic() {
            Some(&self.first_row)
        } else {
            None
        }
    }

    /// Entry `(frame, source)`: 1 if the source is lit in that pattern.
    #[inline]
    pub fn get(&self, frame: usize, source: usize) -> u8 {
        debug_assert!(frame < self.n && source < self.n);
        match self.construction {
            Construction::Sylvester { .. } => (((frame + 1) & (source + 1)).count_ones() & 1) as u8,
            _ => self.first_row[(source + self.n - frame) % self.n],
        }
    }

    /// Pattern `frame`: the lit state of every source.
    pub fn row(&self, frame: usize) -> Vec<u8> {
        (0..self.n).map(|j| self.get(frame, j)).collect()
    }

    /// The whole matrix, row-major (`n²` bytes).
    pub fn to_dense(&self) -> Vec<u8> {
        (0..self.n).flat_map(|i| self.row(i)).collect()
    }

    /// The closed-form inverse `S⁻¹ = 2/(n+1) (2 Sᵀ − J)`, row-major f64.
    pub fn inverse_dense(&self) -> Vec<f64> {
        let n = self.n;
        let c = 2.0 / (n as f64 + 1.0);
        let mut out = vec![0.0; n * n];
        for i in 0..n {
            for j in 0..n {
                out[i * n + j] = c * (2.0 * f64::from(self.get(j, i)) - 1.0);
            }
        }
        out
    }

    /// `m = S x` (multiplexing a single-source vector), dense, f64: the reference the fast
    /// paths are tested against.
    pub fn apply(&self, x: &[f64]) -> Vec<f64> {
        assert_eq!(x.len(), self.n, "apply: vector of length {} for order {}", x.len(), self.n);
        (0..self.n).map(|i| (0..self.n).filter(|&j| self.get(i, j) == 1).map(|j| x[j]).sum()).collect()
    }

    /// `x = S⁻¹ m`, dense closed form, f64 (`O(n²)`).
    pub fn solve(&self, m: &[f64]) -> Vec<f64> {
        assert_eq!(m.len(), self.n, "solve: vector of length {} for order {}", m.len(), self.n);
        let total: f64 = m.iter().sum();
        let c = 2.0 / (self.n as f64 + 1.0);
        (0..self.n)
            .map(|j| {
                let stm: f64 = (0..self.n).filter(|&i| self.get(i, j) == 1).map(|i| m[i]).sum();
                c * (2.0 * stm - total)
            })
            .collect()
    }

    /// The SNR gain over single-source capture for signal-independent noise:
    /// `(n+1) / (2 √n)` (`crate::noise::s_matrix_gain` at `ρ = 0`; with photon noise see
    /// there).
    pub fn gain_read_noise(&self) -> f64 {
        let n = self.n as f64;
        (n + 1.0) / (2.0 * n.sqrt())
    }
}

/// The construction [`SMatrix::of_order`] uses for order `n`, if any.
pub fn construction_of(n: usize) -> Option<Construction> {
    if n >= 1 && (n + 1).is_power_of_two() {
        let k = (n + 1).trailing_zeros();
        if k <= MAX_SYLVESTER_K {
            return Some(Construction::Sylvester { k });
        }
    }
    if n > MAX_PRIME_ORDER {
        return None;
    }
    if n % 4 == 3 && is_prime(n) {
        return Some(Construction::Paley { p: n });
    }
    // n = p(p+2) = (p+1)² − 1.
    let r = ((n + 1) as f64).sqrt().round() as usize;
    if r >= 4 && r * r == n + 1 && is_prime(r - 1) && is_prime(r + 1) {
        return Some(Construction::TwinPrime { p: r - 1 });
    }
    None
}

/// Every order `<= max` with a construction, ascending.
pub fn available_orders(max: usize) -> Vec<usize> {
    (1..=max.min(MAX_PRIME_ORDER)).filter(|&n| construction_of(n).is_some()).collect()
}

/// Deterministic trial division (the orders are at most about a million).
pub fn is_prime(n: usize) -> bool {
    if n < 2 {
        return false;
    }
    if n % 2 == 0 {
        return n == 2;
    }
    let mut d = 3;
    while d * d <= n {
        if n % d == 0 {
            return false;
        }
        d += 2;
    }
    true
}

/// Legendre symbol χ(x) mod prime `p` for x in 0..p: 0, +1 (residue) or −1.
fn legendre_table(p: usize) -> Vec<i8> {
    let mut t = vec![-1i8; p];
    t[0] = 0;
    for x in 1..p {
        t[(x * x) % p] = 1;
    }
    t
}
