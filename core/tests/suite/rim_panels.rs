//! Smooth panels pinned by their rims (issue 42 item 5) over a seeded family: domes, saddles and
//! cylinder-like sheets of random size, curvature and apex, some with a corner trimmed off,
//! seen from any orientation as a camera lattice or random samples, with occlusions and
//! coverage limits (60-100 % of the panel, the rim seen along at least two sides), half of
//! them deformed (a broad bulge and a local dent). No datums, no starting pose: a slide along
//! the surface is pinned only by where the scan ends on the CAD's rim. Every case must put each
//! point within 0.5 mm of where it is on the part and give the right verdict; the same panels
//! scanned short of the rim must stay `not_measured`, naming the slide. `RIM_SEED=N` runs one
//! seed of each family.

use ris_core::geometry::{Point3, Vec3, Vector3};
use ris_core::inspect::{inspect, InspectParams, Inspection};
use ris_core::mesh::{SignedDistance, TriangleMesh};
use ris_core::register::Pose;

use crate::common;
use common::{seeds, Rng};

fn bump(x: f64, y: f64, cx: f64, cy: f64, r: f64, a: f64) -> f64 {
    a * (-((x - cx).powi(2) + (y - cy).powi(2)) / (r * r)).exp()
}

struct Case {
    cad: SignedDistance,
    cloud: Vec<[f64; 3]>,
    field: Vec<f64>,
    sensor_from_cad: Pose,
    deformed: bool,
    dent: (f64, f64),
    coverage: f64,
    describe: String,
}

/// `inset`: the scan's field of view lies inside the panel, at least this share of the
/// half-extent short of the rim and turned 5-25° against it (0: the rim is seen where the
/// case's coverage allows). `symmetric`: the apex at the centre and no
/// corner trimmed, so the panel looks the same turned 180° about its normal.
fn generate(seed: u64, inset: f64, symmetric: bool) -> Case {
    let mut r = Rng(seed * 104_729 + 7);
    let (hx, hy) = (r.range(140.0, 260.0), r.range(90.0, 160.0));
    let shape = seed % 3;
    // Curvature centre off the panel's centre, so the panel has no symmetry.
    let (x0, y0) = (r.range(0.1, 0.3) * hx, r.range(-0.3, -0.1) * hy);
    let (x0, y0) = if symmetric { (0.0, 0.0) } else { (x0, y0) };
    let (kx, ky) = match shape {
        0 => (r.range(3e-4, 1e-3), r.range(3e-4, 1e-3)),
        1 => (r.range(3e-4, 1e-3), -r.range(3e-4, 1e-3)),
        _ => (r.range(1e-3, 2e-3), r.range(-2e-5, 2e-5)),
    };
    let surface = move |x: f64, y: f64| kx * (x - x0).powi(2) + ky * (y - y0).powi(2);
    // A trimmed corner on every other panel.
    let cut = if seed % 4 < 2 && !symmetric {
        Some(r.range(0.2, 0.4) * hy)
    } else {
        None
    };
    let inside = move |x: f64, y: f64| cut.is_none_or(|c| (hx - x) + (hy - y) > c);
    let mut mesh = TriangleMesh::height_field(160, 100, (-hx, hx), (-hy, hy), surface);
    let verts = mesh.vertices.clone();
    mesh.triangles.retain(|t| {
        let c = t.iter().fold(Vec3::zeros(), |a, i| a + verts[*i as usize]) / 3.0;
        inside(c.x, c.y)
    });
    let cad = SignedDistance::new(mesh);
    let deformed = seed % 2 == 1;
    let (bx, by, br, ba) = (
        r.range(-0.3, 0.3) * hx,
        r.range(-0.3, 0.3) * hy,
        0.3 * hx.min(hy),
        r.range(0.6, 1.2),
    );
    let dent = (r.range(-0.5, 0.5) * hx, r.range(-0.5, 0.5) * hy);
    let planted = move |x: f64, y: f64| {
        if deformed {
            bump(x, y, bx, by, br, ba) + bump(x, y, dent.0, dent.1, 10.0, -1.0)
        } else {
            0.0
        }
    };
    // What the scan misses: occluded disks, and on some cases a band along one side (the rim
    // there not seen). The other sides' rims stay in view.
    let disks: Vec<(f64, f64, f64)> = (0..(seed % 3) as usize + 1)
        .map(|_| {
            (
                r.range(-0.6, 0.6) * hx,
                r.range(-0.6, 0.6) * hy,
                r.range(0.1, 0.3) * hy,
            )
        })
        .collect();
    // A shadow's or field of view's limit is no trim line: it wavers by a few millimetres.
    let band = if seed % 5 >= 2 {
        Some((seed % 4, r.range(0.1, 0.25)))
    } else {
        None
    };
    let (wave, period, phase) = (r.range(3.0, 8.0), r.range(30.0, 80.0), r.range(0.0, 6.3));
    let waver = move |t: f64| wave * (std::f64::consts::TAU * t / period + phase).sin();
    // A camera's field of view inside the panel: a rectangle turned against the rim, scaled
    // to keep `inset` of the half-extent clear of it.
    let turn = r.range(5f64, 25.0).to_radians() * if seed.is_multiple_of(2) { 1.0 } else { -1.0 };
    let (ct, st) = (turn.cos(), turn.sin().abs());
    let fit =
        ((1.0 - inset) * hx / (hx * ct + hy * st)).min((1.0 - inset) * hy / (hx * st + hy * ct));
    let (vx, vy) = (fit * hx, fit * hy);
    let view = move |x: f64, y: f64| {
        let (u, v) = (
            x * turn.cos() + y * turn.sin(),
            -x * turn.sin() + y * turn.cos(),
        );
        u.abs() <= vx && v.abs() <= vy
    };
    let missed = move |x: f64, y: f64| {
        disks.iter().any(|d| (x - d.0).hypot(y - d.1) < d.2)
            || band.is_some_and(|(side, share)| match side {
                0 => x > hx * (1.0 - 2.0 * share) + waver(y),
                1 => x < -hx * (1.0 - 2.0 * share) + waver(y),
                2 => y > hy * (1.0 - 2.0 * share) + waver(x),
                _ => y < -hy * (1.0 - 2.0 * share) + waver(x),
            })
            || (inset > 0.0 && !view(x, y))
    };
    let axis = Vector3::new(r.gauss(), r.gauss(), r.gauss()).normalize();
    let sensor_from_cad = Pose::new(
        Vector3::new(
            r.range(-300.0, 300.0),
            r.range(-300.0, 300.0),
            r.range(600.0, 1200.0),
        ),
        axis * r.range(0.0, std::f64::consts::PI),
    );
    let noise = r.range(0.01, 0.04);
    // About 100 k points: a camera lattice at a random angle, or random samples.
    let density = (100_000.0 / (4.0 * hx * hy)).min(1.2);
    let lattice = seed.is_multiple_of(2);
    let spacing = 1.0 / density.sqrt();
    let angle = r.range(0.0, std::f64::consts::PI);
    let (ca, sa) = (angle.cos(), angle.sin());
    let n = (density * 4.0 * hx * hy) as usize;
    let reach = hx.hypot(hy);
    let mut samples = Vec::with_capacity(n);
    if lattice {
        let steps = (reach / spacing).ceil() as i64;
        for i in -steps..=steps {
            for j in -steps..=steps {
                let (u, v) = (i as f64 * spacing, j as f64 * spacing);
                samples.push((ca * u - sa * v, sa * u + ca * v));
            }
        }
    } else {
        for _ in 0..n {
            samples.push((r.range(-hx, hx), r.range(-hy, hy)));
        }
    }
    let (mut cloud, mut field) = (Vec::with_capacity(n), Vec::with_capacity(n));
    let mut panel_samples = 0usize;
    let h = 1e-3;
    for (x, y) in samples {
        if x.abs() > hx || y.abs() > hy || !inside(x, y) {
            continue;
        }
        panel_samples += 1;
        if missed(x, y) {
            continue;
        }
        let zx = (surface(x + h, y) - surface(x - h, y)) / (2.0 * h);
        let zy = (surface(x, y + h) - surface(x, y - h)) / (2.0 * h);
        let nrm = Vec3::new(-zx, -zy, 1.0).normalize();
        let d = planted(x, y);
        let p = Vec3::new(x, y, surface(x, y)) + nrm * (d + noise * r.gauss());
        cloud.push((sensor_from_cad * Point3::from(p)).coords.into());
        field.push(d);
    }
    let coverage = cloud.len() as f64 / panel_samples.max(1) as f64;
    Case {
        cad,
        cloud,
        field,
        sensor_from_cad,
        deformed,
        dent,
        coverage,
        describe: format!(
            "{} {:.0}x{:.0} mm{}, {}, band {band:?}",
            ["dome", "saddle", "sheet"][shape as usize],
            2.0 * hx,
            2.0 * hy,
            if cut.is_some() {
                ", corner trimmed"
            } else {
                ""
            },
            if lattice { "lattice" } else { "random" },
        ),
    }
}

fn run(case: &Case) -> Inspection {
    inspect(
        &case.cloud,
        &case.cad,
        &InspectParams {
            tolerance: 0.3,
            ..InspectParams::default()
        },
    )
    .expect("inspection")
}

/// Largest distance between where the map puts a point and where it is on the part, mm.
fn location_error(case: &Case, result: &Inspection) -> f64 {
    let cad_from_sensor = case.sensor_from_cad.inverse();
    result
        .points
        .iter()
        .zip(&case.cloud)
        .map(|(p, s)| (Vec3::from(*p) - (cad_from_sensor * Point3::from(*s)).coords).norm())
        .fold(0.0, f64::max)
}

/// One case of the family seen to its rim: placed within 0.5 mm, the rim taking part, the
/// planted deviations found and the right verdict. Returns the location error, mm.
fn placed_and_judged(seed: u64) -> f64 {
    let case = generate(seed, 0.0, false);
    let result = run(&case);
    let rep = &result.report;
    let location = location_error(&case, &result);
    let rms = common::rms_against(&result.deviations, &case.field);
    eprintln!(
        "seed {seed} ({}, {:.0} % covered, {} points, deformed {}): {} by {}, location error {location:.3} mm, deviation RMS vs planted {rms:.4} mm, rim {:?}, reasons {:?}, warnings {:?}",
        case.describe,
        100.0 * case.coverage,
        case.cloud.len(),
        case.deformed,
        rep.verdict,
        rep.registration.mode,
        rep.registration.rim,
        rep.reasons,
        rep.warnings
    );
    assert!(
        (0.6..=1.0).contains(&case.coverage),
        "seed {seed}: coverage {}",
        case.coverage
    );
    assert!(location <= 0.5, "seed {seed}: location error {location} mm");
    let rim = rep.registration.rim.as_ref().expect("the rim took part");
    assert!(rim.rms_mm < 0.5, "seed {seed}: {rim:?}");
    if case.deformed {
        assert_eq!(rep.verdict, "fail", "seed {seed}: {:?}", rep.reasons);
        assert!(
            rep.regions_out_of_tolerance.iter().any(|g| {
                (g.centroid[0] - case.dent.0).hypot(g.centroid[1] - case.dent.1) < 40.0
                    && g.peak_deviation_mm < 0.0
            }) || case.field.iter().all(|f| *f > -0.3),
            "seed {seed}: no region below the band near the dent {:?}",
            case.dent
        );
    } else {
        assert_eq!(rep.verdict, "pass", "seed {seed}: {:?}", rep.reasons);
    }
    location
}

#[test]
fn smooth_panels_seen_to_their_rim_are_placed_and_judged() {
    let mut worst = 0.0f64;
    for seed in seeds(4, 24) {
        if std::env::var("RIM_SEED").is_ok_and(|s| s != seed.to_string()) {
            continue;
        }
        worst = worst.max(placed_and_judged(seed));
    }
    eprintln!("worst location error {worst:.3} mm");
}

/// Random clouds of about 0.7 points per mm² (spacing ~1.2 mm, the nearest neighbour ~0.6 mm):
/// a strip across the rim holds few points, and the finest window must reach far enough past
/// the edge to tell it. Sized by the nearest neighbour, it shows edges only where points lie
/// dense, and seed 13 (a saddle with one side unseen) slides 52 mm along its valley, seed 17 (a
/// sheet) is laid turned. Seed 15's dent lies inside the margin of its bulge: a region of its
/// own, below the band.
#[test]
fn sparse_random_clouds_are_placed_by_their_rims() {
    for seed in [13u64, 15, 17] {
        placed_and_judged(seed);
    }
}

/// Seed 13's saddle fitted on 20 000 of its points: placements along one valley of the saddle
/// each match nearly as much rim as the best, so where the rim's evidence is flat along that
/// slide none of them pins it: the inspection places the panel right or says it cannot, and
/// never gives a verdict from a map that far off.
#[test]
fn a_slide_along_which_the_rims_evidence_is_flat_is_not_taken_as_pinned() {
    let case = generate(13, 0.0, false);
    let result = inspect(
        &case.cloud,
        &case.cad,
        &InspectParams {
            tolerance: 0.3,
            fit_points: 20_000,
            ..InspectParams::default()
        },
    )
    .expect("inspection");
    let rep = &result.report;
    let location = location_error(&case, &result);
    eprintln!(
        "seed 13 ({}), 20 000 fit points: {}, location error {location:.3} mm, reasons {:?}, rim {:?}",
        case.describe, rep.verdict, rep.reasons, rep.registration.rim
    );
    let named = rep.verdict == "not_measured"
        && rep
            .reasons
            .iter()
            .any(|m| m.contains("elsewhere") || m.contains("cannot pin"));
    assert!(
        location <= 0.5 || named,
        "{} with the map {location:.1} mm off: {:?}",
        rep.verdict,
        rep.reasons
    );
}

/// A scan whose field of view stops short of the rim all round (turned against it, as a
/// camera's is) never meets the rim. Seed 3's dome is symmetric under a half turn about its
/// apex where the scan sees it: turned, the field of view's straight edge comes near the rim
/// and the fit lays it on the rim, so the placement that stays short of the rim must count
/// as a rival.
#[test]
fn panels_scanned_short_of_their_rim_name_the_slide() {
    for seed in [1u64, 0, 3]
        .into_iter()
        .chain((2..seeds(2, 6).end).filter(|s| *s != 3))
    {
        if std::env::var("RIM_SEED").is_ok_and(|s| s != seed.to_string()) {
            continue;
        }
        let case = generate(seed, 0.08, false);
        let rep = run(&case).report;
        eprintln!(
            "seed {seed} ({}), inset: {} {:?}",
            case.describe, rep.verdict, rep.reasons
        );
        // Never judged as if the rim held it: not measured, naming the slide (and, where the
        // scan's edges met the rim somewhere, that they fit it elsewhere as well), or, where
        // the surface itself pins the slide a little, a verdict that says it is weakly pinned.
        let named = rep.verdict == "not_measured"
            && rep
                .reasons
                .iter()
                .any(|m| m.contains("cannot pin") && m.contains("position along"));
        let weak = rep.verdict != "not_measured"
            && rep.warnings.iter().any(|w| w.contains("weakly pinned"));
        assert!(
            named || weak,
            "seed {seed}: {:?} {:?} {:?} {:?}",
            rep.reasons,
            rep.warnings,
            rep.conditioning.directions,
            rep.registration.rim
        );
    }
}

#[test]
fn a_symmetric_panel_gets_its_verdict_and_a_warning_that_the_map_may_be_turned() {
    // Seeds 1 and 3 are deformed (the map differs turned), 0 is not.
    for seed in [3u64, 1, 0] {
        let case = generate(seed, 0.0, true);
        let result = run(&case);
        let rep = &result.report;
        let location = location_error(&case, &result);
        eprintln!(
            "seed {seed} ({}), symmetric: {} by {}, location error {location:.3} mm, reasons {:?}, warnings {:?}, alignment {:?}, rim {:?}",
            case.describe, rep.verdict, rep.registration.mode, rep.reasons, rep.warnings, rep.registration.alignment, rep.registration.rim
        );
        // The verdict is the data's either way.
        assert_eq!(
            rep.verdict,
            if case.deformed { "fail" } else { "pass" },
            "seed {seed}: {:?}",
            rep.reasons
        );
        // Placed right, or turned by the symmetry (the rim fits both).
        let cad_from_sensor = case.sensor_from_cad.inverse();
        let turned = result
            .points
            .iter()
            .zip(&case.cloud)
            .map(|(p, s)| {
                let t = (cad_from_sensor * Point3::from(*s)).coords;
                (Vec3::from(*p) - Vec3::new(-t.x, -t.y, t.z)).norm()
            })
            .fold(0.0, f64::max);
        assert!(
            location <= 0.5 || turned <= 0.5,
            "seed {seed}: {location} mm, turned {turned} mm"
        );
        let warned = rep
            .warnings
            .iter()
            .any(|w| w.contains("looks the same with the part turned"));
        assert_eq!(warned, case.deformed, "seed {seed}: {:?}", rep.warnings);
    }
}

/// Panels in a cell's fixture (the registration starts from the calibrated pose, 0.1–0.3 mm
/// off), sampled at random as sparsely as 20 000 points over up to 500 × 320 mm, scanned to
/// their rim or ending 2–6 mm short of it all round. Short of the rim, the scan's edges fit it
/// at either side; the fit must not lay one side on the rim (before, a saddle 5 mm short was
/// drawn 11.6 mm along itself, and the report called the position the fixture's) but keep the
/// fixture's pose along what the surface does not pin, and say so. Reaching the rim, the rim
/// places it.
#[test]
fn fixtured_panels_scanned_short_of_their_rim_stay_where_the_fixture_holds_them() {
    for seed in seeds(6, 16) {
        if std::env::var("RIM_SEED").is_ok_and(|s| s != seed.to_string()) {
            continue;
        }
        let mut r = Rng(seed * 7_919 + 3);
        let (hx, hy) = (r.range(150.0, 250.0), r.range(100.0, 160.0));
        let (kx, ky) = (r.range(2e-4, 5e-4), r.range(2e-4, 5e-4));
        let saddle = seed % 2 == 0;
        let ky = if saddle { -ky } else { ky };
        let surface = move |x: f64, y: f64| kx * x * x + ky * y * y;
        let cad = SignedDistance::new(TriangleMesh::height_field(
            60,
            40,
            (-hx, hx),
            (-hy, hy),
            surface,
        ));
        // every third seed reaches the rim; the others stop 2-6 mm short of it
        let short = if seed % 3 == 0 {
            0.0
        } else {
            r.range(2.0, 6.0)
        };
        // where the part sits against its fixture's calibrated pose
        let offset = Vector3::new(r.range(-0.2, 0.2), r.range(-0.2, 0.2), r.range(-0.1, 0.1));
        let cloud: Vec<[f64; 3]> = (0..20_000)
            .map(|_| {
                let (x, y) = (
                    r.range(-hx + short, hx - short),
                    r.range(-hy + short, hy - short),
                );
                (Vector3::new(x, y, surface(x, y) + 0.02 * r.gauss()) + offset).into()
            })
            .collect();
        let result = inspect(
            &cloud,
            &cad,
            &InspectParams {
                tolerance: 0.3,
                init: Some(Pose::identity()),
                ..InspectParams::default()
            },
        )
        .expect("inspection");
        let rep = &result.report;
        let location = result
            .points
            .iter()
            .zip(&cloud)
            .map(|(p, s)| (Vec3::from(*p) - (Vec3::from(*s) - offset)).norm())
            .fold(0.0, f64::max);
        eprintln!(
            "seed {seed} ({} {:.0}x{:.0} mm, {short:.1} mm short): {} placed within {location:.3} mm, rim {:?}, warnings {:?}",
            if saddle { "saddle" } else { "dome" },
            2.0 * hx,
            2.0 * hy,
            rep.verdict,
            rep.registration.rim,
            rep.warnings
        );
        assert_eq!(rep.verdict, "pass", "seed {seed}: {:?}", rep.reasons);
        assert!(location <= 0.5, "seed {seed}: placed {location:.3} mm off");
        if short > 0.0 {
            // the rim did not hold the fit
            assert!(
                rep.registration
                    .rim
                    .as_ref()
                    .is_none_or(|r| r.ambiguous.is_some()),
                "seed {seed}: {:?}",
                rep.registration.rim
            );
        }
    }
}

/// The panels scanned through a field of view that stops short of the rim all round (turned
/// against it, as a camera's is), in a cell's fixture (0.2 mm and 0.01° off the truth). Where
/// the field of view's straight edge comes near the rim, the rim fit can lay it there by
/// carrying the part tens of millimetres (before: 56–74 mm, with a verdict); the fixture's
/// placement, reaching no rim, fits the surface as well, so the rim must not hold the fit.
#[test]
fn a_fixtured_panel_is_not_carried_onto_its_rim_by_the_edge_of_the_view() {
    for seed in [0u64, 6]
        .into_iter()
        .chain((9..seeds(9, 13).end).step_by(3))
    {
        if std::env::var("RIM_SEED").is_ok_and(|s| s != seed.to_string()) {
            continue;
        }
        let case = generate(seed, 0.08, false);
        let held = Pose::new(Vector3::new(0.2, -0.1, 0.1), Vector3::new(0.0, 0.0, 2e-4))
            * case.sensor_from_cad.inverse();
        let result = inspect(
            &case.cloud,
            &case.cad,
            &InspectParams {
                tolerance: 0.3,
                init: Some(held),
                ..InspectParams::default()
            },
        )
        .expect("inspection");
        let rep = &result.report;
        let location = location_error(&case, &result);
        eprintln!(
            "seed {seed} ({}), inset, fixtured: {} placed within {location:.3} mm, rim {:?}",
            case.describe, rep.verdict, rep.registration.rim
        );
        assert!(location <= 1.0, "seed {seed}: placed {location:.3} mm off");
        assert!(
            rep.registration
                .rim
                .as_ref()
                .is_none_or(|r| r.ambiguous.is_some()),
            "seed {seed}: {:?}",
            rep.registration.rim
        );
    }
}
