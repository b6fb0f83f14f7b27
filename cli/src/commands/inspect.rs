//! `ris inspect`: a measured cloud against its CAD model — deviation.ply, deviation.png and
//! report.json with the pass/fail verdict.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};
use ris_core::budget::{self, Budget};
use ris_core::cloud::PointCloud;
use ris_core::inspect::{
    inspect, load_characteristics, load_datums, write_deviation_ply, write_deviation_png,
    InspectParams, InspectedSurface, MapTitle, Report, Viewpoint,
};
use ris_core::mesh::{step, SignedDistance, TriangleMesh};

/// `ris inspect`'s arguments.
#[derive(clap::Args, Debug)]
pub struct InspectCommand {
    /// Measured cloud (PLY).
    #[arg(long)]
    pub cloud: PathBuf,
    /// CAD model: STEP (AP203/AP214/AP242; a build with the `step` feature), or an STL, PLY or
    /// OBJ mesh.
    #[arg(long)]
    pub cad: PathBuf,
    /// Datums (datum tables: name, position, radius; with `order`, a 3-2-1 frame of surface,
    /// point, hole, slot and edge features); without them trusted regions are grown.
    #[arg(long)]
    pub datums: Option<PathBuf>,
    /// Characteristics file: ISO 1101 flatness, profile, diameter and position toleranced on
    /// the STEP model's faces (`[[characteristic]]` tables, docs/commands.md); each is
    /// measured, reported and part of the verdict.
    #[arg(long, value_name = "FILE")]
    pub characteristics: Option<PathBuf>,
    /// Tolerance on |deviation|, mm.
    #[arg(long)]
    pub tolerance: f64,
    /// Minimum fraction of the inspected surface the cloud must cover for a verdict (0 … 1).
    #[arg(long, default_value_t = 0.5)]
    pub min_coverage: f64,
    /// The pose when it is known, so nothing is searched or fitted: `known` (the cloud is in
    /// the CAD's frame already) or a transform file (TOML `matrix`, cad_from_cloud, as
    /// `ris register` writes it); `nominal`: the cloud is near the CAD's frame (a cell's merged
    /// cloud, whose calibration puts the part at its nominal pose) and the fit starts there, as
    /// risd's does. Without it the pose is searched from the data alone.
    #[arg(long, value_name = "known|nominal|FILE")]
    pub pose: Option<String>,
    /// The inspected surface as STEP faces: their entity numbers (`#17,#137` or `17,137`, as
    /// the file and a CAD system's face picker give them). Coverage and the verdict count over
    /// these faces only; points closest to other faces are left out.
    #[arg(long, value_delimiter = ',', value_name = "ENTITY,...", value_parser = parse_entity)]
    pub faces: Vec<u32>,
    /// The inspected surface as what the scan could see: a sensor's camera centre and, after a
    /// colon, its projector's (`X,Y,Z` or `X,Y,Z:X,Y,Z`, mm, the cloud's frame); repeat for each
    /// sensor. Coverage counts over the CAD surface seen from at least one of them.
    #[arg(long, value_name = "X,Y,Z[:X,Y,Z]")]
    pub seen_from: Vec<String>,
    /// Output directory (deviation.ply, deviation.png, report.json).
    #[arg(long)]
    pub out: PathBuf,
    /// The most seconds the inspection may take: past it the command fails naming the
    /// deadline, and nothing is written (a line's cycle time, or a script's guard against a
    /// cloud far larger than expected).
    #[arg(long, value_name = "SECONDS")]
    pub deadline: Option<f64>,
}

/// Run `ris inspect`; the report, whose verdict gives the exit status.
pub fn command(cmd: &InspectCommand) -> Result<Report> {
    anyhow::ensure!(
        cmd.tolerance.is_finite() && cmd.tolerance > 0.0,
        "--tolerance must be a positive number of mm, got {}",
        cmd.tolerance
    );
    if let Some(d) = cmd.deadline {
        anyhow::ensure!(
            d.is_finite() && d > 0.0 && d <= 86_400.0,
            "--deadline must be a number of seconds above 0 and at most 86400, got {d}"
        );
    }
    anyhow::ensure!(
        cmd.faces.is_empty() || cmd.seen_from.is_empty(),
        "give the inspected surface either as --faces or as --seen-from, not both"
    );
    let nominal = cmd.pose.as_deref() == Some("nominal");
    let known = match cmd.pose.as_deref() {
        None => None,
        Some("known" | "nominal") => Some(ris_core::register::Pose::identity()),
        Some(file) => Some(
            ris_core::register::TransformFile::load(Path::new(file))
                .with_context(|| format!("--pose: reading the transform {file}"))?,
        ),
    };
    let viewpoints = cmd
        .seen_from
        .iter()
        .map(|s| parse_viewpoint(s))
        .collect::<Result<Vec<_>>>()?;
    let (cloud, cad, out) = (&cmd.cloud, &cmd.cad, &cmd.out);
    let bar = crate::progress::bar(5, "reading cloud");
    let mut c =
        PointCloud::read_ply(cloud).with_context(|| format!("reading {}", cloud.display()))?;
    // Points flagged outside their sensor's calibrated volume are not trusted to measure.
    let outside = c.drop_outside();
    bar.inc(1);
    bar.set_message("reading CAD");
    let (mesh, surface, characteristics) = if cmd.faces.is_empty() && cmd.characteristics.is_none()
    {
        let mesh =
            TriangleMesh::load(cad).with_context(|| format!("reading CAD {}", cad.display()))?;
        (mesh, InspectedSurface::Whole, Vec::new())
    } else {
        let model = step::read(cad, &step::StepOptions::default()).with_context(|| {
            format!(
                "reading CAD {} ({} needs a STEP model)",
                cad.display(),
                if cmd.faces.is_empty() {
                    "--characteristics"
                } else {
                    "--faces"
                }
            )
        })?;
        let surface = if cmd.faces.is_empty() {
            InspectedSurface::Whole
        } else {
            InspectedSurface::of_faces(&model, &cmd.faces, "--faces")?
        };
        let characteristics = match cmd.characteristics.as_deref() {
            Some(p) => load_characteristics(p, &model)
                .with_context(|| format!("reading characteristics {}", p.display()))?,
            None => Vec::new(),
        };
        (model.mesh, surface, characteristics)
    };
    let surface = match (surface, viewpoints.is_empty()) {
        (InspectedSurface::Whole, false) => InspectedSurface::SeenFrom(viewpoints),
        (s, _) => s,
    };
    let datums = match cmd.datums.as_deref() {
        Some(p) => load_datums(p).with_context(|| format!("reading datums {}", p.display()))?,
        None => Vec::new(),
    };
    let t = Instant::now();
    bar.inc(1);
    bar.set_message("indexing CAD");
    let sd = SignedDistance::new(mesh);
    bar.inc(1);
    bar.set_message(if known.is_some() && !nominal {
        "measuring deviations"
    } else {
        "registering"
    });
    let pts: Vec<[f64; 3]> = c
        .points
        .iter()
        .map(|p| [f64::from(p[0]), f64::from(p[1]), f64::from(p[2])])
        .collect();
    let params = InspectParams {
        tolerance: cmd.tolerance,
        datums: datums.clone(),
        min_coverage: cmd.min_coverage,
        init: known,
        fit_pose: known.is_none() || nominal,
        surface,
        characteristics,
        ..InspectParams::default()
    };
    let mut budget = Budget::new("the inspection");
    if let Some(d) = cmd.deadline {
        budget = budget.deadline(Duration::from_secs_f64(d));
    }
    let mut r = budget::within(budget, || inspect(&pts, &sd, &params))
        .with_context(|| format!("inspecting {}", cloud.display()))?;
    if outside > 0 {
        r.report.warnings.push(format!(
            "{outside} points flagged outside their sensor's calibrated volume were not inspected"
        ));
    }
    let elapsed = t.elapsed();
    bar.inc(1);
    bar.set_message("writing");
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    write_deviation_ply(&out.join("deviation.ply"), &r.points, &r.deviations)?;
    let title = MapTitle {
        part: name_of(cad),
        scan: name_of(cloud),
        time: ris_daemon::scan::utc_time(),
    };
    write_deviation_png(
        &out.join("deviation.png"),
        &r.points,
        &r.deviations,
        &r.report,
        &datums,
        &title,
    )?;
    let json = serde_json::to_string_pretty(&r.report)?;
    ris_core::io::write_atomic(&out.join("report.json"), json.as_bytes())?;
    ris_daemon::page::write_report_page(out)?;
    bar.finish_and_clear();
    let s = &r.report.statistics;
    if s.non_finite > 0 {
        println!(
            "{} points with a NaN or infinite coordinate left out",
            s.non_finite
        );
    }
    let how = match r.report.registration.mode.as_str() {
        "known pose" => "at the known pose".to_string(),
        mode => format!("{mode} registration"),
    };
    let deviations = if s.points == 0 {
        "no deviation measured".to_string()
    } else {
        format!(
            "deviation mean {:+.3} mm, RMS {:.3} mm, range {:+.3} … {:+.3} mm, {:.1} % within ±{} mm",
            s.mean,
            s.rms,
            s.min,
            s.max,
            100.0 * s.within_tolerance,
            cmd.tolerance
        )
    };
    println!(
        "{}: {} points, {:.1} % of {} measured, {deviations} ({how}, {:.1} s)",
        r.report.verdict.to_uppercase().replace('_', " "),
        s.points,
        100.0 * r.report.coverage.fraction,
        r.report.coverage.surface,
        elapsed.as_secs_f64()
    );
    if s.outside_inspected > 0 {
        println!(
            "  {} points closest to faces outside the inspected surface left out",
            s.outside_inspected
        );
    }
    for reason in &r.report.reasons {
        println!("  - {reason}");
    }
    for c in &r.report.characteristics {
        match (c.measured, &c.not_measured) {
            (Some(v), _) => println!(
                "  {} {} of {}: {v:.3} mm ({:.3} … {:.3}) {}",
                c.symbol,
                c.characteristic,
                c.name,
                c.lower_limit,
                c.upper_limit,
                if c.in_tolerance == Some(true) {
                    "ok"
                } else {
                    "OUT"
                }
            ),
            (None, why) => println!(
                "  {} {} of {}: not measured: {}",
                c.symbol,
                c.characteristic,
                c.name,
                why.as_deref().unwrap_or("")
            ),
        }
    }
    for d in &r.report.datums {
        let Some(m) = &d.frame else { continue };
        match (&m.error, m.measured) {
            (Some(why), _) => println!("  datum {} ({:?}): not measured: {why}", d.name, m.feature),
            (None, Some(p)) => println!(
                "  datum {} ({:?}, order {}): at ({:.3}, {:.3}, {:.3}) mm, offset {:?} mm{}",
                d.name,
                m.feature,
                m.order.unwrap_or(0),
                p[0],
                p[1],
                p[2],
                m.offset_mm
                    .iter()
                    .map(|o| (o * 1000.0).round() / 1000.0)
                    .collect::<Vec<_>>(),
                m.size_mm
                    .map(|s| format!(", size {s:.3} mm"))
                    .unwrap_or_default()
            ),
            (None, None) => {}
        }
    }
    println!(
        "wrote {}/deviation.ply, deviation.png, report.json",
        out.display()
    );
    Ok(r.report)
}

/// A file's name for a title.
fn name_of(p: &Path) -> String {
    p.file_name().map_or_else(
        || p.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}

/// A `--seen-from` value: `X,Y,Z` (camera) or `X,Y,Z:X,Y,Z` (camera:projector).
fn parse_viewpoint(s: &str) -> Result<Viewpoint> {
    let point = |p: &str| -> Result<[f64; 3]> {
        let v: Vec<f64> = p
            .split(',')
            .map(|x| x.trim().parse::<f64>())
            .collect::<std::result::Result<_, _>>()
            .map_err(|_| {
                anyhow::anyhow!("--seen-from {s:?}: `{p}` is not three numbers X,Y,Z (mm)")
            })?;
        match v[..] {
            [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok([x, y, z]),
            _ => bail!("--seen-from {s:?}: `{p}` is not three finite numbers X,Y,Z (mm)"),
        }
    };
    match s.split_once(':') {
        None => Ok(Viewpoint {
            camera: point(s)?,
            projector: None,
            image: None,
        }),
        Some((c, p)) => Ok(Viewpoint {
            camera: point(c)?,
            projector: Some(point(p)?),
            image: None,
        }),
    }
}

/// A STEP entity number as a file and a CAD system's face picker give it: `#17` or `17`.
fn parse_entity(text: &str) -> std::result::Result<u32, String> {
    text.trim()
        .trim_start_matches('#')
        .parse()
        .map_err(|_| format!("`{text}` is not a STEP entity number such as #17"))
}
