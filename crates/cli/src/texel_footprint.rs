//! Does the camera resolve a plan's texels? A texel smaller than the sample patch one
//! photosite sees is interpolation, not measurement: on the small-camera rig (2.5 mm per
//! photosite) a 64-texel texture of the 10 cm sample (1.56 mm texels) cannot show corduroy's
//! 3 mm wales, and photometric stereo on it scores like a flat normal map
//! (docs/material-models.md, "The full 81 x 81 plan at 64 texels").

use btfrig_core::config::RigConfig;
use btfrig_core::plan::TextureSettings;

/// A texel's side against the side of the sample patch one photosite sees, at the normal
/// view (the finest an oblique view foreshortens by `cos θ` along one axis).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TexelFootprint {
    /// Texel side, metres.
    pub texel_m: f64,
    /// Sample-plane side of one photosite seen from the camera rail, metres.
    pub photosite_m: f64,
}

impl TexelFootprint {
    /// The footprint of `texture`'s texels on `rig`'s gonioreflectometer camera (pinhole at
    /// the rail radius: a photosite subtends `1 / fx_px` radians).
    pub fn of(rig: &RigConfig, texture: &TextureSettings) -> Self {
        TexelFootprint {
            texel_m: texture.region.side_m() / texture.size as f64,
            photosite_m: rig.geometry.rail_radius_m / rig.camera.fx_px,
        }
    }

    /// Photosites per texel side: below 1 the texture is finer than the camera resolves.
    pub fn photosites_per_texel(&self) -> f64 {
        self.texel_m / self.photosite_m
    }

    /// Whether every texel spans at least one photosite at the normal view.
    pub fn resolved(&self) -> bool {
        self.photosites_per_texel() >= 1.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use btfrig_core::plan::{Plan, PlanContext};

    fn rig(file: &str) -> RigConfig {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../rig-configs").join(file);
        RigConfig::from_toml(&std::fs::read_to_string(&path).unwrap(), file).unwrap()
    }

    fn texture(size: usize) -> TextureSettings {
        let text = format!("[sampling]\nlight = \"bonn81\"\nview = \"bonn81\"\n[texture]\nsize = {size}\n");
        Plan::load_and_validate(&text, "<test>", &PlanContext::with_builtin_names()).unwrap().texture
    }

    #[test]
    fn the_small_camera_does_not_resolve_64_texels_of_the_sample_and_the_default_does() {
        // 0.2 m plate on ~80 px from 1.2 m: 1.2 m / 480 px = 2.5 mm per photosite against
        // 0.1 m / 64 = 1.5625 mm texels; the default camera (fx 4800 px) sees 0.25 mm.
        let small = TexelFootprint::of(&rig("bonn-gonio-sim-small.toml"), &texture(64));
        assert!((small.photosite_m - 2.5e-3).abs() < 1e-12 && (small.texel_m - 1.5625e-3).abs() < 1e-12);
        assert!((small.photosites_per_texel() - 0.625).abs() < 1e-12);
        assert!(!small.resolved());
        let default = TexelFootprint::of(&rig("bonn-gonio-sim.toml"), &texture(64));
        assert!((default.photosite_m - 2.5e-4).abs() < 1e-12);
        assert!(default.resolved());
        // 32 texels (3.125 mm, tests/data/bonn-full-small.toml) are resolved on the small camera.
        assert!(TexelFootprint::of(&rig("bonn-gonio-sim-small.toml"), &texture(32)).resolved());
    }
}
