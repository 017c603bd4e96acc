//! Gaussian-Laplacian pyramid (Burt & Adelson) of one band: `G_0` the image,
//! `G_{k+1} = ↓2(w * G_k)` with the binomial kernel `w = [1 4 6 4 1] / 16` and mirrored
//! borders (sizes `⌈n/2⌉`), `L_k = G_k − ↑2(G_{k+1})`; the last level is the Gaussian
//! `G_{n−1}` itself. [`collapse`] inverts [`decompose`] exactly (the same expansion is
//! subtracted and added back), for any sizes, so synthesised levels collapse the same way.

/// One level: `width x height`, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Level {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Values.
    pub data: Vec<f64>,
}

const KERNEL: [f64; 5] = [1.0 / 16.0, 4.0 / 16.0, 6.0 / 16.0, 4.0 / 16.0, 1.0 / 16.0];

/// Index `i` mirrored into `0..n` (without repeating the edge: −1 → 1).
fn mirror(i: isize, n: usize) -> usize {
    let n = n as isize;
    if n == 1 {
        return 0;
    }
    let p = 2 * (n - 1);
    let m = i.rem_euclid(p);
    (if m < n { m } else { p - m }) as usize
}

/// Sizes of `levels` levels starting at `width x height`.
pub fn sizes(width: usize, height: usize, levels: usize) -> Vec<(usize, usize)> {
    let mut s = vec![(width, height)];
    while s.len() < levels {
        let (w, h) = s[s.len() - 1];
        s.push((w.div_ceil(2), h.div_ceil(2)));
    }
    s
}

/// Blurs along rows (`dx = 1`) or columns and keeps every `step`-th sample of that axis.
fn blur_axis(l: &Level, along_rows: bool, step: usize) -> Level {
    let (w, h) = (l.width, l.height);
    let (ow, oh) = if along_rows { (w.div_ceil(step), h) } else { (w, h.div_ceil(step)) };
    let mut out = vec![0.0; ow * oh];
    for y in 0..oh {
        for x in 0..ow {
            let mut s = 0.0;
            for (k, c) in KERNEL.iter().enumerate() {
                let d = k as isize - 2;
                s += c * if along_rows {
                    l.data[y * w + mirror((x * step) as isize + d, w)]
                } else {
                    l.data[mirror((y * step) as isize + d, h) * w + x]
                };
            }
            out[y * ow + x] = s;
        }
    }
    Level { width: ow, height: oh, data: out }
}

/// `↓2(w * G)`.
fn reduce(g: &Level) -> Level {
    blur_axis(&blur_axis(g, true, 2), false, 2)
}

/// Upsamples along one axis to `n` samples: zeros between the samples, then `2w *`.
fn expand_axis(l: &Level, along_rows: bool, n: usize) -> Level {
    let (w, h) = (l.width, l.height);
    let (ow, oh) = if along_rows { (n, h) } else { (w, n) };
    let mut out = vec![0.0; ow * oh];
    for y in 0..oh {
        for x in 0..ow {
            let mut s = 0.0;
            for (k, c) in KERNEL.iter().enumerate() {
                let d = k as isize - 2;
                let j = mirror(if along_rows { x } else { y } as isize + d, n);
                if j % 2 == 0 {
                    s += 2.0 * c * if along_rows { l.data[y * w + j / 2] } else { l.data[(j / 2) * w + x] };
                }
            }
            out[y * ow + x] = s;
        }
    }
    Level { width: ow, height: oh, data: out }
}

/// `↑2(G)` to `width x height`.
fn expand(g: &Level, width: usize, height: usize) -> Level {
    expand_axis(&expand_axis(g, true, width), false, height)
}

/// The pyramid of `levels` levels (at least 1): Laplacian levels, then the last Gaussian.
pub fn decompose(band: Level, levels: usize) -> Vec<Level> {
    let mut out = Vec::with_capacity(levels);
    let mut g = band;
    for _ in 1..levels.max(1) {
        let next = reduce(&g);
        let up = expand(&next, g.width, g.height);
        let lap = g.data.iter().zip(&up.data).map(|(a, b)| a - b).collect();
        out.push(Level { width: g.width, height: g.height, data: lap });
        g = next;
    }
    out.push(g);
    out
}

/// The band from its pyramid (sizes as [`sizes`] gives them).
pub fn collapse(levels: &[Level]) -> Level {
    let mut it = levels.iter().rev();
    let mut g = it.next().expect("a pyramid has at least one level").clone();
    for lap in it {
        let up = expand(&g, lap.width, lap.height);
        g = Level {
            width: lap.width,
            height: lap.height,
            data: lap.data.iter().zip(&up.data).map(|(a, b)| a + b).collect(),
        };
    }
    g
}
