//! `ris calibrate`: cameras from chessboard images, sensors to the cell frame.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use rayon::prelude::*;
use ris_core::calibrate::chessboard::{detect, BoardSize, DetectParams};
use ris_core::calibrate::{
    calibrate_camera, calibrate_sensor, fit_gauge, overlap_consistency, BoardView,
    CameraCalibration, CameraParams, DroppedView, Gauge, GaugeFit, GaugeParams, SensorCalibration,
    SensorParams, Session,
};
use ris_core::cloud::PointCloud;
use ris_core::image::GrayImage;
use ris_core::io::{read_toml, write_atomic};
use ris_core::sensor::{SensorFile, ToCommonSection};

use super::parse_sensor_cloud;

/// `ris calibrate camera`: detect the board in every image (in parallel), calibrate, print the
/// per-view and overall RMS and every dropped view, and write the camera file atomically.
pub fn camera(
    board: &str,
    square: f64,
    fix_aspect: bool,
    images: &[PathBuf],
    out: &Path,
) -> Result<CameraCalibration> {
    let size = BoardSize::parse(board).with_context(|| {
        format!("--board {board:?}: expected inner corners as COLSxROWS, e.g. 9x6")
    })?;
    anyhow::ensure!(
        square.is_finite() && square > 0.0,
        "--square {square}: the square size must be a positive number of millimetres"
    );
    let bar = crate::progress::bar(images.len() as u64, "corners");
    // Outer error: the image cannot be read (bad input, fatal); inner: no board in it (dropped).
    type Detected = ris_core::Result<(GrayImage, Result<BoardView, String>)>;
    let detected: Vec<Detected> = images
        .par_iter()
        .map(|path| {
            let img = GrayImage::load(path)?;
            let name = path.display().to_string();
            let corners = detect(
                &img.to_levels(),
                img.width as usize,
                img.height as usize,
                size,
                &DetectParams::default(),
            );
            bar.inc(1);
            let view = corners
                .map(|corners| BoardView { name, corners })
                .map_err(|e| e.to_string());
            Ok((img, view))
        })
        .collect();
    bar.finish_and_clear();
    let mut views = Vec::new();
    let mut not_found = Vec::new();
    let mut dims: Option<(u32, u32, PathBuf)> = None;
    for (path, d) in images.iter().zip(detected) {
        let (img, view) = d.with_context(|| format!("reading {}", path.display()))?;
        match &dims {
            None => dims = Some((img.width, img.height, path.clone())),
            Some((w, h, first)) => anyhow::ensure!(
                (*w, *h) == (img.width, img.height),
                "{}: {}x{} differs from {} ({w}x{h}); one camera per calibration",
                path.display(),
                img.width,
                img.height,
                first.display()
            ),
        }
        match view {
            Ok(view) => {
                println!(
                    "{}: {}/{} corners{}",
                    view.name,
                    view.corners.found(),
                    size.len(),
                    if view.corners.found() < size.len() {
                        format!(", missing {:?}", view.corners.missing())
                    } else {
                        String::new()
                    }
                );
                views.push(view);
            }
            Err(reason) => {
                println!("{}: {reason}", path.display());
                not_found.push(DroppedView {
                    image: path.display().to_string(),
                    reason,
                });
            }
        }
    }
    anyhow::ensure!(
        !views.is_empty(),
        "no image shows a {board} board (check --board: inner corners, not squares); nothing \
         was written"
    );
    let (width, height, _) = dims.context("no images given")?;
    let params = CameraParams {
        fix_aspect,
        ..CameraParams::default()
    };
    let mut cal = calibrate_camera(&views, square, width, height, &params)
        .context("camera calibration failed; no file was written")?;
    cal.dropped.splice(0..0, not_found);
    for v in &cal.views {
        println!("  {}: RMS {:.3} px", v.image, v.rms);
    }
    for d in &cal.dropped {
        println!("  dropped {}: {}", d.image, d.reason);
    }
    println!(
        "fx {:.2} fy {:.2} cx {:.2} cy {:.2} dist [{}]; RMS {:.3} px over {} views",
        cal.k[0][0],
        cal.k[1][1],
        cal.k[0][2],
        cal.k[1][2],
        cal.dist.map(|d| format!("{d:.5}")).join(", "),
        cal.rms,
        cal.views.len()
    );
    cal.save(out)
        .with_context(|| format!("writing {}", out.display()))?;
    println!("wrote {}", out.display());
    Ok(cal)
}

/// `ris calibrate sensor`: calibrate from a multi-layer session, print the report, write it as
/// JSON, and write the sensor file (with its residual) only if every gate passed.
pub fn sensor(
    session: &Path,
    camera: Option<&Path>,
    out: &Path,
    report: Option<&Path>,
) -> Result<SensorCalibration> {
    let s = Session::load(session)
        .with_context(|| format!("reading calibration session {}", session.display()))?;
    let mut params = SensorParams::default();
    if let Some(path) = camera {
        let c = CameraCalibration::load(path)
            .with_context(|| format!("reading camera file {}", path.display()))?;
        params.intrinsics = Some(c);
    }
    let bar = crate::progress::bar(s.layers.len() as u64 + 2, "layers");
    let cal = calibrate_sensor(&s, &params, &|stage, _, _| {
        bar.set_message(stage.to_string());
        bar.inc(1);
    });
    bar.finish_and_clear();
    let cal = cal.with_context(|| {
        format!(
            "calibrating from {}; no sensor file was written",
            s.path.display()
        )
    })?;
    let r = &cal.report;
    println!("session {}", r.session);
    for l in &r.layers {
        let fmt =
            |v: Option<f64>, unit: &str| v.map(|x| format!("{x:.3} {unit}")).unwrap_or("-".into());
        println!(
            "  layer {} ({}) h {:.2} mm: {} corners{}, reprojection {}, fitted h {} ± {}, error before {} after {}{}",
            l.layer,
            l.dir,
            l.height,
            l.corners,
            if l.missing.is_empty() { String::new() } else { format!(" ({} missing)", l.missing.len()) },
            fmt(l.reprojection_rms, "px"),
            fmt(l.fitted_height, "mm"),
            fmt(l.fitted_height_sigma, "mm"),
            fmt(l.before.map(|b| b.rms), "mm"),
            fmt(l.after.map(|b| b.rms), "mm"),
            l.excluded.as_ref().map(|e| format!("; EXCLUDED: {e}")).unwrap_or_default()
        );
    }
    println!(
        "camera fx {:.2} fy {:.2} cx {:.2} cy {:.2} dist [{}], reprojection RMS {:.3} px",
        r.k[0][0],
        r.k[1][1],
        r.k[0][2],
        r.k[1][2],
        r.dist.map(|d| format!("{d:.5}")).join(", "),
        r.reprojection_rms
    );
    println!(
        "camera centre [{:.2}, {:.2}, {:.2}] mm, projector centre [{:.2}, {:.2}, {:.2}] mm ({} rays, RMS {:.3} mm)",
        r.camera_center[0], r.camera_center[1], r.camera_center[2],
        r.projector_center[0], r.projector_center[1], r.projector_center[2],
        r.projector_rays, r.projector_ray_rms
    );
    if let (Some(c), Some(rms)) = (r.projector_full_center, r.projector_reprojection_rms) {
        println!(
            "full projector calibration (classical model): centre [{:.2}, {:.2}, {:.2}] mm, reprojection RMS {rms:.3} projector px",
            c[0], c[1], c[2]
        );
    }
    if let (Some(sc), Some(sf)) = (r.camera_center_sigma, r.focal_sigma) {
        println!(
            "camera centre standard error [{:.2}, {:.2}, {:.2}] mm, fx ± {sf:.2} px",
            sc[0], sc[1], sc[2]
        );
        if sc.iter().any(|s| *s > 1.0) {
            println!(
                "  note: the layers decide focal length and distance together poorly; heights stay \
                 consistent, but for a trustworthy pose calibrate the camera with tilted views \
                 (`ris calibrate camera`) and pass it with --camera"
            );
        }
    }
    println!(
        "standoff S {:.1} mm, baseline d {:.1} mm; 0.1 px of decoding error -> {:.3} mm at h = 0, {:.3} mm at the top layer",
        r.standoff, r.baseline, r.height_error_per_tenth_pixel[0], r.height_error_per_tenth_pixel[1]
    );
    println!(
        "height error before compensation RMS {:.3} mm (max {:.3}), after RMS {:.3} mm (max {:.3})",
        r.before.rms, r.before.max, r.after.rms, r.after.max
    );
    for g in &r.gates {
        println!(
            "  gate {}: {:.3} (limit {:.3}) {}",
            g.name,
            g.value,
            g.limit,
            if g.pass { "pass" } else { "FAIL" }
        );
    }
    println!("verdict: {}", r.verdict);
    let report_path = match report {
        Some(p) => p.to_path_buf(),
        None => {
            let stem = out
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or("sensor".into());
            out.with_file_name(format!("{stem}.report.json"))
        }
    };
    if let Some(dir) = report_path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    write_atomic(&report_path, serde_json::to_string_pretty(r)?.as_bytes())
        .with_context(|| format!("writing {}", report_path.display()))?;
    println!("wrote report {}", report_path.display());
    if cal.passed() {
        cal.save(out)
            .with_context(|| format!("writing {}", out.display()))?;
        println!("wrote {}", out.display());
    } else {
        println!(
            "calibration failed its gates; {} was not written",
            out.display()
        );
    }
    Ok(cal)
}

/// `ris calibrate cell`: fit every sensor's measurement of the marker gauge, and only when all
/// of them pass, write each sensor file's `[to_common]` (atomically) and, if asked, a JSON
/// report. Returns the fits in input order.
pub fn cell(
    gauge_path: &Path,
    inputs: &[String],
    params: &GaugeParams,
    report: Option<&Path>,
) -> Result<Vec<GaugeFit>> {
    let gauge = Gauge::load(gauge_path)
        .with_context(|| format!("reading gauge {}", gauge_path.display()))?;
    anyhow::ensure!(
        !inputs.is_empty(),
        "give at least one SENSOR.toml:CLOUD.ply"
    );
    let mut fits = Vec::new();
    let mut files: Vec<(PathBuf, SensorFile)> = Vec::new();
    for arg in inputs {
        let (sensor, cloud) = parse_sensor_cloud(arg)?;
        let file: SensorFile = read_toml(&sensor)
            .with_context(|| format!("reading sensor file {}", sensor.display()))?;
        let c =
            PointCloud::read_ply(&cloud).with_context(|| format!("reading {}", cloud.display()))?;
        let fit = fit_gauge(&c, &gauge, params)
            .with_context(|| format!("{arg}: gauge fit failed; no sensor file was changed"))?;
        println!(
            "{arg}: {} markers ({} matched, {} clusters rejected), centre RMS {:.3} mm, max {:.3} mm",
            fit.markers.len(),
            fit.matched,
            fit.rejected.len(),
            fit.rms,
            fit.max
        );
        for r in &fit.rejected {
            tracing::debug!(sensor = %arg, centroid = ?r.centroid, points = r.points, reason = %r.reason, "cluster rejected");
        }
        fits.push(fit);
        files.push((sensor, file));
    }
    let checks = overlap_consistency(&fits);
    for c in &checks {
        println!(
            "overlap {} / {}: {} shared markers, centre agreement RMS {:.3} mm",
            inputs[c.sensors.0], inputs[c.sensors.1], c.shared, c.rms
        );
    }
    for ((path, mut file), fit) in files.into_iter().zip(&fits) {
        let m = fit.to_common.to_homogeneous();
        file.to_common = Some(ToCommonSection {
            matrix: std::array::from_fn(|i| std::array::from_fn(|j| m[(i, j)])),
        });
        file.save(&path)
            .with_context(|| format!("writing {}", path.display()))?;
        println!("wrote [to_common] of {}", path.display());
    }
    if let Some(report) = report {
        let json = serde_json::json!({
            "gauge": gauge_path.display().to_string(),
            "sensors": inputs.iter().zip(&fits).map(|(arg, f)| serde_json::json!({
                "input": arg,
                "to_common": (0..4).map(|i| (0..4).map(|j| f.to_common.to_homogeneous()[(i, j)]).collect::<Vec<_>>()).collect::<Vec<_>>(),
                "matched": f.matched,
                "rms_mm": f.rms,
                "max_mm": f.max,
                "markers": f.markers,
                "rejected": f.rejected,
            })).collect::<Vec<_>>(),
            "overlaps": checks.iter().map(|c| serde_json::json!({
                "sensors": [inputs[c.sensors.0].clone(), inputs[c.sensors.1].clone()],
                "shared": c.shared,
                "rms_mm": c.rms,
            })).collect::<Vec<_>>(),
        });
        write_atomic(report, serde_json::to_string_pretty(&json)?.as_bytes())
            .with_context(|| format!("writing {}", report.display()))?;
        println!("wrote {}", report.display());
    }
    Ok(fits)
}

/// `ris calibrate omni`: the ray tables from the session in `session`, written with the sensor
/// file `out`; prints what was found.
pub fn omni(session: &Path, out: &Path) -> Result<()> {
    let cal = ris_core::omni::calibrate::calibrate(session)
        .with_context(|| format!("calibrating from {}", session.display()))?;
    if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    cal.save(out)
        .with_context(|| format!("writing {}", out.display()))?;
    let r = &cal.report;
    for (k, [found, in_view]) in r.dots.iter().enumerate() {
        println!(
            "position {}: {found} of {in_view} dots in view found (towards the image's centre they crowd too close to part)",
            k + 1
        );
    }
    use ris_core::omni::fit::{MAX_RAY_SD_DEG, MAX_RMS_PX};
    for (unit, f) in [("camera", &r.camera_fit), ("projector", &r.projector_fit)] {
        if f.used {
            println!(
                "{unit}: model fitted to {} of {} observations: {:.2} px RMS ({:.2} px at 95 %; the drawn file {:.2} px), rays within {:.4}° (1 sigma, worst pixel), mirror moved {:.2} mm and turned {:.2}°",
                f.observations[0], f.observations[1], f.rms_px, f.p95_px, f.nominal_rms_px, f.ray_sd_deg, f.moved_mm, f.turned_deg
            );
        } else if f.observations[0] == 0 {
            println!(
                "{unit}: {} observations are too few to fit the mirror model: its rays are each pixel's own two target points, noisier",
                f.observations[1]
            );
        } else if f.rms_px > MAX_RMS_PX {
            println!(
                "{unit}: the mirror model does not fit its observations ({:.2} px RMS, more than {MAX_RMS_PX} px): its rays are each pixel's own two target points, noisier",
                f.rms_px
            );
        } else {
            println!(
                "{unit}: the observations leave the mirror model loose (rays known to {:.3}° at the worst pixel, more than {MAX_RAY_SD_DEG}°: too few, or one side or distance only): its rays are each pixel's own two target points, noisier",
                f.ray_sd_deg
            );
        }
    }
    println!(
        "camera rays for {} of {} mirror pixels, projector rays for {} of {} (the rest: outside the band of image radii the target covered at both positions, NaN) -> {}",
        r.camera_pixels[0], r.camera_pixels[1], r.projector_pixels[0], r.projector_pixels[1], out.display()
    );
    Ok(())
}
