//! The live preview: tone mapping, the rate gate, and making one on a processing thread.

use std::sync::Arc;
use std::time::{Duration, Instant};

use btfrig_store::StepId;

use crate::Processor;

/// A preview image: the rectified texture of one capture, tone-mapped to 8-bit sRGB.
#[derive(Debug, Clone, PartialEq)]
pub struct Preview {
    /// The capture shown.
    pub step: StepId,
    /// Width, pixels.
    pub width: usize,
    /// Height, pixels.
    pub height: usize,
    /// The PNG file's bytes (what `preview.png` holds).
    pub png: Vec<u8>,
}

/// Tone-maps a linear radiance-factor texture (`width x height`, row-major) to 8-bit sRGB
/// (`RGBRGB...`), enlarged by the smallest whole factor that makes both sides at least
/// `min_side`. Exposure is automatic so dark and glossy captures both show: the 99th
/// percentile of the brightest channel maps to 90 % (gain at most 16, so a black frame stays
/// black rather than showing amplified noise); values are clipped to [0, 1] (NaN to 0) and
/// encoded with the sRGB transfer function. Returns `(width, height, bytes)`.
///
/// # Panics
/// If `texels.len() != width * height`.
pub fn tone_map_preview(texels: &[[f32; 3]], width: usize, height: usize, min_side: usize) -> (usize, usize, Vec<u8>) {
    assert_eq!(texels.len(), width * height, "tone_map_preview: {width}x{height} texels expected");
    let mut peaks: Vec<f32> =
        texels.iter().map(|t| t[0].max(t[1]).max(t[2])).map(|v| if v.is_finite() { v } else { 0.0 }).collect();
    let gain = if peaks.is_empty() {
        1.0
    } else {
        let k = ((peaks.len() - 1) as f64 * 0.99) as usize;
        let (_, p99, _) = peaks.select_nth_unstable_by(k, f32::total_cmp);
        if *p99 > 0.0 {
            (0.9 / *p99).min(16.0)
        } else {
            16.0
        }
    };
    // One lookup per 12-bit input level: the sRGB curve is the costly part otherwise.
    let lut: Vec<u8> = (0..4096)
        .map(|i| {
            let v = btfrig_color::space::srgb_encode(f64::from(i) / 4095.0);
            (v * 255.0).round() as u8
        })
        .collect();
    let enc = |v: f32| {
        let x = v * gain;
        let x = if x.is_finite() { x.clamp(0.0, 1.0) } else { 0.0 };
        lut[(x * 4095.0).round() as usize]
    };
    let k = if width == 0 || height == 0 { 1 } else { min_side.div_ceil(width.min(height)).max(1) };
    let (w, h) = (width * k, height * k);
    let mut out = Vec::with_capacity(w * h * 3);
    let mut row = Vec::with_capacity(w * 3);
    for y in 0..height {
        row.clear();
        for t in &texels[y * width..(y + 1) * width] {
            let px = [enc(t[0]), enc(t[1]), enc(t[2])];
            for _ in 0..k {
                row.extend_from_slice(&px);
            }
        }
        for _ in 0..k {
            out.extend_from_slice(&row);
        }
    }
    (w, h, out)
}

/// When the next preview may be made.
#[derive(Debug, Default)]
pub(crate) struct PreviewGate {
    /// Not before this (`None`: now).
    next: Option<Instant>,
    /// A preview is being made (its cost, which sets `next`, is not known yet).
    pending: bool,
}

/// The right to make one preview; dropping it (preview written, or its step failed) releases
/// the gate with the cost measured so far.
pub(crate) struct PreviewClaim {
    pr: Arc<Processor>,
    started: Instant,
    pub(crate) cost_s: f64,
}

impl Drop for PreviewClaim {
    fn drop(&mut self) {
        let Some(ps) = self.pr.outputs.preview else { return };
        let wait = (self.cost_s / ps.max_share.max(1e-9)).max(ps.min_interval_s).clamp(0.0, 3600.0);
        let mut g = self.pr.preview_gate.lock().unwrap_or_else(|e| e.into_inner());
        g.next = Some(self.started + Duration::from_secs_f64(wait));
        g.pending = false;
    }
}

/// A claim if a preview is due now (none while another is being made, so frames processed in
/// parallel do not both make one).
pub(crate) fn claim_preview(pr: &Arc<Processor>) -> Option<PreviewClaim> {
    pr.outputs.preview?;
    let mut g = pr.preview_gate.lock().unwrap_or_else(|e| e.into_inner());
    let now = Instant::now();
    if g.pending || g.next.is_some_and(|t| now < t) {
        return None;
    }
    g.pending = true;
    Some(PreviewClaim { pr: pr.clone(), started: now, cost_s: 0.0 })
}

/// A preview made on a processing thread, to be written after the step's commit.
pub(crate) struct MadePreview {
    /// `None` if encoding failed.
    pub(crate) preview: Option<Preview>,
    pub(crate) claim: PreviewClaim,
}

pub(crate) fn make_preview(mut claim: PreviewClaim, step: StepId, texels: &[[f32; 3]], n: usize) -> MadePreview {
    let started = Instant::now();
    let min_side = claim.pr.outputs().preview.map_or(0, |p| p.min_side);
    let preview = (texels.len() == n * n && n > 0)
        .then(|| {
            let (width, height, rgb) = tone_map_preview(texels, n, n, min_side);
            let name = std::path::Path::new(btfrig_store::PREVIEW_FILE);
            let png = btfrig_imageio::encode_srgb8_png(name, width, height, &rgb).ok()?;
            Some(Preview { step, width, height, png })
        })
        .flatten();
    claim.cost_s += started.elapsed().as_secs_f64();
    MadePreview { preview, claim }
}
