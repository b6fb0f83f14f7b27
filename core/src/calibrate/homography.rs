//! Plane-to-image homography by the normalised DLT (Eq. 3.7–3.8): both point sets are centred and
//! scaled to mean distance √2, `A h = 0` is solved by SVD, and the normalisation is undone.

use nalgebra::{DMatrix, Matrix3};

use crate::geometry::Mat3;

/// Hartley normalisation: a similarity taking the points to centroid 0, mean distance √2.
fn normalization(points: &[[f64; 2]]) -> Mat3 {
    let n = points.len() as f64;
    let (mx, my) = points
        .iter()
        .fold((0.0, 0.0), |(x, y), p| (x + p[0] / n, y + p[1] / n));
    let mean_dist = points
        .iter()
        .map(|p| ((p[0] - mx).powi(2) + (p[1] - my).powi(2)).sqrt())
        .sum::<f64>()
        / n;
    let s = if mean_dist > 0.0 {
        std::f64::consts::SQRT_2 / mean_dist
    } else {
        1.0
    };
    Matrix3::new(s, 0.0, -s * mx, 0.0, s, -s * my, 0.0, 0.0, 1.0)
}

/// The homography `H` with `dst ~ H src` from at least four correspondences in general position;
/// `None` when the points are degenerate. `H[(2, 2)]` is scaled to 1 where possible.
pub fn homography(src: &[[f64; 2]], dst: &[[f64; 2]]) -> Option<Mat3> {
    if src.len() != dst.len() || src.len() < 4 {
        return None;
    }
    let (ts, td) = (normalization(src), normalization(dst));
    let apply =
        |t: &Mat3, p: &[f64; 2]| [t[(0, 0)] * p[0] + t[(0, 2)], t[(1, 1)] * p[1] + t[(1, 2)]];
    let mut a = DMatrix::<f64>::zeros(2 * src.len(), 9);
    for (k, (s, d)) in src.iter().zip(dst).enumerate() {
        let [x, y] = apply(&ts, s);
        let [u, v] = apply(&td, d);
        let r0 = [x, y, 1.0, 0.0, 0.0, 0.0, -u * x, -u * y, -u];
        let r1 = [0.0, 0.0, 0.0, x, y, 1.0, -v * x, -v * y, -v];
        for j in 0..9 {
            a[(2 * k, j)] = r0[j];
            a[(2 * k + 1, j)] = r1[j];
        }
    }
    // The null vector of A is the eigenvector of AᵀA with the smallest eigenvalue.
    let ata = a.transpose() * &a;
    let eig = ata.symmetric_eigen();
    let (imin, _) = eig
        .eigenvalues
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))?;
    let h = eig.eigenvectors.column(imin);
    let hn = Matrix3::from_fn(|i, j| h[3 * i + j]);
    let h = td.try_inverse()? * hn * ts;
    let scale = h[(2, 2)];
    let h = if scale.abs() > 1e-12 { h / scale } else { h };
    h.iter().all(|v| v.is_finite()).then_some(h)
}

/// Apply a homography to a point.
#[inline]
pub fn apply(h: &Mat3, p: [f64; 2]) -> [f64; 2] {
    let w = h[(2, 0)] * p[0] + h[(2, 1)] * p[1] + h[(2, 2)];
    [
        (h[(0, 0)] * p[0] + h[(0, 1)] * p[1] + h[(0, 2)]) / w,
        (h[(1, 0)] * p[0] + h[(1, 1)] * p[1] + h[(1, 2)]) / w,
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_a_perspective_mapping() {
        let truth = Matrix3::new(1.2, 0.1, 320.0, -0.05, 0.9, 240.0, 1e-4, -2e-4, 1.0);
        let src: Vec<[f64; 2]> = (0..30)
            .map(|k| [(k % 6) as f64 * 40.0 - 100.0, (k / 6) as f64 * 40.0 - 80.0])
            .collect();
        let dst: Vec<[f64; 2]> = src.iter().map(|&p| apply(&truth, p)).collect();
        let h = homography(&src, &dst).expect("homography");
        for (s, d) in src.iter().zip(&dst) {
            let q = apply(&h, *s);
            assert!((q[0] - d[0]).abs() < 1e-8 && (q[1] - d[1]).abs() < 1e-8);
        }
        assert!(homography(&src[..3], &dst[..3]).is_none());
    }
}
