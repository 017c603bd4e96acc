//! Step 3: a quad from a dark region, and the quad's module size.

use nalgebra::{Point2, Vector2};

pub(super) fn cross(a: Vector2<f64>, b: Vector2<f64>) -> f64 {
    a.x * b.y - a.y * b.x
}

/// The centre, in full-image pixels, of pixel `p` of the image binned `bin` x `bin`.
pub(super) fn pixel_centre(p: &(u32, u32), bin: usize) -> Point2<f64> {
    let (s, o) = (bin as f64, 0.5 * (bin as f64 - 1.0));
    Point2::new(p.0 as f64 * s + o, p.1 as f64 * s + o)
}

/// Quad from a region's extreme pixels (of the image binned `bin` x `bin`), in full-image
/// pixels, in clockwise order on screen (y down).
pub(super) fn initial_quad(pixels: &[(u32, u32)], bin: usize) -> Option<[Point2<f64>; 4]> {
    let n = pixels.len() as f64;
    let pt = |p: &(u32, u32)| pixel_centre(p, bin);
    let c = Point2::from(pixels.iter().fold(Vector2::zeros(), |a, p| a + pt(p).coords) / n);
    let far = |from: Point2<f64>| {
        pixels.iter().map(pt).max_by(|a, b| (a - from).norm_squared().total_cmp(&(b - from).norm_squared()))
    };
    let p0 = far(c)?;
    let p2 = far(p0)?;
    let d = p2 - p0;
    let side = |p: &Point2<f64>| cross(d, p - p0);
    let p1 = pixels.iter().map(pt).max_by(|a, b| side(a).total_cmp(&side(b)))?;
    let p3 = pixels.iter().map(pt).min_by(|a, b| side(a).total_cmp(&side(b)))?;
    let mut q = [p0, p1, p2, p3];
    let area: f64 = (0..4).map(|i| cross(q[i].coords, q[(i + 1) % 4].coords)).sum();
    if area < 0.0 {
        q.swap(1, 3);
    }
    // Convex and not degenerate: every turn to the same side.
    for i in 0..4 {
        let (a, b, c) = (q[i], q[(i + 1) % 4], q[(i + 2) % 4]);
        if cross(b - a, c - b) <= 0.0 {
            return None;
        }
    }
    // Pixel centres of the dark region lie about half a (binned) pixel inside its edges.
    let centre = Point2::from((q[0].coords + q[1].coords + q[2].coords + q[3].coords) / 4.0);
    let out = 0.5 * bin as f64 + 0.2;
    for p in &mut q {
        let v = *p - centre;
        *p += v.normalize() * out;
    }
    Some(q)
}

/// Module size across edge `i` of quad `q` (corner `i` to `i + 1`): the distance of the two
/// other corners from the edge's line over the module count. (Not the adjacent sides'
/// length: a sheared, foreshortened quad is much thinner across an edge than its sides.)
pub fn module_across(q: &[Point2<f64>; 4], i: usize, modules: f64) -> f64 {
    let (a, b) = (q[i], q[(i + 1) % 4]);
    let d = (b - a).normalize();
    let dist = |p: Point2<f64>| cross(d, p - a).abs();
    0.5 * (dist(q[(i + 2) % 4]) + dist(q[(i + 3) % 4])) / modules
}
