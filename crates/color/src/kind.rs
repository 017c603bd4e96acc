//! The colour-correction model families ([`ModelKind`]) and their terms: the monomials and
//! roots of camera r, g, b that a model's coefficients weigh (table and reasons in [`crate::model`]).

/// The largest number of terms of any model ([`ModelKind::Polynomial3`]).
pub const MAX_TERMS: usize = 19;

/// A colour-correction model family.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum ModelKind {
    /// 3x3 matrix.
    Linear,
    /// Polynomial of degree 2 without constant (9 terms).
    Polynomial2,
    /// Polynomial of degree 3 without constant (19 terms).
    Polynomial3,
    /// Root-polynomial of degree 2 (6 terms).
    RootPolynomial2,
    /// Root-polynomial of degree 3 (13 terms).
    RootPolynomial3,
}

impl ModelKind {
    /// Every model, simplest first.
    pub const ALL: [ModelKind; 5] = [
        ModelKind::Linear,
        ModelKind::RootPolynomial2,
        ModelKind::RootPolynomial3,
        ModelKind::Polynomial2,
        ModelKind::Polynomial3,
    ];

    /// Short name used in files and on the command line: `linear`, `poly2`, `poly3`,
    /// `rootpoly2`, `rootpoly3`.
    pub const fn name(self) -> &'static str {
        match self {
            ModelKind::Linear => "linear",
            ModelKind::Polynomial2 => "poly2",
            ModelKind::Polynomial3 => "poly3",
            ModelKind::RootPolynomial2 => "rootpoly2",
            ModelKind::RootPolynomial3 => "rootpoly3",
        }
    }

    /// Number of terms (coefficients per output channel).
    pub const fn terms(self) -> usize {
        match self {
            ModelKind::Linear => 3,
            ModelKind::Polynomial2 => 9,
            ModelKind::Polynomial3 => 19,
            ModelKind::RootPolynomial2 => 6,
            ModelKind::RootPolynomial3 => 13,
        }
    }

    /// Names of the terms, in coefficient order.
    pub fn term_names(self) -> &'static [&'static str] {
        const NAMES: [&str; MAX_TERMS] = [
            "r", "g", "b", "r2", "g2", "b2", "rg", "gb", "rb", "r3", "g3", "b3", "rg2", "gb2", "rb2", "gr2", "bg2",
            "br2", "rgb",
        ];
        const ROOT: [&str; 13] = [
            "r",
            "g",
            "b",
            "sqrt(rg)",
            "sqrt(gb)",
            "sqrt(rb)",
            "cbrt(rg2)",
            "cbrt(gb2)",
            "cbrt(rb2)",
            "cbrt(gr2)",
            "cbrt(bg2)",
            "cbrt(br2)",
            "cbrt(rgb)",
        ];
        match self {
            ModelKind::Linear | ModelKind::Polynomial2 | ModelKind::Polynomial3 => &NAMES[..self.terms()],
            ModelKind::RootPolynomial2 | ModelKind::RootPolynomial3 => &ROOT[..self.terms()],
        }
    }

    /// Whether `apply(k·rgb) = k·apply(rgb)` for every k > 0.
    pub const fn exposure_invariant(self) -> bool {
        !matches!(self, ModelKind::Polynomial2 | ModelKind::Polynomial3)
    }

    /// Writes the model's terms of `rgb` into `out[..self.terms()]`.
    #[inline]
    pub fn eval_terms(self, rgb: [f64; 3], out: &mut [f64; MAX_TERMS]) {
        match self {
            ModelKind::Linear => out[..3].copy_from_slice(&rgb),
            ModelKind::Polynomial2 => out[..9].copy_from_slice(&terms_poly2(rgb)),
            ModelKind::Polynomial3 => out[..19].copy_from_slice(&terms_poly3(rgb)),
            ModelKind::RootPolynomial2 => out[..6].copy_from_slice(&terms_root2(rgb)),
            ModelKind::RootPolynomial3 => out[..13].copy_from_slice(&terms_root3(rgb)),
        }
    }
}

#[inline(always)]
pub(crate) fn terms_linear(rgb: [f64; 3]) -> [f64; 3] {
    rgb
}

#[inline(always)]
pub(crate) fn terms_poly2([r, g, b]: [f64; 3]) -> [f64; 9] {
    [r, g, b, r * r, g * g, b * b, r * g, g * b, r * b]
}

#[inline(always)]
pub(crate) fn terms_poly3([r, g, b]: [f64; 3]) -> [f64; 19] {
    [
        r,
        g,
        b,
        r * r,
        g * g,
        b * b,
        r * g,
        g * b,
        r * b,
        r * r * r,
        g * g * g,
        b * b * b,
        r * g * g,
        g * b * b,
        r * b * b,
        g * r * r,
        b * g * g,
        b * r * r,
        r * g * b,
    ]
}

// Roots of products as products of roots: sgn(xy)·√|xy| = (sgn x·√|x|)(sgn y·√|y|) and
// ∛(xy²) = ∛x·(∛y)², exact identities for reals (negative values included) that need 3 roots
// per pixel instead of up to 10.
#[inline(always)]
pub(crate) fn terms_root2([r, g, b]: [f64; 3]) -> [f64; 6] {
    let [sr, sg, sb] = [signed_sqrt(r), signed_sqrt(g), signed_sqrt(b)];
    [r, g, b, sr * sg, sg * sb, sr * sb]
}

/// Cube root for the per-pixel terms: libm's `cbrt` costs ~50 ns here (it dominated applying
/// `rootpoly3` to a texture). Division-free Newton steps on the inverse cube root
/// `z ← z (4 − a z³)/3` from an exponent-thirding first guess (bit pattern), then
/// `∛a = a z²` and one Halley step `y ← y (y³ + 2a)/(2y³ + a)` for the last bits (tested
/// against `f64::cbrt` to 5e-16 relative). Zero, non-finite and extreme magnitudes (where the
/// bit trick does not hold) go to `f64::cbrt`. Odd like `cbrt`.
#[inline(always)]
pub(crate) fn fast_cbrt(x: f64) -> f64 {
    let a = x.abs();
    if !(1e-300..=1e300).contains(&a) {
        return x.cbrt();
    }
    // Exponent field (e + 1023) -> -e/3 + 1023: 1364 = 1023 + 1023/3.
    let mut z = f64::from_bits((1364u64 << 52) - a.to_bits() / 3);
    for _ in 0..5 {
        z *= (4.0 - a * z * z * z) * (1.0 / 3.0);
    }
    let y = a * z * z;
    let y3 = y * y * y;
    (y * (y3 + 2.0 * a) / (2.0 * y3 + a)).copysign(x)
}

#[inline(always)]
pub(crate) fn terms_root3([r, g, b]: [f64; 3]) -> [f64; 13] {
    let [sr, sg, sb] = [signed_sqrt(r), signed_sqrt(g), signed_sqrt(b)];
    let [cr, cg, cb] = [fast_cbrt(r), fast_cbrt(g), fast_cbrt(b)];
    [
        r,
        g,
        b,
        sr * sg,
        sg * sb,
        sr * sb,
        cr * cg * cg,
        cg * cb * cb,
        cr * cb * cb,
        cg * cr * cr,
        cb * cg * cg,
        cb * cr * cr,
        cr * cg * cb,
    ]
}

/// `sgn(x)·√|x|`: finite for negative products (see `crate::model`'s docs).
#[inline]
fn signed_sqrt(x: f64) -> f64 {
    // Branch-free so the per-pixel loop can vectorise.
    x.abs().sqrt().copysign(x)
}

impl std::fmt::Display for ModelKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fast_cbrt_matches_libm_to_rounding() {
        let mut worst: f64 = 0.0;
        for i in 0..200_000 {
            // Log sweep over 1e-12 .. 1e6, both signs, plus the fall-back ranges.
            let x = 10f64.powf(-12.0 + 18.0 * i as f64 / 200_000.0) * if i % 2 == 0 { 1.0 } else { -1.0 };
            let (a, b) = (fast_cbrt(x), x.cbrt());
            worst = worst.max(((a - b) / b).abs());
        }
        assert!(worst < 5e-16, "{worst:e}");
        for x in [0.0, -0.0, 1e-310, -1e-320, 1e305, f64::INFINITY, f64::NEG_INFINITY, 8.0, -27.0] {
            assert_eq!(fast_cbrt(x), x.cbrt(), "{x}");
        }
        assert!(fast_cbrt(f64::NAN).is_nan());
    }

    /// The product-of-roots evaluation equals the roots of the products as documented.
    #[test]
    fn root_terms_equal_their_definitions_including_negative_values() {
        let direct = |[r, g, b]: [f64; 3]| -> [f64; 13] {
            [
                r,
                g,
                b,
                signed_sqrt(r * g),
                signed_sqrt(g * b),
                signed_sqrt(r * b),
                (r * g * g).cbrt(),
                (g * b * b).cbrt(),
                (r * b * b).cbrt(),
                (g * r * r).cbrt(),
                (b * g * g).cbrt(),
                (b * r * r).cbrt(),
                (r * g * b).cbrt(),
            ]
        };
        for rgb in [[0.3, 0.5, 0.9], [-0.001, 0.02, 0.4], [0.0, 0.7, -0.2], [-0.3, -0.4, -0.5], [1e-9, 2.0, 3.0]] {
            let mut t = [0.0; MAX_TERMS];
            ModelKind::RootPolynomial3.eval_terms(rgb, &mut t);
            for (j, (a, b)) in t.iter().zip(direct(rgb)).enumerate() {
                assert!((a - b).abs() <= 1e-14 * b.abs().max(1e-300), "{rgb:?} term {j}: {a} vs {b}");
            }
            let mut t2 = [0.0; MAX_TERMS];
            ModelKind::RootPolynomial2.eval_terms(rgb, &mut t2);
            assert_eq!(t[..6], t2[..6]);
        }
    }
}
