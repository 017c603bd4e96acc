//! PCMF in a shared angular basis (`Method::Pcmf { shared_basis: Some(K) }`): exact on BTFs
//! of its form, the FMF at full rank and one cluster, its two-level storage counted, its
//! files (version 2) round-tripped bit for bit and refused when damaged, the decoder equal
//! to the two-level formula, Bonn export, bad K refused. Small sizes, seeded.

use btfrig_compress::ubo;
use btfrig_compress::{
    build, file, ColorModel, CompressError, Layout, MemorySource, Method, Model, ModelParams, Precision,
};
use btfrig_core::sampling::{Ring, Sampling};
use btfrig_core::Direction;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

type Btf = Vec<Option<Vec<[f32; 3]>>>;

fn layout(w: usize) -> Layout {
    let s = |n: &str| {
        Sampling::from_rings(n, &[Ring::new(0.0, 1, 0.0), Ring::new(20.0, 6, 0.0), Ring::new(45.0, 8, 10.0)]).unwrap()
    };
    Layout::full(s("l"), s("v"), w, w)
}

/// One material family: its mean and its directions, each as RGB weights of the span functions.
type Family = (Vec<[f32; 3]>, Vec<Vec<[f32; 3]>>);

/// Texels of `families` materials (texel x in family `x % families`), each an affine family of
/// rank `r` per channel whose angular functions are combinations of `span` shared random
/// functions: a BTF of exactly the shared-basis form with K = `span` (the centred data spans
/// at most `span`).
fn families(l: &Layout, families: usize, r: usize, span: usize, seed: u64) -> Btf {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (m, n) = (l.n_angular(), l.texels());
    let basis: Vec<Vec<[f32; 3]>> =
        (0..span).map(|_| (0..m).map(|_| [rng.gen(), rng.gen(), rng.gen()]).collect()).collect();
    // Per family: a mean and r directions, each a combination of the span.
    let combo =
        |rng: &mut ChaCha8Rng| -> Vec<[f32; 3]> { (0..span).map(|_| [rng.gen(), rng.gen(), rng.gen()]).collect() };
    let fam: Vec<Family> =
        (0..families).map(|_| (combo(&mut rng), (0..r).map(|_| combo(&mut rng)).collect())).collect();
    // Small texel coefficients: the families lie apart (k-means finds them; local PCA from a
    // bad start can stop in a local minimum, as any local PCA).
    let coef: Vec<Vec<[f32; 3]>> = (0..n)
        .map(|_| (0..r).map(|_| [0.05 * rng.gen::<f32>(), 0.05 * rng.gen::<f32>(), 0.05 * rng.gen::<f32>()]).collect())
        .collect();
    let ang = |a: usize, w: &[[f32; 3]], c: usize| -> f32 { (0..span).map(|i| basis[i][a][c] * w[i][c]).sum() };
    (0..m)
        .map(|a| {
            l.measured[a].then(|| {
                (0..n)
                    .map(|x| {
                        let (mean, dirs) = &fam[x % families];
                        std::array::from_fn(|c| {
                            ang(a, mean, c) + (0..r).map(|j| ang(a, &dirs[j], c) * coef[x][j][c]).sum::<f32>()
                        })
                    })
                    .collect()
            })
        })
        .collect()
}

fn params(method: Method, k: usize, precision: Precision) -> ModelParams {
    let mut p = ModelParams::new(method);
    p.color = ColorModel::Rgb;
    p.terms = [k; 3];
    p.precision = precision;
    p
}

fn fit(l: &Layout, btf: &Btf, p: &ModelParams) -> Model {
    build::<f32>(l.clone(), p, &mut MemorySource { layout: l, textures: btf }).unwrap().0
}

fn rel_err(a: &Model, b: &dyn Fn(usize) -> Vec<[f32; 3]>, m: usize) -> f64 {
    let (mut e, mut t) = (0.0f64, 0.0f64);
    for r in 0..m {
        let want = b(r);
        for (p, q) in a.texture(r).iter().zip(&want) {
            for c in 0..3 {
                e += f64::from(p[c] - q[c]).powi(2);
                t += f64::from(q[c]).powi(2);
            }
        }
    }
    (e / t.max(1e-300)).sqrt()
}

#[test]
fn btfs_of_the_shared_form_are_reproduced() {
    for (w, fams, r, span) in [(8usize, 2usize, 2usize, 6usize), (12, 3, 3, 10)] {
        let l = layout(w);
        let btf = families(&l, fams, r, span, w as u64);
        // K = span + 1: the span plus the global mean (which the FMF subtracts first).
        let p = params(Method::pcmf_shared(fams, span + 1), r, Precision::F32);
        let m = fit(&l, &btf, &p);
        let e = rel_err(&m, &|a| btf[a].clone().unwrap(), l.n_angular());
        assert!(e < 1e-4, "{w} texels, {fams} families of rank {r} in a span of {span}: rel error {e}");
        assert_eq!(m.channels[0].parts.len(), fams);
        // The clusters are the families (up to labels).
        let cl = m.clusters.as_ref().unwrap();
        for x in 0..l.texels() {
            assert_eq!(cl[x], cl[x % fams], "texel {x}");
        }
    }
}

#[test]
fn one_cluster_at_full_rank_reproduces_the_fmf() {
    // Moved from the benchmark's experiment: with one cluster and as many terms as the shared
    // basis, A_1 is a rotation of W's coefficients, so the model is the FMF.
    let l = layout(8);
    let (m, n) = (l.n_angular(), l.texels());
    let btf: Btf = (0..m)
        .map(|a| {
            let (fa, ga) = ((a as f32 * 0.37).sin(), (a as f32 * 0.11).cos());
            Some(
                (0..n)
                    .map(|x| {
                        std::array::from_fn(|c| {
                            0.5 + 0.2 * fa * (x as f32 * 0.3 + c as f32).cos() + 0.1 * ga * (x as f32 * 0.7).sin()
                        })
                    })
                    .collect(),
            )
        })
        .collect();
    for (precision, tol) in [(Precision::F32, 1e-5f32), (Precision::F16, 2e-3)] {
        let fmf = fit(&l, &btf, &params(Method::Fmf, 4, precision));
        let shared = fit(&l, &btf, &params(Method::pcmf_shared(1, 4), 4, precision));
        assert_eq!(shared.clusters.as_ref().unwrap(), &vec![0u16; n]);
        let mut worst = 0.0f32;
        for a in 0..m {
            for (p, q) in fmf.texture(a).iter().zip(&shared.texture(a)) {
                for c in 0..3 {
                    worst = worst.max((p[c] - q[c]).abs());
                }
            }
        }
        assert!(worst < tol, "{precision:?}: worst difference {worst}");
        // The two-level payload: per channel m (K + 1) + K once, K (t + 1) + t per cluster
        // (mean, basis, singular values), t per texel; 2 bytes per texel of cluster map.
        let per_channel = m * 5 + 4 + (4 * 5 + 4) + n * 4;
        assert_eq!(shared.payload_bytes(), 3 * per_channel * precision.bytes() + 2 * n, "{precision:?}");
        assert_eq!(shared.stored_values(), 3 * per_channel);
    }
}

/// The value from the two-level form itself: mu + W (a_j + A_j t_x), in f64.
fn two_level(model: &Model, a: usize, x: usize) -> [f64; 3] {
    std::array::from_fn(|c| {
        let ch = &model.channels[c];
        let sh = ch.shared.as_ref().unwrap();
        let j = model.clusters.as_ref().unwrap()[x] as usize;
        let col = model.cluster_col[x] as usize;
        let t = ch.parts[j].k;
        let tx = &ch.parts[j].sv[col * t..(col + 1) * t];
        let mut v = f64::from(sh.mean[a]);
        for i in 0..sh.k {
            let mut ci = f64::from(sh.cluster_mean[j][i]);
            for (b, c) in sh.cluster_basis[j][i * t..(i + 1) * t].iter().zip(tx) {
                ci += f64::from(*b) * f64::from(*c);
            }
            v += f64::from(sh.w[a * sh.k + i]) * ci;
        }
        v
    })
}

#[test]
fn files_round_trip_bit_exact_and_the_decoder_is_the_two_level_formula() {
    let dir = std::env::temp_dir().join(format!("btfrig-shared-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut l = layout(10);
    let gap = l.index(3, 2);
    l.measured[gap] = false;
    let btf = families(&l, 3, 2, 8, 4);
    for (precision, color) in [(Precision::F16, ColorModel::Rgb), (Precision::F32, ColorModel::Yuv)] {
        let mut p = params(Method::pcmf_shared(4, 12), 3, precision);
        p.color = color;
        let m = fit(&l, &btf, &p);
        let path = dir.join(format!("m-{precision:?}.btfm"));
        let _ = std::fs::remove_file(&path);
        let n = file::write(&path, &m, serde_json::json!({"test": true}), false).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!(n as usize, bytes.len());
        assert_eq!(u32::from_le_bytes(bytes[8..12].try_into().unwrap()), file::VERSION_SHARED);
        let (h, _) = file::read_header(&path).unwrap();
        assert_eq!((h.version, h.shared_basis, h.clusters), (2, Some(12), Some(4)));
        // The file is the two-level form: header + arrays, not the expanded parts.
        let json_len = u32::from_le_bytes(bytes[12..16].try_into().unwrap()) as usize;
        let arrays = h.arrays.len();
        let s_vals: usize = h.arrays.iter().filter(|a| a.dtype == "f32" && a.name.ends_with(".s")).map(|a| a.len).sum();
        let prec = precision.bytes();
        assert_eq!(
            bytes.len(),
            16 + json_len + 32 * (1 + arrays) + m.payload_bytes() + s_vals * (4 - prec),
            "{precision:?}: the file holds exactly the payload (singular values as f32)"
        );
        let back = file::read(&path).unwrap();
        assert_eq!(back.method, m.method);
        assert_eq!(back.channels, m.channels, "{precision:?}: shared factors and expanded parts, bit for bit");
        assert_eq!(back.clusters, m.clusters);
        assert_eq!(back.payload_bytes(), m.payload_bytes());
        for a in [0, gap, 77, l.n_angular() - 1] {
            assert_eq!(back.texture(a), m.texture(a), "angular index {a}");
        }
        let (v, li) = (Direction::from_degrees(12.0, 33.0), Direction::from_degrees(30.0, 250.0));
        assert_eq!(back.query(v, li).texture(), m.query(v, li).texture(), "an interpolated direction pair");
        // The decoder (expanded parts) equals the two-level formula.
        for a in [0, gap, 150] {
            for x in [0, 7, 55, 99] {
                let want = m.color.inverse(two_level(&m, a, x).map(|v| v as f32), m.log_eps);
                let got = back.texel(a, x);
                for c in 0..3 {
                    assert!(
                        (got[c] - want[c]).abs() < 1e-5 * want[c].abs().max(1.0),
                        "a {a} x {x}: {got:?} vs {want:?}"
                    );
                }
            }
        }
        // Damage: a flipped byte in the last array and in W, a cut file, a wrong version.
        let mut bad = bytes.clone();
        let last = bad.len() - 40;
        bad[last] ^= 1;
        assert!(matches!(file::decode(&path, &bad), Err(CompressError::Checksum { .. })));
        let w_start = 16 + json_len + 32 + l.n_angular() * prec + 32 + 5;
        let mut bad = bytes.clone();
        bad[w_start] ^= 4;
        let e = file::decode(&path, &bad).err().unwrap();
        assert!(matches!(e, CompressError::Checksum { ref section, .. } if section == "c0.w.u"), "{e}");
        for cut in [bytes.len() - 1, bytes.len() / 2, 16 + json_len + 40] {
            let e = file::decode(&path, &bytes[..cut]).err().unwrap();
            assert!(e.to_string().contains("truncated"), "cut at {cut}: {e}");
        }
        let mut v1 = bytes.clone();
        v1[8] = 1;
        let e = file::decode(&path, &v1).err().unwrap().to_string();
        assert!(e.contains("header says version 2, the binary field 1"), "{e}");
        let mut v3 = bytes.clone();
        v3[8] = 3;
        let e = file::decode(&path, &v3).err().unwrap().to_string();
        assert!(e.contains("version 3 is not supported"), "{e}");
        // Bonn export: re-encoded from the factored form [mu | W] [1 | a_j + A_j t_x].
        let (u, fit) = ubo::to_dfmf(&back, None, 4).unwrap();
        let again = ubo::compare(&back, &u);
        let tol = if color == ColorModel::Rgb { 1e-4 } else { 1e-3 };
        assert!(fit.rel_rmse < tol && again.rel_rmse < tol, "{precision:?}: {fit:?} {again:?}");
        assert!(fit.terms <= 3 * 13, "at most 3 (K + 1) terms, got {}", fit.terms);
    }
    // Every other model is still version 1.
    let fm = fit(&l, &btf, &params(Method::pcmf(2), 3, Precision::F16));
    let bytes = file::encode(&fm, serde_json::Value::Null);
    assert_eq!(u32::from_le_bytes(bytes[8..12].try_into().unwrap()), file::VERSION);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_version_1_file_still_reads() {
    // Bytes of a version-1 file as written before the shared basis existed: an FMF with one
    // term on a 1 x 1 sampling pair, 1 x 1 texel, written by hand from docs/model-format.md.
    use sha2::{Digest, Sha256};
    let json = serde_json::json!({
        "format": "btfrig-model", "version": 1, "method": "fmf", "clusters": null, "color": "rgb",
        "log_eps": 0.001, "precision": "f32", "sampling_names": ["l", "v"], "light": [[0.0, 0.0]],
        "view": [[0.0, 0.0]], "width": 1, "height": 1, "unmeasured": [],
        "channels": [[{"view": null, "k": 1, "rows": 1, "cols": 1}], [{"view": null, "k": 1, "rows": 1, "cols": 1}],
                     [{"view": null, "k": 1, "rows": 1, "cols": 1}]],
        "arrays": (0..3).flat_map(|c| ["mean", "u", "s", "sv"].map(|w| serde_json::json!({"name": format!("c{c}.p0.{w}"), "dtype": "f32", "len": 1}))).collect::<Vec<_>>(),
        "source": null
    });
    let j = serde_json::to_vec(&json).unwrap();
    let mut b = b"BTFRIGMD".to_vec();
    b.extend_from_slice(&1u32.to_le_bytes());
    b.extend_from_slice(&(j.len() as u32).to_le_bytes());
    b.extend_from_slice(&j);
    b.extend_from_slice(&Sha256::digest(&j));
    for c in 0..3 {
        for v in [0.1f32 * (c + 1) as f32, 1.0, 2.0, 0.5] {
            let p = v.to_le_bytes();
            b.extend_from_slice(&p);
            b.extend_from_slice(&Sha256::digest(p));
        }
    }
    let m = file::decode(std::path::Path::new("<v1>"), &b).unwrap();
    assert_eq!(m.method, Method::Fmf);
    let t = m.texel(0, 0);
    for c in 0..3 {
        assert!((t[c] - (0.1 * (c + 1) as f32 + 0.5)).abs() < 1e-6, "{t:?}");
    }
    // Written again it is version 1, without the new header field.
    let again = file::encode(&m, serde_json::Value::Null);
    assert_eq!(u32::from_le_bytes(again[8..12].try_into().unwrap()), 1);
    assert!(!String::from_utf8_lossy(&again).contains("shared_basis"));
    assert_eq!(file::decode(std::path::Path::new("<again>"), &again).unwrap().channels, m.channels);
}

#[test]
fn bad_shared_basis_is_refused() {
    let l = layout(4);
    let btf = families(&l, 2, 2, 4, 1);
    let bad =
        |p: ModelParams| build::<f32>(l.clone(), &p, &mut MemorySource { layout: &l, textures: &btf }).err().unwrap();
    for (k, terms, allowed) in [(3usize, 4usize, "4..=1024"), (0, 1, "1..=1024"), (2000, 4, "4..=1024")] {
        let e = bad(params(Method::pcmf_shared(2, k), terms, Precision::F16));
        assert!(
            matches!(e, CompressError::BadParameter { field: "shared_basis", .. }) && e.to_string().contains(allowed),
            "K {k} terms {terms}: {e}"
        );
    }
    // More than the FMF can give: 16 texels.
    let e = bad(params(Method::pcmf_shared(2, 17), 4, Precision::F16));
    assert!(e.to_string().contains("at most 16") && e.to_string().contains("16 texels"), "{e}");
    let mut p = params(Method::pcmf_shared(2, 8), 4, Precision::F16);
    p.shared_iters = 51;
    assert!(matches!(bad(p), CompressError::BadParameter { field: "shared_iters", .. }));
}

#[test]
fn passes_are_the_fmf_passes() {
    let mut p = params(Method::pcmf_shared(8, 16), 4, Precision::F16);
    assert_eq!(p.passes(), ModelParams::new(Method::Fmf).passes());
    p.power_iters = 2;
    assert_eq!(p.passes(), 6);
}
