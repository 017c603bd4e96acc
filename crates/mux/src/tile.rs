//! Pattern-major stacks of frames and their pixel tiles.
//!
//! Captures arrive in pattern order, one image per pattern, so a stack of `rows` frames of
//! `cols` values each (pixels × channels, any order) is stored **pattern-major**: value
//! `(frame r, column c)` at `data[r * cols + c]`. Demultiplexing is independent per column, so
//! the work is cut into tiles of `tile` consecutive columns: a tile is `rows` short runs of
//! `tile` contiguous values, `rows × tile` values in all, small enough to stay in cache
//! through all the passes of a transform. Each thread owns a contiguous block of columns and
//! its own scratch, so results do not depend on the number of threads.

use rayon::prelude::*;

/// How many threads a routine may use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Par {
    /// The calling thread only.
    #[default]
    Seq,
    /// Split into this many column blocks on rayon's current pool (0 = the pool's size).
    Rayon(usize),
}

impl Par {
    /// Number of column blocks (= per-thread scratches) this setting uses.
    pub fn blocks(&self) -> usize {
        match *self {
            Par::Seq => 1,
            Par::Rayon(0) => rayon::current_num_threads().max(1),
            Par::Rayon(t) => t,
        }
    }
}

/// Checks a pattern-major buffer's length.
pub(crate) fn check_shape(
    what: &'static str,
    data_len: usize,
    rows: usize,
    cols: usize,
) -> Result<(), crate::MuxError> {
    let expected = rows.saturating_mul(cols);
    if data_len != expected {
        return Err(crate::MuxError::Shape {
            what,
            len: data_len,
            expected,
            shape: format!("{rows} frames x {cols} columns, pattern-major"),
        });
    }
    Ok(())
}

/// Runs `f(tile_rows, scratch)` on every tile of `tile` columns of the pattern-major
/// `data` (`rows × cols`); `tile_rows[r]` is frame `r`'s run of the tile. Column blocks are
/// processed in parallel, one scratch each (`scratches.len()` blocks).
pub(crate) fn for_each_tile<S, F>(data: &mut [f32], rows: usize, cols: usize, tile: usize, scratches: &mut [S], f: F)
where
    S: Send,
    F: Fn(&mut [&mut [f32]], &mut S) + Sync,
{
    if rows == 0 || cols == 0 {
        return;
    }
    let tile = tile.max(1);
    let nb = scratches.len().max(1).min(cols.div_ceil(tile));
    // Block width: a whole number of tiles.
    let width = cols.div_ceil(nb).div_ceil(tile) * tile;
    let mut blocks: Vec<Vec<&mut [f32]>> = (0..nb).map(|_| Vec::with_capacity(rows)).collect();
    for row in data.chunks_mut(cols) {
        let mut rest = row;
        for b in blocks.iter_mut() {
            let w = width.min(rest.len());
            let (head, tail) = rest.split_at_mut(w);
            b.push(head);
            rest = tail;
        }
    }
    let run = |(mut block, scratch): (Vec<&mut [f32]>, &mut S)| {
        let bw = block.first().map_or(0, |r| r.len());
        let mut t0 = 0;
        while t0 < bw {
            let t1 = (t0 + tile).min(bw);
            let mut tile_rows: Vec<&mut [f32]> = block.iter_mut().map(|r| &mut r[t0..t1]).collect();
            f(&mut tile_rows, scratch);
            t0 = t1;
        }
    };
    if nb == 1 {
        blocks.into_iter().zip(scratches.iter_mut()).for_each(run);
    } else {
        blocks.into_par_iter().zip(scratches.par_iter_mut()).for_each(run);
    }
}

/// One thread's column block of an input and an output stack: the rows' runs.
type IoBlock<'a, 'b> = (Vec<&'a [f32]>, Vec<&'b mut [f32]>);

/// Like [`for_each_tile`] with a read-only input stack and a separate output stack
/// (`out_rows × cols`).
#[allow(clippy::too_many_arguments)]
pub(crate) fn for_each_tile_io<S, F>(
    input: &[f32],
    rows: usize,
    out: &mut [f32],
    out_rows: usize,
    cols: usize,
    tile: usize,
    scratches: &mut [S],
    f: F,
) where
    S: Send,
    F: Fn(&[&[f32]], &mut [&mut [f32]], &mut S) + Sync,
{
    if rows == 0 || cols == 0 || out_rows == 0 {
        return;
    }
    let tile = tile.max(1);
    let nb = scratches.len().max(1).min(cols.div_ceil(tile));
    let width = cols.div_ceil(nb).div_ceil(tile) * tile;
    let mut blocks: Vec<IoBlock> = (0..nb).map(|_| (Vec::with_capacity(rows), Vec::with_capacity(out_rows))).collect();
    for row in input.chunks(cols) {
        let mut rest = row;
        for b in blocks.iter_mut() {
            let w = width.min(rest.len());
            let (head, tail) = rest.split_at(w);
            b.0.push(head);
            rest = tail;
        }
    }
    for row in out.chunks_mut(cols) {
        let mut rest = row;
        for b in blocks.iter_mut() {
            let w = width.min(rest.len());
            let (head, tail) = rest.split_at_mut(w);
            b.1.push(head);
            rest = tail;
        }
    }
    let run = |((ins, mut outs), scratch): (IoBlock, &mut S)| {
        let bw = ins.first().map_or(0, |r| r.len());
        let mut t0 = 0;
        while t0 < bw {
            let t1 = (t0 + tile).min(bw);
            let tin: Vec<&[f32]> = ins.iter().map(|r| &r[t0..t1]).collect();
            let mut tout: Vec<&mut [f32]> = outs.iter_mut().map(|r| &mut r[t0..t1]).collect();
            f(&tin, &mut tout, scratch);
            t0 = t1;
        }
    };
    if nb == 1 {
        blocks.into_iter().zip(scratches.iter_mut()).for_each(run);
    } else {
        blocks.into_par_iter().zip(scratches.par_iter_mut()).for_each(run);
    }
}
