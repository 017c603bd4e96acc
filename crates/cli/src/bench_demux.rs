//! `btfrig bench demux`: demultiplexing one view group of S-matrix captures (pattern-major,
//! one f32 image per pattern, `megapixels` × `channels` values each) by the fast transform
//! (FWHT for Sylvester orders, FFT circular convolution for the cyclic ones, f32 and f64
//! accumulation), by the dense closed-form inverse as a matrix product in several tile
//! layouts, by least squares with calibrated intensities (SVD pseudo-inverse applied as a
//! matrix product), and by the high-level demultiplexer (fast path plus fault check); time
//! (median of `repeat`) and error against the known single-light images side by side, with
//! one plain read-and-write pass over the same stack as the memory-bandwidth floor. The
//! machine's memory bandwidth drifts with other load (the pass alone varied 46–128 ms here),
//! so a memory pass runs right before every timed repetition and "x floor" is the median of
//! the ratios to it.
//!
//! The single-light images are a hash of (LED, column) in [0, 1), so nothing but the one
//! stack is held in memory (n × megapixels × channels × 4 bytes: 3.1 GB at n = 255, 1 MP RGB);
//! before each method the stack is refilled with the images and multiplexed by the fast
//! forward transform (not timed).

use btfrig_bench::demux::{load_average, run_order, OrderResult};
use btfrig_mux::SMatrix;

/// `btfrig bench demux`.
#[derive(Debug, clap::Args)]
pub struct BenchDemuxArgs {
    /// S-matrix orders (Sylvester 2^k-1, Paley primes = 3 mod 4, twin primes).
    #[arg(long, value_delimiter = ',', default_values_t = vec![255, 151, 199])]
    pub orders: Vec<usize>,
    /// Megapixels per image.
    #[arg(long, default_value_t = 1.0)]
    pub megapixels: f64,
    /// Channels per pixel.
    #[arg(long, default_value_t = 3)]
    pub channels: usize,
    /// Timed repetitions per method (the median is reported).
    #[arg(long, default_value_t = 5)]
    pub repeat: usize,
    /// Threads (0 = all cores).
    #[arg(long, default_value_t = 0)]
    pub threads: usize,
    /// Skip the dense and least-squares methods (the slow ones).
    #[arg(long)]
    pub fast_only: bool,
    /// Print JSON instead of a table.
    #[arg(long)]
    pub json: bool,
}

/// Runs the benchmark and prints a table (or JSON).
pub fn bench(a: &BenchDemuxArgs) -> anyhow::Result<()> {
    anyhow::ensure!(a.megapixels > 0.0 && a.megapixels <= 16.0, "--megapixels {}: allowed (0, 16]", a.megapixels);
    anyhow::ensure!((1..=4).contains(&a.channels), "--channels {}: allowed 1..=4", a.channels);
    anyhow::ensure!((1..=50).contains(&a.repeat), "--repeat {}: allowed 1..=50", a.repeat);
    anyhow::ensure!(!a.orders.is_empty(), "--orders: give at least one order");
    for &n in &a.orders {
        anyhow::ensure!((3..=4095).contains(&n), "--orders {n}: allowed 3..=4095");
        SMatrix::of_order(n)?;
    }
    let cols = ((a.megapixels * 1e6) as usize).max(1) * a.channels;
    let pool = rayon::ThreadPoolBuilder::new().num_threads(a.threads).build()?;
    let threads = pool.current_num_threads();
    let load_before = load_average();
    let results: Vec<OrderResult> = pool.install(|| {
        a.orders.iter().map(|&n| run_order(n, cols, a.repeat, a.fast_only)).collect::<anyhow::Result<_>>()
    })?;
    if a.json {
        let orders: Vec<serde_json::Value> = results
            .iter()
            .map(|r| {
                let rows: Vec<serde_json::Value> = r
                    .rows
                    .iter()
                    .map(|w| {
                        serde_json::json!({
                            "method": w.method, "layout": w.layout, "accumulate": w.accumulate, "ms": w.ms,
                            "setup_ms": w.setup_ms, "x_floor": w.x_floor, "max_err": w.max_err,
                            "rms_err": w.rms_err, "dense": w.dense,
                        })
                    })
                    .collect();
                serde_json::json!({
                    "n": r.n, "construction": r.construction, "values_per_image": r.cols,
                    "stack_bytes": r.n * r.cols * 4, "floor_ms": r.floor_ms(),
                    "fast_over_best_dense": r.fast().zip(r.best_dense()).map(|(f, d)| d.ms / f.ms),
                    "fast_x_floor": r.fast().map(|f| f.x_floor), "rows": rows,
                })
            })
            .collect();
        let out = serde_json::json!({
            "megapixels": a.megapixels, "channels": a.channels, "threads": threads, "repeat": a.repeat,
            "load_average_before": load_before, "load_average_after": load_average(), "orders": orders,
        });
        println!("{}", serde_json::to_string_pretty(&out)?);
        return Ok(());
    }
    println!(
        "demux benchmark: {} MP x {} channels (f32), pattern-major stack, {threads} threads, median of {}, \
         load average {load_before} before",
        a.megapixels, a.channels, a.repeat
    );
    for r in &results {
        println!();
        println!(
            "order {} ({}): {} values per image, stack {:.2} GB",
            r.n,
            r.construction,
            r.cols,
            (r.n * r.cols * 4) as f64 / 1e9
        );
        println!(
            "{:<14} {:<44} {:>4} {:>10} {:>8} {:>9} {:>10} {:>10}",
            "method", "layout", "acc", "time (ms)", "x floor", "setup ms", "max err", "rms err"
        );
        for w in &r.rows {
            let e = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.2e}"));
            println!(
                "{:<14} {:<44} {:>4} {:>10.1} {:>8.2} {:>9.1} {:>10} {:>10}",
                w.method,
                w.layout,
                w.accumulate,
                w.ms,
                w.x_floor,
                w.setup_ms,
                e(w.max_err),
                e(w.rms_err)
            );
        }
        if let (Some(f), Some(d)) = (r.fast(), r.best_dense()) {
            println!(
                "fast ({}) {:.1} ms: {:.2}x faster than the best dense ({}, {:.1} ms), {:.2}x the memory pass",
                f.method,
                f.ms,
                d.ms / f.ms,
                d.layout,
                d.ms,
                f.x_floor
            );
        }
    }
    println!();
    println!(
        "load average {} after; x floor: median of the ratios to the memory pass run right before each \
         repetition; errors against the known single-light images (values in [0, 1))",
        load_average()
    );
    Ok(())
}
