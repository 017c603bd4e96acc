//! CIEDE2000 against the published test data of Sharma, Wu and Dalal (2005).

mod common;

use btfrig_color::{delta_e_2000, delta_e_2000_parts, delta_e_76};
use common::Csv;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// (L*a*b* 1, L*a*b* 2) of a test pair.
type Pair = ([f64; 3], [f64; 3]);

fn pairs() -> (Csv, Vec<Pair>) {
    let c = Csv::read("ciede2000_sharma.csv");
    assert_eq!(c.rows.len(), 34);
    let p = c.rows.iter().map(|r| ([r[1], r[2], r[3]], [r[4], r[5], r[6]])).collect();
    (c, p)
}

#[test]
fn reproduces_all_34_published_pairs() {
    let (c, p) = pairs();
    let published = c.col("dE00");
    let colour = c.col("dE00_colour_0_4_7");
    let mut worst: f64 = 0.0;
    for (i, (a, b)) in p.iter().enumerate() {
        let de = delta_e_2000(*a, *b);
        // Published to 4 decimals: within rounding (5e-5) of it, and within the 1e-4 the issue asks.
        assert!((de - published[i]).abs() <= 5.000_1e-5, "pair {}: {de} vs {}", i + 1, published[i]);
        // An independent implementation with 10 decimals agrees to its printing precision.
        assert!((de - colour[i]).abs() < 1e-9, "pair {}: {de} vs colour {}", i + 1, colour[i]);
        worst = worst.max((de - published[i]).abs());
    }
    eprintln!("largest deviation from the published 4-decimal values: {worst:.2e}");
}

#[test]
fn pair_14_at_exactly_180_degrees_takes_the_published_branch() {
    let (_, p) = pairs();
    let (a, b) = p[13];
    let parts = delta_e_2000_parts(a, b);
    assert!(((parts.h2p - parts.h1p) - 180.0).abs() < 1e-9);
    assert!((parts.hbarp - 180.034_512).abs() < 1e-6, "hbarp {}", parts.hbarp);
    assert!((parts.de00 - 4.8045).abs() < 5e-5, "{}", parts.de00);
    // Careless handling gives 4.7461, the value of pair 15 (whose hues differ by just over 180°).
    assert!((parts.de00 - 4.7461).abs() > 0.05);
    // Swapped order: same branch, same value.
    assert!((delta_e_2000(b, a) - parts.de00).abs() < 1e-12);
}

#[test]
fn intermediate_values_match_the_published_table() {
    let (_, p) = pairs();
    let t = Csv::read("ciede2000_sharma_intermediates.csv");
    for (i, (a, b)) in p.iter().enumerate() {
        let q = delta_e_2000_parts(*a, *b);
        let r = &t.rows[i];
        let got = [q.a1p, q.c1p, q.h1p, q.a2p, q.c2p, q.h2p, q.hbarp, q.g, q.t, q.sl, q.sc, q.sh, q.rt, q.de00];
        for (k, (g, e)) in got.iter().zip(&r[1..]).enumerate() {
            // Published with 6 decimals.
            assert!((g - e).abs() <= 5.1e-7, "pair {} field {}: {g} vs {e}", i + 1, t.header[k + 1]);
        }
    }
}

#[test]
fn symmetric_non_negative_and_zero_on_identity() {
    let (_, p) = pairs();
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let mut all = p.clone();
    for _ in 0..2000 {
        let mut lab = || [rng.gen_range(0.0..100.0), rng.gen_range(-120.0..120.0), rng.gen_range(-120.0..120.0)];
        all.push((lab(), lab()));
    }
    // Greys and exact hue oppositions exercise the C′ = 0 and 180° branches.
    all.push(([50.0, 0.0, 0.0], [60.0, 0.0, 0.0]));
    all.push(([50.0, 0.0, 0.0], [50.0, 3.0, -4.0]));
    all.push(([50.0, 7.0, 2.0], [50.0, -7.0, -2.0]));
    for (a, b) in all {
        let ab = delta_e_2000(a, b);
        let ba = delta_e_2000(b, a);
        assert!(ab.is_finite() && ab >= 0.0);
        assert!((ab - ba).abs() <= 1e-12 * ab.max(1.0), "{a:?} {b:?}: {ab} {ba}");
        assert_eq!(delta_e_2000(a, a), 0.0);
    }
    // Pure lightness difference at L̄ = 50: S_L = 1, so ΔE00 = ΔL.
    assert!((delta_e_2000([45.0, 0.0, 0.0], [55.0, 0.0, 0.0]) - 10.0).abs() < 1e-12);
}

#[test]
fn cie76_is_euclidean() {
    assert!((delta_e_76([50.0, 3.0, 4.0], [50.0, 0.0, 0.0]) - 5.0).abs() < 1e-15);
    assert!((delta_e_76([10.0, 0.0, 0.0], [12.0, -1.0, 2.0]) - 3.0).abs() < 1e-15);
    // ΔE00 weighs chroma differences of saturated colours far less than ΔE76 (pair 1).
    let (_, p) = pairs();
    assert!(delta_e_2000(p[0].0, p[0].1) < 0.7 * delta_e_76(p[0].0, p[0].1));
}
