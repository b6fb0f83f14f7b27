//! Sensor models (SPEC §6): the plane-induced parallax model with a reference recording, and
//! classical triangulation for sensors with a fully calibrated projector.

mod classical;
mod file;
mod parallax;
mod rays;
pub mod reference;
mod volume;

pub use classical::Classical;
pub use file::{
    CameraSection, ProjectorSection, ReferenceSection, ResidualSection, Sensor, SensorFile,
    ToCommonSection,
};
pub use parallax::{parallel_height, Parallax, ParallaxPoint};
pub use rays::RayTable;
pub use volume::{CalibratedVolume, VolumeSection};

use std::path::Path;

use rayon::prelude::*;

use crate::capture::CaptureSet;
use crate::cloud::PointCloud;
use crate::decode::{decode, DecodeParams, Decoded};
use crate::geometry::{in_rect, Matrix4, Pinhole, Vec3};
use crate::io::npy;
use crate::pattern::CodeAxis;
use crate::sensor::reference::{PlaneCodeMap, PlaneSample, DEFAULT_DEGREE};
use crate::{Error, Result};

/// The projector centre the parallax model needs.
fn parallax_centre(sensor: &Sensor) -> Result<Vec3> {
    sensor.projector_center.ok_or_else(|| {
        Error::invalid(
            "sensor",
            "projector.center",
            "the parallax model needs the projector centre",
        )
    })
}

/// Which model to reconstruct with.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ModelChoice {
    /// Parallax when the sensor has a reference, else classical.
    #[default]
    Auto,
    /// Plane-induced parallax (needs `[reference]` and the projector centre).
    Parallax,
    /// Classical triangulation (needs the full projector calibration).
    Classical,
}

enum Model {
    Parallax {
        geometry: Parallax,
        axis: CodeAxis,
        residual: Option<Vec<[f32; 3]>>,
    },
    Classical(Classical),
}

/// A sensor ready to turn decoded captures into point clouds.
pub struct Reconstructor {
    camera: Pinhole,
    rays: RayTable,
    model: Model,
    /// Sensor → cell transform, if the sensor file has one.
    pub to_common: Option<Matrix4<f64>>,
    /// Where the sensor was calibrated; reconstructed points outside it are flagged.
    pub volume: Option<CalibratedVolume>,
}

impl Reconstructor {
    /// Prepare `sensor`: build the ray table and, for the parallax model, decode and fit the
    /// reference recording.
    pub fn new(
        sensor: &Sensor,
        choice: ModelChoice,
        params: &DecodeParams,
    ) -> Result<Reconstructor> {
        let reference = match (&sensor.reference, Self::uses_parallax(sensor, choice)) {
            (Some(dir), true) => {
                // A missing centre is named before the reference is decoded for nothing.
                parallax_centre(sensor)?;
                Some(Self::decode_reference(sensor, dir, params)?)
            }
            _ => None,
        };
        Reconstructor::with_reference(sensor, choice, reference.as_ref())
    }

    /// Where the sensor looks from: its camera's and its projector's optical centres in the
    /// sensor frame, mm.
    pub fn centres(&self) -> (Vec3, Vec3) {
        let projector = match &self.model {
            Model::Parallax { geometry, .. } => geometry.projector_centre(),
            Model::Classical(c) => c.projector_centre(),
        };
        (self.camera.center(), projector)
    }

    /// Whether `choice` gives the parallax model for `sensor`.
    pub fn uses_parallax(sensor: &Sensor, choice: ModelChoice) -> bool {
        match choice {
            ModelChoice::Auto => sensor.reference.is_some(),
            ModelChoice::Parallax => true,
            ModelChoice::Classical => false,
        }
    }

    /// Load and decode `sensor`'s reference recording `dir`, checked against its camera.
    pub fn decode_reference(sensor: &Sensor, dir: &Path, params: &DecodeParams) -> Result<Decoded> {
        let capture = CaptureSet::load(dir)?;
        check_size(
            &sensor.camera,
            capture.width,
            capture.height,
            &dir.display().to_string(),
        )?;
        decode(&capture, params)
    }

    /// As [`Reconstructor::new`] with the reference recording already decoded (`reference`:
    /// the decode of `sensor.reference`, needed by the parallax model), so a caller that keeps
    /// decoded references (risd's prepared pairs) does not decode twice.
    pub fn with_reference(
        sensor: &Sensor,
        choice: ModelChoice,
        reference: Option<&Decoded>,
    ) -> Result<Reconstructor> {
        let rays = RayTable::new(&sensor.camera);
        let model = if Self::uses_parallax(sensor, choice) {
            let reference = reference.ok_or_else(|| {
                Error::invalid(
                    "sensor",
                    "reference",
                    "the parallax model needs a [reference] capture",
                )
            })?;
            let op = parallax_centre(sensor)?;
            if (reference.width, reference.height) != (sensor.camera.width, sensor.camera.height) {
                return Err(Error::invalid(
                    "sensor",
                    "reference",
                    format!(
                        "the decoded reference is {}x{}; the camera is {}x{}",
                        reference.width,
                        reference.height,
                        sensor.camera.width,
                        sensor.camera.height
                    ),
                ));
            }
            let (geometry, axis) = parallax_from_reference(
                &sensor.camera,
                &rays,
                op,
                reference,
                sensor.reference_extent,
            )?;
            let residual = match &sensor.residual {
                Some(path) => Some(load_residual(path, &sensor.camera)?),
                None => None,
            };
            Model::Parallax {
                geometry,
                axis,
                residual,
            }
        } else {
            let projector = sensor.projector.as_ref().ok_or_else(|| {
                Error::invalid(
                    "sensor",
                    "projector.k/r/t",
                    "the classical model needs the full projector calibration",
                )
            })?;
            Model::Classical(Classical::new(&sensor.camera, projector))
        };
        Ok(Reconstructor {
            camera: sensor.camera.clone(),
            rays,
            model,
            to_common: sensor.to_common,
            volume: sensor.volume,
        })
    }

    /// A parallax reconstructor from parts already in memory (simulation, tests).
    pub fn parallax(
        camera: &Pinhole,
        projector_center: Vec3,
        reference: &Decoded,
    ) -> Result<Reconstructor> {
        Reconstructor::parallax_within(camera, projector_center, reference, None)
    }

    /// As [`Reconstructor::parallax`], using only the reference pixels whose plane point lies in
    /// `extent` (`[x_min, x_max, y_min, y_max]`, mm).
    pub fn parallax_within(
        camera: &Pinhole,
        projector_center: Vec3,
        reference: &Decoded,
        extent: Option<[f64; 4]>,
    ) -> Result<Reconstructor> {
        let rays = RayTable::new(camera);
        let (geometry, axis) =
            parallax_from_reference(camera, &rays, projector_center, reference, extent)?;
        Ok(Reconstructor {
            camera: camera.clone(),
            rays,
            model: Model::Parallax {
                geometry,
                axis,
                residual: None,
            },
            to_common: None,
            volume: None,
        })
    }

    /// A classical reconstructor from both calibrations.
    pub fn classical(camera: &Pinhole, projector: &Pinhole) -> Reconstructor {
        Reconstructor {
            camera: camera.clone(),
            rays: RayTable::new(camera),
            model: Model::Classical(Classical::new(camera, projector)),
            to_common: None,
            volume: None,
        }
    }

    /// Name of the model in use.
    pub fn model_name(&self) -> &'static str {
        match self.model {
            Model::Parallax { .. } => "parallax",
            Model::Classical(_) => "classical",
        }
    }

    /// The camera this sensor reconstructs for.
    pub fn camera(&self) -> &Pinhole {
        &self.camera
    }

    /// The point seen at sub-pixel camera position (x, y) and lit by projector point (u, v)
    /// (an X-point of a single-shot frame), in the sensor world frame; `None` where the model
    /// has no answer (behind the camera, off the reference map). The parallax model uses the
    /// projector coordinate along its reference's code axis and the residual of the nearest
    /// pixel.
    pub fn point_at(&self, x: f64, y: f64, u: f64, v: f64) -> Option<Vec3> {
        let (xn, yn) = self.camera.normalized(x, y);
        match &self.model {
            Model::Parallax {
                geometry,
                axis,
                residual,
            } => {
                let code = match axis {
                    CodeAxis::Column => u,
                    CodeAxis::Row => v,
                };
                let d = self.camera.r.transpose() * Vec3::new(xn, yn, 1.0);
                let (pp, _) = geometry.point_for_direction(&d, code, 0.0)?;
                Some(match residual {
                    Some(res) => {
                        let (w, h) = (self.camera.width as f64, self.camera.height as f64);
                        let (px, py) =
                            (x.round().clamp(0.0, w - 1.0), y.round().clamp(0.0, h - 1.0));
                        let i = py as usize * self.camera.width as usize + px as usize;
                        residual_corrected(geometry, res[i], &pp)
                    }
                    None => pp.point,
                })
            }
            Model::Classical(c) => c.point(xn, yn, u, Some(v)),
        }
    }

    /// Reconstruct every valid pixel into the sensor world frame (parallel over rows).
    pub fn reconstruct(&self, decoded: &Decoded) -> Result<PointCloud> {
        check_size(
            &self.camera,
            decoded.width,
            decoded.height,
            "decoded capture",
        )?;
        let w = decoded.width as usize;
        let mut dense = vec![[f32::NAN; 3]; decoded.col.len()];
        match &self.model {
            Model::Parallax {
                geometry,
                axis,
                residual,
            } => {
                let codes = parallax_codes(decoded, *axis)?;
                dense.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
                    for (u, out) in row.iter_mut().enumerate() {
                        let i = v * w + u;
                        let Some(pp) = parallax_point(geometry, &self.rays, decoded, codes, i)
                        else {
                            continue;
                        };
                        let p = match residual {
                            Some(res) => residual_corrected(geometry, res[i], &pp),
                            None => pp.point,
                        };
                        *out = [p.x as f32, p.y as f32, p.z as f32];
                    }
                });
            }
            Model::Classical(c) => {
                let rows = decoded.row.as_deref();
                dense.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
                    for (u, out) in row.iter_mut().enumerate() {
                        let i = v * w + u;
                        let col = decoded.col[i];
                        if !col.is_finite() {
                            continue;
                        }
                        // With row codes, triangulate ray against ray (well conditioned for any
                        // baseline direction); the column plane serves column-only captures.
                        let r = match rows {
                            Some(r) if r[i].is_finite() => Some(f64::from(r[i])),
                            Some(_) => continue,
                            None => None,
                        };
                        let (x, y) = self.rays.get(i);
                        if let Some(p) = c.point(x, y, f64::from(col), r) {
                            *out = [p.x as f32, p.y as f32, p.z as f32];
                        }
                    }
                });
            }
        }
        let mut cloud = PointCloud::from_dense(&dense, &decoded.confidence, decoded.width);
        if let Some(volume) = &self.volume {
            cloud.outside = cloud
                .points
                .par_iter()
                .map(|p| !volume.contains(p))
                .collect();
        }
        Ok(cloud)
    }
}

impl Reconstructor {
    /// Parallax model only: per pixel `[x, y, z, m]`, the point before residual compensation and
    /// its reference-plane shift m (Eq. 3.27–3.28 fit their residual over m); NaN where invalid.
    pub fn parallax_detail(&self, decoded: &Decoded) -> Result<Vec<[f32; 4]>> {
        check_size(
            &self.camera,
            decoded.width,
            decoded.height,
            "decoded capture",
        )?;
        let Model::Parallax { geometry, axis, .. } = &self.model else {
            return Err(Error::invalid(
                "sensor",
                "model",
                "per-pixel shifts exist only for the parallax model",
            ));
        };
        let codes = parallax_codes(decoded, *axis)?;
        let w = decoded.width as usize;
        let mut out = vec![[f32::NAN; 4]; decoded.col.len()];
        out.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
            for (u, o) in row.iter_mut().enumerate() {
                let i = v * w + u;
                if let Some(pp) = parallax_point(geometry, &self.rays, decoded, codes, i) {
                    let p = pp.point;
                    *o = [p.x as f32, p.y as f32, p.z as f32, pp.shift as f32];
                }
            }
        });
        Ok(out)
    }
}

/// `pp` moved along its camera ray by the calibrated height residual e(m) = a m² + b m + c of
/// its pixel (Eq. 3.28), m being its shift along the epipolar line.
fn residual_corrected(geometry: &Parallax, [a, b, c]: [f32; 3], pp: &ParallaxPoint) -> Vec3 {
    let m = pp.shift;
    let e = f64::from(a) * m * m + f64::from(b) * m + f64::from(c);
    let d = pp.point - geometry.camera_center();
    if d.z.abs() > 1e-12 {
        let k = (pp.point.z - e - geometry.camera_center().z) / d.z;
        geometry.camera_center() + d * k
    } else {
        pp.point
    }
}

fn parallax_codes(decoded: &Decoded, axis: CodeAxis) -> Result<&[f32]> {
    decoded.map(axis).ok_or_else(|| {
        Error::Insufficient(format!(
            "the sensor's reference is decoded along {axis:?} codes, which this capture lacks"
        ))
    })
}

#[inline]
fn parallax_point(
    geometry: &Parallax,
    rays: &RayTable,
    decoded: &Decoded,
    codes: &[f32],
    i: usize,
) -> Option<ParallaxPoint> {
    let c = codes[i];
    if !c.is_finite() || !decoded.col[i].is_finite() {
        return None;
    }
    geometry.point_fast(rays, i, f64::from(c))
}

fn check_size(camera: &Pinhole, w: u32, h: u32, what: &str) -> Result<()> {
    if (w, h) != (camera.width, camera.height) {
        return Err(Error::invalid(
            what,
            "size",
            format!(
                "is {w}x{h} but the sensor's camera is {}x{}",
                camera.width, camera.height
            ),
        ));
    }
    Ok(())
}

/// Fit the reference along the code axis that moves most along the epipolar lines.
fn parallax_from_reference(
    camera: &Pinhole,
    rays: &RayTable,
    op: Vec3,
    reference: &Decoded,
    extent: Option<[f64; 4]>,
) -> Result<(Parallax, CodeAxis)> {
    check_size(
        camera,
        reference.width,
        reference.height,
        "reference capture",
    )?;
    let mut best: Option<(f64, Parallax, CodeAxis)> = None;
    for axis in [CodeAxis::Column, CodeAxis::Row] {
        let Some(codes) = reference.map(axis) else {
            continue;
        };
        let samples = plane_samples(camera, rays, codes, extent);
        if samples.len() < 1000 {
            if axis == CodeAxis::Column {
                return Err(Error::Insufficient(format!(
                    "reference has only {} valid pixels on the plane",
                    samples.len()
                )));
            }
            continue;
        }
        let map = PlaneCodeMap::fit(&samples, DEFAULT_DEGREE)?;
        tracing::debug!(
            ?axis,
            rms = map.rms,
            inliers = map.inliers,
            samples = samples.len(),
            "reference fitted"
        );
        let geometry = Parallax::new(camera, op, map);
        // Sensitivity: code change per mm along the epipolar line at the image centre.
        let d = camera.ray(
            f64::from(camera.width) / 2.0,
            f64::from(camera.height) / 2.0,
        );
        let oc = camera.center();
        let q = oc + d * (-oc.z / d.z);
        let n = (op - oc).cross(&d);
        let len = n.x.hypot(n.y).max(1e-12);
        let (_, gx, gy) = geometry.map.eval(q.x, q.y);
        let sens = (gx * n.y / len - gy * n.x / len).abs();
        if best.as_ref().is_none_or(|b| sens > b.0) {
            best = Some((sens, geometry, axis));
        }
    }
    let (_, g, axis) =
        best.ok_or_else(|| Error::Insufficient("reference has no decodable code".into()))?;
    let pixels = camera.width as usize * camera.height as usize;
    Ok((g.with_table(rays, pixels), axis))
}

/// Plane points of valid reference pixels inside `extent`, subsampled to at most ~300 000.
fn plane_samples(
    camera: &Pinhole,
    rays: &RayTable,
    codes: &[f32],
    extent: Option<[f64; 4]>,
) -> Vec<PlaneSample> {
    let (w, h) = (camera.width as usize, camera.height as usize);
    let stride = ((w * h) as f64 / 300_000.0).sqrt().ceil().max(1.0) as usize;
    let oc = camera.center();
    let r_t = camera.r.transpose();
    (0..h)
        .into_par_iter()
        .step_by(stride)
        .flat_map_iter(|v| {
            let r_t = &r_t;
            (0..w).step_by(stride).filter_map(move |u| {
                let i = v * w + u;
                let c = codes[i];
                if !c.is_finite() {
                    return None;
                }
                let p = rays.on_plane(i, &oc, r_t, 0.0)?;
                let inside = extent.is_none_or(|e| in_rect(&e, p.x, p.y));
                inside.then_some(PlaneSample {
                    x: p.x,
                    y: p.y,
                    code: f64::from(c),
                })
            })
        })
        .collect()
}

fn load_residual(path: &std::path::Path, camera: &Pinhole) -> Result<Vec<[f32; 3]>> {
    let (shape, data) = npy::read::<f32>(path)?;
    let want = [camera.height as usize, camera.width as usize, 3];
    if shape != want {
        return Err(Error::invalid(
            path.display(),
            "shape",
            format!("is {shape:?}, expected {want:?} (H × W × 3)"),
        ));
    }
    Ok(data.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}
