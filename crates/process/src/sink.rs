//! Where committed textures go after the journal commit.

use btfrig_store::StepId;

/// Receives every committed texture, after its journal commit, in commit order, on a
/// blocking thread: e.g. the streaming compressor of `btfrig-compress`. It must return
/// quickly (queue the work): the pipeline waits for it.
pub trait TextureSink: Send + Sync {
    /// The texture (row-major linear RGB, `size x size`) of the committed `step`.
    fn accept(&self, step: StepId, texels: &[[f32; 3]]);
}
