//! Demultiplexing paths against the dense f64 closed form: every method and precision, over
//! orders and tile sizes, round trips, thread-count independence, f32 against f64
//! accumulation, and orders up to 2047.

mod common;

use btfrig_mux::{Accumulate, DemuxParams, Demuxer, DenseLayout, Engine, Method, MuxError, Par, SMatrix};

/// Every method that applies to `s`, with both precisions.
fn configs(s: &SMatrix) -> Vec<DemuxParams> {
    let fast = Method::fast_for(s.construction());
    let mut v = Vec::new();
    for method in [fast, Method::Dense(DenseLayout::PatternMajor), Method::Dense(DenseLayout::PixelMajor)] {
        for accumulate in [Accumulate::F32, Accumulate::F64] {
            v.push(DemuxParams { method: Some(method), tile: 0, accumulate, ..Default::default() });
            if method == Method::Fwht {
                // The generic radix-4 passes and the vector path on AVX2 (the default takes
                // AVX-512 where the CPU has it).
                let p = DemuxParams { method: Some(method), tile: 0, accumulate, ..Default::default() };
                v.push(DemuxParams { engine: Engine::Generic, ..p });
                v.push(DemuxParams { engine: Engine::VectorAvx2, ..p });
            }
            if method == Method::Fft {
                // rustfft for the automatic length (the vector transform is the default), the
                // prime length itself and an odd padded length.
                let n = s.order();
                let p = DemuxParams { method: Some(method), tile: 0, accumulate, ..Default::default() };
                v.push(DemuxParams { engine: Engine::Generic, ..p });
                v.push(DemuxParams { fft_len: n, ..p });
                v.push(DemuxParams { fft_len: 2 * n + 1, ..p });
            }
        }
    }
    v
}

/// Largest |got − want| over the stack, relative to the largest |want|.
fn rel_err(got: &[f32], want: &[f64]) -> f64 {
    let scale = want.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-300);
    got.iter().zip(want).map(|(g, w)| (f64::from(*g) - w).abs()).fold(0.0, f64::max) / scale
}

/// The dense f64 reference: column by column `S⁻¹ m` (or `S x`).
fn reference(s: &SMatrix, data: &[f32], cols: usize, demux: bool) -> Vec<f64> {
    let n = s.order();
    let mut out = vec![0.0; n * cols];
    for c in 0..cols {
        let v: Vec<f64> = (0..n).map(|r| f64::from(data[r * cols + c])).collect();
        let y = if demux { s.solve(&v) } else { s.apply(&v) };
        for r in 0..n {
            out[r * cols + c] = y[r];
        }
    }
    out
}

#[test]
fn every_method_matches_the_closed_form_over_orders_and_tiles() {
    // Orders of each construction; 37 columns: not a multiple of any tile, odd for the FFT pairs.
    let cols = 37;
    for (seed, n) in [3usize, 7, 11, 15, 19, 31, 35, 63, 83, 127, 143, 151, 199, 255].into_iter().enumerate() {
        let s = SMatrix::of_order(n).unwrap();
        let data = common::uniform(n, cols, 0.0, 100.0, seed as u64);
        let want = reference(&s, &data, cols, true);
        for mut p in configs(&s) {
            for tile in [0, 1, 5, 16] {
                p.tile = tile;
                let d = Demuxer::new(&s, &p).unwrap();
                let got = d.demux(&data, cols).unwrap();
                let err = rel_err(&got, &want);
                // f32 rounding of n-term sums: a few ulps times log2(n) (fast) or √n (dense).
                let tol = match p.accumulate {
                    Accumulate::F32 => 4e-7 * (n as f64).sqrt() * (n as f64).log2().max(1.0),
                    Accumulate::F64 => 1.2e-7,
                };
                assert!(
                    err < tol,
                    "order {n} {} {:?} tile {tile}: rel err {err:e} > {tol:e}",
                    d.method().name(),
                    p.accumulate
                );
            }
        }
    }
}

#[test]
fn multiplex_then_demultiplex_round_trips_and_multiplex_matches_s() {
    let cols = 20;
    for (seed, n) in [7usize, 31, 35, 151, 199, 255].into_iter().enumerate() {
        let s = SMatrix::of_order(n).unwrap();
        let x = common::uniform(n, cols, 0.0, 1.0, 100 + seed as u64);
        let want = reference(&s, &x, cols, false);
        for p in configs(&s) {
            let d = Demuxer::new(&s, &p).unwrap();
            let m = d.multiplex(&x, cols).unwrap();
            assert!(rel_err(&m, &want) < 2e-6, "order {n} {}: S x", d.method().name());
            let back = d.demux(&m, cols).unwrap();
            let x64: Vec<f64> = x.iter().map(|&v| f64::from(v)).collect();
            let err = rel_err(&back, &x64);
            // The f32 rounding of m (about (n+1)/2 times larger than x) comes back amplified
            // by at most cond(S) = √(n+1).
            let tol = 4e-7 * ((n + 1) as f64).sqrt() * (n as f64).log2();
            assert!(err < tol, "order {n} {} {:?}: round trip {err:e}", d.method().name(), p.accumulate);
        }
    }
}

#[test]
fn result_is_the_same_for_any_thread_count() {
    for n in [63usize, 151] {
        let s = SMatrix::of_order(n).unwrap();
        let cols = 1000;
        let data = common::uniform(n, cols, 0.0, 1.0, 7);
        let d = Demuxer::new(&s, &DemuxParams { tile: 32, ..Default::default() }).unwrap();
        let seq = d.demux(&data, cols).unwrap();
        for par in [Par::Rayon(2), Par::Rayon(3), Par::Rayon(0)] {
            let mut v = data.clone();
            let mut sc = d.scratch(par);
            d.demux_in_place(&mut v, cols, &mut sc, par).unwrap();
            assert_eq!(v, seq, "order {n} {par:?}");
        }
    }
}

#[test]
fn fast_methods_refuse_the_wrong_construction_and_shapes_are_checked() {
    let p = SMatrix::paley(151).unwrap();
    let e = Demuxer::new(&p, &DemuxParams { method: Some(Method::Fwht), ..Default::default() }).unwrap_err();
    assert!(matches!(e, MuxError::MethodUnsupported { method: "fwht", order: 151, .. }), "{e}");
    let sy = SMatrix::sylvester(8).unwrap();
    let e = Demuxer::new(&sy, &DemuxParams { method: Some(Method::Fft), ..Default::default() }).unwrap_err();
    assert!(e.to_string().contains("cyclic"), "{e}");
    let d = Demuxer::new(&sy, &DemuxParams::default()).unwrap();
    let e = Demuxer::new(&p, &DemuxParams { fft_len: 200, ..Default::default() }).unwrap_err();
    assert!(e.to_string().contains("at least 2n - 1 = 301"), "{e}");
    assert_eq!(btfrig_mux::demux::fft_len(151, 0), 150);
    assert_eq!(btfrig_mux::demux::fft_len(199, 0), 198, "198 = 2 9 11: radices of the vector transform");
    assert_eq!(btfrig_mux::demux::fft_len(1019, 0), 2048, "1018 = 2 509: padded");
    assert_eq!(btfrig_mux::demux::padded_len(151), 320);
    assert_eq!(btfrig_mux::demux::padded_len(199), 400);
    assert_eq!(btfrig_mux::demux::fft_len(15, 0), 15);
    let e = d.demux(&[0.0; 255 * 3 + 1], 3).unwrap_err();
    assert!(e.to_string().contains("766 values, expected 765"), "{e}");
    // Zero columns is fine.
    assert!(d.demux(&[], 0).unwrap().is_empty());
}

/// Numerical stress: large orders, f32 against f64 accumulation, against the f64 closed form.
#[test]
fn large_orders_f32_against_f64_accumulation() {
    let cols = 8;
    for (seed, s) in [
        SMatrix::sylvester(10).unwrap(),
        SMatrix::sylvester(11).unwrap(),
        SMatrix::sylvester(12).unwrap(),
        SMatrix::paley(1019).unwrap(),
        SMatrix::paley(2039).unwrap(),
        SMatrix::twin_prime(41).unwrap(),
    ]
    .into_iter()
    .enumerate()
    {
        let n = s.order();
        let data = common::uniform(n, cols, 0.0, 1000.0, 50 + seed as u64);
        let want = reference(&s, &data, cols, true);
        let mut errs = Vec::new();
        for acc in [Accumulate::F32, Accumulate::F64] {
            let d = Demuxer::new(&s, &DemuxParams { accumulate: acc, ..Default::default() }).unwrap();
            let got = d.demux(&data, cols).unwrap();
            assert!(got.iter().all(|v| v.is_finite()));
            errs.push(rel_err(&got, &want));
        }
        let (e32, e64) = (errs[0], errs[1]);
        let log = (n as f64).log2();
        // f64 accumulation: one rounding to f32 at the end. f32: grows like log2(n) (FWHT) or
        // √n (FFT of a prime length via Rader/Bluestein).
        assert!(e64 < 1.2e-7, "order {n}: f64 accumulation error {e64:e}");
        assert!(e32 < 2e-7 * log * (n as f64).sqrt(), "order {n}: f32 accumulation error {e32:e}");
        eprintln!("order {n} ({}): rel. max error f32 {e32:.2e}, f64 {e64:.2e}", s.construction().name());
    }
}

/// Every FFT length of the cyclic path against the dense f64 closed form, for the domes'
/// Paley orders, a large one, and twin-prime orders: the Rader-domain transform (`n − 1`,
/// Paley only), the zero-padded one, the prime length itself; demultiplex and multiplex, f32
/// and f64 accumulation.
#[test]
fn cyclic_fft_lengths_match_the_dense_f64_closed_form() {
    let cols = 21;
    for (seed, s) in [
        SMatrix::paley(151).unwrap(),
        SMatrix::paley(199).unwrap(),
        SMatrix::paley(1019).unwrap(),
        SMatrix::twin_prime(11).unwrap(),
        SMatrix::twin_prime(17).unwrap(),
    ]
    .into_iter()
    .enumerate()
    {
        let n = s.order();
        let paley = matches!(s.construction(), btfrig_mux::Construction::Paley { .. });
        let data = common::uniform(n, cols, 0.0, 1000.0, 900 + seed as u64);
        let want = reference(&s, &data, cols, true);
        let want_mux = reference(&s, &data, cols, false);
        let mut lens = vec![0, n, btfrig_mux::demux::padded_len(n)];
        if paley {
            lens.push(n - 1);
        }
        for len in lens {
            for (acc, engine) in [
                (Accumulate::F32, Engine::Vector),
                (Accumulate::F32, Engine::VectorAvx2),
                (Accumulate::F32, Engine::Generic),
                (Accumulate::F64, Engine::Vector),
            ] {
                let p = DemuxParams { method: Some(Method::Fft), fft_len: len, accumulate: acc, tile: 0, engine };
                let d = Demuxer::new(&s, &p).unwrap();
                let err = rel_err(&d.demux(&data, cols).unwrap(), &want);
                let err_mux = rel_err(&d.multiplex(&data, cols).unwrap(), &want_mux);
                // f32: the Rader-domain transform (length n − 1) to about an ulp times log2(n);
                // the padded and prime-length ones to the bound of the test above (they mix the
                // column with its ~n/2 times larger sum). f64: one rounding to f32.
                let lg = (n as f64).log2();
                let rader = paley && d.method() == Method::Fft && btfrig_mux::demux::fft_len(n, len) + 1 == n;
                let tol = match acc {
                    Accumulate::F32 if rader => 1e-7 * lg,
                    Accumulate::F32 => 4e-7 * lg * (n as f64).sqrt(),
                    Accumulate::F64 => 1.2e-7,
                };
                assert!(err < tol, "order {n} length {len} {acc:?}: demux rel err {err:e} > {tol:e}");
                assert!(err_mux < tol, "order {n} length {len} {acc:?}: mux rel err {err_mux:e} > {tol:e}");
                eprintln!(
                    "order {n} fft length {len} {acc:?} {engine:?}: rel. max error demux {err:.2e}, mux {err_mux:.2e}"
                );
            }
        }
    }
    // The Rader length is for prime orders only.
    let tp = SMatrix::twin_prime(11).unwrap();
    let e =
        Demuxer::new(&tp, &DemuxParams { method: Some(Method::Fft), fft_len: 142, ..Default::default() }).unwrap_err();
    assert!(e.to_string().contains("at least 2n - 1"), "{e}");
}
