//! Camera calibration from chessboard views (Zhang's method, SPEC §7): a homography per view,
//! focal lengths from the orthonormality of each view's rotation with the principal point at the
//! image centre, poses from the homographies, then Levenberg–Marquardt over K, Brown distortion
//! and every pose. Views whose reprojection error fails the quality gate are named and dropped.

use std::path::Path;

use nalgebra::{DVector, Rotation3};
use serde::{Deserialize, Serialize};

use super::chessboard::Corners;
use super::homography::homography;
use super::lm;
use crate::geometry::{Distortion, Mat3, Pinhole, Vec3};
use crate::io::{read_toml, write_toml};
use crate::{Error, Result};

/// Settings of a camera calibration.
#[derive(Clone, Debug)]
pub struct CameraParams {
    /// Keep fx = fy (OpenCV's `CALIB_FIX_ASPECT_RATIO` with ratio 1).
    pub fix_aspect: bool,
    /// A view is dropped when its RMS exceeds this many times the median view RMS …
    pub gate_relative: f64,
    /// … and this absolute value, pixels.
    pub gate_absolute: f64,
    /// Fewest corners a view must have.
    pub min_corners: usize,
    /// Fewest views a calibration needs.
    pub min_views: usize,
}

impl Default for CameraParams {
    fn default() -> Self {
        CameraParams {
            fix_aspect: false,
            gate_relative: 3.0,
            gate_absolute: 0.5,
            min_corners: 12,
            min_views: 3,
        }
    }
}

/// One chessboard view: its name (the image file) and its corners.
#[derive(Clone, Debug)]
pub struct BoardView {
    /// Name shown in reports (usually the image path).
    pub name: String,
    /// Detected corners.
    pub corners: Corners,
}

/// A view's outcome in a calibration.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ViewResult {
    /// The view's name.
    pub image: String,
    /// Corners used.
    pub corners: usize,
    /// RMS reprojection error, pixels.
    pub rms: f64,
    /// Board → camera rotation as a Rodrigues vector (radians).
    pub rvec: [f64; 3],
    /// Board → camera translation, mm.
    pub t: [f64; 3],
}

/// A view left out of the calibration and why.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DroppedView {
    /// The view's name.
    pub image: String,
    /// Why it was dropped.
    pub reason: String,
}

/// A calibrated camera (`CAMERA.toml`): intrinsics, distortion, and the evidence.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraCalibration {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Intrinsics `[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`.
    pub k: [[f64; 3]; 3],
    /// Brown distortion k1 k2 p1 p2 k3.
    pub dist: [f64; 5],
    /// Overall RMS reprojection error, pixels.
    pub rms: f64,
    /// Chessboard square, mm.
    pub square: f64,
    /// Views used, with their poses and errors.
    #[serde(default, rename = "view")]
    pub views: Vec<ViewResult>,
    /// Views left out, with reasons.
    #[serde(default)]
    pub dropped: Vec<DroppedView>,
}

impl CameraCalibration {
    /// Write atomically as TOML.
    pub fn save(&self, path: &Path) -> Result<()> {
        write_toml(path, self)
    }

    /// Read a camera file and check that it describes a camera.
    pub fn load(path: &Path) -> Result<CameraCalibration> {
        let c: CameraCalibration = read_toml(path)?;
        let ctx = path.display().to_string();
        if c.width == 0 || c.height == 0 {
            return Err(Error::invalid(&ctx, "width/height", "must be positive"));
        }
        let k = &c.k;
        let form = k[1][0] == 0.0 && k[2] == [0.0, 0.0, 1.0] && k[0][0] > 0.0 && k[1][1] > 0.0;
        if !form || k.iter().flatten().any(|v| !v.is_finite()) {
            return Err(Error::invalid(
                &ctx,
                "k",
                "expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with finite fx, fy > 0",
            ));
        }
        if let Some(i) = c.dist.iter().position(|v| !v.is_finite()) {
            return Err(Error::invalid(
                &ctx,
                format!("dist[{i}]"),
                "not a finite number",
            ));
        }
        Ok(c)
    }

    /// The intrinsic matrix.
    pub fn k_matrix(&self) -> Mat3 {
        Mat3::from_fn(|i, j| self.k[i][j])
    }

    /// The distortion model.
    pub fn distortion(&self) -> Distortion {
        Distortion::from_array(self.dist)
    }
}

/// Board point of corner (i, j) in the board's own frame (z = 0), mm.
fn board_point(i: usize, j: usize, square: f64) -> [f64; 2] {
    [i as f64 * square, j as f64 * square]
}

/// A camera from intrinsics `k` (fx, fy, cx, cy, k1, k2, p1, p2, k3) and a pose.
fn pinhole(k: &[f64; 9], r: Mat3, t: Vec3, width: u32, height: u32) -> Pinhole {
    Pinhole {
        width,
        height,
        k: Mat3::new(k[0], 0.0, k[2], 0.0, k[1], k[3], 0.0, 0.0, 1.0),
        dist: Distortion::from_array([k[4], k[5], k[6], k[7], k[8]]),
        r,
        t,
    }
}

/// Append the reprojection residuals (u, v) of `obs` seen by `cam` to `out`; a point behind the
/// camera counts as far off.
pub(crate) fn push_residuals(cam: &Pinhole, obs: &[(Vec3, [f64; 2])], out: &mut Vec<f64>) {
    for (p, q) in obs {
        let (u, v) = cam.project(p).unwrap_or((1e6, 1e6));
        out.push(u - q[0]);
        out.push(v - q[1]);
    }
}

/// RMS reprojection error of `obs` seen by `cam`, pixels.
pub(crate) fn reprojection_rms(cam: &Pinhole, obs: &[(Vec3, [f64; 2])]) -> f64 {
    let mut r = Vec::with_capacity(2 * obs.len());
    push_residuals(cam, obs, &mut r);
    (r.iter().map(|v| v * v).sum::<f64>() / obs.len().max(1) as f64).sqrt()
}

/// Initial fx, fy with the principal point at (cx, cy) from each view's homography: the first two
/// rotation columns K⁻¹h₁, K⁻¹h₂ are orthogonal and of equal length (linear in 1/fx², 1/fy²).
fn initial_focal(homographies: &[Mat3], cx: f64, cy: f64, fix_aspect: bool) -> Option<(f64, f64)> {
    let shift = Mat3::new(1.0, 0.0, -cx, 0.0, 1.0, -cy, 0.0, 0.0, 1.0);
    let (mut a11, mut a12, mut a22, mut b1, mut b2) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for h in homographies {
        let h = shift * h;
        let (h1, h2) = (h.column(0), h.column(1));
        let rows = [
            ([h1.x * h2.x, h1.y * h2.y], -h1.z * h2.z),
            (
                [h1.x * h1.x - h2.x * h2.x, h1.y * h1.y - h2.y * h2.y],
                -(h1.z * h1.z - h2.z * h2.z),
            ),
        ];
        for (a, b) in rows {
            let n = (a[0] * a[0] + a[1] * a[1]).sqrt().max(1e-300);
            let (a, b) = ([a[0] / n, a[1] / n], b / n);
            a11 += a[0] * a[0];
            a12 += a[0] * a[1];
            a22 += a[1] * a[1];
            b1 += a[0] * b;
            b2 += a[1] * b;
        }
    }
    let (ia, ib) = if fix_aspect {
        let v = (b1 + b2) / (a11 + 2.0 * a12 + a22);
        (v, v)
    } else {
        let det = a11 * a22 - a12 * a12;
        if det.abs() < 1e-300 {
            return None;
        }
        ((a22 * b1 - a12 * b2) / det, (a11 * b2 - a12 * b1) / det)
    };
    (ia > 0.0 && ib > 0.0).then(|| (1.0 / ia.sqrt(), 1.0 / ib.sqrt()))
}

/// Board → camera pose from a homography and K (the board in front of the camera).
pub(crate) fn pose_from_homography(h: &Mat3, k: &Mat3) -> Option<(Mat3, Vec3)> {
    let m = k.try_inverse()? * h;
    let (m1, m2, m3) = (m.column(0), m.column(1), m.column(2));
    let mut lambda = 2.0 / (m1.norm() + m2.norm());
    if m3.z * lambda < 0.0 {
        lambda = -lambda;
    }
    let r1 = m1 * lambda;
    let r2 = m2 * lambda;
    let r3 = r1.cross(&r2);
    let approx = Mat3::from_columns(&[r1, r2, r3]);
    let svd = approx.svd(true, true);
    let mut r = svd.u? * svd.v_t?;
    if r.determinant() < 0.0 {
        r = -r;
    }
    Some((r, m3 * lambda))
}

/// Calibrate a camera of `width × height` from chessboard views with squares of `square` mm.
pub fn calibrate_camera(
    views: &[BoardView],
    square: f64,
    width: u32,
    height: u32,
    params: &CameraParams,
) -> Result<CameraCalibration> {
    if !(square.is_finite() && square > 0.0) {
        return Err(Error::invalid(
            "calibrate camera",
            "square",
            format!("{square} mm must be positive"),
        ));
    }
    let mut dropped = Vec::new();
    let mut usable: Vec<&BoardView> = Vec::new();
    for v in views {
        if v.corners.found() < params.min_corners {
            dropped.push(DroppedView {
                image: v.name.clone(),
                reason: format!(
                    "{} corners found, at least {} needed",
                    v.corners.found(),
                    params.min_corners
                ),
            });
        } else {
            usable.push(v);
        }
    }
    loop {
        if usable.len() < params.min_views {
            return Err(Error::Insufficient(format!(
                "camera calibration: {} usable views, at least {} needed{}",
                usable.len(),
                params.min_views,
                dropped
                    .iter()
                    .map(|d| format!("; {}: {}", d.image, d.reason))
                    .collect::<String>()
            )));
        }
        let solved = solve(&usable, square, width, height, params)?;
        let mut rms: Vec<f64> = solved.views.iter().map(|v| v.rms).collect();
        rms.sort_by(f64::total_cmp);
        let median = rms[rms.len() / 2];
        let limit = (params.gate_relative * median).max(params.gate_absolute);
        let worst = solved
            .views
            .iter()
            .enumerate()
            .filter(|(_, v)| v.rms > limit)
            .max_by(|a, b| a.1.rms.total_cmp(&b.1.rms));
        match worst {
            // Drop the worst offender and solve again: one bad view distorts every other's error.
            Some((i, v)) => {
                tracing::info!(image = %v.image, rms = v.rms, limit, "view dropped by the quality gate");
                dropped.push(DroppedView {
                    image: v.image.clone(),
                    reason: format!(
                        "RMS {:.3} px exceeds the gate {:.3} px ({}× the median {:.3} px, at least {} px)",
                        v.rms, limit, params.gate_relative, median, params.gate_absolute
                    ),
                });
                usable.remove(i);
            }
            None => return Ok(CameraCalibration { dropped, ..solved }),
        }
    }
}

fn solve(
    views: &[&BoardView],
    square: f64,
    width: u32,
    height: u32,
    params: &CameraParams,
) -> Result<CameraCalibration> {
    let (cx, cy) = ((width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0);
    let mut homographies = Vec::with_capacity(views.len());
    for v in views {
        let (src, dst): (Vec<[f64; 2]>, Vec<[f64; 2]>) = v
            .corners
            .iter_found()
            .map(|((i, j), p)| (board_point(i, j, square), p))
            .unzip();
        let h = homography(&src, &dst).ok_or_else(|| {
            Error::Insufficient(format!(
                "{}: the corners are degenerate (no homography)",
                v.name
            ))
        })?;
        homographies.push(h);
    }
    let (fx, fy) = initial_focal(&homographies, cx, cy, params.fix_aspect).ok_or_else(|| {
        Error::Insufficient(
            "camera calibration: the views do not constrain the focal length (boards parallel \
             to the image plane?); tilt the board between views"
                .to_string(),
        )
    })?;
    let k0 = Mat3::new(fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0);
    // Parameters: fx, fy, cx, cy, k1, k2, p1, p2, k3, then rvec and t per view.
    let mut x = vec![fx, fy, cx, cy, 0.0, 0.0, 0.0, 0.0, 0.0];
    for (v, h) in views.iter().zip(&homographies) {
        let (r, t) = pose_from_homography(h, &k0).ok_or_else(|| {
            Error::Insufficient(format!("{}: no pose from the homography", v.name))
        })?;
        let rv = Rotation3::from_matrix_unchecked(r).scaled_axis();
        x.extend([rv.x, rv.y, rv.z, t.x, t.y, t.z]);
    }
    let observations: Vec<Vec<(Vec3, [f64; 2])>> = views
        .iter()
        .map(|v| {
            v.corners
                .iter_found()
                .map(|((i, j), p)| {
                    let b = board_point(i, j, square);
                    (Vec3::new(b[0], b[1], 0.0), p)
                })
                .collect()
        })
        .collect();
    let fix_aspect = params.fix_aspect;
    let intrinsics = |p: &DVector<f64>| -> [f64; 9] {
        let fy = if fix_aspect { p[0] } else { p[1] };
        [p[0], fy, p[2], p[3], p[4], p[5], p[6], p[7], p[8]]
    };
    let pose = |p: &DVector<f64>, v: usize| {
        let o = 9 + 6 * v;
        let r = Rotation3::from_scaled_axis(Vec3::new(p[o], p[o + 1], p[o + 2])).into_inner();
        (r, Vec3::new(p[o + 3], p[o + 4], p[o + 5]))
    };
    let residuals = |p: &DVector<f64>, out: &mut Vec<f64>| {
        out.clear();
        let k = intrinsics(p);
        for (v, obs) in observations.iter().enumerate() {
            let (r, t) = pose(p, v);
            push_residuals(&pinhole(&k, r, t, width, height), obs, out);
        }
    };
    let mut scale = vec![
        fx,
        fy,
        width as f64,
        height as f64,
        0.1,
        0.1,
        0.01,
        0.01,
        0.1,
    ];
    for _ in views {
        scale.extend([
            0.1,
            0.1,
            0.1,
            100.0 * square,
            100.0 * square,
            100.0 * square,
        ]);
    }
    let mut p = DVector::from_vec(x);
    let report = lm::minimize(&mut p, &scale, 200, residuals);
    tracing::debug!(?report, "camera calibration LM");
    let k = intrinsics(&p);
    let mut total = 0.0;
    let mut count = 0usize;
    let mut results = Vec::with_capacity(views.len());
    for (v, obs) in observations.iter().enumerate() {
        let (r, t) = pose(&p, v);
        let rms = reprojection_rms(&pinhole(&k, r, t, width, height), obs);
        total += rms * rms * obs.len() as f64;
        count += obs.len();
        let o = 9 + 6 * v;
        results.push(ViewResult {
            image: views[v].name.clone(),
            corners: obs.len(),
            rms,
            rvec: [p[o], p[o + 1], p[o + 2]],
            t: [t.x, t.y, t.z],
        });
    }
    if k.iter().any(|v| !v.is_finite()) || k[0] <= 0.0 || k[1] <= 0.0 {
        return Err(Error::Insufficient(
            "camera calibration did not converge to a valid camera".to_string(),
        ));
    }
    Ok(CameraCalibration {
        width,
        height,
        k: [[k[0], 0.0, k[2]], [0.0, k[1], k[3]], [0.0, 0.0, 1.0]],
        dist: [k[4], k[5], k[6], k[7], k[8]],
        rms: (total / count as f64).sqrt(),
        square,
        views: results,
        dropped: Vec::new(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calibrate::chessboard::BoardSize;

    /// Synthetic views of a 9x6 board seen by a known camera, with corner noise.
    fn views(k: &[f64; 9], noise: f64, poses: &[([f64; 3], [f64; 3])]) -> Vec<BoardView> {
        let board = BoardSize { cols: 9, rows: 6 };
        let mut rng = crate::testing::Rng(7);
        let mut rnd = || rng.range(-0.5, 0.5);
        poses
            .iter()
            .enumerate()
            .map(|(n, (rv, t))| {
                let r = Rotation3::from_scaled_axis(Vec3::from(*rv)).into_inner();
                let cam = pinhole(k, r, Vec3::from(*t), 640, 480);
                let points = (0..board.len())
                    .map(|c| {
                        let b = board_point(c % 9, c / 9, 25.0);
                        let (u, v) = cam.project(&Vec3::new(b[0], b[1], 0.0)).expect("in front");
                        Some([u + noise * rnd(), v + noise * rnd()])
                    })
                    .collect();
                BoardView {
                    name: format!("view{n}"),
                    corners: Corners { board, points },
                }
            })
            .collect()
    }

    const POSES: [([f64; 3], [f64; 3]); 6] = [
        ([0.3, 0.2, 0.05], [-100.0, -60.0, 450.0]),
        ([-0.25, 0.35, -0.1], [-90.0, -70.0, 500.0]),
        ([0.1, -0.4, 0.2], [-80.0, -50.0, 420.0]),
        ([-0.35, -0.2, 0.6], [-60.0, -90.0, 480.0]),
        ([0.45, 0.1, -0.5], [-120.0, -40.0, 520.0]),
        ([0.05, 0.5, 1.2], [-20.0, -110.0, 460.0]),
    ];

    #[test]
    fn recovers_intrinsics_and_distortion_of_a_synthetic_camera() {
        let k = [
            540.0, 536.0, 330.0, 244.0, -0.26, -0.04, 0.0018, -0.0003, 0.24,
        ];
        let views = views(&k, 0.1, &POSES);
        let cal = calibrate_camera(&views, 25.0, 640, 480, &CameraParams::default())
            .expect("calibration");
        assert!(cal.dropped.is_empty(), "{:?}", cal.dropped);
        assert!((cal.k[0][0] - 540.0).abs() < 1.0, "fx {}", cal.k[0][0]);
        assert!((cal.k[1][1] - 536.0).abs() < 1.0, "fy {}", cal.k[1][1]);
        assert!((cal.k[0][2] - 330.0).abs() < 1.0 && (cal.k[1][2] - 244.0).abs() < 1.0);
        assert!((cal.dist[0] + 0.26).abs() < 0.01, "k1 {}", cal.dist[0]);
        // Uniform noise of ±0.05 px has an RMS of 0.029 px per axis: 0.041 px in 2D.
        assert!(cal.rms < 0.06, "rms {}", cal.rms);
    }

    #[test]
    fn a_view_with_wrong_corners_is_dropped_by_name() {
        let k = [540.0, 540.0, 320.0, 240.0, -0.2, 0.05, 0.0, 0.0, 0.0];
        let mut views = views(&k, 0.1, &POSES);
        // Three corners of one view caught on the wrong edge, 4 px off.
        for c in [0, 20, 40] {
            views[2].corners.points[c].as_mut().expect("corner")[0] += 4.0;
        }
        let cal = calibrate_camera(&views, 25.0, 640, 480, &CameraParams::default())
            .expect("calibration");
        assert_eq!(cal.dropped.len(), 1, "{:?}", cal.dropped);
        assert_eq!(cal.dropped[0].image, "view2");
        assert!(
            cal.rms < 0.1 && (cal.k[0][0] - 540.0).abs() < 1.5,
            "{cal:?}"
        );
    }

    #[test]
    fn too_few_views_is_an_error_naming_the_dropped_ones() {
        let k = [540.0, 540.0, 320.0, 240.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        let mut views = views(&k, 0.1, &POSES[..3]);
        views[1]
            .corners
            .points
            .iter_mut()
            .skip(5)
            .for_each(|p| *p = None);
        let err = calibrate_camera(&views, 25.0, 640, 480, &CameraParams::default())
            .expect_err("two views")
            .to_string();
        assert!(err.contains("view1") && err.contains("5 corners"), "{err}");
    }
}
