//! ICP on partial, overlapping, independently sampled clouds of a curved part with known motion.

use nalgebra::{Point3, Vector3};
use ris_core::register::{rotation_angle_deg, Icp, IcpMetric, IcpParams, Pose};

use crate::common;
use common::Rng;

/// A smooth, asymmetric panel so every degree of freedom is constrained.
fn surface(x: f64, y: f64) -> f64 {
    25.0 * (x / 70.0).sin() * (y / 55.0).cos() + 0.0004 * x * x - 0.0002 * x * y
        + 8.0 * (-((x - 40.0).powi(2) + (y + 20.0).powi(2)) / 800.0).exp()
}

/// Random samples of the panel over [x0, x1] × [y0, y1] with Gaussian noise along z.
fn sample(n: usize, x0: f64, x1: f64, y0: f64, y1: f64, noise: f64, seed: u64) -> Vec<[f64; 3]> {
    let mut rng = Rng(seed);
    (0..n)
        .map(|_| {
            let (x, y) = (rng.range(x0, x1), rng.range(y0, y1));
            [x, y, surface(x, y) + noise * rng.gauss()]
        })
        .collect()
}

fn errors(got: &Pose, truth: &Pose) -> (f64, f64) {
    let d = got.inverse() * truth;
    (rotation_angle_deg(&d), d.translation.vector.norm())
}

fn check(metric: IcpMetric, init: Pose, max_iterations: usize, rot_tol_deg: f64, trans_tol: f64) {
    // Fixed: x in [−100, 60]; moving: x in [−40, 100] (100/140 of it overlaps), sampled independently.
    let fixed = sample(60_000, -100.0, 60.0, -80.0, 80.0, 0.03, 1);
    let moving_true = sample(60_000, -40.0, 100.0, -80.0, 80.0, 0.03, 2);
    let truth = Pose::new(
        Vector3::new(4.0, -3.0, 1.5),
        Vector3::new(0.01, -0.02, 0.04),
    );
    // Express the moving scan in its own frame: fixed_from_moving = truth.
    let moving: Vec<[f64; 3]> = moving_true
        .iter()
        .map(|p| (truth.inverse() * Point3::from(*p)).coords.into())
        .collect();
    let icp = Icp::new(&fixed, metric, 12);
    let params = IcpParams {
        metric,
        trim: 0.6,
        max_iterations,
        ..IcpParams::default()
    };
    let r = icp.align(&moving, init, &params);
    let (rot, trans) = errors(&r.fixed_from_moving, &truth);
    eprintln!("{metric:?}: rotation error {rot:.5}°, translation error {trans:.4} mm, RMS {:.4} mm, overlap {:.2}, {} iterations, converged {}", r.rms, r.overlap, r.iterations, r.converged);
    assert!(r.iterations >= 4);
    assert!(
        (r.overlap - 100.0 / 140.0).abs() < 0.05,
        "overlap {} (true: 100/140)",
        r.overlap
    );
    assert!(rot <= rot_tol_deg, "rotation error {rot}°");
    assert!(trans <= trans_tol, "translation error {trans} mm");
}

#[test]
fn point_to_plane_recovers_the_motion_of_partial_scans() {
    // From identity: 5.2 mm and 2.6° away from the truth.
    check(IcpMetric::PointToPlane, Pose::identity(), 50, 0.01, 0.02);
}

#[test]
fn point_to_point_recovers_a_reposed_part_of_the_same_scan() {
    // Point-to-point pairs points, so it is exact only when both clouds hold the same surface
    // samples (independent samples bias it laterally; point-to-plane is the default for that).
    let fixed = sample(60_000, -100.0, 60.0, -80.0, 80.0, 0.0, 1);
    let truth = Pose::new(
        Vector3::new(4.0, -3.0, 1.5),
        Vector3::new(0.01, -0.02, 0.04),
    );
    let mut rng = Rng(7);
    let mut noise = move || 0.03 * rng.gauss();
    let moving: Vec<[f64; 3]> = fixed
        .iter()
        .filter(|p| p[0] > -40.0)
        .map(|p| {
            let q = truth.inverse() * Point3::new(p[0], p[1], p[2] + noise());
            q.coords.into()
        })
        .collect();
    let icp = Icp::new(&fixed, IcpMetric::PointToPoint, 12);
    let params = IcpParams {
        metric: IcpMetric::PointToPoint,
        trim: 0.95,
        max_iterations: 300,
        tolerance: 1e-7,
        ..IcpParams::default()
    };
    let r = icp.align(&moving, Pose::identity(), &params);
    let (rot, trans) = errors(&r.fixed_from_moving, &truth);
    eprintln!("point-to-point: rotation error {rot:.5}°, translation error {trans:.4} mm, RMS {:.4} mm, {} iterations", r.rms, r.iterations);
    assert!(
        rot <= 0.01 && trans <= 0.02,
        "rotation {rot}°, translation {trans} mm"
    );
}

#[test]
fn an_alignment_out_of_budget_stops_at_its_next_iteration() {
    use ris_core::budget::{self, Budget};
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::Arc;
    let fixed = sample(20_000, -100.0, 60.0, -80.0, 80.0, 0.03, 1);
    let moved = Pose::new(
        Vector3::new(4.0, -3.0, 1.5),
        Vector3::new(0.01, -0.02, 0.04),
    );
    let moving: Vec<[f64; 3]> = fixed
        .iter()
        .map(|p| (moved.inverse() * Point3::from(*p)).coords.into())
        .collect();
    let icp = Icp::new(&fixed, IcpMetric::PointToPlane, 12);
    let params = IcpParams {
        max_iterations: 200,
        tolerance: 0.0,
        ..IcpParams::default()
    };
    let free = icp.align(&moving, Pose::identity(), &params);
    assert!(free.iterations >= 3, "{free:?}");
    // Under a budget whose stop flag is raised the alignment ends before its next iteration,
    // unconverged where it was, and the stage's check names why.
    let stop = Arc::new(AtomicBool::new(false));
    let budget = Budget::new("registration test").stop_flag(stop.clone());
    let (before, stopped, e) = budget::within(budget, || {
        let before = icp.align(&moving, Pose::identity(), &params);
        stop.store(true, Ordering::SeqCst);
        let stopped = icp.align(&moving, Pose::identity(), &params);
        (before, stopped, budget::check().expect_err("stopped"))
    });
    assert_eq!(
        before.iterations, free.iterations,
        "a budget not spent changes nothing"
    );
    assert_eq!(stopped.iterations, 0);
    assert!(!stopped.converged);
    assert_eq!(e.to_string(), "registration test: cancelled");
    assert!(budget::check().is_ok(), "the budget ended with its stage");
}
