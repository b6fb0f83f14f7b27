//! The sequencer against the mock pair: a clean run records exactly what the simulator renders,
//! every injectable fault is detected and recovered from or reported, and no capture set ever
//! holds a frame under the wrong pattern.

use std::sync::Arc;
use std::time::Duration;

use ris_core::capture::CaptureSet;
use ris_core::pattern::Pattern;
use ris_core::sim::{Scene, SceneFile, Simulator};
use ris_drivers::mock::{
    replay_pair, simulated_pair, Fault, FaultInjector, MockCamera, MockProjector,
};
use ris_drivers::sequence::{acquire, Acquisition, SequenceError, SequenceParams};
use ris_drivers::{Camera, ErrorKind, Projector, Slide, TriggerMode};

const SCENE: &str = include_str!("../../config/scenes/tiny.toml");

fn scene(noise: f64) -> Scene {
    let mut f: SceneFile = toml::from_str(SCENE).expect("scene");
    f.render.supersample = 2;
    f.camera.noise = noise;
    f.camera.shot_noise = noise * 0.05;
    Scene::from_file(f, std::path::Path::new("."), "test scene").expect("scene")
}

fn params() -> SequenceParams {
    SequenceParams {
        timeout: Duration::from_millis(100),
        ..SequenceParams::default()
    }
}

struct Bench {
    sim: Arc<Simulator>,
    camera: MockCamera,
    projector: MockProjector,
    faults: FaultInjector,
    slides: Vec<Slide>,
}

fn bench(noise: f64) -> Bench {
    let sim = Arc::new(Simulator::new(scene(noise)));
    let (camera, projector, faults) = simulated_pair(sim.clone(), "pair1", 7);
    let slides = sim
        .layout()
        .sequence(true)
        .into_iter()
        .map(Slide::plain)
        .collect();
    Bench {
        sim,
        camera,
        projector,
        faults,
        slides,
    }
}

fn run(b: &mut Bench, p: &SequenceParams) -> Result<Acquisition, SequenceError> {
    let layout = b.sim.layout();
    acquire(
        &mut b.camera,
        &mut b.projector,
        &layout,
        &b.slides,
        p,
        &mut |_| {},
    )
}

/// Every frame equals the noise-free rendering of its own pattern.
fn assert_exact(b: &Bench, capture: &CaptureSet) {
    let layout = b.sim.layout();
    assert_eq!(capture.frames.len(), b.slides.len());
    for s in &b.slides {
        let want = b.sim.frame(&layout, s.pattern, 0);
        assert!(
            capture.frame(s.pattern) == Some(&want),
            "{} holds another pattern's frame",
            s.pattern.name()
        );
    }
}

#[test]
fn clean_sequence_records_every_pattern_with_metadata() {
    let mut b = bench(0.0);
    let mut seen = Vec::new();
    let layout = b.sim.layout();
    let acq = acquire(
        &mut b.camera,
        &mut b.projector,
        &layout,
        &b.slides,
        &params(),
        &mut |p| seen.push(p.done),
    )
    .expect("sequence");
    assert_exact(&b, &acq.capture);
    assert!(acq.report.retries.is_empty(), "{:?}", acq.report.retries);
    assert_eq!(acq.report.triggers, b.slides.len() as u64);
    assert_eq!(seen, (1..=b.slides.len()).collect::<Vec<_>>());
    let ids = acq.capture.meta["frame_ids"].as_table().expect("frame ids");
    assert_eq!(
        ids["white"].as_array().expect("ids")[0].as_integer(),
        Some(1)
    );
    assert_eq!(acq.capture.meta["camera"].as_str(), Some("pair1/camera"));
}

#[test]
fn each_transient_fault_is_detected_and_recovered() {
    for (fault, at, evidence) in [
        (Fault::DropFrame, 3, "dropped"),
        (Fault::MissedTrigger, 5, "timeout"),
        (Fault::LateFrame, 6, "stale"),
        (Fault::WrongPattern, 7, "wrong slide"),
        (Fault::WrongPattern, 0, "white or black"),
        (Fault::Disconnect, 8, "reconnected"),
        (
            Fault::StreamStall,
            9,
            "reconnected after: no frame on 2 triggers in a row",
        ),
    ] {
        let mut b = bench(0.0);
        b.faults.at(at, fault);
        let acq = run(&mut b, &params()).unwrap_or_else(|e| panic!("{fault:?}: {e}"));
        assert_exact(&b, &acq.capture);
        let reasons: Vec<&str> = acq.report.retries.iter().map(|r| r.1.as_str()).collect();
        assert!(
            reasons.iter().any(|r| r.contains(evidence)),
            "{fault:?} at {at}: retries {reasons:?}"
        );
    }
}

#[test]
fn a_projector_slower_than_its_settle_time_is_recaptured_with_a_longer_wait() {
    // Every slide reaches the screen 60 ms after it is shown: each first exposure sees the
    // slide before it. The content checks find them, and the recapture waits long enough.
    let mut b = bench(0.0);
    b.faults.set_latency(std::time::Duration::from_millis(60));
    let acq = run(&mut b, &params()).expect("sequence");
    assert_exact(&b, &acq.capture);
    assert!(!acq.report.retries.is_empty());
    assert!(
        (0.06..=1.0).contains(&acq.report.settle_s),
        "settle {} s",
        acq.report.settle_s
    );
    // Without the latency nothing is raised.
    let mut b = bench(0.0);
    let acq = run(&mut b, &params()).expect("sequence");
    assert_eq!(acq.report.settle_s, 0.0);
}

#[test]
fn duplicated_frames_are_drained_not_recorded() {
    let mut b = bench(0.0);
    b.faults.at(4, Fault::DuplicateFrame);
    b.faults.at(9, Fault::DuplicateFrame);
    let acq = run(&mut b, &params()).expect("sequence");
    assert_exact(&b, &acq.capture);
    assert_eq!(acq.report.stale_frames, 2);
}

#[test]
fn persistent_faults_fail_with_the_slide_and_reason() {
    // The camera ignores every trigger from the fourth on.
    let mut b = bench(0.0);
    for i in 3..20 {
        b.faults.at(i, Fault::MissedTrigger);
    }
    let err = run(&mut b, &params()).expect_err("must fail");
    let msg = err.to_string();
    assert!(matches!(err, SequenceError::Mismatch { .. }), "{msg}");
    assert!(
        msg.contains("gray_col_00_inv") && msg.contains("timeout"),
        "{msg}"
    );

    // A disconnect that does not come back.
    let mut b = bench(0.0);
    b.faults.set_reconnectable(false);
    b.faults.at(2, Fault::Disconnect);
    let err = run(&mut b, &params()).expect_err("must fail");
    match &err {
        SequenceError::Driver { source, .. } => assert_eq!(source.kind, ErrorKind::Disconnected),
        other => panic!("{other}"),
    }
    assert!(err.to_string().contains("did not come back"), "{err}");

    // A stream that stops while the camera keeps answering, with no reconnect allowed: the
    // triggers time out until the attempts are spent.
    let mut b = bench(0.0);
    b.faults.at(6, Fault::StreamStall);
    let err = run(
        &mut b,
        &SequenceParams {
            reconnects: 0,
            ..params()
        },
    )
    .expect_err("must fail");
    assert!(matches!(err, SequenceError::Mismatch { .. }), "{err}");
    assert!(err.to_string().contains("timeout"), "{err}");

    // The projector keeps showing the wrong slide from the fifth exposure on.
    let mut b = bench(0.0);
    for i in 4..400 {
        b.faults.at(i, Fault::WrongPattern);
    }
    let err = run(&mut b, &params()).expect_err("must fail");
    assert!(
        err.to_string().contains("wrong slide") || err.to_string().contains("white or black"),
        "{err}"
    );
}

#[test]
fn averaging_m_frames_reduces_noise_by_sqrt_m() {
    let noise = 3.0;
    let clean = Simulator::new(scene(0.0));
    let layout = clean.layout();
    let truth = clean.frame(&layout, Pattern::White, 0).to_u16();
    let mut rms = Vec::new();
    for m in [1u32, 4] {
        let mut b = bench(noise);
        b.slides = vec![Slide::plain(Pattern::White), Slide::plain(Pattern::Black)];
        let p = SequenceParams {
            average: m,
            ..params()
        };
        let acq = run(&mut b, &p).expect("sequence");
        assert_eq!(acq.report.triggers, 2 * u64::from(m));
        let got = acq.capture.frame(Pattern::White).expect("white").to_u16();
        // Unsaturated pixels only; values are 8-bit scaled by 257.
        let d: Vec<f64> = got
            .iter()
            .zip(&truth)
            .filter(|(_, &t)| t < 200 * 257)
            .map(|(&g, &t)| (f64::from(g) - f64::from(t)) / 257.0)
            .collect();
        rms.push((d.iter().map(|x| x * x).sum::<f64>() / d.len() as f64).sqrt());
    }
    eprintln!("noise rms: m=1 {:.3} DN, m=4 {:.3} DN", rms[0], rms[1]);
    // σ/√4 plus the rounding of the mean (±0.5 DN uniform adds 0.29 DN in quadrature).
    let expected = ((rms[0] / 2.0).powi(2) + 1.0 / 12.0).sqrt();
    assert!(
        (rms[1] - expected).abs() < 0.15 * expected,
        "{rms:?} vs {expected}"
    );
}

#[test]
fn replay_pair_serves_a_recorded_capture() {
    let b = bench(0.0);
    let layout = b.sim.layout();
    let recorded = Arc::new(b.sim.capture(&layout, 0, &|_, _| {}));
    let (mut camera, mut projector, faults) = replay_pair(recorded.clone(), "replay");
    faults.at(2, Fault::WrongPattern);
    let acq = acquire(
        &mut camera,
        &mut projector,
        &layout,
        &b.slides,
        &params(),
        &mut |_| {},
    )
    .expect("replay");
    for (p, img) in &recorded.frames {
        assert_eq!(acq.capture.frame(*p), Some(img), "{}", p.name());
    }
}

#[test]
fn mock_camera_modes_and_errors() {
    let mut b = bench(0.0);
    assert_eq!(
        b.camera.trigger().expect_err("not streaming").kind,
        ErrorKind::Busy
    );
    assert_eq!(
        b.camera
            .set_exposure_us(-1.0)
            .expect_err("bad exposure")
            .kind,
        ErrorKind::InvalidArgument
    );
    b.projector.load(&b.slides).expect("load");
    assert_eq!(
        b.projector.show(999).expect_err("bad slot").kind,
        ErrorKind::InvalidArgument
    );
    // Hardware trigger: the projector's sync exposes a frame at every show.
    b.camera
        .set_trigger(TriggerMode::Hardware {
            source: "Line0".into(),
        })
        .expect("mode");
    b.camera.start().expect("start");
    assert_eq!(
        b.camera
            .set_trigger(TriggerMode::Software)
            .expect_err("busy while streaming")
            .kind,
        ErrorKind::Busy
    );
    b.projector.show(0).expect("show");
    let f = b
        .camera
        .next_frame(Duration::from_millis(100))
        .expect("frame");
    assert_eq!(f.frame_id, 1);
    assert_eq!(
        b.camera
            .next_frame(Duration::from_millis(20))
            .expect_err("no frame")
            .kind,
        ErrorKind::Timeout
    );
    // Doubling the exposure doubles the signal below saturation.
    b.camera.stop().expect("stop");
    b.camera.set_trigger(TriggerMode::Software).expect("mode");
    b.camera.start().expect("start");
    b.projector.show(2).expect("show");
    b.camera.trigger().expect("trigger");
    let one = b
        .camera
        .next_frame(Duration::from_millis(100))
        .expect("frame")
        .image
        .to_u16();
    b.camera.set_exposure_us(20_000.0).expect("exposure");
    b.camera.trigger().expect("trigger");
    let two = b
        .camera
        .next_frame(Duration::from_millis(100))
        .expect("frame")
        .image
        .to_u16();
    let (mut s1, mut s2) = (0.0, 0.0);
    for (a, c) in one.iter().zip(&two) {
        // Lit and unsaturated (rounding to whole DN dominates in the dark).
        if *a >= 20 * 257 && *c < 250 * 257 {
            s1 += f64::from(*a);
            s2 += f64::from(*c);
        }
    }
    assert!((s2 / s1 - 2.0).abs() < 0.02, "ratio {}", s2 / s1);
}

#[test]
fn mock_pair_passes_the_conformance_suite() {
    use ris_drivers::conformance;
    let mut b = bench(0.5);
    conformance::projector(&mut b.projector).expect("mock projector");
    conformance::camera(&mut b.camera, Duration::from_secs(2)).expect("mock camera");
    // A replayed capture behaves the same.
    let capture = run(&mut bench(0.0), &params()).expect("capture").capture;
    let (mut camera, mut projector, _) = replay_pair(Arc::new(capture), "replay");
    conformance::projector(&mut projector).expect("replay projector");
    conformance::camera(&mut camera, Duration::from_secs(2)).expect("replay camera");
}

#[test]
fn hardware_trigger_exposes_at_presentation_and_recovers_faults() {
    // The projector's sync output on the camera's line: no trigger command, one exposure per
    // presentation, the same frames as under the software trigger; averaging re-shows.
    let mut b = bench(0.0);
    let hw = SequenceParams {
        trigger: TriggerMode::Hardware {
            source: "Line0".into(),
        },
        ..params()
    };
    let acq = run(&mut b, &hw).expect("hardware-triggered sequence");
    assert_exact(&b, &acq.capture);
    assert_eq!(acq.report.triggers, b.slides.len() as u64);
    assert!(acq.report.retries.is_empty(), "{:?}", acq.report.retries);
    let averaged = run(
        &mut b,
        &SequenceParams {
            average: 3,
            ..hw.clone()
        },
    )
    .expect("averaged");
    assert_exact(&b, &averaged.capture);
    assert_eq!(averaged.report.shows, 3 * b.slides.len() as u64);
    // A dropped and a duplicated frame are caught exactly as under the software trigger.
    let at = b.faults.exposures();
    b.faults.at(at + 4, Fault::DropFrame);
    b.faults.at(at + 9, Fault::DuplicateFrame);
    let acq = run(&mut b, &hw).expect("recovered");
    assert_exact(&b, &acq.capture);
    assert_eq!(acq.report.retries.len(), 2, "{:?}", acq.report.retries);
    // A free-running camera cannot be sequenced.
    let free = SequenceParams {
        trigger: TriggerMode::FreeRun,
        ..params()
    };
    assert!(matches!(run(&mut b, &free), Err(SequenceError::Invalid(_))));
}
