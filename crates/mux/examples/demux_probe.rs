//! Quick timing probe of the demultiplexing paths on a smaller stack than `btfrig bench
//! demux` (min of repeats, so load spikes matter less):
//! `cargo run --release -p btfrig-mux --example demux_probe -- 151,199 300000 5 2`
//! (orders, columns, repeats, threads). With threads = 1 the times are the thread's on-CPU
//! time (robust to load; `WALL=1` for wall time).

use std::time::Instant;

/// On-CPU time of the calling thread (ns, /proc/thread-self/schedstat), or wall time when
/// unavailable: with threads = 1 this is robust to other processes taking the cores.
fn cpu_ns() -> Option<u64> {
    std::fs::read_to_string("/proc/thread-self/schedstat").ok()?.split_whitespace().next()?.parse().ok()
}

fn timed<F: FnMut()>(mut f: F) -> f64 {
    let (t, c) = (Instant::now(), cpu_ns());
    f();
    match (c, cpu_ns()) {
        (Some(a), Some(b)) if std::env::var_os("WALL").is_none() => (b - a) as f64 * 1e-6,
        _ => t.elapsed().as_secs_f64() * 1e3,
    }
}

use btfrig_mux::{Accumulate, DemuxParams, Demuxer, DenseLayout, Engine, Method, Par, SMatrix};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let orders: Vec<usize> =
        args.get(1).map_or("151,199".into(), |s| s.clone()).split(',').map(|s| s.parse().unwrap()).collect();
    let cols: usize = args.get(2).map_or(300_000, |s| s.parse().unwrap());
    let reps: usize = args.get(3).map_or(5, |s| s.parse().unwrap());
    let threads: usize = args.get(4).map_or(2, |s| s.parse().unwrap());
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
    let par = if threads == 1 { Par::Seq } else { Par::Rayon(threads) };
    pool.install(|| {
        for n in orders {
            let s = SMatrix::of_order(n).unwrap();
            let mut data: Vec<f32> = (0..n * cols).map(|i| ((i * 2654435761) % 1000) as f32 / 1000.0).collect();
            let pristine = data.clone();
            // Refilled before every run: repeated in-place demultiplexing shrinks the values
            // geometrically into subnormals.
            let time = |d: &Demuxer, data: &mut Vec<f32>| {
                let mut sc = d.scratch(par);
                data.copy_from_slice(&pristine);
                d.demux_in_place(data, cols, &mut sc, par).unwrap();
                (0..reps)
                    .map(|_| {
                        data.copy_from_slice(&pristine);
                        timed(|| d.demux_in_place(data, cols, &mut sc, par).unwrap())
                    })
                    .fold(f64::INFINITY, f64::min)
            };
            let k = std::hint::black_box(1.0f32);
            use rayon::prelude::*;
            let floor = (0..reps)
                .map(|_| timed(|| data.par_chunks_mut(1 << 16).for_each(|c| c.iter_mut().for_each(|v| *v *= k))))
                .fold(f64::INFINITY, f64::min);
            println!("order {n}: {cols} columns, floor {floor:.1} ms");
            let mut configs: Vec<(String, DemuxParams)> = Vec::new();
            let fast = Method::fast_for(s.construction());
            for tile in [256, 1024, 1 << 15] {
                configs.push((format!("fast tile {tile}"), DemuxParams { method: Some(fast), tile, ..Default::default() }));
            }
            configs.push((
                "fast generic".into(),
                DemuxParams { method: Some(fast), engine: Engine::Generic, ..Default::default() },
            ));
            if fast == Method::Fft {
                let pl = btfrig_mux::demux::padded_len(n);
                configs.push((
                    format!("fft padded {pl}"),
                    DemuxParams { method: Some(fast), fft_len: pl, ..Default::default() },
                ));
                configs.push((
                    "fast f64".into(),
                    DemuxParams { method: Some(fast), accumulate: Accumulate::F64, ..Default::default() },
                ));
            }
            for tile in [256, 1024] {
                configs.push((
                    format!("dense pattern {tile}"),
                    DemuxParams { method: Some(Method::Dense(DenseLayout::PatternMajor)), tile, ..Default::default() },
                ));
            }
            let only = std::env::var("ONLY").ok();
            for (name, p) in configs {
                if only.as_ref().is_some_and(|o| !name.contains(o.as_str())) {
                    continue;
                }
                let d = Demuxer::new(&s, &p).unwrap();
                let ms = time(&d, &mut data);
                println!("  {name:<22} {ms:8.1} ms  {:6.2}x floor", ms / floor);
            }
        }
    });
}
