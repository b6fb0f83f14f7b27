//! Against Aravis's own GigE Vision fake camera (`arv-fake-gv-camera-0.8`, Debian
//! `aravis-tools`) on 127.0.0.1, opened by address: no discovery broadcast, loopback only.
#![cfg(feature = "aravis")]

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use ris_aravis::{AravisCamera, DeviceSpec, OpenOptions};
use ris_drivers::{Camera, ErrorKind, TriggerMode};

/// The fake camera process, killed on drop.
struct Fake(Child);

impl Fake {
    fn start() -> Fake {
        let child = Command::new("arv-fake-gv-camera-0.8")
            .args(["-i", "127.0.0.1"])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("arv-fake-gv-camera-0.8 (apt-get install aravis-tools)");
        std::thread::sleep(Duration::from_millis(500));
        Fake(child)
    }
}

impl Drop for Fake {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn open() -> AravisCamera {
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        match AravisCamera::open(
            DeviceSpec::parse("127.0.0.1"),
            OpenOptions {
                frame_rate: Some(100.0),
                ..OpenOptions::default()
            },
        ) {
            Ok(c) => return c,
            Err(e) if Instant::now() < deadline => {
                eprintln!("waiting for the fake camera: {e}");
                std::thread::sleep(Duration::from_millis(200));
            }
            Err(e) => panic!("fake camera on 127.0.0.1: {e}"),
        }
    }
}

/// One test so that only one fake camera binds 127.0.0.1:3956 at a time.
#[test]
fn triggered_frames_disconnect_and_reconnect() {
    let fake = Fake::start();
    let mut cam = open();
    assert_eq!((cam.info().width, cam.info().height), (512, 512));
    // The GigE Vision fake honours the software trigger (the in-process `Fake` interface
    // streams at its trigger frequency regardless), so the suite runs here.
    ris_drivers::conformance::camera(&mut cam, Duration::from_secs(2)).expect("conformance");
    cam.set_exposure_us(1000.0).expect("exposure");
    cam.set_trigger(TriggerMode::Software)
        .expect("software trigger");
    cam.start().expect("start");
    let mut ids = Vec::new();
    for _ in 0..3 {
        let t = Instant::now();
        cam.trigger().expect("trigger");
        let f = cam.next_frame(Duration::from_secs(3)).expect("frame");
        eprintln!("trigger to frame: {:?}", t.elapsed());
        assert_eq!((f.width(), f.height(), f.bit_depth), (512, 512, 8));
        ids.push(f.frame_id);
    }
    assert!(ids.windows(2).all(|w| w[1] != w[0]), "{ids:?}");

    // Kill the camera mid-stream: a typed disconnect within the timeout.
    drop(fake);
    let t = Instant::now();
    let mut kind = ErrorKind::Timeout;
    for _ in 0..5 {
        let _ = cam.trigger();
        match cam.next_frame(Duration::from_millis(500)) {
            Err(e) => {
                kind = e.kind;
                if kind == ErrorKind::Disconnected {
                    break;
                }
            }
            Ok(_) => continue,
        }
    }
    assert_eq!(kind, ErrorKind::Disconnected);
    assert!(t.elapsed() < Duration::from_secs(10), "{:?}", t.elapsed());

    // The camera returns: reconnect restores the stream and its trigger mode.
    let _fake = Fake::start();
    let deadline = Instant::now() + Duration::from_secs(10);
    while let Err(e) = cam.reconnect() {
        assert!(Instant::now() < deadline, "reconnect: {e}");
        std::thread::sleep(Duration::from_millis(300));
    }
    cam.trigger().expect("trigger after reconnect");
    let f = cam
        .next_frame(Duration::from_secs(3))
        .expect("frame after reconnect");
    assert_eq!(f.width(), 512);
}
