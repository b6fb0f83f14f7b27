//! `ris verify`: the VDI/VDE 2634-2 acceptance test or re-verification of a cell from measured
//! clouds of calibrated artefacts — verify.json, the certificate verify.html and residual maps.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use ris_core::verify::{
    certificate_html, evaluate, write_residual_map, Artefacts, Certificate, MeasuredCloud, Status,
    VerifyParams,
};

/// `ris verify`: clouds of calibrated artefacts evaluated here, or a running cell's
/// verification session driven over Zenoh.
#[derive(Clone, Debug, clap::Args)]
pub struct VerifyCommand {
    /// The artefacts file: `[ball_bar]`, `[sphere]`, `[plane]`, `[mpe]` and optionally
    /// `[volume]` (for clouds evaluated here).
    #[arg(long)]
    pub artefacts: Option<PathBuf>,
    /// Clouds (PLY or E57) of the ball bar, one position each.
    #[arg(long = "ball-bar", num_args = 1..)]
    pub ball_bar: Vec<PathBuf>,
    /// Clouds of the flat, one position each.
    #[arg(long, num_args = 1..)]
    pub plane: Vec<PathBuf>,
    /// Clouds of the probing sphere, one position each.
    #[arg(long, num_args = 1..)]
    pub sphere: Vec<PathBuf>,
    /// Instead of measured clouds: render a whole acceptance set (7 bar, 6 flat and 10
    /// sphere positions through the artefacts file's `[volume]`) through the sensor of
    /// this simulator scene, and evaluate it (the clouds are written under `clouds/`).
    #[arg(long, conflicts_with_all = ["ball_bar", "plane", "sphere"])]
    pub simulate: Option<PathBuf>,
    /// Output directory (verify.json, verify.html, residual maps; with a cell: the finished
    /// session's certificate and page, or the measured clouds); must not exist or be empty.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// A running cell's verification session instead (`--connect`, `--cell`).
    #[command(flatten)]
    pub session: super::verify_session::SessionArgs,
}

/// Run `ris verify`: the exit status of the verdict (3 fail, 4 not measured).
pub fn command(c: &VerifyCommand) -> Result<Option<i32>> {
    if let Some(action) = c.session.action()? {
        anyhow::ensure!(
            c.artefacts.is_none()
                && c.simulate.is_none()
                && c.ball_bar.is_empty()
                && c.plane.is_empty()
                && c.sphere.is_empty(),
            "a cell's verification evaluates its own scans against its [verify] artefacts file: leave out --artefacts, --simulate and the clouds"
        );
        return super::verify_session::run(&c.session, &action, c.out.as_deref());
    }
    let (Some(artefacts), Some(out)) = (&c.artefacts, &c.out) else {
        anyhow::bail!(
            "give --artefacts ARTEFACTS.toml and --out DIR with the clouds (--ball-bar, --plane, --sphere) or --simulate SCENE; or drive a running cell's verification with --start, --measure, --check, --finish, --status or --history"
        );
    };
    let cert = match &c.simulate {
        Some(scene) => simulate(artefacts, scene, out)?,
        None => run(
            artefacts,
            &Clouds {
                ball_bar: c.ball_bar.clone(),
                plane: c.plane.clone(),
                sphere: c.sphere.clone(),
            },
            out,
        )?,
    };
    Ok(exit_code(cert.verdict))
}

/// The exit status of a verdict: none for a pass, 3 for a failure, 4 when not measured.
pub fn exit_code(s: Status) -> Option<i32> {
    match s {
        Status::Pass => None,
        Status::Fail => Some(3),
        Status::NotMeasured => Some(4),
    }
}

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
                points: c.positions(),
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
    finish(&a, artefacts, [bars, planes, spheres], &[], out, &bar)
}

/// Render a whole acceptance set (7 bar, 6 flat, 10 sphere positions through the artefacts
/// file's `[volume]`) through the sensor of `scene` (its optics, table and noise; the parallax
/// model from its own reference plane), then evaluate it as [`run`] does; the clouds are
/// written too, as `clouds/<position>.ply`.
pub fn simulate(artefacts: &Path, scene: &Path, out: &Path) -> Result<Certificate> {
    use ris_core::verify::scenes::{acceptance_set, decode_set, Placement};
    let a = Artefacts::load(artefacts)?;
    let volume = a.volume.as_ref().with_context(|| {
        format!(
            "{}: --simulate places the artefacts through the calibrated volume; add [volume]",
            artefacts.display()
        )
    })?;
    let base = ris_core::sim::Scene::load(scene)?;
    let set = acceptance_set(&a, volume);
    anyhow::ensure!(
        !set.is_empty(),
        "{}: no artefact to place (give [ball_bar], [plane] or [sphere])",
        artefacts.display()
    );
    let bar = crate::progress::bar(
        set.len() as u64 + 3,
        &format!("rendering and decoding {} positions", set.len()),
    );
    let decoded = decode_set(
        &base,
        &a,
        &set,
        &ris_core::decode::DecodeParams::default(),
        &|done, _| bar.set_position(done as u64),
    )?;
    let rec = ris_core::sensor::Reconstructor::parallax(
        &base.camera,
        base.projector.center(),
        &decoded.reference,
    )?;
    let (mut bars, mut planes, mut spheres) = (vec![], vec![], vec![]);
    let mut clouds = Vec::with_capacity(set.len());
    for (p, d) in set.iter().zip(&decoded.positions) {
        let cloud = rec.reconstruct(d)?;
        let measured = MeasuredCloud {
            name: format!("{}.ply", p.label),
            points: cloud.positions(),
        };
        match p.placement {
            Placement::Bar { .. } => bars.push(measured),
            Placement::Flat { .. } => planes.push(measured),
            Placement::Sphere { .. } => spheres.push(measured),
        }
        clouds.push((format!("{}.ply", p.label), cloud));
    }
    finish(&a, artefacts, [bars, planes, spheres], &clouds, out, &bar)
}

/// Evaluate and write the output directory (with `clouds` under `clouds/`).
fn finish(
    a: &Artefacts,
    artefacts: &Path,
    [bars, planes, spheres]: [Vec<MeasuredCloud>; 3],
    clouds: &[(String, ris_core::cloud::PointCloud)],
    out: &Path,
    bar: &indicatif::ProgressBar,
) -> Result<Certificate> {
    bar.set_message("finding and fitting the artefacts");
    let (cert, maps) = evaluate(
        a,
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
        if !clouds.is_empty() {
            ris_core::io::create_dir(&dir.join("clouds"))?;
            for (name, cloud) in clouds {
                ris_core::io::write_atomic(&dir.join("clouds").join(name), &cloud.to_ply())?;
            }
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
