//! Aravis's in-process "Fake" interface: a GenICam camera that lives in this process and
//! needs no network (the GigE Vision interface is disabled first, so nothing broadcasts).

use std::time::Duration;

use btfrig_genicam::{GenicamCamera, ImageFormat, OpenOptions, PixelFormat, Target, Trigger};

#[test]
fn every_frame_has_the_configured_size_format_exposure_and_gain() {
    btfrig_genicam::disable_gige_interface();
    btfrig_genicam::enable_fake_interface();
    let cam = GenicamCamera::open(OpenOptions::new(Target::Id("Fake_1".into()))).unwrap();
    let info = cam.info();
    println!("{info:?}");
    assert_eq!((info.vendor.as_str(), info.model.as_str()), ("Aravis", "Fake"));
    assert!(info.pixel_formats.iter().any(|f| f == "BayerRG8"), "{:?}", info.pixel_formats);

    // Formats the stock fake camera lists; each with its own size, exposure and gain.
    let cases =
        [("Mono8", 320, 240, 2000.0, 3.0), ("BayerRG8", 512, 256, 1500.0, 0.0), ("Mono16", 64, 48, 10_000.0, 7.0)];
    for (name, width, height, exposure_us, gain) in cases {
        let pixel_format = PixelFormat::from_name(name).unwrap();
        cam.set_image_format(ImageFormat { width, height, pixel_format }).unwrap();
        assert_eq!(cam.set_exposure_us(exposure_us).unwrap(), exposure_us);
        assert_eq!(cam.set_gain(gain).unwrap(), gain);
        cam.set_trigger(Trigger::Software).unwrap();
        cam.start().unwrap();
        let mut last = None;
        for _ in 0..5 {
            let f = cam.trigger_software(Duration::from_secs(5)).unwrap();
            assert_eq!((f.width, f.height, f.pixel_format), (width, height, pixel_format), "{name}");
            assert_eq!(f.data.len(), pixel_format.image_bytes(width as usize, height as usize), "{name}");
            assert_eq!((f.exposure_us, f.gain), (exposure_us, gain), "{name}");
            if let Some(prev) = last {
                assert_eq!(f.sequence, prev + 1, "{name}: one frame per trigger, ids unwrapped");
            }
            last = Some(f.sequence);
        }
        cam.stop().unwrap();
    }
    let stats = cam.stats().unwrap();
    println!("{stats:?}");
    assert_eq!((stats.completed, stats.failures, stats.timeouts, stats.skipped_ids), (15, 0, 0, 0));

    // What the camera does not offer is refused with what it does.
    let e = cam
        .set_image_format(ImageFormat {
            width: 64,
            height: 48,
            pixel_format: PixelFormat::from_name("BayerRG12").unwrap(),
        })
        .unwrap_err();
    assert!(e.to_string().contains("BayerRG12") && e.to_string().contains("Mono8"), "{e}");
    let e = cam.set_exposure_us(1e12).unwrap_err();
    assert!(e.to_string().contains("ExposureTime"), "{e}");
}

#[test]
fn opening_by_id_without_permission_refuses_to_broadcast() {
    let e = GenicamCamera::open(OpenOptions::new(Target::parse("Aravis-Fake-GV01"))).unwrap_err();
    assert!(e.to_string().contains("broadcasts"), "{e}");
    assert_eq!(e.kind(), btfrig_hw::ErrorKind::Unsupported);
}
