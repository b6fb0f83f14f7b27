//! Closed-form rigid fit from correspondences with unit quaternions (Horn 1987; Eq. 5.3–5.13).

use nalgebra::{Matrix4, Quaternion, UnitQuaternion, Vector3};

use super::Pose;

/// The rigid transform `T` minimising Σ wᵢ |T pᵢ − qᵢ|² (moving `p` onto fixed `q`); the
/// rotation is the eigenvector of Horn's 4×4 matrix N with the largest eigenvalue.
/// `None` with fewer than 3 pairs or degenerate (collinear) input.
pub fn fit_rigid(p: &[[f64; 3]], q: &[[f64; 3]], weights: Option<&[f64]>) -> Option<Pose> {
    let n = p.len().min(q.len());
    if n < 3 {
        return None;
    }
    let w = |i: usize| weights.map_or(1.0, |w| w[i]);
    let (mut sw, mut cp, mut cq) = (0.0, Vector3::zeros(), Vector3::zeros());
    for i in 0..n {
        sw += w(i);
        cp += Vector3::from(p[i]) * w(i);
        cq += Vector3::from(q[i]) * w(i);
    }
    if sw <= 0.0 {
        return None;
    }
    cp /= sw;
    cq /= sw;
    // Cross-covariance S = Σ w (p − p̄)(q − q̄)ᵀ.
    let mut s = nalgebra::Matrix3::<f64>::zeros();
    for i in 0..n {
        s += (Vector3::from(p[i]) - cp) * (Vector3::from(q[i]) - cq).transpose() * w(i);
    }
    let (sxx, sxy, sxz) = (s[(0, 0)], s[(0, 1)], s[(0, 2)]);
    let (syx, syy, syz) = (s[(1, 0)], s[(1, 1)], s[(1, 2)]);
    let (szx, szy, szz) = (s[(2, 0)], s[(2, 1)], s[(2, 2)]);
    #[rustfmt::skip]
    let nmat = Matrix4::new(
        sxx + syy + szz, syz - szy,        szx - sxz,        sxy - syx,
        syz - szy,       sxx - syy - szz,  sxy + syx,        szx + sxz,
        szx - sxz,       sxy + syx,        -sxx + syy - szz, syz + szy,
        sxy - syx,       szx + sxz,        syz + szy,        -sxx - syy + szz,
    );
    let eig = nmat.symmetric_eigen();
    let (imax, _) = eig
        .eigenvalues
        .iter()
        .enumerate()
        .max_by(|a, b| a.1.total_cmp(b.1))?;
    let v = eig.eigenvectors.column(imax);
    // Degenerate input (collinear points) leaves the two largest eigenvalues equal.
    let mut ev: Vec<f64> = eig.eigenvalues.iter().copied().collect();
    ev.sort_by(|a, b| b.total_cmp(a));
    if (ev[0] - ev[1]).abs() <= 1e-12 * ev[0].abs().max(1e-300) {
        return None;
    }
    let rot = UnitQuaternion::from_quaternion(Quaternion::new(v[0], v[1], v[2], v[3]));
    let t = cq - rot * cp;
    Some(Pose::from_parts(t.into(), rot))
}

/// Rotation angle of a pose, degrees.
pub fn rotation_angle_deg(pose: &Pose) -> f64 {
    pose.rotation.angle().to_degrees()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_an_exact_transform() {
        let truth = Pose::new(Vector3::new(12.0, -7.5, 3.25), Vector3::new(0.3, -0.2, 0.9));
        let p: Vec<[f64; 3]> = (0..50)
            .map(|i| {
                let f = i as f64;
                [
                    f.sin() * 100.0,
                    (f * 0.7).cos() * 80.0,
                    (f * 0.3).sin() * 20.0,
                ]
            })
            .collect();
        let q: Vec<[f64; 3]> = p
            .iter()
            .map(|x| (truth * nalgebra::Point3::from(*x)).coords.into())
            .collect();
        let got = fit_rigid(&p, &q, None).expect("fit");
        assert!((got.to_homogeneous() - truth.to_homogeneous()).abs().max() < 1e-9);
        let collinear: Vec<[f64; 3]> = (0..10).map(|i| [i as f64, 2.0 * i as f64, 0.0]).collect();
        assert!(fit_rigid(&collinear, &collinear, None).is_none());
    }
}
