//! Colour spaces: CIE XYZ, CIE L*a*b*, linear sRGB (Rec. 709 primaries, D65 white), Bradford
//! chromatic adaptation and the sRGB transfer function.
//!
//! Conventions: XYZ is scaled so that the reference white has Y = 1 (not 100). The project's
//! output space is **linear sRGB, D65**: a perfect white reflector is (1, 1, 1), whose XYZ is
//! [`d65_white`]. Colour differences are computed in L*a*b* relative to that white
//! ([`linear_srgb_to_lab`]).

use nalgebra::{Matrix3, Vector3};

/// A 3x3 matrix, row-major: `m[row][column]`.
pub type Mat3 = [[f64; 3]; 3];

/// sRGB / Rec. 709 primaries, CIE 1931 xy chromaticities (IEC 61966-2-1).
pub const SRGB_PRIMARIES_XY: [[f64; 2]; 3] = [[0.64, 0.33], [0.30, 0.60], [0.15, 0.06]];
/// D65 white point chromaticity as sRGB defines it (4 decimals).
pub const D65_XY: [f64; 2] = [0.3127, 0.3290];

/// Bradford cone-response matrix (Lam 1985, as used by ICC and Lindbloom).
const BRADFORD: Mat3 = [[0.8951, 0.2664, -0.1614], [-0.7502, 1.7135, 0.0367], [0.0389, -0.0685, 1.0296]];

fn m3(a: &Mat3) -> Matrix3<f64> {
    Matrix3::from_fn(|r, c| a[r][c])
}

fn arr(m: &Matrix3<f64>) -> Mat3 {
    std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)]))
}

/// XYZ (Y = 1) of a chromaticity `xy` (y must be non-zero).
pub fn xy_to_xyz(xy: [f64; 2]) -> [f64; 3] {
    [xy[0] / xy[1], 1.0, (1.0 - xy[0] - xy[1]) / xy[1]]
}

/// XYZ of the D65 white of linear sRGB (Y = 1): the XYZ of RGB (1, 1, 1).
pub fn d65_white() -> [f64; 3] {
    xy_to_xyz(D65_XY)
}

fn srgb_to_xyz() -> Matrix3<f64> {
    // Columns are the primaries' XYZ scaled so that their sum is the white: derived, not copied
    // with 4 decimals, so RGB (1, 1, 1) maps to D65 to rounding error.
    let p = Matrix3::from_columns(&SRGB_PRIMARIES_XY.map(|xy| Vector3::from(xy_to_xyz(xy))));
    let w = Vector3::from(d65_white());
    let s = p.try_inverse().expect("sRGB primaries are linearly independent") * w;
    p * Matrix3::from_diagonal(&s)
}

/// The linear-sRGB-to-XYZ matrix (D65, Y_white = 1), derived from primaries and white.
pub fn srgb_to_xyz_matrix() -> Mat3 {
    arr(&srgb_to_xyz())
}

/// The XYZ-to-linear-sRGB matrix (inverse of [`srgb_to_xyz_matrix`]).
pub fn xyz_to_srgb_matrix() -> Mat3 {
    arr(&srgb_to_xyz().try_inverse().expect("invertible"))
}

/// Bradford chromatic adaptation matrix taking colours seen under white `src` to the
/// corresponding colours under white `dst` (both XYZ): `M_B⁻¹ diag(M_B dst / M_B src) M_B`.
pub fn bradford(src: [f64; 3], dst: [f64; 3]) -> Mat3 {
    let b = m3(&BRADFORD);
    let s = b * Vector3::from(src);
    let d = b * Vector3::from(dst);
    let scale = Matrix3::from_diagonal(&d.component_div(&s));
    arr(&(b.try_inverse().expect("Bradford matrix is invertible") * scale * b))
}

/// `m · v`.
pub fn mat3_apply(m: &Mat3, v: [f64; 3]) -> [f64; 3] {
    std::array::from_fn(|r| m[r][0] * v[0] + m[r][1] * v[1] + m[r][2] * v[2])
}

/// `a · b`.
pub fn mat3_mul(a: &Mat3, b: &Mat3) -> Mat3 {
    std::array::from_fn(|r| std::array::from_fn(|c| (0..3).map(|k| a[r][k] * b[k][c]).sum()))
}

/// The sRGB transfer function (IEC 61966-2-1): linear value to encoded value. Not clamped
/// (negative input gives negative output); callers clamp to [0, 1] before quantising.
pub fn srgb_encode(linear: f64) -> f64 {
    if linear <= 0.003_130_8 {
        12.92 * linear
    } else {
        1.055 * linear.powf(1.0 / 2.4) - 0.055
    }
}

/// Inverse of [`srgb_encode`].
pub fn srgb_decode(encoded: f64) -> f64 {
    if encoded <= 0.040_45 {
        encoded / 12.92
    } else {
        ((encoded + 0.055) / 1.055).powf(2.4)
    }
}

/// CIE ε = (6/29)³: below it, L*a*b*'s cube root is replaced by a line.
const LAB_EPS: f64 = 216.0 / 24389.0;
/// CIE κ = (29/3)³.
const LAB_KAPPA: f64 = 24389.0 / 27.0;

/// CIE XYZ to L*a*b* relative to the white `white` (XYZ, normally Y = 1). Exact CIE
/// constants (ε = 216/24389, κ = 24389/27), so the two branches meet continuously. Negative
/// XYZ (noise on black) stays finite: the linear branch is used below ε.
pub fn xyz_to_lab(xyz: [f64; 3], white: [f64; 3]) -> [f64; 3] {
    let f = |t: f64| if t > LAB_EPS { t.cbrt() } else { (LAB_KAPPA * t + 16.0) / 116.0 };
    let [fx, fy, fz] = [0, 1, 2].map(|i| f(xyz[i] / white[i]));
    [116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)]
}

/// CIE L*a*b* to XYZ relative to the white `white` (inverse of [`xyz_to_lab`]).
pub fn lab_to_xyz(lab: [f64; 3], white: [f64; 3]) -> [f64; 3] {
    let fy = (lab[0] + 16.0) / 116.0;
    let fx = fy + lab[1] / 500.0;
    let fz = fy - lab[2] / 200.0;
    let inv = |f: f64| if f * f * f > LAB_EPS { f * f * f } else { (116.0 * f - 16.0) / LAB_KAPPA };
    let y = if lab[0] > LAB_KAPPA * LAB_EPS { fy * fy * fy } else { lab[0] / LAB_KAPPA };
    [inv(fx) * white[0], y * white[1], inv(fz) * white[2]]
}

/// Linear sRGB (D65) to XYZ (Y_white = 1).
pub fn linear_srgb_to_xyz(rgb: [f64; 3]) -> [f64; 3] {
    mat3_apply(&srgb_to_xyz_matrix(), rgb)
}

/// XYZ (Y_white = 1, D65-relative) to linear sRGB.
pub fn xyz_to_linear_srgb(xyz: [f64; 3]) -> [f64; 3] {
    mat3_apply(&xyz_to_srgb_matrix(), xyz)
}

/// L*a*b* of a linear sRGB triple, relative to the space's D65 white (so (1, 1, 1) is
/// L* = 100, a* = b* = 0).
pub fn linear_srgb_to_lab(rgb: [f64; 3]) -> [f64; 3] {
    xyz_to_lab(linear_srgb_to_xyz(rgb), d65_white())
}

/// Linear sRGB of an L*a*b* triple (D65 white); inverse of [`linear_srgb_to_lab`].
pub fn lab_to_linear_srgb(lab: [f64; 3]) -> [f64; 3] {
    xyz_to_linear_srgb(lab_to_xyz(lab, d65_white()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_matrix_matches_the_standard_and_white_is_d65() {
        // IEC 61966-2-1 prints the matrix to 4 decimals.
        let m = xyz_to_srgb_matrix();
        let std = [[3.2406, -1.5372, -0.4986], [-0.9689, 1.8758, 0.0415], [0.0557, -0.2040, 1.0570]];
        for r in 0..3 {
            for c in 0..3 {
                assert!((m[r][c] - std[r][c]).abs() < 6e-4, "{r}{c}: {}", m[r][c]);
            }
        }
        let w = linear_srgb_to_xyz([1.0; 3]);
        let d = d65_white();
        assert!((0..3).all(|i| (w[i] - d[i]).abs() < 1e-14), "{w:?}");
        let lab = linear_srgb_to_lab([1.0; 3]);
        assert!((lab[0] - 100.0).abs() < 1e-12 && lab[1].abs() < 1e-12 && lab[2].abs() < 1e-12);
        let back = xyz_to_linear_srgb(linear_srgb_to_xyz([0.2, 0.5, 0.9]));
        assert!((0..3).all(|i| (back[i] - [0.2, 0.5, 0.9][i]).abs() < 1e-14));
    }

    #[test]
    fn transfer_function_round_trips_and_matches_known_values() {
        for i in 0..=1000 {
            let x = i as f64 / 1000.0;
            assert!((srgb_decode(srgb_encode(x)) - x).abs() < 1e-12);
        }
        assert!((srgb_encode(1.0) - 1.0).abs() < 1e-12);
        // 18 % grey encodes to 0.4614 (117.6 / 255).
        assert!((srgb_encode(0.18) - 0.461_356).abs() < 1e-6);
        // The two branches nearly meet at the breakpoint (the standard's constants are rounded).
        assert!((srgb_encode(0.003_130_8) - srgb_encode(0.003_130_800_1)).abs() < 1e-7);
    }

    #[test]
    fn lab_round_trips_on_both_branches() {
        let white = d65_white();
        for xyz in [[0.2, 0.3, 0.1], [0.001, 0.002, 0.003], [0.9, 1.0, 1.05], [-0.001, 0.0005, 0.0]] {
            let back = lab_to_xyz(xyz_to_lab(xyz, white), white);
            assert!((0..3).all(|i| (back[i] - xyz[i]).abs() < 1e-12), "{xyz:?} {back:?}");
        }
        // Middle grey Y = 0.18 has L* = 49.496 (CIE formula, independent hand computation).
        let l = xyz_to_lab([0.18 * white[0], 0.18, 0.18 * white[2]], white);
        assert!((l[0] - 49.496_1).abs() < 1e-3 && l[1].abs() < 1e-12, "{l:?}");
    }

    #[test]
    fn bradford_matches_published_d50_to_d65() {
        // Lindbloom's Bradford D50 -> D65 matrix (ASTM E308 whites).
        let m = bradford([0.96422, 1.0, 0.82521], [0.95047, 1.0, 1.08883]);
        let ref_m = [
            [0.9555766, -0.0230393, 0.0631636],
            [-0.0282895, 1.0099416, 0.0210077],
            [0.0122982, -0.0204830, 1.3299098],
        ];
        for r in 0..3 {
            for c in 0..3 {
                assert!((m[r][c] - ref_m[r][c]).abs() < 1e-6, "{r}{c}");
            }
        }
        // Maps the source white onto the destination white exactly.
        let w = mat3_apply(&m, [0.96422, 1.0, 0.82521]);
        assert!((0..3).all(|i| (w[i] - [0.95047, 1.0, 1.08883][i]).abs() < 1e-12));
    }
}
