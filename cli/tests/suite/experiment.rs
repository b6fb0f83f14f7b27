//! The Table 7.1 experiment on the challenge scene (black box, dark dome, shiny sphere and box
//! with specular lobes and inter-reflection): the adaptive projection mask must recover what a
//! powder-sprayed part gives, where the naive scan loses the black part.

use std::path::Path;

use ris_cli::commands::experiment::completeness;

#[test]
fn adaptive_mask_recovers_challenging_materials() {
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/scenes/challenge.toml");
    let c = completeness(&scene, None).expect("experiment");
    ris_cli::commands::experiment::print_table(&c);
    for (name, f) in &c.materials {
        assert!(
            f.sprayed > 5000,
            "{name}: only {} sprayed points",
            f.sprayed
        );
        assert!(
            f.adaptive_relative >= 0.97,
            "{name}: adaptive {:.1} % of sprayed",
            100.0 * f.adaptive_relative
        );
        assert!(
            f.adaptive_mean_abs_error_mm <= 0.1,
            "{name}: mean |error| {:.4} mm",
            f.adaptive_mean_abs_error_mm
        );
    }
    let black = &c.materials["black"];
    assert!(
        black.naive_relative <= 0.8,
        "naive black {:.1} %",
        100.0 * black.naive_relative
    );
    let json = serde_json::to_value(&c).expect("json");
    for key in ["sprayed", "naive", "adaptive", "adaptive_mean_abs_error_mm"] {
        assert!(json["materials"]["shiny"][key].is_number(), "{key} missing");
    }
    assert!(c.adaptive_frames > c.naive_frames);
}

/// Ch. 7.1.2 measured: as the demo scene's parts move along x (a conveyor), the Gray-code
/// scan (42 frames at 60 fps) smears and its error grows, while one single-shot frame keeps
/// its error and its points. One ray per pixel keeps the test short (each moving frame is
/// rendered twice over its exposure); the figures are those of supersampling 2 within
/// 0.022 mm and 0.2 % of the points.
#[test]
fn a_moving_part_smears_the_gray_scan_but_not_the_single_shot_frame() {
    let dir = tempfile::tempdir().expect("tmp");
    let demo = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/scenes/demo.toml"),
    )
    .expect("demo scene");
    let scene = dir.path().join("moving.toml");
    std::fs::write(&scene, demo + "\n[render]\nsupersample = 1\n").expect("scene");
    let m =
        ris_cli::commands::experiment::motion(&scene, &[0.0, 100.0], [1.0, 0.0, 0.0], 60.0, 5.0)
            .expect("experiment");
    ris_cli::commands::experiment::print_motion(&m);
    let (still, moving) = (&m.rows[0], &m.rows[1]);
    assert_eq!(m.gray_frames, 42);
    assert!((moving.gray_travel_mm - 100.0 * 41.0 / 60.0).abs() < 1e-9);
    // Still, the Gray-code scan is the accurate one.
    assert!(still.gray_mean_abs_mm < 0.1, "{still:?}");
    assert!(still.single_mean_abs_mm < 0.5, "{still:?}");
    // Moving: the Gray-code error grows several times and points leave the 1 mm band ...
    assert!(
        moving.gray_mean_abs_mm > 4.0 * still.gray_mean_abs_mm,
        "gray {:.3} -> {:.3} mm",
        still.gray_mean_abs_mm,
        moving.gray_mean_abs_mm
    );
    assert!(
        (moving.gray_within_1mm as f64) < 0.95 * still.gray_within_1mm as f64,
        "gray within 1 mm {} -> {}",
        still.gray_within_1mm,
        moving.gray_within_1mm
    );
    // ... while the single frame stays as it was.
    assert!(
        (moving.single_mean_abs_mm - still.single_mean_abs_mm).abs() < 0.05,
        "single-shot {:.3} -> {:.3} mm",
        still.single_mean_abs_mm,
        moving.single_mean_abs_mm
    );
    assert!(
        (moving.single_within_1mm as f64) > 0.97 * still.single_within_1mm as f64,
        "single-shot within 1 mm {} -> {}",
        still.single_within_1mm,
        moving.single_within_1mm
    );
    let bad = ris_cli::commands::experiment::motion(&scene, &[-1.0], [1.0, 0.0, 0.0], 60.0, 5.0);
    assert!(bad.is_err());
}
