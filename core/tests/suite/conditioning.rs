//! Registration conditioning over seeded families of parts: a plane cannot pin its in-plane
//! position, a cylinder-like sheet its axis, a gently curved panel its slide along its own
//! curvature — registered from the data alone, each is `not_measured` with the direction
//! named, never a confident map; started from a calibrated nominal pose (a cell), the report
//! says the position along that direction is the calibration's. A part with features pins
//! every direction.

use ris_core::geometry::{Point3, Vec3, Vector3};
use ris_core::inspect::{inspect, InspectParams, Report};
use ris_core::mesh::{SignedDistance, TriangleMesh};
use ris_core::register::Pose;

use crate::common;
use common::{seeds, Rng};

/// Inspect a cloud sampled from `surface` over ±hx × ±hy (CAD frame), seen from a random pose
/// with noise; the registration starts near the truth.
fn case(seed: u64, hx: f64, hy: f64, prior: bool, surface: &dyn Fn(f64, f64) -> f64) -> Report {
    let mut r = Rng(seed);
    let mesh = TriangleMesh::height_field(120, 90, (-hx, hx), (-hy, hy), surface);
    let cad = SignedDistance::new(mesh);
    let sensor_from_cad = Pose::new(
        Vector3::new(
            r.range(-300.0, 300.0),
            r.range(-300.0, 300.0),
            r.range(500.0, 900.0),
        ),
        Vector3::new(r.range(-0.5, 0.5), r.range(-0.5, 0.5), r.range(-3.0, 3.0)),
    );
    let noise = r.range(0.01, 0.05);
    let h = 1e-3;
    let pts: Vec<[f64; 3]> = (0..20_000)
        .map(|_| {
            let (x, y) = (
                r.range(-0.97 * hx, 0.97 * hx),
                r.range(-0.97 * hy, 0.97 * hy),
            );
            let dx = (surface(x + h, y) - surface(x - h, y)) / (2.0 * h);
            let dy = (surface(x, y + h) - surface(x, y - h)) / (2.0 * h);
            let n = Vec3::new(-dx, -dy, 1.0).normalize();
            let p = Vec3::new(x, y, surface(x, y)) + n * (noise * r.gauss());
            (sensor_from_cad * Point3::from(p)).coords.into()
        })
        .collect();
    // Start 1 mm and 0.2° off the truth.
    let nudge = Pose::new(
        Vector3::new(0.6, -0.5, 0.6),
        Vector3::new(0.002, -0.002, 0.003),
    );
    inspect(
        &pts,
        &cad,
        &InspectParams {
            tolerance: 0.3,
            init: prior.then(|| nudge * sensor_from_cad.inverse()),
            ..InspectParams::default()
        },
    )
    .expect("inspection")
    .report
}

fn unpinned(report: &Report) -> Vec<&ris_core::inspect::Direction> {
    report
        .conditioning
        .directions
        .iter()
        .filter(|d| d.strength < ris_core::inspect::UNPINNED_STRENGTH)
        .collect()
}

#[test]
fn planes_and_cylinders_are_not_measured_features_pin_every_direction() {
    for seed in seeds(2, 6) {
        let mut r = Rng(seed * 7 + 1);
        let (hx, hy) = (r.range(120.0, 300.0), r.range(90.0, 250.0));

        let plane = case(seed, hx, hy, false, &|_, _| 0.0);
        let free = unpinned(&plane);
        assert_eq!(
            plane.verdict, "not_measured",
            "plane {seed}: {:?}",
            plane.reasons
        );
        assert!(
            plane.reasons.iter().any(|m| m.contains("cannot pin")),
            "plane {seed}: {:?}",
            plane.reasons
        );
        assert!(
            free.len() >= 3,
            "plane {seed}: {} free directions",
            free.len()
        );
        assert!(
            free.iter()
                .any(|d| d.kind == "translation" && d.axis[2].abs() < 0.1),
            "plane {seed}: an in-plane translation must be free: {free:?}"
        );

        let radius = r.range(250.0, 700.0);
        let cylinder = case(seed + 100, hx, hy, false, &move |x, _| {
            x * x / (2.0 * radius)
        });
        let free = unpinned(&cylinder);
        assert_eq!(
            cylinder.verdict, "not_measured",
            "cylinder {seed}: {:?}",
            cylinder.reasons
        );
        assert!(
            free.iter()
                .any(|d| d.kind == "translation" && d.axis[1].abs() > 0.9),
            "cylinder {seed} (R {radius:.0}): the axis (y) must be free: {free:?}"
        );

        let bumps = case(seed + 200, hx, hy, seed % 2 == 0, &|x, y| {
            35.0 * (x / 80.0).sin() * (y / 70.0).cos() + 0.0006 * x * x
        });
        assert!(
            bumps.conditioning.pinned,
            "bumps {seed}: {:?}",
            bumps.conditioning
        );
        assert_eq!(bumps.verdict, "pass", "bumps {seed}: {:?}", bumps.reasons);
        assert!(
            bumps.warnings.iter().all(|w| w.contains("weakly pinned")),
            "bumps {seed}: {:?}",
            bumps.warnings
        );
        assert!(
            bumps.conditioning.directions[0].slide_mm < 20.0 * 0.3,
            "bumps {seed}: {:?}",
            bumps.conditioning.directions[0]
        );
    }
}

#[test]
fn a_gently_curved_panel_slides_along_itself_unless_a_calibrated_pose_holds_it() {
    for seed in seeds(2, 4) {
        let mut r = Rng(seed + 40);
        let (a, b) = (r.range(4000.0, 6000.0), r.range(7000.0, 9000.0));
        let surface = move |x: f64, y: f64| -x * x / a - y * y / b;
        // From the data alone: the slide along the surface is not pinned.
        let alone = case(seed + 300, 550.0, 400.0, false, &surface);
        assert!(
            !alone.conditioning.pinned,
            "panel {seed}: {:?}",
            alone.conditioning
        );
        assert_eq!(
            alone.verdict, "not_measured",
            "panel {seed}: {:?}",
            alone.reasons
        );
        let weakest = &alone.conditioning.directions[0];
        assert!(
            weakest.kind == "translation" && weakest.axis[2].abs() < 0.1,
            "panel {seed}: the weakest direction is a slide along the surface: {weakest:?}"
        );
        assert!(weakest.slide_mm > 30.0, "panel {seed}: {weakest:?}");
        // In a cell (calibrated nominal pose): a pass that says where its position comes from.
        let cell = case(seed + 300, 550.0, 400.0, true, &surface);
        assert_eq!(cell.verdict, "pass", "panel {seed}: {:?}", cell.reasons);
        assert!(
            cell.warnings
                .iter()
                .any(|w| w.contains("does not pin") && w.contains("calibration")),
            "panel {seed}: {:?}",
            cell.warnings
        );
    }
}
