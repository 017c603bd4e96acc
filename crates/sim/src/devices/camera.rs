//! The simulated camera.

use std::sync::Arc;

use async_trait::async_trait;
use btfrig_core::config::timing::CameraTiming;
use btfrig_core::frame::RawFrame;
use btfrig_hw::{
    frame_checksum, verify_frame, Camera, CameraCapabilities, CaptureSettings, DeviceError, DeviceInfo, ErrorKind,
};

use crate::faults::{derive_seed, FaultGate, FrameFate, FrameFaults, COMMAND_TIMEOUT_S};
use crate::options::SimCameraOptions;
use crate::world::FaultKind;
use crate::{FrameSource, SimWorld, TrueState};

#[derive(Debug)]
struct Pending {
    sequence: u64,
    truth: TrueState,
    settings: CaptureSettings,
}

/// A simulated raw camera: trigger latency, exposure, read-out into a one-frame buffer,
/// transfer at a fixed bandwidth, pixels from a [`FrameSource`], dropped and corrupt
/// frames from the fault scenario.
pub struct SimCamera {
    info: DeviceInfo,
    gate: FaultGate,
    caps: CameraCapabilities,
    settings: CaptureSettings,
    timing: CameraTiming,
    world: SimWorld,
    source: Arc<dyn FrameSource>,
    frame_faults: FrameFaults,
    pending: Option<Pending>,
    next_sequence: u64,
    readouts: u64,
    seed: u64,
    /// The noise key of the last frame and how many frames in a row had it.
    last_noise_key: (u64, u64),
}

impl std::fmt::Debug for SimCamera {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimCamera").field("info", &self.info).field("settings", &self.settings).finish_non_exhaustive()
    }
}

impl SimCamera {
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn new(
        opts: &SimCameraOptions,
        timing: &CameraTiming,
        gate: FaultGate,
        world: SimWorld,
        source: Arc<dyn FrameSource>,
        frame_faults: FrameFaults,
        seed: u64,
    ) -> Self {
        let f = source.format();
        let caps = CameraCapabilities {
            width: f.width,
            height: f.height,
            bit_depth: f.bit_depth,
            bayer: f.bayer,
            black_level: f.black_level,
            white_level: f.white_level,
            exposure_range_s: (opts.exposure_range_s[0], opts.exposure_range_s[1]),
            gain_range: (opts.gain_range[0], opts.gain_range[1]),
            f_number_range: opts.has_aperture.then_some((opts.f_number_range[0], opts.f_number_range[1])),
        };
        let settings = CaptureSettings {
            exposure_s: opts.exposure_s,
            gain: opts.gain,
            f_number: opts.has_aperture.then_some(opts.f_number),
        };
        SimCamera {
            info: super::info(gate.name(), &opts.model),
            gate,
            caps,
            settings,
            timing: *timing,
            world,
            source,
            frame_faults,
            pending: None,
            next_sequence: 0,
            readouts: 0,
            seed,
            last_noise_key: (0, 0),
        }
    }

    /// Bytes sent per frame: the configured figure, or 2 bytes per photosite.
    pub fn frame_bytes(&self) -> u64 {
        self.timing.frame_bytes.unwrap_or((self.caps.width * self.caps.height * 2) as u64)
    }

    /// The sensor-noise seed of a frame: keyed by the scene state and settings it shows and
    /// by how many frames in a row showed the same (so a series of dark frames still has
    /// independent noise), never by the frame counter, so a run resumed after a crash gets
    /// the same noise as the uninterrupted run at the same step.
    fn noise_seed(&mut self, p: &Pending) -> u64 {
        let j = &p.truth.joints;
        let s = &p.settings;
        let leds: Vec<u64> = p.truth.leds.iter().map(|l| l.to_bits()).collect();
        let base = crate::faults::seed_for(derive_seed(self.seed, "camera-noise", 0), &leds);
        let key = crate::faults::seed_for(
            base,
            &[
                j.rail.to_bits(),
                j.robot[0].to_bits(),
                j.robot[1].to_bits(),
                j.robot[2].to_bits(),
                j.turntable.to_bits(),
                p.truth.lamp_intensity.to_bits(),
                s.exposure_s.to_bits(),
                s.gain.to_bits(),
                s.f_number.map_or(0, f64::to_bits),
            ],
        );
        let repeat = if self.last_noise_key.0 == key { self.last_noise_key.1 + 1 } else { 0 };
        self.last_noise_key = (key, repeat);
        crate::faults::seed_for(key, &[repeat])
    }

    /// Time to transfer one frame to the host, seconds.
    pub fn transfer_s(&self) -> f64 {
        self.frame_bytes() as f64 / self.timing.transfer_bytes_per_s
    }

    fn check(&self, what: &str, v: f64, (lo, hi): (f64, f64)) -> Result<(), DeviceError> {
        if v >= lo && v <= hi {
            Ok(())
        } else {
            Err(DeviceError::out_of_range(&self.info.name, what, v, format!("[{lo}, {hi}]")))
        }
    }

    async fn command(&mut self, op: &str) -> Result<(), DeviceError> {
        self.gate.begin(op, COMMAND_TIMEOUT_S).await?;
        self.world.clock().sleep_s(self.timing.command_s).await;
        Ok(())
    }
}

impl_sim_device!(SimCamera);

#[async_trait]
impl Camera for SimCamera {
    fn capabilities(&self) -> CameraCapabilities {
        self.caps.clone()
    }

    fn settings(&self) -> CaptureSettings {
        self.settings
    }

    async fn set_exposure_s(&mut self, exposure_s: f64) -> Result<(), DeviceError> {
        self.check("exposure (s)", exposure_s, self.caps.exposure_range_s)?;
        self.command("set_exposure_s").await?;
        self.settings.exposure_s = exposure_s;
        Ok(())
    }

    async fn set_gain(&mut self, gain: f64) -> Result<(), DeviceError> {
        self.check("gain", gain, self.caps.gain_range)?;
        self.command("set_gain").await?;
        self.settings.gain = gain;
        Ok(())
    }

    async fn set_f_number(&mut self, f_number: f64) -> Result<(), DeviceError> {
        let Some(range) = self.caps.f_number_range else {
            return Err(DeviceError::unsupported(&self.info.name, "aperture control"));
        };
        self.check("f-number", f_number, range)?;
        self.command("set_f_number").await?;
        self.settings.f_number = Some(f_number);
        Ok(())
    }

    async fn trigger(&mut self, timeout_s: f64) -> Result<u64, DeviceError> {
        self.gate.begin("trigger", timeout_s).await?;
        if let Some(p) = self.pending.take() {
            // Contract (see the trait): a new trigger discards an unread frame, so a
            // retried capture never sticks on a frame whose read-out failed.
            tracing::warn!(device = %self.info.name, sequence = p.sequence, "unread frame discarded by a new trigger");
        }
        let t = &self.timing;
        let needed = t.trigger_latency_s + self.settings.exposure_s + t.read_out_s;
        if needed > timeout_s {
            self.world.clock().sleep_s(timeout_s).await;
            return Err(DeviceError::new(
                &self.info.name,
                ErrorKind::Timeout,
                format!("trigger: exposure and read-out need {needed:.3} s, more than the timeout {timeout_s} s"),
            ));
        }
        let clock = self.world.clock().clone();
        clock.sleep_s(t.trigger_latency_s).await;
        // The image is what the scene was at the start of the exposure; later changes
        // (the robot moving on during read-out and transfer) do not reach it.
        let truth = self.world.truth();
        clock.sleep_s(self.settings.exposure_s + t.read_out_s).await;
        let sequence = self.next_sequence;
        self.next_sequence += 1;
        self.pending = Some(Pending { sequence, truth, settings: self.settings });
        Ok(sequence)
    }

    async fn read_frame(&mut self, timeout_s: f64) -> Result<RawFrame, DeviceError> {
        let call = self.gate.begin("read_frame", timeout_s).await?;
        let Some(p) = self.pending.take() else {
            return Err(DeviceError::new(&self.info.name, ErrorKind::Other, "read_frame: no frame was triggered"));
        };
        self.readouts += 1;
        let name = self.info.name.clone();
        let clock = self.world.clock().clone();
        let fate = self.frame_faults.fate(self.readouts);
        let transfer_s = self.transfer_s();
        if fate == FrameFate::Dropped || transfer_s > timeout_s {
            if fate == FrameFate::Dropped {
                self.world.log_fault(&name, call, FaultKind::DroppedFrame);
            }
            clock.sleep_s(timeout_s).await;
            return Err(DeviceError::new(
                &name,
                ErrorKind::Timeout,
                format!("read_frame: frame {} did not arrive within {timeout_s} s", p.sequence),
            ));
        }
        let noise_seed = self.noise_seed(&p);
        let mut frame = self.source.render(&p.truth, &p.settings, noise_seed);
        let c = &self.caps;
        frame.meta.sequence = p.sequence;
        frame.meta.timestamp_s = p.truth.time_s;
        frame.meta.exposure_s = p.settings.exposure_s;
        frame.meta.gain = p.settings.gain;
        frame.meta.f_number = p.settings.f_number;
        frame.meta.black_level = c.black_level;
        frame.meta.white_level = c.white_level;
        frame.meta.bit_depth = c.bit_depth;
        frame.meta.bayer = c.bayer;
        // The camera computes the checksum before sending; the link may then damage data.
        let sent_checksum = frame_checksum(&frame.data);
        clock.sleep_s(transfer_s).await;
        if fate == FrameFate::Corrupted {
            self.world.log_fault(&name, call, FaultKind::CorruptFrame);
            self.frame_faults.corrupt(&mut frame.data, c.bit_depth, 1);
        }
        verify_frame(&name, &frame, sent_checksum)?;
        Ok(frame)
    }
}
