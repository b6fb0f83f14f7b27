//! The Table 7.1 experiment on the challenge scene (black box, dark dome, shiny sphere and box
//! with specular lobes and inter-reflection): the adaptive projection mask must recover what a
//! powder-sprayed part gives, where the naive scan loses the black part.

use std::path::Path;

use ris_daemon::commands::experiment::completeness;

#[test]
fn adaptive_mask_recovers_challenging_materials() {
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/scenes/challenge.toml");
    let c = completeness(&scene, None).expect("experiment");
    ris_daemon::commands::experiment::print_table(&c);
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
