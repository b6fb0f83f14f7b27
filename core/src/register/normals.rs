//! Surface normals by local PCA: the eigenvector of the smallest eigenvalue of the covariance
//! of each point's k nearest neighbours.

use rayon::prelude::*;

use crate::spatial::KdTree;

/// Unit normal per point from its `k` nearest neighbours in `tree` (built over `points`),
/// oriented towards `viewpoint` (e.g. the sensor) when given. Degenerate neighbourhoods give
/// a zero vector.
pub fn estimate_normals(
    points: &[[f64; 3]],
    tree: &KdTree,
    k: usize,
    viewpoint: Option<[f64; 3]>,
) -> Vec<[f64; 3]> {
    points
        .par_iter()
        .map_init(Vec::new, |nn, p| {
            tree.k_nearest(p, k, nn);
            let n = nn.len() as f64;
            if nn.len() < 3 {
                return [0.0; 3];
            }
            let mut c = [0.0; 3];
            for &(i, _) in nn.iter() {
                for a in 0..3 {
                    c[a] += points[i][a] / n;
                }
            }
            let mut m = [0.0; 6]; // xx xy xz yy yz zz
            for &(i, _) in nn.iter() {
                let d = [
                    points[i][0] - c[0],
                    points[i][1] - c[1],
                    points[i][2] - c[2],
                ];
                m[0] += d[0] * d[0];
                m[1] += d[0] * d[1];
                m[2] += d[0] * d[2];
                m[3] += d[1] * d[1];
                m[4] += d[1] * d[2];
                m[5] += d[2] * d[2];
            }
            let mut normal = smallest_eigenvector(&m);
            if let Some(v) = viewpoint {
                let to_v = [v[0] - p[0], v[1] - p[1], v[2] - p[2]];
                if normal[0] * to_v[0] + normal[1] * to_v[1] + normal[2] * to_v[2] < 0.0 {
                    normal = normal.map(|x| -x);
                }
            }
            normal
        })
        .collect()
}

/// Unit eigenvector of the smallest eigenvalue of the symmetric matrix (xx xy xz yy yz zz):
/// closed-form eigenvalues, then the largest cross product of two rows of A − λI.
fn smallest_eigenvector(m: &[f64; 6]) -> [f64; 3] {
    let [a, b, c, d, e, f] = *m;
    let scale = a
        .abs()
        .max(b.abs())
        .max(c.abs())
        .max(d.abs())
        .max(e.abs())
        .max(f.abs());
    if scale <= 0.0 {
        return [0.0; 3];
    }
    let (a, b, c, d, e, f) = (
        a / scale,
        b / scale,
        c / scale,
        d / scale,
        e / scale,
        f / scale,
    );
    // Eigenvalues of [[a b c] [b d e] [c e f]] (trigonometric method).
    let q = (a + d + f) / 3.0;
    let p1 = b * b + c * c + e * e;
    let p2 = (a - q).powi(2) + (d - q).powi(2) + (f - q).powi(2) + 2.0 * p1;
    let p = (p2 / 6.0).sqrt();
    if p < 1e-15 {
        return [0.0; 3]; // isotropic: no preferred normal
    }
    let (ba, bd, bf) = ((a - q) / p, (d - q) / p, (f - q) / p);
    let det = ba * (bd * bf - (e / p) * (e / p)) - (b / p) * ((b / p) * bf - (e / p) * (c / p))
        + (c / p) * ((b / p) * (e / p) - bd * (c / p));
    let r = (det / 2.0).clamp(-1.0, 1.0);
    let phi = r.acos() / 3.0;
    let lambda_min = q + 2.0 * p * (phi + 2.0 * std::f64::consts::PI / 3.0).cos();
    let rows = [
        [a - lambda_min, b, c],
        [b, d - lambda_min, e],
        [c, e, f - lambda_min],
    ];
    let cross = |u: &[f64; 3], v: &[f64; 3]| {
        [
            u[1] * v[2] - u[2] * v[1],
            u[2] * v[0] - u[0] * v[2],
            u[0] * v[1] - u[1] * v[0],
        ]
    };
    let cands = [
        cross(&rows[0], &rows[1]),
        cross(&rows[0], &rows[2]),
        cross(&rows[1], &rows[2]),
    ];
    let norm2 = |v: &[f64; 3]| v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
    let best = cands
        .iter()
        .max_by(|x, y| norm2(x).total_cmp(&norm2(y)))
        .copied()
        .unwrap_or([0.0; 3]);
    let n = norm2(&best).sqrt();
    if n < 1e-300 {
        return [0.0; 3];
    }
    best.map(|x| x / n)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normals_of_a_tilted_plane_and_a_sphere() {
        let mut pts = Vec::new();
        for i in 0..40 {
            for j in 0..40 {
                let (x, y) = (i as f64, j as f64);
                pts.push([x, y, 0.5 * x - 0.25 * y + 3.0]);
            }
        }
        let tree = KdTree::new(&pts);
        let normals = estimate_normals(&pts, &tree, 10, Some([0.0, 0.0, 1000.0]));
        let want = {
            let v: [f64; 3] = [-0.5, 0.25, 1.0];
            let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            v.map(|x| x / n)
        };
        for n in &normals {
            assert!((0..3).all(|k| (n[k] - want[k]).abs() < 1e-9), "{n:?}");
        }
        let sphere: Vec<[f64; 3]> = (0..2000)
            .map(|i| {
                let t = (i as f64 + 0.5) / 2000.0;
                let (z, phi) = (1.0 - 2.0 * t, i as f64 * 2.399_963);
                let r = (1.0 - z * z).sqrt();
                [50.0 * r * phi.cos(), 50.0 * r * phi.sin(), 50.0 * z]
            })
            .collect();
        let tree = KdTree::new(&sphere);
        let normals = estimate_normals(&sphere, &tree, 12, None);
        let worst = sphere
            .iter()
            .zip(&normals)
            .map(|(p, n)| 1.0 - ((p[0] * n[0] + p[1] * n[1] + p[2] * n[2]) / 50.0).abs())
            .fold(0.0, f64::max);
        assert!(worst < 1e-3, "sphere normals off by {worst}");
    }
}
