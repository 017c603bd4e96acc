//! Colour differences: CIEDE2000 (Sharma, Wu, Dalal 2005) and CIE76.

/// The intermediate values of a CIEDE2000 evaluation, named as in Sharma, Wu and Dalal (2005),
/// "The CIEDE2000 color-difference formula: implementation notes, supplementary test data and
/// mathematical observations", Color Res. Appl. 30(1). Angles in degrees.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ciede2000Parts {
    /// a′ of the first colour: `(1 + G) a*`.
    pub a1p: f64,
    /// C′ of the first colour.
    pub c1p: f64,
    /// h′ of the first colour, degrees in [0, 360).
    pub h1p: f64,
    /// a′ of the second colour.
    pub a2p: f64,
    /// C′ of the second colour.
    pub c2p: f64,
    /// h′ of the second colour, degrees in [0, 360).
    pub h2p: f64,
    /// Mean hue h̄′, degrees.
    pub hbarp: f64,
    /// Chroma correction factor G.
    pub g: f64,
    /// Hue weighting T.
    pub t: f64,
    /// Lightness weighting S_L.
    pub sl: f64,
    /// Chroma weighting S_C.
    pub sc: f64,
    /// Hue weighting S_H.
    pub sh: f64,
    /// Rotation term R_T.
    pub rt: f64,
    /// The colour difference ΔE00.
    pub de00: f64,
}

/// CIEDE2000 colour difference of two L*a*b* colours with k_L = k_C = k_H = 1.
///
/// Follows Sharma, Wu and Dalal (2005) step by step (see [`delta_e_2000_parts`]); reproduces
/// their 34 test pairs to the published 4 decimals. Symmetric in its arguments.
pub fn delta_e_2000(lab1: [f64; 3], lab2: [f64; 3]) -> f64 {
    delta_e_2000_parts(lab1, lab2).de00
}

/// CIEDE2000 with all intermediate values (for testing against Sharma et al.'s table).
///
/// The one delicate case is a hue difference of exactly 180°: the formula's branches
/// (`|h′1 − h′2| ≤ 180`) must see it as 180 although `atan2` of the two colours can round to
/// 180 ± 1 ulp. We decide "exactly opposite" from the (a′, b) vectors themselves (their cross
/// product is exactly zero and their dot product negative), which is exact for inputs that are
/// exactly antiparallel in floating point, as Sharma's pair 14 is; every other pair takes the
/// branch its computed hue angles give. (With this evaluation order the rounded hues of pair
/// 14 happen to differ by exactly 180.0 anyway; the vector test keeps the branch from
/// depending on how `atan2` and the degree conversion round on a given platform.)
pub fn delta_e_2000_parts(lab1: [f64; 3], lab2: [f64; 3]) -> Ciede2000Parts {
    let [l1, a1, b1] = lab1;
    let [l2, a2, b2] = lab2;
    let pow7 = |x: f64| x.powi(7);
    const P25_7: f64 = 6_103_515_625.0; // 25^7
    let c1 = a1.hypot(b1);
    let c2 = a2.hypot(b2);
    let cbar = 0.5 * (c1 + c2);
    let g = 0.5 * (1.0 - (pow7(cbar) / (pow7(cbar) + P25_7)).sqrt());
    let a1p = (1.0 + g) * a1;
    let a2p = (1.0 + g) * a2;
    let c1p = a1p.hypot(b1);
    let c2p = a2p.hypot(b2);
    let hue = |a: f64, b: f64| {
        if a == 0.0 && b == 0.0 {
            0.0
        } else {
            let h = b.atan2(a).to_degrees();
            if h < 0.0 {
                h + 360.0
            } else {
                h
            }
        }
    };
    let h1p = hue(a1p, b1);
    let h2p = hue(a2p, b2);
    let chroma_zero = c1p * c2p == 0.0;
    // Exactly opposite hues (see the doc comment): |h′1 − h′2| = 180 falls in the "≤ 180" branch.
    let opposite = !chroma_zero && a1p * b2 - b1 * a2p == 0.0 && a1p * a2p + b1 * b2 < 0.0;
    let diff = h2p - h1p;
    let within_180 = opposite || diff.abs() <= 180.0;

    let dlp = l2 - l1;
    let dcp = c2p - c1p;
    let dhp = if chroma_zero {
        0.0
    } else if within_180 {
        diff
    } else if diff > 180.0 {
        diff - 360.0
    } else {
        diff + 360.0
    };
    let dhp_big = 2.0 * (c1p * c2p).sqrt() * (dhp.to_radians() * 0.5).sin();

    let lbarp = 0.5 * (l1 + l2);
    let cbarp = 0.5 * (c1p + c2p);
    let hbarp = if chroma_zero {
        h1p + h2p
    } else if within_180 {
        0.5 * (h1p + h2p)
    } else if h1p + h2p < 360.0 {
        0.5 * (h1p + h2p + 360.0)
    } else {
        0.5 * (h1p + h2p - 360.0)
    };
    let cosd = |deg: f64| deg.to_radians().cos();
    let t = 1.0 - 0.17 * cosd(hbarp - 30.0) + 0.24 * cosd(2.0 * hbarp) + 0.32 * cosd(3.0 * hbarp + 6.0)
        - 0.20 * cosd(4.0 * hbarp - 63.0);
    let dtheta = 30.0 * (-((hbarp - 275.0) / 25.0).powi(2)).exp();
    let rc = 2.0 * (pow7(cbarp) / (pow7(cbarp) + P25_7)).sqrt();
    let l50 = (lbarp - 50.0).powi(2);
    let sl = 1.0 + 0.015 * l50 / (20.0 + l50).sqrt();
    let sc = 1.0 + 0.045 * cbarp;
    let sh = 1.0 + 0.015 * cbarp * t;
    let rt = -(2.0 * dtheta).to_radians().sin() * rc;
    let (tl, tc, th) = (dlp / sl, dcp / sc, dhp_big / sh);
    // The sum is non-negative in exact arithmetic (|R_T| < 2); max(0) guards rounding.
    let de00 = (tl * tl + tc * tc + th * th + rt * tc * th).max(0.0).sqrt();
    Ciede2000Parts { a1p, c1p, h1p, a2p, c2p, h2p, hbarp, g, t, sl, sc, sh, rt, de00 }
}

/// CIE 1976 colour difference ΔE*ab: Euclidean distance in L*a*b*.
pub fn delta_e_76(lab1: [f64; 3], lab2: [f64; 3]) -> f64 {
    ((lab1[0] - lab2[0]).powi(2) + (lab1[1] - lab2[1]).powi(2) + (lab1[2] - lab2[2]).powi(2)).sqrt()
}
