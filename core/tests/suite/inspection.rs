//! Inspection against CAD with planted deformations: the registration must not absorb them.

use ris_core::geometry::{Point3, Vec3, Vector3};
use ris_core::inspect::{inspect, Datum, InspectParams};
use ris_core::mesh::{stl, SignedDistance, TriangleMesh};
use ris_core::register::Pose;

use crate::common;
use common::Rng;

fn surface(x: f64, y: f64) -> f64 {
    35.0 * (x / 160.0).sin() * (y / 140.0).cos() + 0.0006 * x * x
}

fn normal(x: f64, y: f64) -> Vec3 {
    let h = 1e-4;
    let dx = (surface(x + h, y) - surface(x - h, y)) / (2.0 * h);
    let dy = (surface(x, y + h) - surface(x, y - h)) / (2.0 * h);
    Vec3::new(-dx, -dy, 1.0).normalize()
}

/// The CAD panel (400 × 300 mm), written to and read back from a binary STL.
fn cad(dir: &std::path::Path) -> SignedDistance {
    let m = TriangleMesh::height_field(200, 150, (-200.0, 200.0), (-150.0, 150.0), surface);
    let path = dir.join("panel.stl");
    stl::write_binary(&path, &m).expect("stl");
    SignedDistance::new(TriangleMesh::load(&path).expect("load stl"))
}

fn planted(x: f64, y: f64) -> f64 {
    let g =
        |cx: f64, cy: f64, s: f64| (-((x - cx).powi(2) + (y - cy).powi(2)) / (2.0 * s * s)).exp();
    1.0 * g(0.0, 0.0, 60.0) - 0.8 * g(120.0, 80.0, 8.0) - 0.6 * g(-130.0, -70.0, 12.0)
}

/// Measured cloud in its own (unknown) frame, with the planted deviation of each point.
fn measure(deformed: bool) -> (Vec<[f64; 3]>, Vec<f64>, Pose) {
    let mut rng = Rng(11);
    let sensor_from_cad = Pose::new(
        Vector3::new(300.0, -150.0, 80.0),
        Vector3::new(0.2, -0.3, 0.35),
    );
    let (mut pts, mut truth) = (Vec::new(), Vec::new());
    for _ in 0..80_000 {
        let (x, y) = (rng.range(-195.0, 195.0), rng.range(-145.0, 145.0));
        let d = if deformed { planted(x, y) } else { 0.0 };
        let noise = 0.03 * rng.gauss();
        let p = Vec3::new(x, y, surface(x, y)) + normal(x, y) * (d + noise);
        pts.push((sensor_from_cad * Point3::from(p)).coords.into());
        truth.push(d);
    }
    (pts, truth, sensor_from_cad)
}

fn datums() -> Vec<Datum> {
    [
        (-170.0, -120.0),
        (170.0, -120.0),
        (170.0, 120.0),
        (-170.0, 120.0),
    ]
    .iter()
    .enumerate()
    .map(|(i, &(x, y))| Datum::region(&format!("D{}", i + 1), [x, y, surface(x, y)], 20.0))
    .collect()
}

fn error_rms(dev: &[f64], truth: &[f64]) -> f64 {
    (dev.iter()
        .zip(truth)
        .map(|(d, t)| (d - t).powi(2))
        .sum::<f64>()
        / dev.len() as f64)
        .sqrt()
}

fn deviation_error(
    cloud: &[[f64; 3]],
    truth: &[f64],
    cad: &SignedDistance,
    datums: Vec<Datum>,
) -> (f64, ris_core::inspect::Inspection) {
    let r = inspect(
        cloud,
        cad,
        &InspectParams {
            tolerance: 0.5,
            datums,
            ..InspectParams::default()
        },
    )
    .expect("inspect");
    (error_rms(&r.deviations, truth), r)
}

#[test]
fn with_datums_the_deformation_is_measured_not_absorbed() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cad = cad(dir.path());
    let (cloud, truth, _) = measure(true);
    let (err, r) = deviation_error(&cloud, &truth, &cad, datums());
    eprintln!(
        "datums: deviation error RMS {err:.4} mm (noise alone 0.03), verdict {}, reasons {:?}",
        r.report.verdict, r.report.reasons
    );
    assert!(err <= 0.05, "deviation error RMS {err} mm");
    assert_eq!(
        r.report.verdict, "fail",
        "the deformed part must fail at 0.5 mm"
    );
    let peaks: Vec<f64> = r
        .report
        .regions_out_of_tolerance
        .iter()
        .map(|g| g.peak_deviation_mm)
        .collect();
    assert_eq!(peaks.len(), 3, "bulge, dent and sink: {peaks:?}");
    assert!(
        peaks.iter().any(|p| *p > 0.9) && peaks.iter().filter(|p| **p < -0.5).count() == 2,
        "{peaks:?}"
    );
    assert!(r
        .report
        .datums
        .iter()
        .all(|d| d.in_tolerance && d.points > 500));
}

#[test]
fn without_datums_trusted_regions_keep_the_deformation_out_of_the_fit() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cad = cad(dir.path());
    let (cloud, truth, _) = measure(true);
    // Plain least squares: one datum covering the whole part.
    let all = vec![Datum::region("all", [0.0, 0.0, 0.0], 1e4)];
    let (plain, _) = deviation_error(&cloud, &truth, &cad, all);
    let (trimmed, r) = deviation_error(&cloud, &truth, &cad, Vec::new());
    eprintln!("no datums: deviation error RMS {trimmed:.4} mm vs plain least squares {plain:.4} mm; trusted {:.2}", r.report.registration.trusted_fraction);
    assert!(
        plain > 0.2,
        "plain least squares should absorb the bulge ({plain} mm)"
    );
    assert!(
        trimmed < 0.6 * plain,
        "trimming must beat plain least squares: {trimmed} vs {plain}"
    );
    assert_eq!(r.report.verdict, "fail");
}

#[test]
fn undeformed_part_passes() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cad = cad(dir.path());
    let (cloud, _, _) = measure(false);
    for ds in [datums(), Vec::new()] {
        let r = inspect(
            &cloud,
            &cad,
            &InspectParams {
                tolerance: 0.5,
                datums: ds,
                ..InspectParams::default()
            },
        )
        .expect("inspect");
        eprintln!(
            "undeformed ({}): RMS {:.4} mm, verdict {}",
            r.report.registration.mode, r.report.statistics.rms, r.report.verdict
        );
        assert_eq!(r.report.verdict, "pass", "{:?}", r.report.reasons);
        assert!(r.report.statistics.rms <= 0.05);
    }
}

#[test]
fn a_part_with_a_datum_out_of_tolerance_fails_and_says_so() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cad = cad(dir.path());
    let (cloud, _, _) = measure(false);
    let mut ds = datums();
    // A fifth datum D5 whose measured patch sits 2 mm proud of the nominal: it cannot be met.
    ds.push(Datum::region("D5", [0.0, 100.0, surface(0.0, 100.0)], 15.0));
    let mut cloud = cloud;
    let sensor_from_cad = measure(false).2;
    for p in cloud.iter_mut() {
        let c = sensor_from_cad.inverse() * Point3::from(*p);
        if (c.x).powi(2) + (c.y - 100.0).powi(2) < 15.0f64.powi(2) {
            let moved = c + normal(c.x, c.y) * 2.0;
            *p = (sensor_from_cad * moved).coords.into();
        }
    }
    let r = inspect(
        &cloud,
        &cad,
        &InspectParams {
            tolerance: 0.5,
            datums: ds,
            ..InspectParams::default()
        },
    )
    .expect("inspect");
    assert_eq!(r.report.verdict, "fail");
    assert!(
        r.report.reasons.iter().any(|m| m.contains("datum D5")),
        "{:?}",
        r.report.reasons
    );
    assert!(
        !r.report
            .datums
            .iter()
            .find(|d| d.name == "D5")
            .expect("D5")
            .in_tolerance
    );
}

/// The deviation map carries its numbers: verdict, title, statistics, mm ticks with the
/// tolerance, each datum's residual and each region's peak, each label legible (its box shows
/// exactly its text, nothing drawn over it) and where it belongs.
#[test]
fn the_deviation_map_is_labelled_with_what_a_reader_needs() {
    use ris_core::inspect::{render_deviation_map, verdict_colour, MapTitle};
    let dir = tempfile::tempdir().expect("tempdir");
    let cad = cad(dir.path());
    let (cloud, _, _) = measure(true);
    let (_, r) = deviation_error(&cloud, &[0.0; 80_000], &cad, datums());
    assert_eq!(r.report.verdict, "fail");
    let title = MapTitle {
        part: "door panel 7".into(),
        scan: "20261123T101500.000Z-4".into(),
        time: "2026-11-23 10:15:00 UTC".into(),
    };
    let map = render_deviation_map(&r.points, &r.deviations, &r.report, &datums(), &title);
    let white = [255, 255, 255];
    let find = |text: &str| {
        map.labels
            .iter()
            .find(|l| l.text == text)
            .unwrap_or_else(|| {
                panic!(
                    "no label {text:?} among {:?}",
                    map.labels.iter().map(|l| &l.text).collect::<Vec<_>>()
                )
            })
            .clone()
    };
    // Title and scan, legible on white.
    assert!(map.shows(&find("door panel 7"), white));
    assert!(map
        .labels
        .iter()
        .any(|l| l.text.contains("20261123T101500.000Z-4")
            && l.text.contains("2026-11-23 10:15:00 UTC")));
    // The verdict, in white on its colour.
    let verdict = find("FAIL");
    assert!(map.shows(&verdict, verdict_colour("fail")));
    // Statistics with the same numbers as the report.
    let s = &r.report.statistics;
    let stats = map
        .labels
        .iter()
        .find(|l| l.text.starts_with("mean "))
        .expect("statistics");
    assert!(
        stats.text.contains(&format!("RMS {:.3}", s.rms)),
        "{}",
        stats.text
    );
    assert!(stats
        .text
        .contains(&format!("{:.1} %", 100.0 * s.within_tolerance)));
    assert!(map.shows(stats, white));
    // Colour bar and histogram ticked in mm at ±1 and ±2 tolerances (0.5 mm) and 0; the
    // tolerance named.
    for text in ["+1.000", "+0.500", "0", "-0.500", "-1.000", "± 0.5 mm"] {
        let n = map.labels.iter().filter(|l| l.text == text).count();
        assert!(n >= 1, "{text}");
        assert!(map.shows(&find(text), white), "{text}");
    }
    // The +0.5 tick label sits level with the bar's yellow/green boundary (where +tol is).
    let tick = map
        .labels
        .iter()
        .filter(|l| l.text == "+0.500")
        .min_by_key(|l| l.y)
        .expect("tick");
    let bar_x = tick.x - 30;
    let (above, below) = (
        map.rgb[((tick.y as usize - 2) * map.width + bar_x as usize) * 3..][..3].to_vec(),
        map.rgb[((tick.y as usize + 18) * map.width + bar_x as usize) * 3..][..3].to_vec(),
    );
    assert!(
        above[0] == 255 && below[0] < 200,
        "{above:?} above, {below:?} below +tol"
    );
    // Every datum named with its residual; every region flagged with its peak.
    for (d, res) in datums().iter().zip(&r.report.datums) {
        let label = find(&format!("{} RMS {:.3} mm", d.name, res.rms));
        assert!(map.shows(&label, white), "{}", label.text);
    }
    for (i, g) in r.report.regions_out_of_tolerance.iter().take(8).enumerate() {
        let label = find(&format!("{}: {:+.3} mm", i + 1, g.peak_deviation_mm));
        assert!(map.shows(&label, white), "{}", label.text);
    }
    assert!(
        map.labels
            .iter()
            .any(|l| l.text.ends_with(" mm") && l.text.len() <= 7),
        "scale bar"
    );
}
