//! Multi-layer sensor calibration (SPEC §7, Ch. 3.2.4). The chessboard at known heights is a 3D
//! target: the camera's projection follows by DLT (Eq. 3.25) and Levenberg–Marquardt with Brown
//! distortion. Each lifted layer's codes, traced back to the reference layer, give projector rays
//! whose common point is the projector centre (least squares). The per-pixel quadratic residual
//! of Eq. 3.27–3.28 absorbs what the model leaves. Layers without a board or with a height that
//! contradicts the others are reported and excluded; gates decide the verdict.

use std::path::Path;

use nalgebra::{DMatrix, DVector, Matrix3, Rotation3, Vector3};
use rayon::prelude::*;
use serde::Serialize;

use super::camera::{push_residuals, reprojection_rms, CameraCalibration};
use super::chessboard::{detect, DetectParams};
use super::lm;
use super::session::Session;
use crate::capture::CaptureSet;
use crate::decode::{decode, DecodeParams, Decoded};
use crate::geometry::{in_rect, rows_of, Distortion, Mat3, Pinhole, Vec3};
use crate::image::gaussian_blur;
use crate::io::{npy, relative_path};
use crate::pattern::Pattern;
use crate::sensor::reference::{PlaneCodeMap, PlaneSample};
use crate::sensor::{
    CalibratedVolume, ProjectorSection, RayTable, Reconstructor, ReferenceSection, ResidualSection,
    SensorFile,
};
use crate::{Error, Result};

/// Settings and gates of a sensor calibration.
#[derive(Clone, Debug)]
pub struct SensorParams {
    /// Decoding of every layer.
    pub decode: DecodeParams,
    /// Chessboard detection.
    pub detect: DetectParams,
    /// A layer whose fitted height differs from its stated height by more than this (mm), and
    /// by more than `height_sigmas` standard errors of the fit, is excluded.
    pub height_gate: f64,
    /// Standard errors of the fitted height a deviation must also exceed (low-resolution
    /// cameras measure heights from corners less precisely).
    pub height_sigmas: f64,
    /// Gate on the camera's reprojection RMS, pixels.
    pub max_reprojection_rms: f64,
    /// Gate on the height residual after compensation (RMS over all layers), mm.
    pub max_residual_rms: f64,
    /// Fewest layers (the reference included) a calibration needs.
    pub min_layers: usize,
    /// Pixel stride of the samples for the projector centre and reference maps.
    pub sample_stride: usize,
    /// Smoothing (σ, pixels) of the per-layer height errors before the per-pixel fit.
    pub residual_smoothing: f32,
    /// Known camera intrinsics from `ris calibrate camera` with tilted views: the layers then
    /// only fix the pose, which a small board decides far better than focal length and
    /// distance together. Its image size must be the session's.
    pub intrinsics: Option<CameraCalibration>,
}

impl Default for SensorParams {
    fn default() -> Self {
        SensorParams {
            decode: DecodeParams::default(),
            detect: DetectParams::default(),
            height_gate: 0.5,
            height_sigmas: 6.0,
            max_reprojection_rms: 0.5,
            max_residual_rms: 0.2,
            min_layers: 4,
            sample_stride: 3,
            residual_smoothing: 2.0,
            intrinsics: None,
        }
    }
}

/// Summary of a set of errors, mm.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct ErrorStats {
    /// Samples.
    pub count: usize,
    /// Mean (signed).
    pub mean: f64,
    /// Root mean square.
    pub rms: f64,
    /// Largest magnitude.
    pub max: f64,
}

impl ErrorStats {
    fn of(values: impl Iterator<Item = f64>) -> ErrorStats {
        let (mut n, mut s, mut s2, mut m) = (0usize, 0.0, 0.0, 0.0f64);
        for v in values {
            n += 1;
            s += v;
            s2 += v * v;
            m = m.max(v.abs());
        }
        if n == 0 {
            return ErrorStats::default();
        }
        ErrorStats {
            count: n,
            mean: s / n as f64,
            rms: (s2 / n as f64).sqrt(),
            max: m,
        }
    }
}

/// What happened to one layer.
#[derive(Clone, Debug, Serialize)]
pub struct LayerReport {
    /// Index in the session.
    pub layer: usize,
    /// Capture directory.
    pub dir: String,
    /// Stated height, mm.
    pub height: f64,
    /// Corners found.
    pub corners: usize,
    /// Grid indices (i, j) of corners not found.
    pub missing: Vec<[usize; 2]>,
    /// Reprojection RMS of its corners with the final camera, pixels.
    pub reprojection_rms: Option<f64>,
    /// Height that best fits its corners with the final camera, mm.
    pub fitted_height: Option<f64>,
    /// Standard error of that height, mm.
    pub fitted_height_sigma: Option<f64>,
    /// Height error before residual compensation, mm.
    pub before: Option<ErrorStats>,
    /// Height error after residual compensation, mm.
    pub after: Option<ErrorStats>,
    /// Why the layer was left out, if it was.
    pub excluded: Option<String>,
}

/// One gate of the verdict.
#[derive(Clone, Debug, Serialize)]
pub struct Gate {
    /// What is checked.
    pub name: String,
    /// Measured value.
    pub value: f64,
    /// Limit.
    pub limit: f64,
    /// Whether the value is within the limit.
    pub pass: bool,
}

/// The calibration report (printed, and written beside the sensor file).
#[derive(Clone, Debug, Serialize)]
pub struct SensorReport {
    /// Session file.
    pub session: String,
    /// Per layer.
    pub layers: Vec<LayerReport>,
    /// Camera intrinsics.
    pub k: [[f64; 3]; 3],
    /// Camera distortion.
    pub dist: [f64; 5],
    /// Camera reprojection RMS over the used layers, pixels.
    pub reprojection_rms: f64,
    /// Camera centre in the board frame, mm.
    pub camera_center: [f64; 3],
    /// Standard error of the camera centre from the corners alone (all camera parameters
    /// free), mm; large when the session decides focal length and distance poorly.
    pub camera_center_sigma: Option<[f64; 3]>,
    /// Standard error of fx from the corners alone, pixels.
    pub focal_sigma: Option<f64>,
    /// Projector centre in the board frame, mm.
    pub projector_center: [f64; 3],
    /// RMS distance of the traced projector rays from the fitted centre, mm.
    pub projector_ray_rms: f64,
    /// Projector rays used.
    pub projector_rays: usize,
    /// Centre of the full projector calibration, mm (compare with `projector_center`).
    pub projector_full_center: Option<[f64; 3]>,
    /// Reprojection RMS of the full projector calibration, projector pixels.
    pub projector_reprojection_rms: Option<f64>,
    /// Standoff S of the parallel form (projector centre height), mm.
    pub standoff: f64,
    /// Baseline d of the parallel form (horizontal camera–projector distance), mm.
    pub baseline: f64,
    /// Predicted height error for 0.1 px of decoding error at the image centre (Eq. 3.3), at the
    /// reference plane and at the highest layer, mm.
    pub height_error_per_tenth_pixel: [f64; 2],
    /// Height error over all used layers before compensation, mm.
    pub before: ErrorStats,
    /// Height error over all used layers after compensation, mm.
    pub after: ErrorStats,
    /// The gates applied.
    pub gates: Vec<Gate>,
    /// "pass" or "fail".
    pub verdict: String,
}

/// A calibrated sensor with its evidence.
#[derive(Clone, Debug)]
pub struct SensorCalibration {
    /// The camera in the board frame.
    pub camera: Pinhole,
    /// Projector size (from the layer-0 capture).
    pub projector_size: (u32, u32),
    /// Projector centre O_p, mm.
    pub projector_center: Vec3,
    /// The projector calibrated as an inverse camera from the decoded board points (classical
    /// model), when the fit succeeded.
    pub projector: Option<Pinhole>,
    /// The reference recording (layer 0's capture directory).
    pub reference: std::path::PathBuf,
    /// Valid area of the reference plane `[x_min, x_max, y_min, y_max]`, mm.
    pub extent: [f64; 4],
    /// The box the session measured: the extent over the heights of the layers kept.
    pub volume: CalibratedVolume,
    /// Residual coefficients A, B, C per pixel (H × W × 3).
    pub residual: Vec<f32>,
    /// The report.
    pub report: SensorReport,
}

impl SensorCalibration {
    /// Whether every gate passed.
    pub fn passed(&self) -> bool {
        self.report.verdict == "pass"
    }

    /// Write the sensor file `out` (parallax model: camera, projector centre, the reference as a
    /// path relative to `out`, its valid extent) and its residual `<stem>.residual.npy` beside
    /// it, each atomically.
    pub fn save(&self, out: &Path) -> Result<SensorFile> {
        let dir = out
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        crate::io::create_dir(dir)?;
        let stem = out
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "sensor".into());
        let residual_name = format!("{stem}.residual.npy");
        let (w, h) = (self.camera.width as usize, self.camera.height as usize);
        npy::write(&dir.join(&residual_name), &[h, w, 3], &self.residual)?;
        let reference = relative_path(dir, &self.reference)?;
        let op = self.projector_center;
        let file = SensorFile {
            camera: SensorFile::camera_section(&self.camera),
            projector: ProjectorSection {
                width: self.projector_size.0,
                height: self.projector_size.1,
                center: Some([op.x, op.y, op.z]),
                k: self.projector.as_ref().map(|p| rows_of(&p.k)),
                dist: self.projector.as_ref().map(|p| p.dist.to_array()),
                r: self.projector.as_ref().map(|p| rows_of(&p.r)),
                t: self.projector.as_ref().map(|p| [p.t.x, p.t.y, p.t.z]),
            },
            reference: Some(ReferenceSection {
                capture: reference.to_string_lossy().into_owned(),
                extent: Some(self.extent),
            }),
            residual: Some(ResidualSection {
                file: residual_name,
            }),
            to_common: None,
            volume: Some(self.volume.section()),
        };
        file.save(out)?;
        Ok(file)
    }
}

/// One decoded layer.
struct LayerData {
    corners: Option<Vec<(Vec3, [f64; 2])>>,
    decoded: Decoded,
}

/// Calibrate the sensor of `session`, loading each layer's capture set from disk.
pub fn calibrate_sensor(
    session: &Session,
    params: &SensorParams,
    progress: &(dyn Fn(&str, usize, usize) + Sync),
) -> Result<SensorCalibration> {
    calibrate_sensor_with(
        session,
        params,
        &|i| CaptureSet::load(&session.layers[i].dir),
        progress,
    )
}

/// As [`calibrate_sensor`] with the capture of layer `i` supplied by `load(i)` (benchmarks and
/// tests keep them in memory).
pub fn calibrate_sensor_with(
    session: &Session,
    params: &SensorParams,
    load: &(dyn Fn(usize) -> Result<CaptureSet> + Sync),
    progress: &(dyn Fn(&str, usize, usize) + Sync),
) -> Result<SensorCalibration> {
    let n = session.layers.len();
    let mut reports: Vec<LayerReport> = Vec::with_capacity(n);
    let mut layers: Vec<LayerData> = Vec::with_capacity(n);
    let mut size: Option<(u32, u32, (u32, u32))> = None;
    for (i, layer) in session.layers.iter().enumerate() {
        let dir = layer.dir.display().to_string();
        let capture = load(i)?;
        let dims = (
            capture.width,
            capture.height,
            (capture.layout.width, capture.layout.height),
        );
        match size {
            None => {
                if let Some(c) = &params.intrinsics {
                    if (c.width, c.height) != (dims.0, dims.1) {
                        return Err(Error::invalid(
                            &dir,
                            "size",
                            format!(
                                "images are {}x{} but the camera calibration is for {}x{}",
                                dims.0, dims.1, c.width, c.height
                            ),
                        ));
                    }
                }
                size = Some(dims)
            }
            Some(s) if s != dims => {
                return Err(Error::invalid(
                    &dir,
                    "size",
                    format!(
                        "camera {}x{} / projector {}x{} differs from layer 0's",
                        dims.0, dims.1, dims.2 .0, dims.2 .1
                    ),
                ))
            }
            Some(_) => {}
        }
        if !capture.has_code(crate::pattern::CodeAxis::Row) {
            return Err(Error::invalid(
                &dir,
                "frames",
                "a calibration layer needs row codes as well as column codes",
            ));
        }
        let white = capture.frame(Pattern::White).ok_or_else(|| {
            Error::invalid(&dir, "frames", "no `white` frame to find the board in")
        })?;
        let found = detect(
            &white.to_levels(),
            capture.width as usize,
            capture.height as usize,
            session.board,
            &params.detect,
        );
        let decoded = decode(&capture, &params.decode)?;
        drop(capture);
        let mut report = LayerReport {
            layer: i,
            dir,
            height: layer.height,
            corners: 0,
            missing: Vec::new(),
            reprojection_rms: None,
            fitted_height: None,
            fitted_height_sigma: None,
            before: None,
            after: None,
            excluded: None,
        };
        let corners = match found {
            Ok(c) => {
                report.corners = c.found();
                report.missing = c.missing().into_iter().map(|(a, b)| [a, b]).collect();
                let min = session.board.len() / 2;
                if c.found() < min {
                    report.excluded = Some(format!(
                        "{} of {} corners found, at least {min} needed",
                        c.found(),
                        session.board.len()
                    ));
                    None
                } else {
                    Some(
                        c.iter_found()
                            .map(|((a, b), p)| {
                                (Vec3::from(session.corner_point(a, b, layer.height)), p)
                            })
                            .collect(),
                    )
                }
            }
            Err(e) => {
                report.excluded = Some(format!("no board: {e}"));
                None
            }
        };
        tracing::info!(layer = i, corners = report.corners, excluded = ?report.excluded, "layer decoded");
        reports.push(report);
        layers.push(LayerData { corners, decoded });
        progress("layers", i + 1, n);
    }
    let (width, height, projector_size) =
        size.ok_or_else(|| Error::Insufficient("no layers".into()))?;
    if let Some(reason) = &reports[0].excluded {
        return Err(Error::Insufficient(format!(
            "layer 0 ({}) is the reference plane and must show the board: {reason}",
            reports[0].dir
        )));
    }

    // Camera from the 3D target; exclude layers whose height contradicts the others.
    let mut used: Vec<usize> = (0..n).filter(|&i| layers[i].corners.is_some()).collect();
    let camera = loop {
        if used.len() < params.min_layers {
            return Err(Error::Insufficient(format!(
                "{} usable layers, at least {} needed:{}",
                used.len(),
                params.min_layers,
                reports
                    .iter()
                    .filter_map(|r| r
                        .excluded
                        .as_ref()
                        .map(|e| format!(" layer {} ({}): {e};", r.layer, r.dir)))
                    .collect::<String>()
            )));
        }
        let obs: Vec<(Vec3, [f64; 2])> = used
            .iter()
            .flat_map(|&i| layers[i].corners.iter().flatten().copied())
            .collect();
        let known = params
            .intrinsics
            .as_ref()
            .map(|c| (c.k_matrix(), c.distortion()));
        let camera = fit_camera(&obs, width, height, known.as_ref())?;
        // The layer whose height deviates most, relative to its gate.
        let mut worst: Option<(usize, f64, f64)> = None;
        for &i in &used {
            let corners = layers[i].corners.as_deref().unwrap_or_default();
            let (fitted, sigma) = fit_height(&camera, corners, session.layers[i].height);
            reports[i].fitted_height = Some(fitted);
            reports[i].fitted_height_sigma = Some(sigma);
            reports[i].reprojection_rms = Some(reprojection_rms(&camera, corners));
            let dev = (fitted - session.layers[i].height).abs();
            let gate = params.height_gate.max(params.height_sigmas * sigma);
            if worst.is_none_or(|(_, d, g)| dev / gate > d / g) {
                worst = Some((i, dev, gate));
            }
        }
        match worst {
            Some((0, dev, gate)) if dev > gate => {
                return Err(Error::Insufficient(format!(
                    "the reference layer 0 ({}) fits height {:.2} mm instead of 0: the layer \
                     heights are inconsistent; no calibration written",
                    reports[0].dir,
                    reports[0].fitted_height.unwrap_or(f64::NAN)
                )));
            }
            Some((i, dev, gate)) if dev > gate => {
                reports[i].excluded = Some(format!(
                    "its corners fit height {:.2} mm, not the stated {:.2} mm ({dev:.2} mm > gate {gate:.2} mm)",
                    reports[i].fitted_height.unwrap_or(f64::NAN),
                    session.layers[i].height,
                ));
                tracing::warn!(
                    layer = i,
                    deviation = dev,
                    "layer excluded: inconsistent height"
                );
                used.retain(|&u| u != i);
            }
            _ => break camera,
        }
    };
    let obs: Vec<(Vec3, [f64; 2])> = used
        .iter()
        .flat_map(|&i| layers[i].corners.iter().flatten().copied())
        .collect();
    let camera_rms = reprojection_rms(&camera, &obs);
    let uncertainty = if params.intrinsics.is_none() {
        camera_uncertainty(&camera, &obs)
    } else {
        None
    };
    let rays = RayTable::new(&camera);
    let oc_world = camera.center();
    let r_world = camera.r.transpose();
    let [hx, hy] = session.board_half_extent();
    let extent = [-hx, hx, -hy, hy];

    // Reference maps (layer 0, board area) and the projector centre.
    let stride = params.sample_stride.max(1);
    let (col_map, row_map) = reference_maps(&camera, &rays, &layers[0].decoded, extent, stride)?;
    let lifted: Vec<(usize, f64)> = used
        .iter()
        .filter(|&&i| i != 0)
        .map(|&i| (i, session.layers[i].height))
        .collect();
    let (op, ray_rms, ray_count) = projector_center(
        &camera,
        &rays,
        &lifted
            .iter()
            .map(|&(i, h)| (&layers[i].decoded, h))
            .collect::<Vec<_>>(),
        &col_map,
        &row_map,
        extent,
        stride,
    )?;
    // The full projector calibration (classical model): the board points of every used layer
    // with their decoded projector coordinates are a 3D target for the projector as a camera.
    let mut proj_obs: Vec<(Vec3, [f64; 2])> = Vec::new();
    for &i in &used {
        let d = &layers[i].decoded;
        let Some(row) = d.row.as_ref() else { continue };
        let h = session.layers[i].height;
        let (w, hh) = (d.width as usize, d.height as usize);
        let step = (stride * 4).max(1);
        for v in (0..hh).step_by(step) {
            for u in (0..w).step_by(step) {
                let k = v * w + u;
                let (c, r) = (d.col[k], row[k]);
                if !(c.is_finite() && r.is_finite()) {
                    continue;
                }
                if let Some(p) = rays
                    .on_plane(k, &oc_world, &r_world, h)
                    .filter(|p| in_rect(&extent, p.x, p.y))
                {
                    proj_obs.push((p, [f64::from(c), f64::from(r)]));
                }
            }
        }
    }
    let projector = match fit_camera(&proj_obs, projector_size.0, projector_size.1, None) {
        Ok(p) => Some(p),
        Err(e) => {
            tracing::warn!(error = %e, "full projector calibration failed; the parallax model does not need it");
            None
        }
    };
    let projector_rms = projector.as_ref().map(|p| reprojection_rms(p, &proj_obs));
    progress("projector", 1, 1);

    // Residual per pixel.
    let rec = Reconstructor::parallax_within(&camera, op, &layers[0].decoded, Some(extent))?;
    let mut maps: Vec<Vec<[f32; 2]>> = Vec::new();
    for &i in &used {
        let detail = rec.parallax_detail(&layers[i].decoded)?;
        let h = session.layers[i].height as f32;
        let em: Vec<[f32; 2]> = detail
            .par_iter()
            .map(|&[x, y, z, m]| {
                let inside = in_rect(&extent, f64::from(x), f64::from(y));
                if z.is_finite() && inside {
                    [z - h, m]
                } else {
                    [f32::NAN; 2]
                }
            })
            .collect();
        maps.push(em);
    }
    let residual = fit_height_residual(
        &maps,
        width as usize,
        height as usize,
        params.residual_smoothing,
    );
    progress("residual", 1, 1);
    let mut all_before = Vec::new();
    let mut all_after = Vec::new();
    for (i, em) in used.iter().zip(&maps) {
        let before: Vec<f64> = em
            .iter()
            .filter(|v| v[0].is_finite())
            .map(|v| f64::from(v[0]))
            .collect();
        let after: Vec<f64> = em
            .iter()
            .enumerate()
            .filter(|(_, v)| v[0].is_finite())
            .map(|(p, v)| {
                let [a, b, c] = [residual[3 * p], residual[3 * p + 1], residual[3 * p + 2]];
                let m = v[1];
                f64::from(v[0] - (a * m * m + b * m + c))
            })
            .collect();
        reports[*i].before = Some(ErrorStats::of(before.iter().copied()));
        reports[*i].after = Some(ErrorStats::of(after.iter().copied()));
        all_before.extend(before);
        all_after.extend(after);
    }
    let before = ErrorStats::of(all_before.into_iter());
    let after = ErrorStats::of(all_after.into_iter());

    // Parallel-form figures and the predicted sensitivity (Eq. 3.3).
    let oc = camera.center();
    let standoff = op.z;
    let baseline = (op - oc).xy().norm();
    let (cu, cv) = (f64::from(width) / 2.0, f64::from(height) / 2.0);
    let on_plane = |u: f64, v: f64| {
        let d = camera.ray(u, v);
        oc + d * (-oc.z / d.z)
    };
    let k_mm = (on_plane(cu + 1.0, cv) - on_plane(cu, cv)).norm();
    let top = used
        .iter()
        .map(|&i| session.layers[i].height)
        .fold(0.0, f64::max);
    let sensitivity = |h: f64| {
        let m = baseline * h / (standoff - h);
        let dm = 0.1 * k_mm;
        standoff * (m + dm) / (baseline + m + dm) - standoff * m / (baseline + m)
    };

    let gates = vec![
        gate(
            "camera reprojection RMS (px)",
            camera_rms,
            params.max_reprojection_rms,
        ),
        gate(
            "height residual RMS after compensation (mm)",
            after.rms,
            params.max_residual_rms,
        ),
        Gate {
            name: "layers used (at least)".into(),
            value: used.len() as f64,
            limit: params.min_layers as f64,
            pass: used.len() >= params.min_layers,
        },
        Gate {
            name: "projector centre above the highest layer (mm)".into(),
            value: standoff,
            limit: top,
            pass: standoff > top,
        },
    ];
    let verdict = if gates.iter().all(|g| g.pass) {
        "pass"
    } else {
        "fail"
    };
    let report = SensorReport {
        session: session.path.display().to_string(),
        layers: reports,
        k: rows_of(&camera.k),
        dist: camera.dist.to_array(),
        reprojection_rms: camera_rms,
        camera_center: [oc.x, oc.y, oc.z],
        camera_center_sigma: uncertainty.map(|u| u.1),
        focal_sigma: uncertainty.map(|u| u.0),
        projector_center: [op.x, op.y, op.z],
        projector_full_center: projector.as_ref().map(|p| {
            let c = p.center();
            [c.x, c.y, c.z]
        }),
        projector_reprojection_rms: projector_rms,
        projector_ray_rms: ray_rms,
        projector_rays: ray_count,
        standoff,
        baseline,
        height_error_per_tenth_pixel: [sensitivity(0.0), sensitivity(top)],
        before,
        after,
        gates,
        verdict: verdict.into(),
    };
    Ok(SensorCalibration {
        camera,
        projector_size,
        projector_center: op,
        projector,
        reference: session.layers[0].dir.clone(),
        volume: CalibratedVolume {
            extent,
            heights: session
                .layers
                .iter()
                .zip(&report.layers)
                .filter(|(_, r)| r.excluded.is_none())
                .fold([f64::INFINITY, f64::NEG_INFINITY], |h, (l, _)| {
                    [h[0].min(l.height), h[1].max(l.height)]
                }),
        },
        extent,
        residual,
        report,
    })
}

fn gate(name: &str, value: f64, limit: f64) -> Gate {
    Gate {
        name: name.into(),
        value,
        limit,
        pass: value.is_finite() && value <= limit,
    }
}

/// Normalized image radius (tan of the field angle) the corners must reach for k2 to be fitted.
const K2_REACH: f64 = 0.35;

/// Camera by normalised DLT on non-coplanar points (Eq. 3.25), decomposed into K [R | t] by RQ,
/// then refined with Brown distortion by Levenberg–Marquardt.
/// With `intrinsics` (K and distortion from `ris calibrate camera`) only the pose is refined.
pub(crate) fn fit_camera(
    obs: &[(Vec3, [f64; 2])],
    width: u32,
    height: u32,
    intrinsics: Option<&(Mat3, Distortion)>,
) -> Result<Pinhole> {
    if obs.len() < 12 {
        return Err(Error::Insufficient(format!(
            "{} corners; the camera needs at least 12 on two or more heights",
            obs.len()
        )));
    }
    let n = obs.len() as f64;
    let c3 = obs.iter().fold(Vec3::zeros(), |a, (p, _)| a + p / n);
    let s3 = 3f64.sqrt() / (obs.iter().map(|(p, _)| (p - c3).norm()).sum::<f64>() / n).max(1e-12);
    let (mu, mv) = obs
        .iter()
        .fold((0.0, 0.0), |a, (_, q)| (a.0 + q[0] / n, a.1 + q[1] / n));
    let s2 = 2f64.sqrt()
        / (obs
            .iter()
            .map(|(_, q)| ((q[0] - mu).powi(2) + (q[1] - mv).powi(2)).sqrt())
            .sum::<f64>()
            / n)
            .max(1e-12);
    let mut a = DMatrix::<f64>::zeros(2 * obs.len(), 12);
    for (k, (p, q)) in obs.iter().enumerate() {
        let x = (p - c3) * s3;
        let xh = [x.x, x.y, x.z, 1.0];
        let (u, v) = ((q[0] - mu) * s2, (q[1] - mv) * s2);
        for j in 0..4 {
            a[(2 * k, j)] = xh[j];
            a[(2 * k, 8 + j)] = -u * xh[j];
            a[(2 * k + 1, 4 + j)] = xh[j];
            a[(2 * k + 1, 8 + j)] = -v * xh[j];
        }
    }
    let eig = (a.transpose() * &a).symmetric_eigen();
    let imin = eig
        .eigenvalues
        .iter()
        .enumerate()
        .min_by(|x, y| x.1.total_cmp(y.1))
        .map(|(i, _)| i)
        .unwrap_or(0);
    let pv = eig.eigenvectors.column(imin);
    let pn = nalgebra::Matrix3x4::from_fn(|i, j| pv[4 * i + j]);
    let t2inv = Matrix3::new(1.0 / s2, 0.0, mu, 0.0, 1.0 / s2, mv, 0.0, 0.0, 1.0);
    let t3 = nalgebra::Matrix4::new(
        s3,
        0.0,
        0.0,
        -s3 * c3.x,
        0.0,
        s3,
        0.0,
        -s3 * c3.y,
        0.0,
        0.0,
        s3,
        -s3 * c3.z,
        0.0,
        0.0,
        0.0,
        1.0,
    );
    let mut p = t2inv * pn * t3;
    let mut m: Mat3 = p.fixed_view::<3, 3>(0, 0).into_owned();
    if m.determinant() < 0.0 {
        p = -p;
        m = -m;
    }
    // RQ by QR of the row-reversed transpose.
    let flip = Matrix3::new(0.0, 0.0, 1.0, 0.0, 1.0, 0.0, 1.0, 0.0, 0.0);
    let qr = (flip * m).transpose().qr();
    let (q, r) = (qr.q(), qr.r());
    let mut k = flip * r.transpose() * flip;
    let mut rot = flip * q.transpose();
    let signs = Matrix3::from_diagonal(&Vector3::new(
        k[(0, 0)].signum(),
        k[(1, 1)].signum(),
        k[(2, 2)].signum(),
    ));
    k *= signs;
    rot = signs * rot;
    let t = k
        .try_inverse()
        .ok_or_else(|| Error::Insufficient("degenerate camera (DLT)".into()))?
        * p.column(3);
    if rot.determinant() < 0.0 {
        return Err(Error::Insufficient(
            "the corners do not determine a camera (DLT gave a reflection)".into(),
        ));
    }
    let k = k / k[(2, 2)];
    let rv = Rotation3::from_matrix(&rot).scaled_axis();
    let residuals = |cam: &Pinhole, out: &mut Vec<f64>| {
        out.clear();
        push_residuals(cam, obs, out);
    };
    if let Some((kf, df)) = intrinsics {
        let unpack = |x: &DVector<f64>| Pinhole {
            width,
            height,
            k: *kf,
            dist: *df,
            r: Rotation3::from_scaled_axis(Vec3::new(x[0], x[1], x[2])).into_inner(),
            t: Vec3::new(x[3], x[4], x[5]),
        };
        let mut x = DVector::from_vec(vec![rv.x, rv.y, rv.z, t.x, t.y, t.z]);
        let scale = [0.1, 0.1, 0.1, t.norm(), t.norm(), t.norm()];
        lm::minimize(&mut x, &scale, 100, |x, out| residuals(&unpack(x), out));
        return Ok(unpack(&x));
    }
    // k3 stays 0: one board pose rarely reaches the image corners, where k3 would be decided.
    // k2 is only fitted when the corners reach far enough from the image centre to tell it from
    // k1; otherwise it is free to take any value that suits the centre and bends every ray
    // beyond the board (a 9x7 board in the middle of the field gave k2 = 0.28 for a true 0.02).
    let reach = obs
        .iter()
        .filter_map(|(p, _)| {
            let c = rot * p + t;
            (c.z > 0.0).then(|| (c.x / c.z).hypot(c.y / c.z))
        })
        .fold(0.0, f64::max);
    let free_k2 = reach >= K2_REACH;
    let x0 = vec![
        k[(0, 0)],
        k[(1, 1)],
        k[(0, 2)],
        k[(1, 2)],
        0.0,
        0.0,
        0.0,
        0.0,
        rv.x,
        rv.y,
        rv.z,
        t.x,
        t.y,
        t.z,
    ];
    let unpack = |x: &DVector<f64>| Pinhole {
        width,
        height,
        k: Mat3::new(x[0], 0.0, x[2], 0.0, x[1], x[3], 0.0, 0.0, 1.0),
        dist: Distortion::from_array([x[4], if free_k2 { x[5] } else { 0.0 }, x[6], x[7], 0.0]),
        r: Rotation3::from_scaled_axis(Vec3::new(x[8], x[9], x[10])).into_inner(),
        t: Vec3::new(x[11], x[12], x[13]),
    };
    let scale = [
        k[(0, 0)],
        k[(1, 1)],
        f64::from(width),
        f64::from(height),
        0.1,
        0.1,
        0.01,
        0.01,
        0.1,
        0.1,
        0.1,
        t.norm(),
        t.norm(),
        t.norm(),
    ];
    let mut x = DVector::from_vec(x0);
    let report = lm::minimize(&mut x, &scale, 100, |x, out| residuals(&unpack(x), out));
    tracing::debug!(?report, "sensor camera LM");
    let cam = unpack(&x);
    if !cam.k.iter().all(|v| v.is_finite()) || cam.k[(0, 0)] <= 0.0 || cam.k[(1, 1)] <= 0.0 {
        return Err(Error::Insufficient(
            "camera calibration did not converge".into(),
        ));
    }
    Ok(cam)
}

/// Standard errors of the camera's focal length (px) and centre (mm) fitted from `obs`
/// (all parameters free, as [`fit_camera`] without intrinsics): how well the session decides
/// them. A small board far away leaves focal length and distance entangled.
pub(crate) fn camera_uncertainty(
    cam: &Pinhole,
    obs: &[(Vec3, [f64; 2])],
) -> Option<(f64, [f64; 3])> {
    let rv = Rotation3::from_matrix(&cam.r).scaled_axis();
    let d = cam.dist.to_array();
    let x = DVector::from_vec(vec![
        cam.k[(0, 0)],
        cam.k[(1, 1)],
        cam.k[(0, 2)],
        cam.k[(1, 2)],
        d[0],
        d[1],
        d[2],
        d[3],
        rv.x,
        rv.y,
        rv.z,
        cam.t.x,
        cam.t.y,
        cam.t.z,
    ]);
    let unpack = |x: &DVector<f64>| Pinhole {
        width: cam.width,
        height: cam.height,
        k: Mat3::new(x[0], 0.0, x[2], 0.0, x[1], x[3], 0.0, 0.0, 1.0),
        dist: Distortion::from_array([x[4], x[5], x[6], x[7], 0.0]),
        r: Rotation3::from_scaled_axis(Vec3::new(x[8], x[9], x[10])).into_inner(),
        t: Vec3::new(x[11], x[12], x[13]),
    };
    let tn = cam.t.norm();
    let scale = [
        x[0], x[1], 1000.0, 1000.0, 0.1, 0.1, 0.01, 0.01, 0.1, 0.1, 0.1, tn, tn, tn,
    ];
    let cov = lm::covariance(&x, &scale, |x, out| {
        out.clear();
        push_residuals(&unpack(x), obs, out);
    })?;
    // Propagate to the centre C = −Rᵀ t through its numerical Jacobian in the pose parameters.
    let c0 = unpack(&x).center();
    let mut g = nalgebra::DMatrix::<f64>::zeros(3, x.len());
    for j in 8..14 {
        let h = 1e-6 * scale[j];
        let mut xj = x.clone();
        xj[j] += h;
        let dc = (unpack(&xj).center() - c0) / h;
        for i in 0..3 {
            g[(i, j)] = dc[i];
        }
    }
    let sc = &g * &cov * g.transpose();
    Some((
        cov[(0, 0)].max(0.0).sqrt(),
        [0, 1, 2].map(|i| sc[(i, i)].max(0.0).sqrt()),
    ))
}

/// The board height that best explains a layer's corners with `camera` (Gauss–Newton in one
/// unknown, starting from the stated height), with its standard error from the residuals.
fn fit_height(camera: &Pinhole, obs: &[(Vec3, [f64; 2])], start: f64) -> (f64, f64) {
    let cost = |h: f64| -> f64 {
        obs.iter()
            .map(|(p, q)| match camera.project(&Vec3::new(p.x, p.y, h)) {
                Some((u, v)) => (u - q[0]).powi(2) + (v - q[1]).powi(2),
                None => 1e12,
            })
            .sum()
    };
    let mut h = start;
    for _ in 0..20 {
        let e = 1e-3;
        let (c0, cp, cm) = (cost(h), cost(h + e), cost(h - e));
        let g = (cp - cm) / (2.0 * e);
        let curv = (cp - 2.0 * c0 + cm) / (e * e);
        if curv <= 0.0 {
            break;
        }
        let step = -g / curv;
        h += step;
        if step.abs() < 1e-6 {
            break;
        }
    }
    // σ_h² = σ² / Σ |∂(u, v)/∂h|², σ² the residual variance per coordinate.
    let e = 1e-3;
    let mut jj = 0.0;
    for (p, _) in obs {
        if let (Some(a), Some(b)) = (
            camera.project(&Vec3::new(p.x, p.y, h + e)),
            camera.project(&Vec3::new(p.x, p.y, h - e)),
        ) {
            jj += ((a.0 - b.0) / (2.0 * e)).powi(2) + ((a.1 - b.1) / (2.0 * e)).powi(2);
        }
    }
    let dof = (2 * obs.len()).saturating_sub(1).max(1) as f64;
    let sigma = (cost(h) / dof).sqrt() / jj.max(1e-300).sqrt();
    (h, sigma)
}

/// Column and row code maps of the reference plane from layer 0 inside `extent`.
fn reference_maps(
    camera: &Pinhole,
    rays: &RayTable,
    decoded: &Decoded,
    extent: [f64; 4],
    stride: usize,
) -> Result<(PlaneCodeMap, PlaneCodeMap)> {
    let row = decoded
        .row
        .as_ref()
        .ok_or_else(|| Error::Insufficient("layer 0 has no row codes".into()))?;
    let (w, h) = (decoded.width as usize, decoded.height as usize);
    let oc = camera.center();
    let r_t = camera.r.transpose();
    let mut cols = Vec::new();
    let mut rows = Vec::new();
    for v in (0..h).step_by(stride) {
        for u in (0..w).step_by(stride) {
            let i = v * w + u;
            let (c, r) = (decoded.col[i], row[i]);
            if !(c.is_finite() && r.is_finite()) {
                continue;
            }
            let Some(p) = rays
                .on_plane(i, &oc, &r_t, 0.0)
                .filter(|p| in_rect(&extent, p.x, p.y))
            else {
                continue;
            };
            cols.push(PlaneSample {
                x: p.x,
                y: p.y,
                code: f64::from(c),
            });
            rows.push(PlaneSample {
                x: p.x,
                y: p.y,
                code: f64::from(r),
            });
        }
    }
    Ok((PlaneCodeMap::fit(&cols, 5)?, PlaneCodeMap::fit(&rows, 5)?))
}

/// Least-squares common point of the projector rays: each decoded pixel of a lifted layer (its
/// board point P_s at the layer's height) and the reference-plane point P_r carrying the same
/// code. Rays are weighted by h² (their direction error shrinks with the lift); a second pass
/// drops rays farther than 4 robust sigmas.
fn projector_center(
    camera: &Pinhole,
    rays: &RayTable,
    lifted: &[(&Decoded, f64)],
    col_map: &PlaneCodeMap,
    row_map: &PlaneCodeMap,
    extent: [f64; 4],
    stride: usize,
) -> Result<(Vec3, f64, usize)> {
    let oc = camera.center();
    let r_t = camera.r.transpose();
    let inside = |x: f64, y: f64| in_rect(&extent, x, y);
    let mut lines: Vec<(Vec3, Vec3, f64)> = Vec::new();
    for &(decoded, h) in lifted {
        let Some(row) = decoded.row.as_ref() else {
            continue;
        };
        let (w, hgt) = (decoded.width as usize, decoded.height as usize);
        let found: Vec<(Vec3, Vec3, f64)> = (0..hgt)
            .into_par_iter()
            .step_by(stride)
            .flat_map_iter(|v| {
                let r_t = &r_t;
                (0..w).step_by(stride).filter_map(move |u| {
                    let i = v * w + u;
                    let (c, r) = (f64::from(decoded.col[i]), f64::from(row[i]));
                    if !(c.is_finite() && r.is_finite()) {
                        return None;
                    }
                    let ps = rays.on_plane(i, &oc, r_t, h).filter(|p| inside(p.x, p.y))?;
                    // Newton on (φ_col, φ_row)(x, y) = (c, r), from the point straight below.
                    let (mut px, mut py) = (ps.x, ps.y);
                    for _ in 0..12 {
                        let (fc, cx, cy) = col_map.eval(px, py);
                        let (fr, rx, ry) = row_map.eval(px, py);
                        let det = cx * ry - cy * rx;
                        if det.abs() < 1e-12 {
                            return None;
                        }
                        let (ec, er) = (c - fc, r - fr);
                        let dx = (ry * ec - cy * er) / det;
                        let dy = (-rx * ec + cx * er) / det;
                        px += dx;
                        py += dy;
                        if dx * dx + dy * dy < 1e-10 {
                            break;
                        }
                    }
                    if !inside(px, py) {
                        return None;
                    }
                    let pr = Vec3::new(px, py, 0.0);
                    let dir = (ps - pr).normalize();
                    Some((pr, dir, (h / 100.0).powi(2)))
                })
            })
            .collect();
        lines.extend(found);
    }
    if lines.len() < 100 {
        return Err(Error::Insufficient(format!(
            "only {} projector rays traced between the layers and the reference; the lifted \
             boards must be lit by the projector and decodable",
            lines.len()
        )));
    }
    let solve = |keep: &dyn Fn(usize) -> bool| -> Option<Vec3> {
        let mut a = Mat3::zeros();
        let mut b = Vec3::zeros();
        for (k, (p, d, w)) in lines.iter().enumerate() {
            if !keep(k) {
                continue;
            }
            let m = (Mat3::identity() - d * d.transpose()) * *w;
            a += m;
            b += m * p;
        }
        a.try_inverse().map(|ai| ai * b)
    };
    let dist = |o: &Vec3, (p, d, _): &(Vec3, Vec3, f64)| (o - p).cross(d).norm();
    let first = solve(&|_| true)
        .ok_or_else(|| Error::Insufficient("projector rays are parallel".into()))?;
    let mut ds: Vec<f64> = lines.iter().map(|l| dist(&first, l)).collect();
    let mut sorted = ds.clone();
    sorted.sort_by(f64::total_cmp);
    let limit = 4.0 * 1.4826 * sorted[sorted.len() / 2] + 1e-9;
    let op = solve(&|k| ds[k] <= limit).unwrap_or(first);
    ds = lines.iter().map(|l| dist(&op, l)).collect();
    let kept: Vec<f64> = ds.into_iter().filter(|d| *d <= limit).collect();
    let rms = (kept.iter().map(|d| d * d).sum::<f64>() / kept.len().max(1) as f64).sqrt();
    Ok((op, rms, kept.len()))
}

/// Per-pixel quadratic e = A m² + B m + C (Eq. 3.28) from per-layer maps of `[e, m]` (height
/// error, mm, NaN where unmeasured; reference-plane shift m, mm), each map smoothed by a NaN-aware
/// Gaussian of `sigma` pixels first. Returns A, B, C interleaved, `w × h × 3`.
///
/// A point on the reference plane (m = 0) is reconstructed exactly by construction, so C is
/// only fitted where the pixel's layers reach down to the plane; elsewhere the quadratic is
/// pinned through e(0) = 0 rather than extrapolated to it. Pixels measured on fewer than four
/// layers take a smooth (affine in u, v) fit of the measured pixels' A and B, not a copy of an
/// edge pixel's noise.
pub fn fit_height_residual(errors: &[Vec<[f32; 2]>], w: usize, h: usize, sigma: f32) -> Vec<f32> {
    let smoothed: Vec<Vec<[f32; 2]>> = errors
        .iter()
        .map(|em| {
            let valid: Vec<f32> = em
                .iter()
                .map(|v| if v[0].is_finite() { 1.0 } else { 0.0 })
                .collect();
            let e: Vec<f32> = em
                .iter()
                .map(|v| if v[0].is_finite() { v[0] } else { 0.0 })
                .collect();
            let bw = gaussian_blur(&valid, w, h, sigma);
            let be = gaussian_blur(&e, w, h, sigma);
            em.iter()
                .enumerate()
                .map(|(i, v)| {
                    if v[0].is_finite() && bw[i] > 1e-3 {
                        [be[i] / bw[i], v[1]]
                    } else {
                        [f32::NAN; 2]
                    }
                })
                .collect()
        })
        .collect();
    let mut coef = vec![[f32::NAN; 3]; w * h];
    coef.par_iter_mut().enumerate().for_each(|(i, out)| {
        let mut ata = [[0.0f64; 3]; 3];
        let mut atb = [0.0f64; 3];
        let mut n = 0;
        let (mut mlo, mut mhi) = (f64::MAX, f64::MIN);
        for s in &smoothed {
            let [e, m] = s[i];
            if !e.is_finite() || !m.is_finite() {
                continue;
            }
            let (e, m) = (f64::from(e), f64::from(m));
            let basis = [m * m, m, 1.0];
            for r in 0..3 {
                for c in 0..3 {
                    ata[r][c] += basis[r] * basis[c];
                }
                atb[r] += basis[r] * e;
            }
            n += 1;
            mlo = mlo.min(m);
            mhi = mhi.max(m);
        }
        if n < 4 || mhi - mlo < 1e-3 {
            return;
        }
        if mlo <= 0.1 * mhi {
            let a = Mat3::from_fn(|r, c| ata[r][c]);
            if let Some(x) = a.try_inverse().map(|ai| ai * Vec3::from(atb)) {
                if x.iter().all(|v| v.is_finite()) {
                    *out = [x[0] as f32, x[1] as f32, x[2] as f32];
                }
            }
        } else {
            let a = nalgebra::Matrix2::new(ata[0][0], ata[0][1], ata[1][0], ata[1][1]);
            let b = nalgebra::Vector2::new(atb[0], atb[1]);
            if let Some(x) = a.try_inverse().map(|ai| ai * b) {
                if x.iter().all(|v| v.is_finite()) {
                    *out = [x[0] as f32, x[1] as f32, 0.0];
                }
            }
        }
    });
    let fill = affine_fill(&coef, w);
    let mut out = Vec::with_capacity(3 * w * h);
    for (i, c) in coef.iter().enumerate() {
        if c[0].is_finite() {
            out.extend(*c);
        } else {
            let (u, v) = ((i % w) as f64, (i / w) as f64);
            let at = |k: usize| (fill[k][0] * u + fill[k][1] * v + fill[k][2]) as f32;
            out.extend([at(0), at(1), 0.0]);
        }
    }
    out
}

/// Least-squares planes `A(u, v)`, `B(u, v)` through the fitted pixels' coefficients (zero
/// when too few pixels were fitted).
fn affine_fill(coef: &[[f32; 3]], w: usize) -> [[f64; 3]; 2] {
    let mut ata = Mat3::zeros();
    let mut atb = [Vec3::zeros(); 2];
    for (i, c) in coef.iter().enumerate().filter(|(_, c)| c[0].is_finite()) {
        let x = Vec3::new((i % w) as f64, (i / w) as f64, 1.0);
        ata += x * x.transpose();
        atb[0] += x * f64::from(c[0]);
        atb[1] += x * f64::from(c[1]);
    }
    match ata.try_inverse() {
        Some(ai) if ata[(2, 2)] >= 100.0 => {
            let (a, b) = (ai * atb[0], ai * atb[1]);
            [[a.x, a.y, a.z], [b.x, b.y, b.z]]
        }
        _ => [[0.0; 3]; 2],
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::look_at;

    #[test]
    fn dlt_and_refinement_recover_a_camera_from_layered_corners() {
        let (r, t) = look_at(
            Vec3::new(30.0, -20.0, 1200.0),
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        );
        let truth = Pinhole {
            width: 800,
            height: 600,
            k: Mat3::new(1010.0, 0.0, 405.0, 0.0, 1005.0, 296.0, 0.0, 0.0, 1.0),
            dist: Distortion::from_array([-0.08, 0.03, 0.0005, -0.0003, 0.0]),
            r,
            t,
        };
        let mut obs = Vec::new();
        let mut rng = crate::testing::Rng(3);
        for h in [0.0, 40.0, 80.0, 120.0, 160.0] {
            for j in 0..9 {
                for i in 0..13 {
                    let p = Vec3::new((i as f64 - 6.0) * 40.0, (4.0 - j as f64) * 40.0, h);
                    let (u, v) = truth.project(&p).expect("visible");
                    let n = rng.range(-0.05, 0.05);
                    obs.push((p, [u + n, v - n]));
                }
            }
        }
        let cam = fit_camera(&obs, 800, 600, None).expect("camera");
        let fixed = fit_camera(&obs, 800, 600, Some(&(truth.k, truth.dist))).expect("pose");
        let dc = (fixed.center() - truth.center()).norm();
        assert!(
            dc < 0.5,
            "with known intrinsics the centre is off by {dc} mm"
        );
        assert!((cam.k[(0, 0)] - 1010.0).abs() < 2.0, "fx {}", cam.k[(0, 0)]);
        assert!((cam.k[(1, 1)] - 1005.0).abs() < 2.0, "fy {}", cam.k[(1, 1)]);
        assert!((cam.k[(0, 2)] - 405.0).abs() < 2.0 && (cam.k[(1, 2)] - 296.0).abs() < 2.0);
        let dc = (cam.center() - truth.center()).norm();
        assert!(dc < 2.0, "camera centre off by {dc} mm");
        assert!(reprojection_rms(&cam, &obs) < 0.05);
        let (h, sigma) = fit_height(&cam, &obs[117 * 2..117 * 3], 70.0);
        assert!(sigma > 0.0 && sigma < 0.05, "σ_h {sigma}");
        assert!((h - 80.0).abs() < 0.05, "fitted height {h}");
    }
}
