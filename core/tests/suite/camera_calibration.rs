//! Camera calibration on OpenCV's real `left01..14.jpg` (`../shared/data/opencv_chessboard_9x6`,
//! Apache-2.0): every board found, and K within the acceptance of the published reference
//! (fx = fy = 535.92, cx = 342.28, cy = 235.57, RMS 0.393 px with OpenCV).

use std::path::{Path, PathBuf};

use ris_core::calibrate::chessboard::{detect, BoardSize, DetectParams};
use ris_core::calibrate::{calibrate_camera, BoardView, CameraParams};
use ris_core::image::GrayImage;

fn images() -> Vec<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/opencv_chessboard_9x6");
    assert!(dir.is_dir(), "shared test data missing: {}", dir.display());
    let mut v: Vec<PathBuf> = std::fs::read_dir(&dir)
        .expect("read dir")
        .map(|e| e.expect("entry").path())
        .filter(|p| {
            let n = p.file_name().and_then(|n| n.to_str()).unwrap_or("");
            n.starts_with("left") && n.ends_with(".jpg")
        })
        .collect();
    v.sort();
    assert_eq!(v.len(), 13);
    v
}

fn views(paths: &[PathBuf]) -> Vec<BoardView> {
    let board = BoardSize { cols: 9, rows: 6 };
    paths
        .iter()
        .map(|p| {
            let img = GrayImage::load(p).expect("image");
            let corners = detect(
                &img.to_levels(),
                img.width as usize,
                img.height as usize,
                board,
                &DetectParams::default(),
            )
            .unwrap_or_else(|e| panic!("{}: {e}", p.display()));
            assert_eq!(
                corners.found(),
                54,
                "{}: {:?}",
                p.display(),
                corners.missing()
            );
            BoardView {
                name: p.display().to_string(),
                corners,
            }
        })
        .collect()
}

#[test]
fn opencv_left_images_calibrate_to_the_reference_intrinsics() {
    let views = views(&images());
    let cal =
        calibrate_camera(&views, 25.0, 640, 480, &CameraParams::default()).expect("calibrate");
    let (fx, fy, cx, cy) = (cal.k[0][0], cal.k[1][1], cal.k[0][2], cal.k[1][2]);
    eprintln!(
        "fx {fx:.2} fy {fy:.2} cx {cx:.2} cy {cy:.2} dist {:?} rms {:.4} dropped {:?}",
        cal.dist, cal.rms, cal.dropped
    );
    for v in &cal.views {
        eprintln!("  {} rms {:.3}", v.image, v.rms);
    }
    let reference = 535.9157;
    assert!((fx / reference - 1.0).abs() < 0.005, "fx {fx}");
    assert!((fy / reference - 1.0).abs() < 0.005, "fy {fy}");
    assert!((cx - 342.2832).abs() < 2.0, "cx {cx}");
    assert!((cy - 235.5708).abs() < 2.0, "cy {cy}");
    assert!(cal.rms <= 0.45, "rms {}", cal.rms);
    assert!(cal.views.len() >= 12, "{:?}", cal.dropped);
    // Square size is in millimetres: the boards hang 0.28–0.40 m in front of the camera.
    for v in &cal.views {
        assert!((250.0..450.0).contains(&v.t[2]), "{}: t {:?}", v.image, v.t);
    }
}

#[test]
fn with_fixed_aspect_the_result_matches_opencv_closely() {
    let views = views(&images());
    let params = CameraParams {
        fix_aspect: true,
        ..CameraParams::default()
    };
    let cal = calibrate_camera(&views, 25.0, 640, 480, &params).expect("calibrate");
    assert_eq!(cal.k[0][0], cal.k[1][1]);
    eprintln!(
        "fixed aspect: f {:.2} c ({:.2}, {:.2}) rms {:.4} dropped {}",
        cal.k[0][0],
        cal.k[0][2],
        cal.k[1][2],
        cal.rms,
        cal.dropped.len()
    );
    assert!((cal.k[0][0] / 535.9157 - 1.0).abs() < 0.005);
}
