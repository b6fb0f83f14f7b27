//! Seeded families of artefact clouds, made as a sensor above the volume sees them (front faces
//! towards the camera, a shadowed side towards the projector, the post and the table), with
//! figures checked against the truth the generator knows.

use super::synthetic::*;
use super::*;

fn cloud(name: &str, points: Vec<Vec3>) -> MeasuredCloud {
    MeasuredCloud {
        name: name.into(),
        points,
    }
}

fn sphere_artefacts(d: f64) -> Artefacts {
    let mut a = artefacts();
    a.sphere = Some(SphereArtefact {
        diameter: d,
        form: 0.0,
    });
    a
}

fn run(
    a: &Artefacts,
    bars: &[MeasuredCloud],
    planes: &[MeasuredCloud],
    spheres: &[MeasuredCloud],
) -> Certificate {
    evaluate(
        a,
        bars,
        planes,
        spheres,
        &VerifyParams::default(),
        "now".into(),
    )
    .expect("evaluate")
    .0
}

#[test]
fn spheres_of_20_to_60_mm_anywhere_in_the_volume_give_the_truth() {
    let mut rng = Noise::new(2634);
    let v = volume();
    for case in 0..12 {
        let d = rng.range(20.0, 60.0);
        let c = Vec3::new(
            rng.range(v.min[0] + 40.0, v.max[0] - 40.0),
            rng.range(v.min[1] + 40.0, v.max[1] - 40.0),
            rng.range(v.min[2] + 40.0, v.max[2] - 40.0),
        );
        // Noise up to 0.012 mm: 6 sigma stays under the 0.1 mm PF limit.
        let sigma = rng.range(0.003, 0.012);
        let (pts, off) = sphere_on_post(&mut rng, c, 0.5 * d, sigma);
        let cert = run(&sphere_artefacts(d), &[], &[], &[cloud("s.ply", pts)]);
        let (pf, ps) = (&cert.probing_form[0], &cert.probing_size[0]);
        assert_eq!(
            pf.status,
            Status::Pass,
            "case {case}: {:?} {:?} d {d} sigma {sigma}",
            pf.reason,
            pf.measured
        );
        let u = ps.fit_uncertainty.expect("u");
        // PS: within four of the fit's own standard uncertainties of zero.
        assert!(
            ps.error.expect("PS").abs() <= 4.0 * u + 1e-4,
            "case {case}: PS {:?} (u {u})",
            ps.error
        );
        // PF: the range of the true offsets within 15 % (the fit absorbs a little).
        let truth = truth_range(&off);
        let got = pf.measured.expect("PF");
        assert!(
            (got - truth).abs() <= 0.15 * truth + 0.002,
            "case {case}: PF {got} truth {truth}"
        );
        let centre = Vec3::from(ps.position.centre.expect("centre"));
        assert!(
            (centre - c).norm() < 0.01,
            "case {case}: centre off {}",
            (centre - c).norm()
        );
        assert!(pf.left_out <= fit::allowed_left_out(pf.points + pf.left_out));
    }
}

#[test]
fn a_sphere_with_a_form_error_or_a_wrong_size_fails_its_figure() {
    let mut rng = Noise::new(5);
    let c = Vec3::new(20.0, -30.0, 10.0);
    // A bump of 0.15 mm on the sphere's top: PF must see it (MPE 0.1).
    let (pts, _) = sphere_on_post(&mut rng, c, 20.0, 0.005);
    let bumped: Vec<Vec3> = pts
        .iter()
        .map(|p| {
            let d = p - c;
            if (d.norm() - 20.0).abs() < 0.1 && d.z > 0.0 && d.x > 8.0 && d.x < 12.0 {
                c + d.normalize() * (d.norm() + 0.15)
            } else {
                *p
            }
        })
        .collect();
    let cert = run(
        &sphere_artefacts(40.0),
        &[],
        &[],
        &[cloud("bump.ply", bumped)],
    );
    assert_eq!(cert.probing_form[0].status, Status::Fail);
    assert_eq!(cert.verdict, Status::Fail);
    // A sphere measured 0.1 mm small (every point 0.05 mm inside): PS fails, PF passes.
    let small: Vec<Vec3> = pts
        .iter()
        .map(|p| {
            let d = p - c;
            if (d.norm() - 20.0).abs() < 0.1 {
                c + d.normalize() * (d.norm() - 0.05)
            } else {
                *p
            }
        })
        .collect();
    let cert = run(
        &sphere_artefacts(40.0),
        &[],
        &[],
        &[cloud("small.ply", small)],
    );
    let ps = &cert.probing_size[0];
    assert_eq!(ps.status, Status::Fail, "{ps:?}");
    assert!(
        (ps.error.expect("PS") + 0.1).abs() < 0.01,
        "PS {:?}",
        ps.error
    );
    assert_eq!(cert.probing_form[0].status, Status::Pass);
}

#[test]
fn seven_bar_positions_pass_with_the_truth_and_a_scale_error_fails_sd() {
    let mut rng = Noise::new(77);
    let a = artefacts();
    let good: Vec<MeasuredCloud> = bar_positions(Vec3::new(10.0, -5.0, 0.0))
        .iter()
        .enumerate()
        .map(|(i, (p, q))| {
            cloud(
                &format!("bar{i}.ply"),
                bar_cloud(&mut rng, *p, *q, 15.0, 0.01, 1.0),
            )
        })
        .collect();
    let cert = run(&a, &good, &[], &[]);
    for f in &cert.sphere_spacing {
        assert_eq!(
            f.status,
            Status::Pass,
            "{}: {:?} {:?}",
            f.cloud,
            f.error,
            f.reason
        );
        let u = f.fit_uncertainty.expect("u");
        assert!(
            f.error.expect("SD").abs() <= 4.0 * u + 1e-4,
            "{}: SD {:?}",
            f.cloud,
            f.error
        );
    }
    assert!(
        !cert
            .coverage
            .missing
            .iter()
            .any(|m| m.contains("ball") || m.contains("space diagonal")),
        "{:?}",
        cert.coverage.missing
    );
    // A scale error of 0.05 % (a projector centre or baseline off in scale): SD = 0.2 mm,
    // beyond the 0.13 mm MPE at 400 mm.
    let scaled: Vec<MeasuredCloud> = bar_positions(Vec3::new(10.0, -5.0, 0.0))
        .iter()
        .enumerate()
        .map(|(i, (p, q))| {
            cloud(
                &format!("bar{i}.ply"),
                bar_cloud(&mut rng, *p, *q, 15.0, 0.01, 1.0005),
            )
        })
        .collect();
    let cert = run(&a, &scaled, &[], &[]);
    assert_eq!(cert.verdict, Status::Fail);
    for f in &cert.sphere_spacing {
        assert_eq!(f.status, Status::Fail, "{}: {:?}", f.cloud, f.reason);
        assert!(
            (f.error.expect("SD") - 0.2).abs() < 0.01,
            "{}: {:?}",
            f.cloud,
            f.error
        );
    }
}

#[test]
fn flats_in_six_positions_give_the_truth_and_a_warp_fails_f() {
    let mut rng = Noise::new(11);
    let a = artefacts();
    let mut clouds = Vec::new();
    let mut truths = Vec::new();
    for (k, (yaw, tilt)) in FLAT_POSES.iter().enumerate() {
        let c = Vec3::new(
            rng.range(-100.0, 100.0),
            rng.range(-80.0, 80.0),
            rng.range(-60.0, 60.0),
        );
        let sigma = rng.range(0.004, 0.015);
        let (pts, off) = flat_cloud(&mut rng, c, *yaw, *tilt, 0.0, sigma, |_, _| true);
        clouds.push(cloud(&format!("flat{k}.ply"), pts));
        truths.push(truth_range(&off));
    }
    let cert = run(&a, &[], &clouds, &[]);
    for (f, t) in cert.flatness.iter().zip(&truths) {
        assert_eq!(f.status, Status::Pass, "{}: {:?}", f.cloud, f.reason);
        let got = f.measured.expect("F");
        assert!(
            (got - t).abs() <= 0.1 * t + 0.002,
            "{}: F {got} truth {t}",
            f.cloud
        );
    }
    assert!(
        !cert.coverage.missing.iter().any(|m| m.contains("flat")),
        "{:?}",
        cert.coverage.missing
    );
    // A 0.2 mm bowl (a camera rotation or a wrong reference bends planes): F sees all of it.
    let (pts, off) = flat_cloud(&mut rng, Vec3::zeros(), 20.0, 10.0, 0.2, 0.005, |_, _| true);
    let cert = run(&a, &[], &[cloud("bowl.ply", pts)], &[]);
    let f = &cert.flatness[0];
    assert_eq!(f.status, Status::Fail, "{:?}", f.reason);
    let t = truth_range(&off);
    let got = f.measured.expect("F");
    // The least-squares plane of a bowl is not its rim plane: F is below the 0.2 sag plus
    // noise, but within 10 % of the truth range about the same kind of plane.
    assert!(got > 0.15 && got <= t + 0.01, "F {got}, truth range {t}");
}

#[test]
fn what_cannot_be_measured_says_why() {
    let mut rng = Noise::new(19);
    let a = artefacts();
    // Out of view: only the table and clutter.
    let empty = table(&mut rng, 0.0, 0.0, 0.0, 100.0, 1.0, 0.01);
    // Too thin in points: the sphere sampled every 4 mm.
    let (thin, _) = sphere_points(&mut rng, Vec3::new(0.0, 0.0, 50.0), 20.0, 4.0, 0.01, |_| {
        true
    });
    // A small cap: only the top 15° of the sphere seen.
    let (cap, _) = sphere_points(&mut rng, Vec3::new(0.0, 0.0, 50.0), 20.0, 0.3, 0.01, |u| {
        u.z > 15f64.to_radians().cos()
    });
    let cert = run(
        &a,
        &[],
        &[],
        &[
            cloud("empty.ply", empty.clone()),
            cloud("thin.ply", thin),
            cloud("cap.ply", cap),
        ],
    );
    let reasons: Vec<String> = cert
        .probing_form
        .iter()
        .map(|f| {
            assert_eq!(f.status, Status::NotMeasured, "{}", f.cloud);
            assert!(f.measured.is_none() && f.pass.is_none());
            f.reason.clone().expect("reason")
        })
        .collect();
    assert!(reasons[0].contains("no sphere"), "{}", reasons[0]);
    assert!(reasons[1].contains("points"), "{}", reasons[1]);
    assert!(
        reasons[2].contains("sr of the sphere") || reasons[2].contains("pins its diameter"),
        "{}",
        reasons[2]
    );
    assert_eq!(cert.verdict, Status::NotMeasured);
    // A cap wide enough to find and judge its form (35°, 1.1 sr) but too narrow to pin the
    // diameter within a quarter of PS's MPE: PF is given, PS is not, with its uncertainty.
    for seed in 0..4 {
        let mut rng = Noise::new(40 + seed);
        let c = Vec3::new(rng.range(-200.0, 200.0), rng.range(-200.0, 200.0), 50.0);
        let (cap, _) = sphere_points(&mut rng, c, 20.0, 1.0, 0.012, |u| {
            u.z > 35f64.to_radians().cos()
        });
        let cert = run(&a, &[], &[], &[cloud("cap.ply", cap)]);
        let (pf, ps) = (&cert.probing_form[0], &cert.probing_size[0]);
        assert!(
            pf.measured.is_some() && pf.status != Status::NotMeasured,
            "seed {seed}: {pf:?}"
        );
        assert_eq!(ps.status, Status::NotMeasured, "seed {seed}: {ps:?}");
        let u = ps.fit_uncertainty.expect("PS's uncertainty");
        assert!(u > 0.25 * a.mpe.probing_size, "seed {seed}: u {u}");
        assert!(
            ps.reason
                .as_deref()
                .is_some_and(|r| r.contains("pins its diameter")),
            "seed {seed}: {:?}",
            ps.reason
        );
        assert!(ps.measured.is_none() && ps.pass.is_none());
    }
    // Half a flat (the other half occluded) and a bar with one sphere out of view.
    let (half, _) = flat_cloud(&mut rng, Vec3::zeros(), 10.0, 5.0, 0.0, 0.005, |u, _| {
        u < 0.5
    });
    let (one, _) = sphere_on_post(&mut rng, Vec3::new(100.0, 0.0, 0.0), 15.0, 0.01);
    let cert = run(
        &a,
        &[cloud("one.ply", one)],
        &[cloud("half.ply", half)],
        &[],
    );
    let f = &cert.flatness[0];
    assert!(
        f.reason.as_deref().is_some_and(|r| r.contains("% of the")),
        "{:?}",
        f.reason
    );
    let b = &cert.sphere_spacing[0];
    assert!(
        b.reason
            .as_deref()
            .is_some_and(|r| r.contains("not both found")),
        "{:?}",
        b.reason
    );
    // A table alone is no flat: it is larger than the flat.
    let cert = run(&a, &[], &[cloud("table.ply", empty)], &[]);
    let r = cert.flatness[0].reason.clone().expect("reason");
    assert!(r.contains("larger than the flat"), "{r}");
}

#[test]
fn bad_artefact_files_name_the_field() {
    let mut a = artefacts();
    a.sphere = Some(SphereArtefact {
        diameter: -4.0,
        form: 0.0,
    });
    let e = a
        .validate("A.toml")
        .expect_err("negative diameter")
        .to_string();
    assert!(e.contains("A.toml") && e.contains("sphere.diameter"), "{e}");
    let mut a = artefacts();
    a.ball_bar = Some(BallBar {
        diameter_a: 30.0,
        diameter_b: 30.0,
        spacing: 20.0,
    });
    let e = a.validate("A.toml").expect_err("overlap").to_string();
    assert!(e.contains("ball_bar.spacing"), "{e}");
    let mut a = artefacts();
    a.volume = Some(Volume {
        min: [0.0, 0.0, 0.0],
        max: [1.0, f64::NAN, 1.0],
    });
    assert!(a.validate("A.toml").is_err());
    let mut a = artefacts();
    a.mpe.flatness = 0.0;
    let e = a.validate("A.toml").expect_err("zero MPE").to_string();
    assert!(e.contains("mpe.flatness"), "{e}");
    // Clouds of an artefact the file does not describe.
    let mut a = artefacts();
    a.plane = None;
    let err = evaluate(
        &a,
        &[],
        &[cloud("f.ply", vec![])],
        &[],
        &VerifyParams::default(),
        String::new(),
    )
    .expect_err("no [plane]")
    .to_string();
    assert!(err.contains("plane"), "{err}");
}

#[test]
fn the_certificate_and_maps_are_written() {
    let mut rng = Noise::new(3);
    let (pts, _) = sphere_on_post(&mut rng, Vec3::new(0.0, 0.0, 0.0), 20.0, 0.01);
    let (cert, maps) = evaluate(
        &sphere_artefacts(40.0),
        &[],
        &[],
        &[cloud("s.ply", pts)],
        &VerifyParams::default(),
        "2026-11-26 12:00:00 UTC".into(),
    )
    .expect("evaluate");
    let dir = tempfile::tempdir().expect("tmp");
    for m in &maps {
        write_residual_map(dir.path(), m).expect("png");
        let img = image::open(dir.path().join(&m.file)).expect("decodes");
        assert_eq!(img.width(), 480);
    }
    let html = certificate_html(&cert);
    assert!(html.contains("sphere-1.png") && html.contains("Probing error form"));
    assert!(
        html.contains("spot check"),
        "one position is no acceptance test"
    );
    let json = serde_json::to_value(&cert).expect("json");
    for key in ["sphere_spacing", "flatness", "probing_form", "probing_size"] {
        assert!(json[key].is_array(), "{key}");
    }
    let pf = &json["probing_form"][0];
    for key in [
        "cloud",
        "position",
        "measured",
        "calibrated",
        "error",
        "mpe",
        "points",
        "left_out",
        "pass",
    ] {
        assert!(pf.get(key).is_some(), "{key} missing");
    }
    assert_eq!(json["verdict"], "pass");
}

#[test]
fn a_full_acceptance_set_covers_the_volume_and_passes_and_a_scale_error_fails_it() {
    let a = artefacts();
    let (bars, planes, spheres) = acceptance_set(2634, 0.008, 1.0);
    let cert = run(&a, &bars, &planes, &spheres);
    assert_eq!(
        cert.verdict,
        Status::Pass,
        "{:?}",
        cert.figures()
            .filter(|f| f.status != Status::Pass)
            .map(|f| (&f.cloud, f.error, &f.reason))
            .collect::<Vec<_>>()
    );
    assert!(cert.coverage.acceptance_test, "{:?}", cert.coverage.missing);
    assert_eq!(cert.sphere_spacing.len(), 7);
    assert_eq!(cert.flatness.len(), 6);
    assert_eq!(cert.probing_form.len(), 10);
    // The same set measured 0.05 % large: every bar fails SD (0.2 mm against 0.13 mm); the
    // spheres and flats, too small to show it, pass.
    let (bars, planes, spheres) = acceptance_set(2634, 0.008, 1.0005);
    let cert = run(&a, &bars, &planes, &spheres);
    assert_eq!(cert.verdict, Status::Fail);
    assert!(cert.sphere_spacing.iter().all(|f| f.status == Status::Fail));
    assert!(cert.flatness.iter().all(|f| f.status == Status::Pass));
    // Leaving out the diagonal positions makes it a spot check that says what is missing.
    let cert = run(&a, &bars[4..], &planes, &spheres);
    assert!(!cert.coverage.acceptance_test);
    assert!(
        cert.coverage
            .missing
            .iter()
            .any(|m| m.contains("space diagonal 1")),
        "{:?}",
        cert.coverage.missing
    );
}
