//! Structural properties of every construction: 0/1, (n+1)/2 ones per row and column,
//! Sᵀ S = (n+1)/4 (I + J), cyclic rows for the cyclic constructions, the closed-form inverse,
//! the orders on offer and the error for an order without a construction.

use btfrig_mux::{available_orders, construction_of, Construction, MuxError, SMatrix};

/// Column bitsets (64 sources per word) of `s`, and its rows.
fn bitsets(s: &SMatrix) -> (Vec<Vec<u64>>, Vec<Vec<u8>>) {
    let n = s.order();
    let words = n.div_ceil(64);
    let rows: Vec<Vec<u8>> = (0..n).map(|i| s.row(i)).collect();
    let mut cols = vec![vec![0u64; words]; n];
    for (i, r) in rows.iter().enumerate() {
        for (j, &b) in r.iter().enumerate() {
            assert!(b <= 1, "order {n}: entry ({i}, {j}) = {b}");
            if b == 1 {
                cols[j][i / 64] |= 1 << (i % 64);
            }
        }
    }
    (cols, rows)
}

fn check_structure(s: &SMatrix) {
    let n = s.order();
    let half = n.div_ceil(2);
    let (cols, rows) = bitsets(s);
    for (i, r) in rows.iter().enumerate() {
        let ones = r.iter().filter(|&&b| b == 1).count();
        assert_eq!(ones, half, "order {n} ({:?}): row {i} has {ones} ones", s.construction());
    }
    let quarter = (n + 1) / 4;
    for a in 0..n {
        for b in a..n {
            let dot: u32 = cols[a].iter().zip(&cols[b]).map(|(x, y)| (x & y).count_ones()).sum();
            let want = if a == b { half } else { quarter };
            assert_eq!(dot as usize, want, "order {n} ({:?}): (SᵀS)[{a}][{b}] = {dot}, want {want}", s.construction());
        }
    }
    if let Some(first) = s.first_row() {
        for (i, r) in rows.iter().enumerate() {
            for j in 0..n {
                assert_eq!(r[j], first[(j + n - i) % n], "order {n}: row {i} is not row 0 rotated by {i}");
            }
        }
    }
}

#[test]
fn every_available_order_up_to_300_is_an_s_matrix() {
    let orders = available_orders(300);
    assert!(orders.len() > 30, "{orders:?}");
    for n in orders {
        let s = SMatrix::of_order(n).unwrap();
        assert_eq!(s.order(), n);
        check_structure(&s);
    }
}

#[test]
fn large_orders_of_each_construction_are_s_matrices() {
    for s in [
        SMatrix::sylvester(10).unwrap(), // 1023
        SMatrix::sylvester(11).unwrap(), // 2047
        SMatrix::paley(1019).unwrap(),
        SMatrix::paley(1031).unwrap(),
        SMatrix::twin_prime(29).unwrap(), // 899
        SMatrix::twin_prime(41).unwrap(), // 1763
    ] {
        check_structure(&s);
    }
}

#[test]
fn each_construction_is_available_where_it_should_be() {
    // Both Sylvester and Paley exist for 7, 31, 127: Sylvester is preferred (FWHT).
    for (n, c) in [
        (7, Construction::Sylvester { k: 3 }),
        (31, Construction::Sylvester { k: 5 }),
        (255, Construction::Sylvester { k: 8 }),
        (151, Construction::Paley { p: 151 }),
        (199, Construction::Paley { p: 199 }),
        (83, Construction::Paley { p: 83 }),
        (35, Construction::TwinPrime { p: 5 }),
        (143, Construction::TwinPrime { p: 11 }),
        (323, Construction::TwinPrime { p: 17 }),
    ] {
        assert_eq!(construction_of(n), Some(c), "order {n}");
    }
    // The Paley matrix of 7 and 31 exists too and is a (cyclic) S-matrix.
    check_structure(&SMatrix::paley(7).unwrap());
    check_structure(&SMatrix::paley(31).unwrap());
    // Twin prime 15 = 3 x 5 (the order is also Sylvester).
    check_structure(&SMatrix::twin_prime(3).unwrap());
}

#[test]
fn an_order_without_construction_names_the_nearest_available_ones() {
    // 198 LEDs: no S-matrix of order 198 (not 3 mod 4); 195 = 3 mod 4 but 3·5·13.
    for (n, below, above) in [(198, 191, 199), (195, 191, 199), (4, 3, 7), (87, 83, 103)] {
        match SMatrix::of_order(n) {
            Err(MuxError::NoConstruction { order, below: b, above: a }) => {
                assert_eq!((order, b, a), (n, Some(below), Some(above)), "order {n}");
                let text = MuxError::NoConstruction { order, below: b, above: a }.to_string();
                assert!(text.contains(&format!("below {below}, above {above}")), "{text}");
            }
            other => panic!("order {n}: {other:?}"),
        }
    }
}

#[test]
fn for_sources_pads_with_always_off_slots() {
    let p = SMatrix::for_sources(198).unwrap();
    assert_eq!((p.s.order(), p.sources, p.padding), (199, 198, 1));
    let p = SMatrix::for_sources(151).unwrap();
    assert_eq!((p.s.order(), p.padding), (151, 0));
    let p = SMatrix::for_sources(250).unwrap();
    assert_eq!((p.s.order(), p.padding), (251, 1)); // Paley 251
    assert!(SMatrix::for_sources(0).is_err());
}

#[test]
fn bad_parameters_are_named() {
    let e = SMatrix::paley(13).unwrap_err().to_string(); // 13 = 1 mod 4
    assert!(e.contains("p = 13") && e.contains("3 mod 4"), "{e}");
    let e = SMatrix::sylvester(0).unwrap_err().to_string();
    assert!(e.contains("k = 0"), "{e}");
    let e = SMatrix::twin_prime(7).unwrap_err().to_string(); // 9 is not prime
    assert!(e.contains("p = 7"), "{e}");
}

#[test]
fn closed_form_inverse_is_the_inverse_and_singular_values_match() {
    for n in [3, 7, 11, 15, 19, 35, 63, 83, 151] {
        let s = SMatrix::of_order(n).unwrap();
        let inv = s.inverse_dense();
        let dense = s.to_dense();
        let mut worst = 0.0f64;
        for i in 0..n {
            for j in 0..n {
                let v: f64 = (0..n).map(|k| inv[i * n + k] * f64::from(dense[k * n + j])).sum();
                worst = worst.max((v - if i == j { 1.0 } else { 0.0 }).abs());
            }
        }
        assert!(worst < 1e-12 * n as f64, "order {n}: |S⁻¹S − I| = {worst:e}");
        // cond(S) = √(n+1): singular values (n+1)/2 once and √(n+1)/2.
        let m = nalgebra::DMatrix::from_fn(n, n, |i, j| f64::from(dense[i * n + j]));
        let mut sv: Vec<f64> = m.singular_values().iter().copied().collect();
        sv.sort_by(f64::total_cmp);
        let (lo, hi) = (sv[0], sv[n - 1]);
        assert!((hi - (n as f64 + 1.0) / 2.0).abs() < 1e-9 * n as f64, "order {n}: σmax {hi}");
        assert!((lo - (n as f64 + 1.0).sqrt() / 2.0).abs() < 1e-9 * n as f64, "order {n}: σmin {lo}");
        assert!((hi / lo - (n as f64 + 1.0).sqrt()).abs() < 1e-9 * n as f64);
    }
}
