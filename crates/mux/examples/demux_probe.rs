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

/// Environment variables to set for one config of a sweep.
type EnvSet = Vec<(String, String)>;

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
            let k = std::hint::black_box(1.0f32);
            use rayon::prelude::*;
            let floor_pass = |data: &mut Vec<f32>| {
                timed(|| data.par_chunks_mut(1 << 16).for_each(|c| c.iter_mut().for_each(|v| *v *= k)))
            };
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
            configs.retain(|(name, _)| only.as_ref().is_none_or(|o| name.contains(o.as_str())));
            // SWEEP="A=1,B=2;A=3": every config once per setting of those environment
            // variables (for tuning knobs read from the environment while experimenting).
            let sweep: Vec<EnvSet> = std::env::var("SWEEP")
                .map(|s| {
                    s.split(';')
                        .map(|set| {
                            set.split(',')
                                .filter_map(|kv| kv.split_once('=').map(|(k, v)| (k.to_string(), v.to_string())))
                                .collect()
                        })
                        .collect()
                })
                .unwrap_or_else(|_| vec![Vec::new()]);
            let configs: Vec<(String, DemuxParams, EnvSet)> = configs
                .into_iter()
                .flat_map(|(name, p)| {
                    sweep.iter().map(move |set| {
                        let tag: Vec<String> = set.iter().map(|(k, v)| format!("{k}={v}")).collect();
                        (format!("{name} {}", tag.join(" ")), p, set.clone())
                    })
                })
                .collect();
            // Rounds of (floor pass, every config once), so that drifts of the machine's
            // memory bandwidth hit all of them alike; per config the fastest run and the median
            // of its ratios to the same round's floor pass.
            let plans: Vec<Demuxer> = configs.iter().map(|(_, p, _)| Demuxer::new(&s, p).unwrap()).collect();
            let mut scratches: Vec<_> = plans.iter().map(|d| d.scratch(par)).collect();
            let mut floors = Vec::new();
            let mut times = vec![Vec::new(); plans.len()];
            floor_pass(&mut data);
            for _ in 0..reps {
                for (i, d) in plans.iter().enumerate() {
                    // Refilled before every run: repeated in-place demultiplexing shrinks the
                    // values geometrically into subnormals.
                    data.copy_from_slice(&pristine);
                    // Every variable of the sweep unset, then this config's set.
                    for (k, _) in sweep.iter().flatten() {
                        std::env::remove_var(k);
                    }
                    for (k, v) in &configs[i].2 {
                        std::env::set_var(k, v);
                    }
                    let f = floor_pass(&mut data);
                    if i == 0 {
                        floors.push(f);
                    }
                    let ms = timed(|| d.demux_in_place(&mut data, cols, &mut scratches[i], par).unwrap());
                    times[i].push((ms, ms / f));
                }
            }
            let floor = floors.iter().copied().fold(f64::INFINITY, f64::min);
            println!("order {n}: {cols} columns, floor {floor:.1} ms (fastest of {reps})");
            for ((name, _, _), t) in configs.iter().zip(&mut times) {
                let best = t.iter().map(|x| x.0).fold(f64::INFINITY, f64::min);
                t.sort_by(|a, b| a.1.total_cmp(&b.1));
                let ratio = t[t.len() / 2].1;
                println!("  {name:<32} {best:8.1} ms  {:6.2}x floor (fastest/fastest), {ratio:5.2}x (median of per-round ratios)", best / floor);
            }
        }
    });
}
