//! A scan through the real hardware paths: the projector window under Xvfb shows every slide,
//! and a GigE Vision camera on 127.0.0.1 (Aravis's device-side implementation in this process,
//! its images rendered by the simulator for the slide on screen) is opened by address and
//! software-triggered through the sequencer. Its capture and cloud must equal those of the pure
//! mock pair on the same scene.
#![cfg(all(feature = "aravis", feature = "projector"))]

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Duration;

use ris_aravis::{AravisCamera, DeviceSpec, LoopbackCamera, OpenOptions};
use ris_core::capture::CaptureSet;
use ris_core::decode::{decode, DecodeParams};
use ris_core::image::Pixels;
use ris_core::sensor::Reconstructor;
use ris_core::sim::{Scene, SceneFile, Simulator};
use ris_drivers::mock::simulated_pair;
use ris_drivers::sequence::{acquire, SequenceParams};
use ris_drivers::{Projector, ProjectorInfo, Shown, Slide};
use ris_projector::{WindowOptions, WindowProjector};

mod common;
use common::Xvfb;

/// The window projector, telling the simulated optics which slide is on screen once it is.
struct Optics {
    window: WindowProjector,
    on_screen: Arc<AtomicUsize>,
}

impl Projector for Optics {
    fn info(&self) -> &ProjectorInfo {
        self.window.info()
    }
    fn load(&mut self, slides: &[Slide]) -> ris_drivers::Result<()> {
        self.window.load(slides)
    }
    fn show(&mut self, slot: usize) -> ris_drivers::Result<Shown> {
        let shown = self.window.show(slot)?;
        self.on_screen.store(slot, Ordering::SeqCst);
        Ok(shown)
    }
}

fn scene() -> Scene {
    let mut f: SceneFile =
        toml::from_str(include_str!("../../config/scenes/tiny.toml")).expect("scene");
    // Noise-free, so that both paths render the same images.
    f.camera.noise = 0.0;
    f.camera.shot_noise = 0.0;
    Scene::from_file(f, std::path::Path::new("."), "tiny scene").expect("scene")
}

fn cloud(scene: &Scene, capture: &CaptureSet) -> Vec<[f32; 3]> {
    let decoded = decode(capture, &DecodeParams::default()).expect("decode");
    Reconstructor::classical(&scene.camera, &scene.projector)
        .reconstruct(&decoded)
        .expect("reconstruct")
        .points
}

#[test]
fn a_scan_through_the_gige_camera_and_the_projector_window_equals_the_mock_scan() {
    let scene = scene();
    let sim = Arc::new(Simulator::new(scene.clone()));
    let layout = sim.layout();
    let slides: Vec<Slide> = layout
        .sequence(true)
        .into_iter()
        .map(Slide::plain)
        .collect();
    let params = SequenceParams {
        timeout: Duration::from_secs(2),
        ..SequenceParams::default()
    };

    // The pure mock pair.
    let (mut cam, mut proj, _) = simulated_pair(sim.clone(), "mock", 1);
    let mock = acquire(&mut cam, &mut proj, &layout, &slides, &params, &mut |_| {})
        .expect("mock scan")
        .capture;

    // The hardware paths.
    let x = Xvfb::start(None, layout.width, layout.height).expect("Xvfb (.ci/run installs it)");
    // This test binary holds one test, so no other thread reads the environment meanwhile.
    std::env::set_var("DISPLAY", x.display());
    let window = WindowProjector::open(&WindowOptions {
        width: layout.width,
        height: layout.height,
        monitor: 0,
    })
    .expect("projector window");
    let on_screen = Arc::new(AtomicUsize::new(0));
    let frames: Vec<Vec<u8>> = slides
        .iter()
        .map(|s| match sim.frame(&layout, s.pattern, 0).pixels {
            Pixels::U8(v) => v,
            Pixels::U16(_) => panic!("the tiny scene's camera is 8-bit"),
        })
        .collect();
    let shown = on_screen.clone();
    let (w, h) = (scene.camera.width, scene.camera.height);
    let _gige = LoopbackCamera::start(
        "127.0.0.1",
        200.0,
        Box::new(move |buf: &mut [u8], fw: u32, fh: u32, _exposure_us: f64| {
            if (fw, fh) == (w, h) {
                buf.copy_from_slice(&frames[shown.load(Ordering::SeqCst)]);
            }
        }),
    )
    .expect("loopback GigE Vision camera");
    let mut camera = AravisCamera::open(
        DeviceSpec::parse("127.0.0.1"),
        OpenOptions {
            roi: Some((0, 0, w as i32, h as i32)),
            ..OpenOptions::default()
        },
    )
    .expect("camera on 127.0.0.1");
    let mut optics = Optics { window, on_screen };
    let acquired = acquire(
        &mut camera,
        &mut optics,
        &layout,
        &slides,
        &params,
        &mut |_| {},
    )
    .expect("scan through the GigE camera and the window");
    eprintln!(
        "hardware-path scan: {} triggers, {} retries, {} stale frames",
        acquired.report.triggers,
        acquired.report.retries.len(),
        acquired.report.stale_frames
    );
    let hw = acquired.capture;

    assert_eq!(hw.frames.len(), mock.frames.len());
    for ((p, a), (q, b)) in hw.frames.iter().zip(&mock.frames) {
        assert_eq!(p, q);
        assert!(a == b, "frame {} differs from the mock's", p.name());
    }
    let (a, b) = (cloud(&scene, &hw), cloud(&scene, &mock));
    assert!(a.len() > 5_000, "{} points", a.len());
    assert_eq!(a, b, "the clouds differ");

    // The X server ends under the open window: the projector reports it (Xlib's default would
    // exit the process from the display thread), and this process goes on to pass.
    drop(x);
    let t = std::time::Instant::now();
    let lost = loop {
        match optics.show(0) {
            Err(e) => break e,
            Ok(_) => {
                assert!(
                    t.elapsed() < Duration::from_secs(10),
                    "the window kept presenting after its X server ended"
                );
                std::thread::sleep(Duration::from_millis(50));
            }
        }
    };
    assert_eq!(lost.kind, ris_drivers::ErrorKind::Disconnected, "{lost}");
    assert!(lost.to_string().contains("X server"), "{lost}");
    assert!(
        t.elapsed() < Duration::from_secs(5),
        "the loss took {:?} to surface",
        t.elapsed()
    );
}
