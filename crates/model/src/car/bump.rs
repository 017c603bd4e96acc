//! The range map's part of the synthesis (seed 002, III): its enlargement to the requested
//! size and the bump-mapping filter, a per-texel shading factor from its normals.
//!
//! The factor is the Lambertian cosine relative to a flat surface's, `max(0, n·l) / l_z`: 1
//! where the relief faces the light as the mean plane does, darker on slopes turned away,
//! 0 in attached shadow. It multiplies the synthesised smooth texture; the analysis divides
//! the measured one by the factor (at most by 1/[`MIN_SHADE`]) so the shading is not counted
//! twice.

/// Shading factors below this are treated as this in the analysis' division (shadowed texels
/// would otherwise blow up).
pub const MIN_SHADE: f64 = 0.25;

/// Unit normals of a `width x height` height map (metres, row 0 at the top, texel side
/// `texel_m`), sample frame (x right, y up): central differences, one-sided at the edges.
pub fn normals(width: usize, height: usize, h: &[f64], texel_m: f64) -> Vec<[f64; 3]> {
    let at = |x: usize, y: usize| h[y * width + x];
    let mut out = Vec::with_capacity(width * height);
    for y in 0..height {
        for x in 0..width {
            let (x0, x1) = (x.saturating_sub(1), (x + 1).min(width - 1));
            let (y0, y1) = (y.saturating_sub(1), (y + 1).min(height - 1));
            let dx = if x1 > x0 { (at(x1, y) - at(x0, y)) / ((x1 - x0) as f64 * texel_m) } else { 0.0 };
            // Rows grow along −y.
            let dy = if y1 > y0 { -(at(x, y1) - at(x, y0)) / ((y1 - y0) as f64 * texel_m) } else { 0.0 };
            let n = (dx * dx + dy * dy + 1.0).sqrt();
            out.push([-dx / n, -dy / n, 1.0 / n]);
        }
    }
    out
}

/// The bump-mapping factor `max(0, n·l) / l_z` of each normal under the light `l`.
pub fn shading(normals: &[[f64; 3]], l: &[f64; 3]) -> Vec<f64> {
    let lz = l[2].max(0.05);
    normals.iter().map(|n| (n[0] * l[0] + n[1] * l[1] + n[2] * l[2]).max(0.0) / lz).collect()
}

/// Index `i` folded into `0..n` by mirrored repetition (edge texel repeated: n → n − 1).
fn fold(i: usize, n: usize) -> usize {
    let m = i % (2 * n);
    if m < n {
        m
    } else {
        2 * n - 1 - m
    }
}

/// A `width x height` map enlarged (or cropped) to `out_w x out_h` by mirrored tiling:
/// continuous across the tile edges, periodic with twice the map's size.
pub fn tile_mirrored(width: usize, height: usize, h: &[f64], out_w: usize, out_h: usize) -> Vec<f64> {
    (0..out_h).flat_map(|y| (0..out_w).map(move |x| h[fold(y, height) * width + fold(x, width)])).collect()
}
