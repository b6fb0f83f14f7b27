//! `ris inspect`: a measured cloud against its CAD model — deviation.ply, deviation.png and
//! report.json with the pass/fail verdict.

use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result};
use ris_core::cloud::PointCloud;
use ris_core::inspect::{
    inspect, load_datums, write_deviation_ply, write_deviation_png, InspectParams, MapTitle, Report,
};
use ris_core::mesh::{SignedDistance, TriangleMesh};

/// Inspect `cloud` against `cad` (STL, PLY or OBJ mesh) and write the three outputs into `out`.
pub fn run(
    cloud: &Path,
    cad: &Path,
    datums: Option<&Path>,
    tolerance: f64,
    min_coverage: f64,
    pose: Option<&str>,
    out: &Path,
) -> Result<Report> {
    anyhow::ensure!(
        tolerance.is_finite() && tolerance > 0.0,
        "--tolerance must be a positive number of mm, got {tolerance}"
    );
    let known = match pose {
        None => None,
        Some("known") => Some(ris_core::register::Pose::identity()),
        Some(file) => Some(
            ris_core::register::TransformFile::load(Path::new(file))
                .with_context(|| format!("--pose: reading the transform {file}"))?,
        ),
    };
    let bar = crate::progress::bar(5, "reading cloud");
    let mut c =
        PointCloud::read_ply(cloud).with_context(|| format!("reading {}", cloud.display()))?;
    // Points flagged outside their sensor's calibrated volume are not trusted to measure.
    let outside = c.drop_outside();
    bar.inc(1);
    bar.set_message("reading CAD");
    let mesh = TriangleMesh::load(cad).with_context(|| format!("reading CAD {}", cad.display()))?;
    let datums = match datums {
        Some(p) => load_datums(p).with_context(|| format!("reading datums {}", p.display()))?,
        None => Vec::new(),
    };
    let t = Instant::now();
    bar.inc(1);
    bar.set_message("indexing CAD");
    let sd = SignedDistance::new(mesh);
    bar.inc(1);
    bar.set_message(if known.is_some() {
        "measuring deviations"
    } else {
        "registering"
    });
    let pts: Vec<[f64; 3]> = c
        .points
        .iter()
        .map(|p| [f64::from(p[0]), f64::from(p[1]), f64::from(p[2])])
        .collect();
    let mut r = inspect(
        &pts,
        &sd,
        &InspectParams {
            tolerance,
            datums: datums.clone(),
            min_coverage,
            init: known,
            fit_pose: known.is_none(),
            ..InspectParams::default()
        },
    )
    .with_context(|| format!("inspecting {}", cloud.display()))?;
    if outside > 0 {
        r.report.warnings.push(format!(
            "{outside} points flagged outside their sensor's calibrated volume were not inspected"
        ));
    }
    let elapsed = t.elapsed();
    bar.inc(1);
    bar.set_message("writing");
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    write_deviation_ply(&out.join("deviation.ply"), &r.points, &r.deviations)?;
    let title = MapTitle {
        part: name_of(cad),
        scan: name_of(cloud),
        time: ris_daemon::scan::utc_time(),
    };
    write_deviation_png(
        &out.join("deviation.png"),
        &r.points,
        &r.deviations,
        &r.report,
        &datums,
        &title,
    )?;
    let json = serde_json::to_string_pretty(&r.report)?;
    ris_core::io::write_atomic(&out.join("report.json"), json.as_bytes())?;
    ris_daemon::page::write_report_page(out)?;
    bar.finish_and_clear();
    let s = &r.report.statistics;
    if s.non_finite > 0 {
        println!(
            "{} points with a NaN or infinite coordinate left out",
            s.non_finite
        );
    }
    println!(
        "{}: {} points, {:.1} % of the CAD surface measured, deviation mean {:+.3} mm, RMS {:.3} mm, range {:+.3} … {:+.3} mm, {:.1} % within ±{tolerance} mm ({}, {:.1} s)",
        r.report.verdict.to_uppercase().replace('_', " "),
        s.points,
        100.0 * r.report.coverage.fraction,
        s.mean,
        s.rms,
        s.min,
        s.max,
        100.0 * s.within_tolerance,
        match r.report.registration.mode.as_str() {
            "known pose" => "at the known pose".to_string(),
            mode => format!("{mode} registration"),
        },
        elapsed.as_secs_f64()
    );
    for reason in &r.report.reasons {
        println!("  - {reason}");
    }
    for d in &r.report.datums {
        let Some(m) = &d.frame else { continue };
        match (&m.error, m.measured) {
            (Some(why), _) => println!("  datum {} ({:?}): not measured: {why}", d.name, m.feature),
            (None, Some(p)) => println!(
                "  datum {} ({:?}, order {}): at ({:.3}, {:.3}, {:.3}) mm, offset {:?} mm{}",
                d.name,
                m.feature,
                m.order.unwrap_or(0),
                p[0],
                p[1],
                p[2],
                m.offset_mm
                    .iter()
                    .map(|o| (o * 1000.0).round() / 1000.0)
                    .collect::<Vec<_>>(),
                m.size_mm
                    .map(|s| format!(", size {s:.3} mm"))
                    .unwrap_or_default()
            ),
            (None, None) => {}
        }
    }
    println!(
        "wrote {}/deviation.ply, deviation.png, report.json",
        out.display()
    );
    Ok(r.report)
}

/// A file's name for a title.
fn name_of(p: &Path) -> String {
    p.file_name().map_or_else(
        || p.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}
