//! Rigid registration (Ch. 5, SPEC §9): closed-form fit from correspondences, surface normals,
//! and ICP (point-to-point and point-to-plane) with multi-resolution and trimmed pairs.

mod icp;
mod normal_equations;
mod normals;
mod rigid;

pub use icp::{Icp, IcpMetric, IcpParams, IcpResult};
pub use normal_equations::{accumulate, NormalEquations};
pub use normals::estimate_normals;
pub use rigid::{fit_rigid, rotation_angle_deg};

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::geometry::Mat3;
use crate::io::{read_toml, write_toml};
use crate::{Error, Result};

/// A rigid transform, named by the frames it maps (e.g. `fixed_from_moving`).
pub type Pose = nalgebra::Isometry3<f64>;

/// A transform file: a 4×4 row-major matrix and, when written by registration, its figures.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TransformFile {
    /// Row-major homogeneous matrix mapping moving-cloud points into the fixed cloud's frame.
    pub matrix: [[f64; 4]; 4],
    /// RMS distance of the kept pairs, mm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rms: Option<f64>,
    /// Fraction of moving points with a partner within the rejection distance.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub overlap: Option<f64>,
    /// ICP iterations run.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub iterations: Option<usize>,
}

impl TransformFile {
    /// A file holding `pose`.
    pub fn from_pose(pose: &Pose) -> TransformFile {
        let m = pose.to_homogeneous();
        TransformFile {
            matrix: std::array::from_fn(|i| std::array::from_fn(|j| m[(i, j)])),
            rms: None,
            overlap: None,
            iterations: None,
        }
    }

    /// Read and validate (finite, a proper rotation, last row 0 0 0 1).
    pub fn load(path: &Path) -> Result<Pose> {
        let f: TransformFile = read_toml(path)?;
        let ctx = path.display().to_string();
        for (i, row) in f.matrix.iter().enumerate() {
            if let Some(v) = row.iter().find(|v| !v.is_finite()) {
                return Err(Error::invalid(
                    &ctx,
                    format!("matrix[{i}]"),
                    format!("{v} is not a finite number"),
                ));
            }
        }
        if f.matrix[3] != [0.0, 0.0, 0.0, 1.0] {
            return Err(Error::invalid(
                &ctx,
                "matrix[3]",
                "the last row of a rigid transform must be [0, 0, 0, 1]",
            ));
        }
        let r = Mat3::from_fn(|i, j| f.matrix[i][j]);
        let err = (r.transpose() * r - Mat3::identity()).abs().max();
        if err > 1e-6 || r.determinant() < 0.0 {
            return Err(Error::invalid(
                &ctx,
                "matrix",
                format!("the 3×3 block is not a rotation (|RᵀR − I| = {err:.1e})"),
            ));
        }
        let rot = crate::geometry::rotation_of(&f.matrix);
        Ok(Pose::from_parts(
            nalgebra::Translation3::new(f.matrix[0][3], f.matrix[1][3], f.matrix[2][3]),
            rot,
        ))
    }

    /// Write atomically.
    pub fn save(&self, path: &Path) -> Result<()> {
        write_toml(path, self)
    }
}
