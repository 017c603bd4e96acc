//! rustfft f32 time per transform for lengths near the cyclic orders' (batch of 16, in L1,
//! on-CPU time of this thread): `cargo run --release -p btfrig-mux --example fft_lengths`.
use rustfft::num_complex::Complex;
use rustfft::FftPlanner;

fn cpu_ns() -> u64 {
    std::fs::read_to_string("/proc/thread-self/schedstat").unwrap().split_whitespace().next().unwrap().parse().unwrap()
}

fn main() {
    let lens: Vec<usize> = std::env::args()
        .nth(1)
        .map_or("150,151,160,192,198,199,200,256,300,320,384,396,400,512".into(), |s| s)
        .split(',')
        .map(|s| s.parse().unwrap())
        .collect();
    let batch = 16;
    for len in lens {
        let mut planner = FftPlanner::<f32>::new();
        let f = planner.plan_fft_forward(len);
        let mut buf: Vec<Complex<f32>> =
            (0..len * batch).map(|i| Complex::new((i % 7) as f32, (i % 3) as f32)).collect();
        let mut scratch = vec![Complex::new(0.0, 0.0); f.get_inplace_scratch_len()];
        let reps = 2000;
        let best = (0..5)
            .map(|_| {
                let t = cpu_ns();
                for _ in 0..reps {
                    f.process_with_scratch(&mut buf, &mut scratch);
                    buf.iter_mut().for_each(|v| *v *= 1.0 / len as f32);
                }
                (cpu_ns() - t) as f64 / (reps * batch) as f64
            })
            .fold(f64::INFINITY, f64::min);
        let flops = 5.0 * len as f64 * (len as f64).log2();
        println!("len {len:4}: {best:7.1} ns per transform ({:.1} GFLOP/s nominal)", flops / best);
    }
}
