//! Registration without an initial pose over a seeded family of parts (issue 14): asymmetric
//! panels with features, seen from random poses (any rotation), 60–100 % of the part measured,
//! with and without a planted deformation (a broad bulge and a local dent, up to a third of the
//! area), noise 0.01–0.04 mm. Every case must put each point within 0.5 mm of where it is on
//! the part, deformed or not, measure the planted field within 0.10 mm RMS, pass when
//! undeformed and fail with the dent's region when deformed, or say the case is ambiguous / not
//! measured (at most 3 of 30).

use ris_core::geometry::{Point3, Vec3, Vector3};
use ris_core::inspect::{inspect, InspectParams};
use ris_core::mesh::{SignedDistance, TriangleMesh};
use ris_core::register::Pose;

use crate::common;
use common::{seeds, Rng};

/// A gaussian bump.
fn bump(x: f64, y: f64, cx: f64, cy: f64, r: f64, a: f64) -> f64 {
    a * (-((x - cx).powi(2) + (y - cy).powi(2)) / (r * r)).exp()
}

#[test]
fn parts_in_random_poses_with_partial_coverage_and_deformation_are_placed_right() {
    let (mut placed, mut flagged, mut worst_deformed) = (0, 0, 0.0f64);
    // 8 poses by default, the whole family of 30 in the long tier.
    let family = seeds(8, 30);
    let cases = family.end;
    for seed in family {
        let mut r = Rng(seed * 131 + 7);
        let (hx, hy) = (r.range(150.0, 250.0), r.range(90.0, 140.0));
        // Panel: a saddle or dome of random curvature with three asymmetric features.
        let (kx, ky) = (r.range(-8e-4, 8e-4), r.range(-8e-4, 8e-4));
        let f: Vec<(f64, f64, f64, f64)> = (0..3)
            .map(|_| {
                (
                    r.range(-0.7 * hx, 0.7 * hx),
                    r.range(-0.7 * hy, 0.7 * hy),
                    r.range(15.0, 35.0),
                    r.range(-12.0, 12.0),
                )
            })
            .collect();
        let surface = |x: f64, y: f64| {
            kx * x * x
                + ky * y * y
                + f.iter()
                    .map(|&(cx, cy, rr, a)| bump(x, y, cx, cy, rr, a))
                    .sum::<f64>()
        };
        let cad = SignedDistance::new(TriangleMesh::height_field(
            160,
            110,
            (-hx, hx),
            (-hy, hy),
            surface,
        ));
        let deformed = seed % 2 == 1;
        let (bx, by, br, ba) = (
            r.range(-0.5 * hx, 0.5 * hx),
            r.range(-0.5 * hy, 0.5 * hy),
            0.35 * hx.min(hy),
            r.range(0.6, 1.2),
        );
        let (dx, dy) = (r.range(-0.6 * hx, 0.6 * hx), r.range(-0.6 * hy, 0.6 * hy));
        let planted = |x: f64, y: f64| {
            if deformed {
                bump(x, y, bx, by, br, ba) + bump(x, y, dx, dy, 12.0, -1.0)
            } else {
                0.0
            }
        };
        // Any orientation.
        let axis = Vector3::new(r.gauss(), r.gauss(), r.gauss()).normalize();
        let sensor_from_cad = Pose::new(
            Vector3::new(
                r.range(-200.0, 200.0),
                r.range(-200.0, 200.0),
                r.range(600.0, 900.0),
            ),
            axis * r.range(0.0, std::f64::consts::PI),
        );
        // Coverage: a band of the part left unseen (x beyond a random cut).
        let seen = r.range(0.6, 1.0);
        let cut = -hx + 2.0 * hx * seen;
        let noise = r.range(0.01, 0.04);
        let h = 1e-3;
        let mut truth = Vec::new();
        let mut field = Vec::new();
        let pts: Vec<[f64; 3]> = (0..25_000)
            .filter_map(|_| {
                let (x, y) = (
                    r.range(-0.98 * hx, 0.98 * hx),
                    r.range(-0.98 * hy, 0.98 * hy),
                );
                if x > cut {
                    return None;
                }
                let zx = (surface(x + h, y) - surface(x - h, y)) / (2.0 * h);
                let zy = (surface(x, y + h) - surface(x, y - h)) / (2.0 * h);
                let n = Vec3::new(-zx, -zy, 1.0).normalize();
                let on = Vec3::new(x, y, surface(x, y));
                let d = planted(x, y);
                truth.push(on);
                field.push(d);
                let p = on + n * (d + noise * r.gauss());
                Some((sensor_from_cad * Point3::from(p)).coords.into())
            })
            .collect();
        let result = inspect(
            &pts,
            &cad,
            &InspectParams {
                tolerance: 0.3,
                init: std::env::var("RIS_INIT_TRUE")
                    .ok()
                    .map(|_| sensor_from_cad.inverse()),
                ..InspectParams::default()
            },
        )
        .expect("inspection");
        let rep = &result.report;
        // Where the map puts each point against where it is on the part (the surface point it
        // was measured at, moved along the normal by its planted deviation).
        let cad_from_sensor = sensor_from_cad.inverse();
        let location = result
            .points
            .iter()
            .zip(&pts)
            .map(|(p, s)| {
                let t = cad_from_sensor * Point3::from(*s);
                (Vec3::from(*p) - t.coords).norm()
            })
            .fold(0.0, f64::max);
        let dev_rms = {
            let (mut s, mut n) = (0.0, 0usize);
            for (d, t) in result.deviations.iter().zip(&field) {
                if d.is_finite() {
                    s += (d - t).powi(2);
                    n += 1;
                }
            }
            (s / n.max(1) as f64).sqrt()
        };
        let align = rep.registration.alignment.as_ref();
        let stability = rep
            .registration
            .stability
            .as_ref()
            .map_or(f64::NAN, |s| s.shift_mm);
        let said = rep.verdict == "not_measured" || align.is_some_and(|a| a.ambiguous());
        eprintln!(
            "seed {seed}: {:.0}x{:.0} mm, {:.0} % seen, deformed {deformed}: verdict {}, location error {location:.3} mm (stability {stability:.3} mm), deviation RMS vs planted {dev_rms:.4} mm, alignment {:?} (runner-up {:?}), regions {:?}, warnings {:?}",
            2.0 * hx,
            2.0 * hy,
            100.0 * seen,
            rep.verdict,
            align.map(|a| a.best_score),
            align.map(|a| a.runner_up_score),
            rep.regions_out_of_tolerance.iter().map(|g| g.centroid).collect::<Vec<_>>(),
            rep.warnings
        );
        if said {
            flagged += 1;
            continue;
        }
        placed += 1;
        // Deformed or not: a bulge must not pull the fit along the surface.
        assert!(location <= 0.5, "seed {seed}: location error {location} mm");
        worst_deformed = worst_deformed.max(if deformed { location } else { 0.0 });
        assert!(dev_rms <= 0.10, "seed {seed}: deviation RMS {dev_rms} mm");
        if deformed {
            assert_eq!(rep.verdict, "fail", "seed {seed}");
            assert!(!rep.regions_out_of_tolerance.is_empty(), "seed {seed}");
            let near_dent = rep.regions_out_of_tolerance.iter().any(|g| {
                (g.centroid[0] - dx).hypot(g.centroid[1] - dy) < 15.0 && g.peak_deviation_mm < -0.3
            });
            assert!(
                // (unless the dent is unseen, or lies in the bulge: out-of-tolerance points of
                // either sign form one region then, centred between them)
                near_dent || dx > cut || (dx - bx).hypot(dy - by) < 2.0 * br,
                "seed {seed}: no region at the dent ({dx:.0}, {dy:.0})"
            );
        } else {
            assert_eq!(rep.verdict, "pass", "seed {seed}: {:?}", rep.reasons);
        }
    }
    eprintln!("{placed} placed, {flagged} reported ambiguous or not measured; worst location error of a deformed part {worst_deformed:.3} mm");
    // At most one in ten left unplaced (reported, never wrong).
    let misses = (cases as usize).div_ceil(10);
    assert!(
        placed + misses >= cases as usize,
        "{placed} of {cases} placed"
    );
}
