//! Against a physical V4L2 camera (this machine has none and cannot load one). Run on a machine
//! with a camera:
//!
//! ```sh
//! RIS_V4L2_DEVICE=/dev/video0 cargo test -p ris-v4l2 --features v4l2 --test device -- --ignored
//! ```
#![cfg(feature = "v4l2")]

use std::path::PathBuf;
use std::time::Duration;

use ris_drivers::Camera;
use ris_v4l2::V4l2Camera;

#[test]
#[ignore = "needs a V4L2 camera: RIS_V4L2_DEVICE=/dev/video0 cargo test -p ris-v4l2 --features v4l2 --test device -- --ignored"]
fn a_real_camera_passes_the_conformance_suite() {
    let path =
        PathBuf::from(std::env::var("RIS_V4L2_DEVICE").unwrap_or_else(|_| "/dev/video0".into()));
    let mut cam = V4l2Camera::open(&path, None, None).expect("open");
    eprintln!(
        "{}: {} {}x{}, {} bit",
        cam.info().id,
        cam.info().model,
        cam.info().width,
        cam.info().height,
        cam.info().bit_depth
    );
    ris_drivers::conformance::camera(&mut cam, Duration::from_secs(2)).expect("conformance");
}
