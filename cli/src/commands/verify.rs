//! `ris verify`: the VDI/VDE 2634-2 acceptance test or re-verification of a cell from measured
//! clouds of calibrated artefacts — verify.json, the certificate verify.html and residual maps.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use ris_core::geometry::Vec3;
use ris_core::verify::{
    certificate_html, evaluate, write_residual_map, Artefacts, Certificate, MeasuredCloud, Status,
    VerifyParams,
};

/// The clouds of one run, by artefact.
#[derive(Clone, Debug, Default)]
pub struct Clouds {
    /// Ball-bar clouds, one position each.
    pub ball_bar: Vec<PathBuf>,
    /// Flat clouds.
    pub plane: Vec<PathBuf>,
    /// Probing-sphere clouds.
    pub sphere: Vec<PathBuf>,
}

fn load(paths: &[PathBuf]) -> Result<Vec<MeasuredCloud>> {
    paths
        .iter()
        .map(|p| {
            let mut c = super::convert::read(p)?;
            let dropped = c.retain_finite();
            // Points flagged outside their sensor's calibrated volume are not trusted to measure.
            let outside = c.drop_outside();
            if outside > 0 {
                tracing::warn!(
                    "{}: {outside} points outside the calibrated volume left out",
                    p.display()
                );
            }
            anyhow::ensure!(
                !c.is_empty(),
                "{}: the cloud has no finite points{}",
                p.display(),
                if dropped > 0 {
                    format!(" ({dropped} were NaN or infinite)")
                } else {
                    String::new()
                }
            );
            Ok(MeasuredCloud {
                name: p
                    .file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .unwrap_or_else(|| p.display().to_string()),
                points: c
                    .points
                    .iter()
                    .map(|q| Vec3::new(f64::from(q[0]), f64::from(q[1]), f64::from(q[2])))
                    .collect(),
            })
        })
        .collect()
}

/// Evaluate the clouds against `artefacts` and write `verify.json`, `verify.html` and the
/// residual maps into `out` (created whole or not at all).
pub fn run(artefacts: &Path, clouds: &Clouds, out: &Path) -> Result<Certificate> {
    let a = Artefacts::load(artefacts)?;
    anyhow::ensure!(
        !(clouds.ball_bar.is_empty() && clouds.plane.is_empty() && clouds.sphere.is_empty()),
        "no clouds: give --ball-bar, --plane or --sphere clouds of the artefacts"
    );
    let total = clouds.ball_bar.len() + clouds.plane.len() + clouds.sphere.len();
    let bar = crate::progress::bar(3, &format!("reading {total} clouds"));
    let bars = load(&clouds.ball_bar)?;
    let planes = load(&clouds.plane)?;
    let spheres = load(&clouds.sphere)?;
    bar.inc(1);
    bar.set_message("finding and fitting the artefacts");
    let (cert, maps) = evaluate(
        &a,
        &bars,
        &planes,
        &spheres,
        &VerifyParams::default(),
        ris_daemon::scan::utc_time(),
    )
    .with_context(|| format!("evaluating against {}", artefacts.display()))?;
    bar.inc(1);
    bar.set_message("writing the certificate");
    let json = serde_json::to_vec_pretty(&cert).context("encoding verify.json")?;
    let html = certificate_html(&cert);
    ris_core::io::write_dir_atomically(out, |dir| {
        ris_core::io::create_dir(dir)?;
        for m in &maps {
            write_residual_map(dir, m)?;
        }
        ris_core::io::write_atomic(&dir.join("verify.json"), &json)?;
        ris_core::io::write_atomic(&dir.join("verify.html"), html.as_bytes())
    })
    .with_context(|| format!("writing {}", out.display()))?;
    bar.finish_and_clear();
    print_summary(&cert);
    println!("wrote {}", out.display());
    Ok(cert)
}

fn print_summary(cert: &Certificate) {
    let groups = [
        ("SD", &cert.sphere_spacing),
        ("F ", &cert.flatness),
        ("PF", &cert.probing_form),
        ("PS", &cert.probing_size),
    ];
    for (symbol, figures) in groups {
        for f in figures.iter() {
            match (f.error, &f.reason) {
                (Some(e), _) => println!(
                    "{symbol} {:<10} {:>+9.4} mm  MPE {:.4} mm  {}  ({})",
                    f.position.label,
                    e,
                    f.mpe,
                    word(f.status),
                    f.cloud
                ),
                (None, Some(r)) => println!(
                    "{symbol} {:<10} NOT MEASURED: {r} ({})",
                    f.position.label, f.cloud
                ),
                (None, None) => {}
            }
        }
    }
    println!("{}", cert.coverage.kind);
    for m in &cert.coverage.missing {
        println!("  - {m}");
    }
    println!("verification: {}", word(cert.verdict));
}

/// The verdict in words.
pub fn word(s: Status) -> &'static str {
    match s {
        Status::Pass => "PASS",
        Status::Fail => "FAIL",
        Status::NotMeasured => "NOT MEASURED",
    }
}
