//! The acceptance test and re-verification of an optical 3D measuring system by VDI/VDE 2634
//! Part 2 (ISO 10360-13 carries the same ideas): calibrated artefacts measured in positions
//! spread through the measuring volume, each figure compared with the maximum permissible
//! error (MPE) the system claims.
//!
//! - probing error form **PF**: range of the radial residuals of a least-squares sphere fit;
//! - probing error size **PS**: fitted minus calibrated diameter;
//! - sphere-spacing error **SD**: measured minus calibrated distance of a ball bar's centres;
//! - flatness measurement error **F**: range of the signed distances from the least-squares
//!   plane of a flat.
//!
//! Each evaluation may leave out the 0.3 % of points with the largest residuals, and says how
//! many it did. An artefact is found in a cloud that also holds the table, posts and clutter
//! from its known size; where it is not found, too little of it is seen, or the fit does not pin
//! the figure well enough against its MPE, the figure is `not_measured` with the reason, never
//! a number from a fit that cannot be trusted.

mod artefacts;
mod find;
pub mod fit;
mod picture;
pub mod scenes;
pub mod synthetic;

pub use artefacts::{
    Artefacts, BallBar, Mpe, PlaneArtefact, SpacingMpe, SphereArtefact, System, Volume,
};
pub use picture::{certificate_html, certificate_page, write_residual_map, ResidualMap};

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::geometry::Vec3;
use find::{FoundSphere, Searchable};
use fit::{
    correlation_inflation, fit_leaving_out, fit_plane, fit_sphere, range, PlaneFit, SphereFit,
};

/// Thresholds that decide when an artefact counts as measured.
#[derive(Clone, Debug)]
pub struct VerifyParams {
    /// Fewest points an artefact (each sphere of a bar) must have after the left-out share.
    pub min_points: usize,
    /// Smallest solid angle of a sphere that must be seen, steradian (a hemisphere is 6.28).
    pub min_solid_angle: f64,
    /// Largest standard uncertainty of a figure from the fit itself, as a share of its MPE:
    /// beyond it the points do not pin the figure (a thin or one-sided cap).
    pub max_uncertainty_share: f64,
    /// Smallest share of a flat's face that must be measured.
    pub min_area_share: f64,
    /// Largest relative difference of a found sphere's radius from the calibrated one.
    pub radius_tolerance: f64,
    /// Largest relative difference of a found bar's spacing from the calibrated one.
    pub spacing_tolerance: f64,
}

impl Default for VerifyParams {
    fn default() -> Self {
        VerifyParams {
            min_points: 200,
            min_solid_angle: 1.0,
            max_uncertainty_share: 0.25,
            min_area_share: 0.8,
            radius_tolerance: 0.1,
            spacing_tolerance: 0.05,
        }
    }
}

/// A measured cloud of one artefact in one position.
#[derive(Clone, Debug)]
pub struct MeasuredCloud {
    /// The file name as given (it names the entries of `verify.json`).
    pub name: String,
    /// The points, mm, in any frame (the volume, when given, is in the same frame).
    pub points: Vec<Vec3>,
}

/// Outcome of one figure.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Status {
    /// Within its MPE.
    Pass,
    /// Beyond its MPE.
    Fail,
    /// The artefact was not found or the data do not pin the figure.
    NotMeasured,
}

/// Where an artefact stood.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Position {
    /// `bar 3`, `flat 2`, `sphere 7`: the kind and the index of its cloud (1-based).
    pub label: String,
    /// Centre (sphere centre, midpoint of a bar's centres, centroid of a flat), mm.
    pub centre: Option<[f64; 3]>,
    /// The centre in the calibrated volume, 0 … 1 per axis (when a volume is given).
    pub in_volume: Option<[f64; 3]>,
    /// Whether the artefact lies inside the calibrated volume.
    pub inside: Option<bool>,
    /// The bar's axis or the flat's long axis (unit vector).
    pub direction: Option<[f64; 3]>,
    /// The flat's normal.
    pub normal: Option<[f64; 3]>,
    /// The volume direction the bar or flat lies along (`space diagonal 2`, `x axis`, …) and
    /// the angle to it, degrees.
    pub along: Option<String>,
}

/// One figure of one position.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Figure {
    /// The cloud file name.
    pub cloud: String,
    /// Where the artefact stood.
    pub position: Position,
    /// The measured quantity (PF, F: the range; PS: the fitted diameter; SD: the distance), mm.
    pub measured: Option<f64>,
    /// The calibrated value of the same quantity, mm.
    pub calibrated: f64,
    /// The figure compared with the MPE (PF, F: the range less the calibrated form; PS, SD:
    /// measured − calibrated), mm.
    pub error: Option<f64>,
    /// The limit on |error|, mm.
    pub mpe: f64,
    /// Points evaluated (after the left-out share).
    pub points: usize,
    /// Points left out (at most 0.3 % of the artefact's points).
    pub left_out: usize,
    /// |error| ≤ MPE; `None` when not measured.
    pub pass: Option<bool>,
    /// Pass, fail or not measured.
    pub status: Status,
    /// Why it was not measured.
    pub reason: Option<String>,
    /// The residual map's file name, when one was drawn.
    pub map: Option<String>,
    /// Standard uncertainty of the figure from the fit alone (not the system's), mm: from the
    /// residuals and the points' spread, inflated by the residuals' correlation between
    /// neighbouring points (a decoder's sub-pixel fit spreads one edge's noise over several).
    pub fit_uncertainty: Option<f64>,
}

/// Whether the positions make an acceptance test or only a spot check.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Coverage {
    /// Every present artefact's positions cover the volume as the guideline recommends.
    pub acceptance_test: bool,
    /// `acceptance test` or `spot check`.
    pub kind: String,
    /// What is missing for an acceptance test, in words.
    pub missing: Vec<String>,
    /// The volume's diagonal L0, mm.
    pub volume_diagonal: Option<f64>,
}

/// The result of an acceptance test or re-verification (`verify.json`).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Certificate {
    /// The system and the artefacts' calibration.
    pub system: System,
    /// The artefacts and limits evaluated against.
    pub artefacts: Artefacts,
    /// When it was evaluated (UTC).
    pub time: String,
    /// SD, one per ball-bar cloud.
    pub sphere_spacing: Vec<Figure>,
    /// F, one per flat cloud.
    pub flatness: Vec<Figure>,
    /// PF, one per sphere cloud.
    pub probing_form: Vec<Figure>,
    /// PS, one per sphere cloud.
    pub probing_size: Vec<Figure>,
    /// How well the positions cover the volume.
    pub coverage: Coverage,
    /// `fail` when any figure exceeds its MPE, else `not_measured` when any is not measured
    /// (or none was given), else `pass`.
    pub verdict: Status,
}

impl Certificate {
    /// Every figure, SD first.
    pub fn figures(&self) -> impl Iterator<Item = &Figure> {
        self.sphere_spacing
            .iter()
            .chain(&self.flatness)
            .chain(&self.probing_form)
            .chain(&self.probing_size)
    }
}

/// Evaluate the clouds of each artefact against `artefacts`. Clouds of an artefact the file
/// does not describe are an error naming the artefact.
pub fn evaluate(
    artefacts: &Artefacts,
    bars: &[MeasuredCloud],
    planes: &[MeasuredCloud],
    spheres: &[MeasuredCloud],
    params: &VerifyParams,
    time: String,
) -> crate::Result<(Certificate, Vec<ResidualMap>)> {
    let missing = |what: &str, n: usize| {
        crate::Error::invalid(
            "artefacts file",
            what,
            format!("{n} {what} clouds given but the artefacts file has no [{what}] section"),
        )
    };
    if !bars.is_empty() && artefacts.ball_bar.is_none() {
        return Err(missing("ball_bar", bars.len()));
    }
    if !planes.is_empty() && artefacts.plane.is_none() {
        return Err(missing("plane", planes.len()));
    }
    if !spheres.is_empty() && artefacts.sphere.is_none() {
        return Err(missing("sphere", spheres.len()));
    }
    let volume = artefacts.volume.as_ref();
    let bar_results: Vec<(Figure, Vec<ResidualMap>)> = bars
        .par_iter()
        .enumerate()
        .map(|(i, c)| {
            let bar = artefacts.ball_bar.expect("checked above");
            ball_bar(c, i + 1, &bar, &artefacts.mpe, volume, params)
        })
        .collect();
    let plane_results: Vec<(Figure, Vec<ResidualMap>)> = planes
        .par_iter()
        .enumerate()
        .map(|(i, c)| {
            let flat = artefacts.plane.expect("checked above");
            flat_figure(c, i + 1, &flat, artefacts.mpe.flatness, volume, params)
        })
        .collect();
    let sphere_results: Vec<(Figure, Figure, Vec<ResidualMap>)> = spheres
        .par_iter()
        .enumerate()
        .map(|(i, c)| {
            let sphere = artefacts.sphere.expect("checked above");
            probing(c, i + 1, &sphere, &artefacts.mpe, volume, params)
        })
        .collect();
    let mut maps = Vec::new();
    let mut sphere_spacing = Vec::new();
    for (f, m) in bar_results {
        sphere_spacing.push(f);
        maps.extend(m);
    }
    let mut flatness = Vec::new();
    for (f, m) in plane_results {
        flatness.push(f);
        maps.extend(m);
    }
    let (mut probing_form, mut probing_size) = (Vec::new(), Vec::new());
    for (pf, ps, m) in sphere_results {
        probing_form.push(pf);
        probing_size.push(ps);
        maps.extend(m);
    }
    let cert = assemble(
        artefacts,
        [sphere_spacing, flatness, probing_form, probing_size],
        time,
    );
    Ok((cert, maps))
}

/// The certificate of figures measured separately (positions scanned one at a time, as a
/// daemon's verification session gathers them): `[sphere_spacing, flatness, probing_form,
/// probing_size]`, with the volume's coverage and the verdict judged over all of them.
pub fn assemble(
    artefacts: &Artefacts,
    [sphere_spacing, flatness, probing_form, probing_size]: [Vec<Figure>; 4],
    time: String,
) -> Certificate {
    let coverage = coverage(artefacts, &sphere_spacing, &flatness, &probing_form);
    let mut cert = Certificate {
        system: artefacts.system.clone(),
        artefacts: artefacts.clone(),
        time,
        sphere_spacing,
        flatness,
        probing_form,
        probing_size,
        coverage,
        verdict: Status::NotMeasured,
    };
    cert.verdict = verdict(cert.figures().map(|f| f.status));
    cert
}

/// `fail` when any figure fails, else `not_measured` when any is not measured or there is
/// none, else `pass`.
pub fn verdict(statuses: impl IntoIterator<Item = Status>) -> Status {
    let mut out = None;
    for s in statuses {
        out = match (out, s) {
            (_, Status::Fail) | (Some(Status::Fail), _) => Some(Status::Fail),
            (_, Status::NotMeasured) | (Some(Status::NotMeasured), _) => Some(Status::NotMeasured),
            _ => Some(Status::Pass),
        };
    }
    out.unwrap_or(Status::NotMeasured)
}

/// A figure that could not be measured.
fn not_measured(
    cloud: &str,
    position: Position,
    calibrated: f64,
    mpe: f64,
    reason: String,
) -> Figure {
    Figure {
        cloud: cloud.to_string(),
        position,
        measured: None,
        calibrated,
        error: None,
        mpe,
        points: 0,
        left_out: 0,
        pass: None,
        status: Status::NotMeasured,
        reason: Some(reason),
        map: None,
        fit_uncertainty: None,
    }
}

#[allow(clippy::too_many_arguments)]
fn measured(
    cloud: &str,
    position: Position,
    measured: f64,
    calibrated: f64,
    error: f64,
    mpe: f64,
    points: usize,
    left_out: usize,
    map: Option<String>,
    fit_uncertainty: Option<f64>,
) -> Figure {
    let pass = error.abs() <= mpe;
    Figure {
        cloud: cloud.to_string(),
        position,
        measured: Some(measured),
        calibrated,
        error: Some(error),
        mpe,
        points,
        left_out,
        pass: Some(pass),
        status: if pass { Status::Pass } else { Status::Fail },
        reason: None,
        map,
        fit_uncertainty,
    }
}

fn position(label: String, centre: Option<Vec3>, volume: Option<&Volume>) -> Position {
    let c = centre.map(|c| [c.x, c.y, c.z]);
    let in_volume = c.zip(volume).map(|(c, v)| v.normalised(c));
    Position {
        label,
        centre: c,
        in_volume,
        inside: in_volume.map(|u| u.iter().all(|t| (0.0..=1.0).contains(t))),
        direction: None,
        normal: None,
        along: None,
    }
}

/// The named direction of the volume nearest to `d` (sign-free) and the angle to it.
fn along(d: &Vec3, volume: &Volume) -> (String, f64) {
    let e: [f64; 3] = std::array::from_fn(|k| volume.max[k] - volume.min[k]);
    let mut named: Vec<(String, Vec3)> = vec![
        ("x axis".into(), Vec3::x()),
        ("y axis".into(), Vec3::y()),
        ("z axis".into(), Vec3::z()),
    ];
    for (k, (sx, sy)) in [(1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0)]
        .iter()
        .enumerate()
    {
        named.push((
            format!("space diagonal {}", k + 1),
            Vec3::new(sx * e[0], sy * e[1], e[2]),
        ));
    }
    for (a, b, name) in [(0, 1, "xy"), (0, 2, "xz"), (1, 2, "yz")] {
        for s in [1.0, -1.0] {
            let mut v = Vec3::zeros();
            v[a] = e[a];
            v[b] = s * e[b];
            let tag = if s > 0.0 { "+" } else { "-" };
            named.push((format!("{name} face diagonal {tag}"), v));
        }
    }
    named
        .into_iter()
        .map(|(n, v)| {
            let cos = d.normalize().dot(&v.normalize()).abs().min(1.0);
            (n, cos.acos().to_degrees())
        })
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .unwrap_or_default()
}

/// Solid angle (sr) that the directions of `points` from `centre` cover, from the occupied
/// cells of an equal-area grid on the unit sphere (20 bands of equal height × 40 sectors).
pub fn solid_angle(points: &[Vec3], centre: &Vec3) -> f64 {
    const BANDS: usize = 20;
    const SECTORS: usize = 40;
    let mut occupied = [false; BANDS * SECTORS];
    for p in points {
        let d = p - centre;
        let n = d.norm();
        if n == 0.0 {
            continue;
        }
        let z = (d.z / n).clamp(-1.0, 1.0);
        let band = (((z + 1.0) * 0.5 * BANDS as f64) as usize).min(BANDS - 1);
        let phi = d.y.atan2(d.x) + std::f64::consts::PI;
        let sector = ((phi / std::f64::consts::TAU * SECTORS as f64) as usize).min(SECTORS - 1);
        occupied[band * SECTORS + sector] = true;
    }
    let cell = 4.0 * std::f64::consts::PI / (BANDS * SECTORS) as f64;
    occupied.iter().filter(|&&o| o).count() as f64 * cell
}

/// A sphere measured for its figures, or the reason it cannot be.
struct SphereMeasured {
    fit: SphereFit,
    kept: Vec<Vec3>,
    left_out: usize,
    form: f64,
}

fn measure_sphere(
    s: &Searchable<'_>,
    found: &FoundSphere,
    name: &str,
    params: &VerifyParams,
) -> Result<SphereMeasured, String> {
    let pts: Vec<Vec3> = found.inliers.iter().map(|&j| s.points[j]).collect();
    let (fit, kept, left_out) = fit_leaving_out(&pts, fit_sphere, SphereFit::residual)
        .ok_or_else(|| format!("{name}: the sphere's points do not determine a sphere"))?;
    if kept.len() < params.min_points {
        return Err(format!(
            "{name}: only {} points on the sphere (at least {} needed)",
            kept.len(),
            params.min_points
        ));
    }
    let omega = solid_angle(&kept, &fit.centre);
    if omega < params.min_solid_angle {
        return Err(format!(
            "{name}: only {omega:.2} sr of the sphere was seen (at least {:.2} sr needed): \
             too little of it is measured to fix its centre and size",
            params.min_solid_angle
        ));
    }
    let residuals: Vec<f64> = kept.iter().map(|p| fit.residual(p)).collect();
    let form = range(residuals.iter().copied());
    // Neighbouring points share part of their error: the fit's uncertainties count it.
    let inflation = correlation_inflation(&kept, &residuals, omega * fit.radius * fit.radius);
    let mut fit = fit;
    fit.radius_uncertainty *= inflation.sqrt();
    fit.centre_uncertainty *= inflation.sqrt();
    Ok(SphereMeasured {
        fit,
        kept,
        left_out,
        form,
    })
}

fn sphere_map(file: String, title: String, m: &SphereMeasured, scale: f64) -> ResidualMap {
    // View along the mean direction of the seen points: the cap faces the reader.
    let mean = m
        .kept
        .iter()
        .fold(Vec3::zeros(), |a, p| a + (p - m.fit.centre).normalize());
    let view = if mean.norm() > 1e-9 {
        mean.normalize()
    } else {
        Vec3::z()
    };
    let e1 = if view.x.abs() < 0.9 {
        view.cross(&Vec3::x()).normalize()
    } else {
        view.cross(&Vec3::y()).normalize()
    };
    let e2 = view.cross(&e1);
    ResidualMap {
        file,
        title,
        uv: m
            .kept
            .iter()
            .map(|p| {
                let d = p - m.fit.centre;
                [d.dot(&e1), d.dot(&e2)]
            })
            .collect(),
        residual: m.kept.iter().map(|p| m.fit.residual(p)).collect(),
        scale,
        disc_radius: Some(m.fit.radius),
    }
}

fn probing(
    cloud: &MeasuredCloud,
    index: usize,
    sphere: &SphereArtefact,
    mpe: &Mpe,
    volume: Option<&Volume>,
    params: &VerifyParams,
) -> (Figure, Figure, Vec<ResidualMap>) {
    let label = format!("sphere {index}");
    let s = Searchable::new(&cloud.points);
    let radius = 0.5 * sphere.diameter;
    let found = find::spheres(&s, radius, params.radius_tolerance, params.min_points, 4);
    let fail = |reason: String, centre: Option<Vec3>| {
        let p = position(label.clone(), centre, volume);
        (
            not_measured(
                &cloud.name,
                p.clone(),
                sphere.form,
                mpe.probing_form,
                reason.clone(),
            ),
            not_measured(&cloud.name, p, sphere.diameter, mpe.probing_size, reason),
            Vec::new(),
        )
    };
    let Some(best) = found.first() else {
        return fail(
            format!(
                "no sphere of {} mm diameter (±{:.0} %) found in the cloud's {} points",
                sphere.diameter,
                100.0 * params.radius_tolerance,
                cloud.points.len()
            ),
            None,
        );
    };
    let m = match measure_sphere(&s, best, &label, params) {
        Ok(m) => m,
        Err(reason) => return fail(reason, Some(best.fit.centre)),
    };
    let u_d = 2.0 * m.fit.radius_uncertainty;
    let p = position(label.clone(), Some(m.fit.centre), volume);
    let file = format!("sphere-{index}.png");
    let d = 2.0 * m.fit.radius;
    let pf = measured(
        &cloud.name,
        p.clone(),
        m.form,
        sphere.form,
        m.form - sphere.form,
        mpe.probing_form,
        m.kept.len(),
        m.left_out,
        Some(file.clone()),
        None,
    );
    // PF is the residuals' range whatever the cap; PS needs a diameter the points pin.
    let ps = if u_d > params.max_uncertainty_share * mpe.probing_size {
        let reason = format!(
            "{label}: the seen part of the sphere pins its diameter only to ±{u_d:.3} mm \
             (standard uncertainty, the error neighbouring points share counted), more than \
             {:.0} % of the PS limit {} mm",
            100.0 * params.max_uncertainty_share,
            mpe.probing_size
        );
        Figure {
            points: m.kept.len(),
            left_out: m.left_out,
            fit_uncertainty: Some(u_d),
            ..not_measured(&cloud.name, p, sphere.diameter, mpe.probing_size, reason)
        }
    } else {
        measured(
            &cloud.name,
            p,
            d,
            sphere.diameter,
            d - sphere.diameter,
            mpe.probing_size,
            m.kept.len(),
            m.left_out,
            Some(file.clone()),
            Some(u_d),
        )
    };
    let map = sphere_map(
        file,
        format!("{label}: radial residuals, PF {:.3} mm", m.form),
        &m,
        0.5 * mpe.probing_form,
    );
    (pf, ps, vec![map])
}

fn ball_bar(
    cloud: &MeasuredCloud,
    index: usize,
    bar: &BallBar,
    mpe: &Mpe,
    volume: Option<&Volume>,
    params: &VerifyParams,
) -> (Figure, Vec<ResidualMap>) {
    let label = format!("bar {index}");
    let limit = mpe.sphere_spacing.at(bar.spacing);
    let fail = |reason: String, centre: Option<Vec3>| {
        (
            not_measured(
                &cloud.name,
                position(label.clone(), centre, volume),
                bar.spacing,
                limit,
                reason,
            ),
            Vec::new(),
        )
    };
    let s = Searchable::new(&cloud.points);
    let (ra, rb) = (0.5 * bar.diameter_a, 0.5 * bar.diameter_b);
    let a_list = find::spheres(&s, ra, params.radius_tolerance, params.min_points, 6);
    let same = (ra - rb).abs() <= params.radius_tolerance * ra.min(rb);
    let b_list = if same {
        a_list.clone()
    } else {
        find::spheres(&s, rb, params.radius_tolerance, params.min_points, 6)
    };
    let tol = (params.spacing_tolerance * bar.spacing).max(2.0);
    // Of the pairs the calibrated spacing allows, the best supported (the smaller sphere's
    // points): a stray fit on clutter near a true sphere must not win by a closer distance.
    let mut best: Option<(usize, usize, usize)> = None;
    for (i, a) in a_list.iter().enumerate() {
        for (j, b) in b_list.iter().enumerate() {
            if same && i == j {
                continue;
            }
            let miss = ((a.fit.centre - b.fit.centre).norm() - bar.spacing).abs();
            let support = a.inliers.len().min(b.inliers.len());
            if miss <= tol && best.is_none_or(|(s, _, _)| support > s) {
                best = Some((support, i, j));
            }
        }
    }
    let Some((_, i, j)) = best else {
        let found = if same {
            format!("{} spheres of {} mm", a_list.len(), bar.diameter_a)
        } else {
            format!(
                "{} spheres of {} mm and {} of {} mm",
                a_list.len(),
                bar.diameter_a,
                b_list.len(),
                bar.diameter_b
            )
        };
        return fail(
            format!(
                "the bar's two spheres were not both found: {found} in the cloud, no pair \
                 {} mm (±{tol:.1} mm) apart",
                bar.spacing
            ),
            a_list.first().or(b_list.first()).map(|f| f.fit.centre),
        );
    };
    let ma = measure_sphere(&s, &a_list[i], &format!("{label}, sphere A"), params);
    let mb = measure_sphere(&s, &b_list[j], &format!("{label}, sphere B"), params);
    let mid = 0.5 * (a_list[i].fit.centre + b_list[j].fit.centre);
    let (ma, mb) = match (ma, mb) {
        (Ok(a), Ok(b)) => (a, b),
        (Err(e), _) | (_, Err(e)) => return fail(e, Some(mid)),
    };
    let axis = mb.fit.centre - ma.fit.centre;
    let length = axis.norm();
    let u = (ma.fit.centre_uncertainty.powi(2) + mb.fit.centre_uncertainty.powi(2)).sqrt();
    if u > params.max_uncertainty_share * limit {
        return fail(
            format!(
                "{label}: the seen parts of the spheres pin their centres only to ±{u:.3} mm \
                 (standard uncertainty), more than {:.0} % of the SD limit {limit:.3} mm",
                100.0 * params.max_uncertainty_share
            ),
            Some(mid),
        );
    }
    let mut p = position(
        label.clone(),
        Some(0.5 * (ma.fit.centre + mb.fit.centre)),
        volume,
    );
    let dir = axis / length;
    p.direction = Some([dir.x, dir.y, dir.z]);
    if let Some(v) = volume {
        let (name, angle) = along(&dir, v);
        p.along = Some(format!("{name} ({angle:.0}°)"));
    }
    let (fa, fb) = (format!("bar-{index}-a.png"), format!("bar-{index}-b.png"));
    let points = ma.kept.len() + mb.kept.len();
    let figure = measured(
        &cloud.name,
        p,
        length,
        bar.spacing,
        length - bar.spacing,
        limit,
        points,
        ma.left_out + mb.left_out,
        Some(fa.clone()),
        Some(u),
    );
    let maps = vec![
        sphere_map(
            fa,
            format!("{label}, sphere A: radial residuals"),
            &ma,
            0.5 * mpe.probing_form,
        ),
        sphere_map(
            fb,
            format!("{label}, sphere B: radial residuals"),
            &mb,
            0.5 * mpe.probing_form,
        ),
    ];
    (figure, maps)
}

fn flat_figure(
    cloud: &MeasuredCloud,
    index: usize,
    flat: &PlaneArtefact,
    limit: f64,
    volume: Option<&Volume>,
    params: &VerifyParams,
) -> (Figure, Vec<ResidualMap>) {
    let label = format!("flat {index}");
    let fail = |reason: String, centre: Option<Vec3>| {
        (
            not_measured(
                &cloud.name,
                position(label.clone(), centre, volume),
                flat.flatness,
                limit,
                reason,
            ),
            Vec::new(),
        )
    };
    let s = Searchable::new(&cloud.points);
    let regions = find::planes(&s, 8);
    let fits = |r: &find::FoundPlane| {
        r.extent[0] <= 1.1 * flat.length + 2.0 && r.extent[1] <= 1.1 * flat.width + 2.0
    };
    let Some(region) = regions
        .iter()
        .filter(|r| fits(r))
        .max_by(|a, b| a.area.total_cmp(&b.area))
    else {
        let seen: Vec<String> = regions
            .iter()
            .take(3)
            .map(|r| format!("{:.0} x {:.0} mm", r.extent[0], r.extent[1]))
            .collect();
        return fail(
            format!(
                "no flat of {} x {} mm found; the planar regions in the cloud are {}",
                flat.length,
                flat.width,
                if seen.is_empty() {
                    "none".to_string()
                } else {
                    format!("{} (larger than the flat)", seen.join(", "))
                }
            ),
            None,
        );
    };
    let share = (region.area / (flat.length * flat.width)).min(1.0);
    if share < params.min_area_share {
        return fail(
            format!(
                "only {:.0} % of the {} x {} mm flat was measured (at least {:.0} % needed): it is \
                 out of view, occluded or shadowed in part",
                100.0 * share,
                flat.length,
                flat.width,
                100.0 * params.min_area_share
            ),
            Some(region.fit.point),
        );
    }
    let pts: Vec<Vec3> = region.inliers.iter().map(|&j| s.points[j]).collect();
    let Some((fit, kept, left_out)) = fit_leaving_out(&pts, fit_plane, PlaneFit::residual) else {
        return fail("the flat's points do not determine a plane".into(), None);
    };
    if kept.len() < params.min_points {
        return fail(
            format!(
                "only {} points on the flat (at least {} needed)",
                kept.len(),
                params.min_points
            ),
            Some(fit.point),
        );
    }
    let f = range(kept.iter().map(|p| fit.residual(p)));
    let (u, v) = find::in_plane_axes(&kept, &fit);
    let mut p = position(label.clone(), Some(fit.point), volume);
    p.direction = Some([u.x, u.y, u.z]);
    p.normal = Some([fit.normal.x, fit.normal.y, fit.normal.z]);
    if let Some(vol) = volume {
        let (name, angle) = along(&u, vol);
        p.along = Some(format!("{name} ({angle:.0}°)"));
    }
    let file = format!("flat-{index}.png");
    let figure = measured(
        &cloud.name,
        p,
        f,
        flat.flatness,
        f - flat.flatness,
        limit,
        kept.len(),
        left_out,
        Some(file.clone()),
        None,
    );
    let map = ResidualMap {
        file,
        title: format!("{label}: distances from the least-squares plane, F {f:.3} mm"),
        uv: kept
            .iter()
            .map(|q| {
                let d = q - fit.point;
                [d.dot(&u), d.dot(&v)]
            })
            .collect(),
        residual: kept.iter().map(|q| fit.residual(q)).collect(),
        scale: 0.5 * limit,
        disc_radius: None,
    };
    (figure, vec![map])
}

/// Whether the measured positions cover the volume as VDI/VDE 2634-2 recommends: the bar in
/// at least 7 positions including the volume's four space diagonals, the flat in at least 6
/// positions in more than one orientation, the sphere in at least 10 positions spread over
/// both halves of the volume along every axis, and every artefact inside the volume.
fn coverage(
    artefacts: &Artefacts,
    bars: &[Figure],
    flats: &[Figure],
    spheres: &[Figure],
) -> Coverage {
    let mut missing = Vec::new();
    let Some(volume) = &artefacts.volume else {
        return Coverage {
            acceptance_test: false,
            kind: "spot check".into(),
            missing: vec![
                "no calibrated volume given ([volume] in the artefacts file): the positions \
                 cannot be judged against it"
                    .into(),
            ],
            volume_diagonal: None,
        };
    };
    let ok = |f: &&Figure| f.status != Status::NotMeasured;
    if artefacts.ball_bar.is_some() {
        let measured: Vec<&Figure> = bars.iter().filter(ok).collect();
        if measured.len() < 7 {
            missing.push(format!(
                "the ball bar was measured in {} positions; the guideline asks for 7",
                measured.len()
            ));
        }
        for k in 1..=4 {
            let name = format!("space diagonal {k} ");
            let covered = measured.iter().any(|f| {
                f.position
                    .along
                    .as_deref()
                    .is_some_and(|a| a.starts_with(&name) && angle_of(a) <= 15.0)
            });
            if !covered {
                missing.push(format!(
                    "no ball-bar position along the volume's space diagonal {k} (within 15°)"
                ));
            }
        }
    }
    if artefacts.plane.is_some() {
        let measured: Vec<&Figure> = flats.iter().filter(ok).collect();
        if measured.len() < 6 {
            missing.push(format!(
                "the flat was measured in {} positions; the guideline asks for 6",
                measured.len()
            ));
        }
        let normals: Vec<Vec3> = measured
            .iter()
            .filter_map(|f| f.position.normal.map(Vec3::from))
            .collect();
        let tilted = normals.iter().any(|a| {
            normals
                .iter()
                .any(|b| a.dot(b).abs() < 30f64.to_radians().cos())
        });
        if !tilted {
            missing
                .push("the flat was measured in one orientation only (normals within 30°)".into());
        }
    }
    if artefacts.sphere.is_some() {
        let measured: Vec<&Figure> = spheres.iter().filter(ok).collect();
        if measured.len() < 10 {
            missing.push(format!(
                "the sphere was measured in {} positions; the guideline asks for 10",
                measured.len()
            ));
        }
        for (k, axis) in ["x", "y", "z"].iter().enumerate() {
            let lower = measured
                .iter()
                .any(|f| f.position.in_volume.is_some_and(|u| u[k] < 0.5));
            let upper = measured
                .iter()
                .any(|f| f.position.in_volume.is_some_and(|u| u[k] >= 0.5));
            if !(lower && upper) {
                missing.push(format!(
                    "the sphere positions do not reach both halves of the volume along {axis}"
                ));
            }
        }
    }
    for f in bars.iter().chain(flats).chain(spheres) {
        if f.position.inside == Some(false) {
            missing.push(format!(
                "{} lies outside the calibrated volume",
                f.position.label
            ));
        }
    }
    let acceptance_test = missing.is_empty();
    Coverage {
        acceptance_test,
        kind: if acceptance_test {
            "acceptance test".into()
        } else {
            "spot check".into()
        },
        missing,
        volume_diagonal: Some(volume.diagonal()),
    }
}

/// The angle in an `along` text (`space diagonal 2 (7°)`).
fn angle_of(along: &str) -> f64 {
    along
        .rsplit_once('(')
        .and_then(|(_, a)| a.trim_end_matches(")").trim_end_matches('°').parse().ok())
        .unwrap_or(f64::INFINITY)
}

#[cfg(test)]
mod tests;
