//! `ris register`: rigid ICP of one point cloud onto another, writing the transform.

use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result};
use ris_core::cloud::PointCloud;
use ris_core::register::{
    rotation_angle_deg, Icp, IcpMetric, IcpParams, IcpResult, Pose, TransformFile,
};

fn points(cloud: &PointCloud) -> Vec<[f64; 3]> {
    cloud
        .points
        .iter()
        .map(|p| [f64::from(p[0]), f64::from(p[1]), f64::from(p[2])])
        .collect()
}

/// Align `moving` onto `fixed` (optionally from `init`) and write the fixed_from_moving
/// transform with its RMS, overlap and iteration count to `out`.
pub fn run(
    fixed: &Path,
    moving: &Path,
    init: Option<&Path>,
    params: &IcpParams,
    out: &Path,
) -> Result<IcpResult> {
    let f = PointCloud::read_ply(fixed).with_context(|| format!("reading {}", fixed.display()))?;
    let m =
        PointCloud::read_ply(moving).with_context(|| format!("reading {}", moving.display()))?;
    anyhow::ensure!(
        f.len() >= 3,
        "{} has {} points; registration needs at least 3",
        fixed.display(),
        f.len()
    );
    anyhow::ensure!(
        m.len() >= 3,
        "{} has {} points; registration needs at least 3",
        moving.display(),
        m.len()
    );
    let start = match init {
        Some(p) => TransformFile::load(p)
            .with_context(|| format!("reading initial transform {}", p.display()))?,
        None => Pose::identity(),
    };
    let t = Instant::now();
    let icp = Icp::new(&points(&f), params.metric, params.normal_neighbours);
    let r = icp.align(&points(&m), start, params);
    let elapsed = t.elapsed();
    anyhow::ensure!(
        r.rms.is_finite(),
        "registration found no usable point pairs between {} and {}",
        fixed.display(),
        moving.display()
    );
    // A registration that ran out of iterations has not found the pose: no transform is
    // written that a script could take for one.
    anyhow::ensure!(
        r.converged,
        "ICP did not converge within {} iterations (RMS {:.3} mm, overlap {:.1} %) aligning {} onto {}: give a closer --init or more --max-iterations; nothing written",
        params.max_iterations,
        r.rms,
        100.0 * r.overlap,
        moving.display(),
        fixed.display()
    );
    let mut file = TransformFile::from_pose(&r.fixed_from_moving);
    file.rms = Some(r.rms);
    file.overlap = Some(r.overlap);
    file.iterations = Some(r.iterations);
    file.save(out)
        .with_context(|| format!("writing {}", out.display()))?;
    println!(
        "{:?} ICP: RMS {:.4} mm, overlap {:.1} %, {} iterations ({}), rotation {:.4}°, translation {:.3} mm, {:.0} ms; wrote {}",
        params.metric,
        r.rms,
        100.0 * r.overlap,
        r.iterations,
        if r.converged { "converged" } else { "iteration limit" },
        rotation_angle_deg(&r.fixed_from_moving),
        r.fixed_from_moving.translation.vector.norm(),
        elapsed.as_secs_f64() * 1e3,
        out.display()
    );
    Ok(r)
}

/// Parse `point-to-plane` / `point-to-point`.
pub fn metric(name: &str) -> Result<IcpMetric> {
    match name {
        "point-to-plane" => Ok(IcpMetric::PointToPlane),
        "point-to-point" => Ok(IcpMetric::PointToPoint),
        other => anyhow::bail!("unknown metric `{other}` (point-to-plane, point-to-point)"),
    }
}
