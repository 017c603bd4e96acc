//! Colour correction on spectral synthetic data: ColorChecker 24 spectra (and mixtures of
//! them) seen by a Nikon D5100 (NPL-measured sensitivities) under a lamp; target = the
//! colour a CIE 1931 observer adapted to the lamp sees, in linear sRGB D65.

mod common;

use btfrig_color::{
    cross_validate, evaluate, screen_patches, select_model, valid_indices, ColorError, ColorModel, FitOptions,
    ModelKind, PatchStatus, ScreenOptions, TargetSpace,
};
use common::{add_noise, chart_spectra, mixtures, pairs, Spectral};

const SPACE: TargetSpace = TargetSpace::LinearSrgb;

#[test]
fn explore() {
    for lamp in [
        "D65",
        "D50",
        "A",
        "LED-B1",
        "LED-B5",
        "LED-BH1",
        "LED-RGB1",
        "LED-V1",
        "LED-V2",
        "LS_Metal_Halide",
        "LS_MHC100_U_MP_4K",
        "LS_Phosphor_LED_YAG",
    ] {
        let s = Spectral::new(lamp);
        let chart = chart_spectra();
        let (cam, tgt) = pairs(&s, &chart, 0.9);
        let test = mixtures(&chart, 200, 2);
        let (tcam, ttgt) = pairs(&s, &test, 0.9);
        for kind in [ModelKind::Linear] {
            let m = ColorModel::fit(kind, &cam, &tgt, None, &FitOptions::default());
            match m {
                Ok(m) => {
                    let e = evaluate(&m, &tcam, &ttgt, SPACE).unwrap();
                    let cv = cross_validate(kind, &cam, &tgt, None, &FitOptions::default(), SPACE, 24);
                    eprintln!(
                        "{lamp} {kind}: cond {:.3e} held-out mean {:.3} p95 {:.3} max {:.3} cv {:?}",
                        m.condition(),
                        e.mean,
                        e.p95,
                        e.max,
                        cv.map(|c| (c.mean, c.max))
                    );
                }
                Err(e) => eprintln!("{lamp} {kind}: {e}"),
            }
        }
    }
}
