//! Shared helpers of the store's integration tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

use btfrig_core::frame::{FrameMeta, RawFrame};
use btfrig_core::Direction;
use btfrig_store::{Manifest, RigInfo, Samplings, SkippedStep, StepId, TextureFormat, TextureRegion, TextureSpec};

/// A temporary directory removed on drop.
pub struct TempDir(pub PathBuf);
impl TempDir {
    pub fn new(tag: &str) -> Self {
        let p = std::env::temp_dir().join(format!("btfrig-store-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&p);
        std::fs::create_dir_all(&p).unwrap();
        TempDir(p)
    }
    pub fn path(&self) -> &Path {
        &self.0
    }
}
impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

pub const W: usize = 4;
pub const H: usize = 3;

/// 2 lights x 3 views, step (1, 2) skipped by the plan: 5 expected steps.
pub fn manifest(plan: &str, format: TextureFormat, raw: bool) -> Manifest {
    let light = [Direction::from_degrees(0.0, 0.0), Direction::from_degrees(45.0, 90.0)];
    let view =
        [Direction::from_degrees(0.0, 0.0), Direction::from_degrees(30.0, 0.0), Direction::from_degrees(60.0, 180.0)];
    let mut samplings = Samplings::full(&light, &view);
    samplings.skipped.push(SkippedStep { step: StepId { light: 1, view: 2 }, reason: "unreachable: test".into() });
    Manifest::new(
        RigInfo { name: "test-rig".into(), config_toml: "[rig]\nname = \"test-rig\"\n".into() },
        plan,
        samplings,
        TextureSpec {
            width: W as u32,
            height: H as u32,
            region: TextureRegion { center_m: [0.0, 0.0], size_m: [0.05, 0.0375] },
            format,
        },
        raw,
        7,
    )
}

/// A texture that differs per step and texel; values exact in half precision.
pub fn texels(step: StepId) -> Vec<[f32; 3]> {
    (0..W * H).map(|i| [step.light as f32 + 0.25 * i as f32, step.view as f32 * 0.5, 1.0 / (1 + i) as f32]).collect()
}

pub fn raw_frame(step: StepId) -> RawFrame {
    RawFrame {
        width: 6,
        height: 4,
        data: (0..24u16).map(|i| i * 1000 + step.view as u16 * 7).collect(),
        meta: FrameMeta {
            sequence: u64::from(step.light) * 100 + u64::from(step.view),
            exposure_s: 0.01,
            gain: 1.0,
            f_number: None,
            black_level: 64,
            white_level: 4095,
            bit_depth: 12,
            bayer: None,
            timestamp_s: 1.5,
            temperature_c: None,
        },
    }
}
