//! `EmulatedBackend::open_calibration`: the inner backend opens the simulated halves with the
//! target mounted (here a stand-in inner backend, since the simulated rig's calibration
//! targets are being built elsewhere), and the emulated devices come back behind their
//! firmware, as for a run.

use std::sync::{Arc, Mutex};

use btfrig_core::config::RigConfig;
use btfrig_emulated_backend::EmulatedBackend;
use btfrig_measurement::backend::{
    CalibrationOpenRequest, GonioOpenRequest, InProcess, MountedTarget, OpenedGonio, OpenedRig, RigBackend, RigTime,
};
use btfrig_measurement::RunError;
use btfrig_sim::{FaultScenario, FlatFrameSource, SimRig};

const SERIAL: &str = include_str!("../../../rig-configs/bonn-gonio-serial.toml");

/// An inner backend whose calibration opening is the simulated devices of the rig it is given
/// (which it records), with a flat frame source.
#[derive(Default)]
struct Inner {
    asked: Mutex<Vec<(RigConfig, MountedTarget)>>,
}

#[async_trait::async_trait]
impl RigBackend for Inner {
    fn name(&self) -> &'static str {
        "test inner"
    }

    fn kinds(&self) -> &'static [&'static str] {
        &["sim"]
    }

    async fn open_gonio(&self, _req: GonioOpenRequest<'_>) -> Result<OpenedGonio, RunError> {
        Err(RunError::Rig("not here".into()))
    }

    async fn open_calibration(&self, req: CalibrationOpenRequest<'_>) -> Result<OpenedRig, RunError> {
        self.asked.lock().unwrap().push((req.rig.clone(), req.target.clone()));
        let clock = btfrig_hw::TokioClock::shared();
        let sim = SimRig::from_rig_config(
            req.rig,
            &FaultScenario::none(),
            clock.clone(),
            Arc::new(FlatFrameSource::new(8, 6, 100.0)),
        )
        .map_err(|e| RunError::Rig(e.to_string()))?;
        let SimRig { robot, rail, lamp, camera, .. } = sim;
        Ok(OpenedRig::Gonio(OpenedGonio { robot, rail, lamp, camera, clock, truth: None, links: Box::new(InProcess) }))
    }
}

#[test]
fn calibration_devices_come_back_behind_their_emulated_firmware() {
    let rig = RigConfig::from_toml(SERIAL, "bonn-gonio-serial").unwrap();
    let inner = Arc::new(Inner::default());
    let backend = EmulatedBackend::new(inner.clone());
    let rt = btfrig_measurement::virtual_time_runtime().unwrap();
    let target = MountedTarget::WhiteTile { albedo: 0.9 };
    let opened = rt
        .block_on(backend.open_calibration(CalibrationOpenRequest {
            rig: &rig,
            target: &target,
            cameras: &[],
            seed: 1,
            time: RigTime::Virtual,
        }))
        .unwrap_or_else(|e| panic!("{e}"));
    let OpenedRig::Gonio(mut g) = opened else { panic!("a gonioreflectometer was asked for") };
    // The devices are the real serial and PTP backends in front of the simulated ones.
    assert_eq!(g.robot.info().backend, "serial-robot");
    assert_eq!(g.camera.info().backend, "ptp");
    assert_eq!(g.links.count(), 4, "robot, rail, lamp and camera firmware");
    // They work: the robot answers through its firmware and homes on virtual time.
    rt.block_on(async {
        assert!(!g.robot.is_homed().await.unwrap());
        g.robot.home(btfrig_hw::MoveOptions::default()).await.unwrap();
        assert!(g.robot.is_homed().await.unwrap());
    });
    // The inner backend got the simulated rig behind the firmware, and the target.
    let asked = inner.asked.lock().unwrap();
    assert_eq!(asked.len(), 1);
    assert!(asked[0].0.devices.entries().iter().all(|(_, e)| e.kind == "sim"), "{:?}", asked[0].0.devices);
    assert_eq!(asked[0].1, target);
    drop(g);
}

#[test]
fn real_devices_on_virtual_time_are_refused_naming_them() {
    let text = SERIAL.replacen("link = { emulated = true, poll_s = 0.01 }", "link = { port = \"/dev/ttyNOPE\" }", 1);
    let rig = RigConfig::from_toml(&text, "real robot").unwrap();
    let backend = EmulatedBackend::new(Arc::new(Inner::default()));
    let rt = btfrig_measurement::virtual_time_runtime().unwrap();
    let target = MountedTarget::Capped;
    let e = rt
        .block_on(backend.open_calibration(CalibrationOpenRequest {
            rig: &rig,
            target: &target,
            cameras: &[],
            seed: 1,
            time: RigTime::Virtual,
        }))
        .err()
        .expect("refused");
    assert!(e.to_string().contains("devices.robot") && e.to_string().contains("wall clock"), "{e}");
    assert_eq!(RigTime::for_rig(&rig), RigTime::Wall);
}
