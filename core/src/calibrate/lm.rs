//! Levenberg–Marquardt least squares with a forward-difference Jacobian computed column-parallel:
//! the non-linear refinement shared by camera, homography and sensor calibration.

use nalgebra::{DMatrix, DVector};
use rayon::prelude::*;

/// Outcome of a minimisation.
#[derive(Clone, Copy, Debug)]
pub struct LmReport {
    /// Sum of squared residuals at the start.
    pub initial_cost: f64,
    /// Sum of squared residuals at the solution.
    pub cost: f64,
    /// Iterations taken.
    pub iterations: usize,
}

/// Minimise `Σ rᵢ(x)²` from `x`; `residuals(x, out)` fills `out` (always the same length).
/// `scale[j]` is the typical magnitude of parameter `j` and sets its difference step.
pub fn minimize<F>(
    x: &mut DVector<f64>,
    scale: &[f64],
    max_iterations: usize,
    residuals: F,
) -> LmReport
where
    F: Fn(&DVector<f64>, &mut Vec<f64>) + Sync,
{
    let n = x.len();
    let mut r = Vec::new();
    residuals(x, &mut r);
    let m = r.len();
    let cost_of = |r: &[f64]| r.iter().map(|v| v * v).sum::<f64>();
    let initial_cost = cost_of(&r);
    let mut cost = initial_cost;
    let mut lambda = 1e-3;
    let mut iterations = 0;
    let mut trial = Vec::with_capacity(m);
    while iterations < max_iterations {
        iterations += 1;
        let jac = jacobian(x, scale, &r, &residuals);
        let jt = jac.transpose();
        let a = &jt * &jac;
        let g = &jt * DVector::from_column_slice(&r);
        let mut improved = false;
        for _ in 0..12 {
            let mut damped = a.clone();
            for j in 0..n {
                damped[(j, j)] += lambda * a[(j, j)].max(1e-12);
            }
            let Some(chol) = damped.cholesky() else {
                lambda *= 10.0;
                continue;
            };
            let delta = chol.solve(&(-&g));
            let candidate = &*x + &delta;
            trial.clear();
            residuals(&candidate, &mut trial);
            let c = cost_of(&trial);
            if c.is_finite() && c < cost {
                let relative = (cost - c) / cost.max(1e-300);
                *x = candidate;
                std::mem::swap(&mut r, &mut trial);
                cost = c;
                lambda = (lambda / 5.0).max(1e-12);
                improved = true;
                if relative < 1e-12 {
                    return LmReport {
                        initial_cost,
                        cost,
                        iterations,
                    };
                }
                break;
            }
            lambda *= 8.0;
        }
        if !improved {
            break;
        }
    }
    LmReport {
        initial_cost,
        cost,
        iterations,
    }
}

/// Forward-difference Jacobian of `residuals` at `x` (steps as in [`minimize`]).
fn jacobian<F>(x: &DVector<f64>, scale: &[f64], r: &[f64], residuals: &F) -> DMatrix<f64>
where
    F: Fn(&DVector<f64>, &mut Vec<f64>) + Sync,
{
    let m = r.len();
    let columns: Vec<Vec<f64>> = (0..x.len())
        .into_par_iter()
        .map(|j| {
            let h = 1e-7 * scale[j].abs().max(1e-12) + 1e-10 * x[j].abs();
            let mut xj = x.clone();
            xj[j] += h;
            let mut rj = Vec::with_capacity(m);
            residuals(&xj, &mut rj);
            rj.iter().zip(r).map(|(a, b)| (a - b) / h).collect()
        })
        .collect();
    DMatrix::from_fn(m, x.len(), |i, j| columns[j][i])
}

/// Covariance σ² (JᵀJ)⁻¹ of the parameters at a least-squares solution `x`, with σ² the
/// residual variance per degree of freedom; `None` when the problem is singular there.
pub fn covariance<F>(x: &DVector<f64>, scale: &[f64], residuals: F) -> Option<DMatrix<f64>>
where
    F: Fn(&DVector<f64>, &mut Vec<f64>) + Sync,
{
    let mut r = Vec::new();
    residuals(x, &mut r);
    let dof = r.len().checked_sub(x.len()).filter(|&d| d > 0)?;
    let sigma2 = r.iter().map(|v| v * v).sum::<f64>() / dof as f64;
    let j = jacobian(x, scale, &r, &residuals);
    let jtj = j.transpose() * &j;
    jtj.try_inverse().map(|inv| inv * sigma2)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fits_an_exponential_from_a_poor_start() {
        // y = a exp(b t) + c with a = 2.5, b = -1.3, c = 0.4.
        let ts: Vec<f64> = (0..40).map(|i| i as f64 * 0.1).collect();
        let ys: Vec<f64> = ts.iter().map(|t| 2.5 * (-1.3 * t).exp() + 0.4).collect();
        let mut x = DVector::from_vec(vec![1.0, -0.5, 0.0]);
        let report = minimize(&mut x, &[1.0, 1.0, 1.0], 100, |p, out| {
            out.clear();
            out.extend(
                ts.iter()
                    .zip(&ys)
                    .map(|(t, y)| p[0] * (p[1] * t).exp() + p[2] - y),
            );
        });
        assert!(report.cost < 1e-16, "{report:?}");
        assert!(
            (x[0] - 2.5).abs() < 1e-6 && (x[1] + 1.3).abs() < 1e-6 && (x[2] - 0.4).abs() < 1e-6
        );
    }
}
