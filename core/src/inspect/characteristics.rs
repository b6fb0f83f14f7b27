//! Geometric characteristics on CAD faces (ISO 1101), toleranced in a characteristics file and
//! measured on the registered cloud: flatness of a plane, profile of any surface (in the datum
//! frame the registration set up), and the diameter and position of a hole's or a boss's
//! cylinder. Each is measured from the points whose closest CAD triangle belongs to its faces
//! and says when too little of it was seen rather than report a figure the data do not pin.
//!
//! Form and profile are evaluated on cell means (square cells of `filter` mm, 2.5 mm by default:
//! the low-pass ISO 12781 and ISO 1660 apply before the zone is taken), so sensor noise does not
//! read as form: the zone of raw points grows with the noise and the point count. A cylinder is
//! fitted to its wall when the wall was seen over at least a third of its circumference (a
//! least-squares circle across the nominal axis); otherwise to its rim: the innermost (hole) or
//! outermost (boss) measured point in each angular sector of the surface around it, corrected for
//! the sampling gap (the first point lies on average s²/(L + s) inside the true edge, for point
//! spacing s over a sector of arc length L).

use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use std::path::Path;

use crate::io::read_toml;
use crate::mesh::step::{CadModel, FaceSurface};
use crate::mesh::{SignedDistance, TriangleMesh};
use crate::{Error, Result};

/// The ISO 1101 characteristic a [`CharacteristicSpec`] tolerances.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Kind {
    /// Flatness (⏥) of a plane: the distance of the two parallel planes closest together that
    /// hold the surface (minimum zone); `tolerance` is the zone's width.
    Flatness,
    /// Profile of a surface (⌓) in the datum frame: twice the largest distance of the surface
    /// from its nominal; `tolerance` is the zone's width, centred on the nominal.
    Profile,
    /// Diameter (⌀) of a cylindrical face: `lower` and `upper` are the limit deviations from
    /// the CAD's diameter.
    Diameter,
    /// Position (⌖) of a cylinder's axis in the datum frame: twice its distance from the
    /// nominal axis; `tolerance` is the diameter of the cylindrical zone.
    Position,
}

impl Kind {
    /// The characteristic's name and symbol as ISO 1101 gives them.
    pub fn iso_name(self) -> (&'static str, &'static str) {
        match self {
            Kind::Flatness => ("flatness", "⏥"),
            Kind::Profile => ("profile of a surface", "⌓"),
            Kind::Diameter => ("diameter", "⌀"),
            Kind::Position => ("position", "⌖"),
        }
    }
}

/// One `[[characteristic]]` of a characteristics file.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CharacteristicSpec {
    /// Name used in the report.
    pub name: String,
    /// What is toleranced.
    pub kind: Kind,
    /// The STEP faces (ADVANCED_FACE entity numbers) the characteristic is on.
    pub faces: Vec<u32>,
    /// Width of the tolerance zone, mm (flatness, profile, position).
    #[serde(default)]
    pub tolerance: Option<f64>,
    /// Lower limit deviation of a diameter, mm (negative: smaller than nominal).
    #[serde(default)]
    pub lower: Option<f64>,
    /// Upper limit deviation of a diameter, mm.
    #[serde(default)]
    pub upper: Option<f64>,
    /// Share of the feature that must be measured for a figure: of a surface's area, of a
    /// cylinder's circumference (default 0.5).
    #[serde(default)]
    pub min_coverage: Option<f64>,
    /// Cell of the low-pass applied before a form or profile zone is taken, mm (default 2.5).
    #[serde(default)]
    pub filter: Option<f64>,
    /// Band along a surface's boundary left out of form and profile, mm (default 1): what a
    /// moved neighbour, an edge's radius or a mixed pixel puts there is not the face's form.
    #[serde(default)]
    pub border: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct CharacteristicsFile {
    characteristic: Vec<CharacteristicSpec>,
}

/// A nominal cylinder: a point of its axis, the unit axis, radius, whether it is a hole
/// (material outside) and the axial extent of its face.
#[derive(Clone, Debug)]
struct Cylinder {
    origin: Vector3<f64>,
    axis: Vector3<f64>,
    radius: f64,
    hole: bool,
    extent: (f64, f64),
}

/// A characteristic resolved against its CAD model: the triangles of its faces (and, for a
/// cylinder, of the faces around it) and the nominal geometry.
#[derive(Clone, Debug)]
pub struct Characteristic {
    /// What the file says.
    pub spec: CharacteristicSpec,
    /// The CAD triangles of the characteristic's faces, and of the faces that touch them
    /// (sorted ids: memory follows the feature, not the model).
    on_faces: Vec<u32>,
    touching: Vec<u32>,
    cylinder: Option<Cylinder>,
    /// Area of the faces, mm², and an area-uniform sample of them.
    area: f64,
    samples: Vec<[f64; 3]>,
    /// Points along the faces' boundary, 0.25 mm apart.
    boundary: Vec<[f64; 3]>,
}

/// One characteristic's result.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct CharacteristicResult {
    /// Its name in the characteristics file.
    pub name: String,
    /// The ISO 1101 characteristic (`flatness`, `profile of a surface`, `diameter`, `position`).
    pub characteristic: String,
    /// Its symbol.
    pub symbol: String,
    /// The STEP faces it is on.
    pub faces: Vec<u32>,
    /// Nominal value, mm (a diameter; 0 for form, profile and position).
    pub nominal: f64,
    /// Measured value, mm (`None`: not measured).
    pub measured: Option<f64>,
    /// Lowest acceptable value, mm.
    pub lower_limit: f64,
    /// Highest acceptable value, mm.
    pub upper_limit: f64,
    /// Whether the measured value lies within the limits (`None`: not measured).
    pub in_tolerance: Option<bool>,
    /// Points the figure rests on.
    pub points: usize,
    /// Share of the feature measured: of its area, or of a cylinder's circumference.
    pub coverage: f64,
    /// How it was evaluated, in words.
    pub method: String,
    /// Position: the measured axis' offset from the nominal, CAD frame, mm.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub offset_mm: Option<[f64; 3]>,
    /// Why it was not measured.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub not_measured: Option<String>,
}

/// Read a characteristics file (`[[characteristic]]` tables, see [`CharacteristicSpec`]) and
/// resolve it against the STEP model whose faces it names.
pub fn load_characteristics(path: &Path, model: &CadModel) -> Result<Vec<Characteristic>> {
    let f: CharacteristicsFile = read_toml(path)?;
    resolve(&path.display().to_string(), f.characteristic, model)
}

/// Check characteristics and resolve them against `model`; `ctx` names their source in errors.
pub fn resolve(
    ctx: &str,
    specs: Vec<CharacteristicSpec>,
    model: &CadModel,
) -> Result<Vec<Characteristic>> {
    let mesh = &model.mesh;
    let mut out = Vec::with_capacity(specs.len());
    for (i, spec) in specs.into_iter().enumerate() {
        let field = |f: &str| format!("characteristic[{i}].{f}");
        let positive = |f: &str, v: Option<f64>, needed: bool| -> Result<()> {
            match v {
                Some(x) if !(x.is_finite() && x > 0.0) => Err(Error::invalid(
                    ctx,
                    field(f),
                    format!("{x} must be positive"),
                )),
                None if needed => Err(Error::invalid(
                    ctx,
                    field(f),
                    format!("is required for {}", spec.kind.iso_name().0),
                )),
                _ => Ok(()),
            }
        };
        if spec.faces.is_empty() {
            return Err(Error::invalid(ctx, field("faces"), "names no face"));
        }
        positive("tolerance", spec.tolerance, spec.kind != Kind::Diameter)?;
        positive("filter", spec.filter, false)?;
        if let Some(b) = spec.border {
            if !(b.is_finite() && b >= 0.0) {
                return Err(Error::invalid(
                    ctx,
                    field("border"),
                    format!("{b} must be zero or positive"),
                ));
            }
        }
        if let Some(c) = spec.min_coverage {
            if !(0.0..=1.0).contains(&c) {
                return Err(Error::invalid(
                    ctx,
                    field("min_coverage"),
                    format!("{c} must be within 0 … 1"),
                ));
            }
        }
        if spec.kind == Kind::Diameter {
            match (spec.lower, spec.upper) {
                (Some(l), Some(u)) if l.is_finite() && u.is_finite() && l < u => {}
                (Some(l), Some(u)) => {
                    return Err(Error::invalid(
                        ctx,
                        field("lower"),
                        format!("{l} … {u} is not a range (lower below upper, both finite)"),
                    ))
                }
                _ => {
                    return Err(Error::invalid(
                        ctx,
                        field("lower"),
                        "a diameter needs its limit deviations `lower` and `upper` (mm)",
                    ))
                }
            }
        }
        let on = model.triangles_of(&spec.faces, &format!("{ctx}: characteristic[{i}]"))?;
        let surfaces: Vec<&FaceSurface> = spec
            .faces
            .iter()
            .filter_map(|n| model.face(*n))
            .map(|k| &model.faces[k].surface)
            .collect();
        let kinds = || {
            surfaces
                .iter()
                .map(|s| s.kind())
                .collect::<Vec<_>>()
                .join(", ")
        };
        let cylinder = match spec.kind {
            Kind::Diameter | Kind::Position => {
                Some(cylinder_of(mesh, &on, &surfaces).ok_or_else(|| {
                    Error::invalid(
                        ctx,
                        field("faces"),
                        format!(
                            "{} needs one cylindrical face (or the faces of one cylinder); {:?} are {}",
                            spec.kind.iso_name().0,
                            spec.faces,
                            kinds()
                        ),
                    )
                })?)
            }
            Kind::Flatness => {
                if surfaces
                    .iter()
                    .any(|s| !matches!(s, FaceSurface::Plane { .. }))
                {
                    return Err(Error::invalid(
                        ctx,
                        field("faces"),
                        format!("flatness is of planes; {:?} are {}", spec.faces, kinds()),
                    ));
                }
                None
            }
            Kind::Profile => None,
        };
        let (on_faces, touching) = roles(mesh, &on);
        let (samples, area) = face_samples(mesh, &on);
        let boundary = boundary_points(mesh, &on);
        out.push(Characteristic {
            spec,
            on_faces,
            touching,
            cylinder,
            area,
            samples,
            boundary,
        });
    }
    Ok(out)
}

/// The nominal cylinder of the faces `on` (one cylinder, possibly split into several faces).
fn cylinder_of(mesh: &TriangleMesh, on: &[bool], surfaces: &[&FaceSurface]) -> Option<Cylinder> {
    let mut it = surfaces.iter().map(|s| match s {
        FaceSurface::Cylinder {
            origin,
            axis,
            radius,
        } => Some((*origin, *axis, *radius)),
        _ => None,
    });
    let (origin, axis, radius) = it.next()??;
    for s in it {
        let (o, a, r) = s?;
        let off = o - origin;
        if (r - radius).abs() > 1e-6 * radius.max(1.0)
            || a.cross(&axis).norm() > 1e-6
            || (off - axis * off.dot(&axis)).norm() > 1e-6 * radius.max(1.0)
        {
            return None;
        }
    }
    let axis = axis.try_normalize(1e-12)?;
    // Hole or boss: the faces' outward normals point towards the axis on a hole.
    let (mut toward, mut lo, mut hi) = (0.0, f64::INFINITY, f64::NEG_INFINITY);
    for t in (0..mesh.triangles.len()).filter(|&t| on[t]) {
        let [a, b, c] = mesh.corners(t);
        let n = (b - a).cross(&(c - a));
        let centre = (a + b + c) / 3.0;
        let q = centre - origin;
        let radial = q - axis * q.dot(&axis);
        toward += n.dot(&radial);
        for p in [a, b, c] {
            let h = (p - origin).dot(&axis);
            lo = lo.min(h);
            hi = hi.max(h);
        }
    }
    Some(Cylinder {
        origin,
        axis,
        radius,
        hole: toward < 0.0,
        extent: (lo, hi),
    })
}

impl Characteristic {
    /// 1 for a triangle of the characteristic's faces, 2 for one touching them, 0 else.
    fn role(&self, triangle: u32) -> u8 {
        if self.on_faces.binary_search(&triangle).is_ok() {
            1
        } else if self.touching.binary_search(&triangle).is_ok() {
            2
        } else {
            0
        }
    }
}

/// The triangles `on`, and those sharing a vertex with them: sorted ids.
fn roles(mesh: &TriangleMesh, on: &[bool]) -> (Vec<u32>, Vec<u32>) {
    let mut touched = vec![false; mesh.vertices.len()];
    for (t, tri) in mesh.triangles.iter().enumerate() {
        if on[t] {
            for &v in tri {
                touched[v as usize] = true;
            }
        }
    }
    let (mut faces, mut touching) = (Vec::new(), Vec::new());
    for (t, tri) in mesh.triangles.iter().enumerate() {
        if on[t] {
            faces.push(t as u32);
        } else if tri.iter().any(|&v| touched[v as usize]) {
            touching.push(t as u32);
        }
    }
    (faces, touching)
}

/// Points every 0.25 mm along the boundary of the triangles `on` (their edges used once).
fn boundary_points(mesh: &TriangleMesh, on: &[bool]) -> Vec<[f64; 3]> {
    let mut uses = std::collections::HashMap::<(u32, u32), u32>::new();
    for tri in mesh
        .triangles
        .iter()
        .zip(on)
        .filter(|(_, o)| **o)
        .map(|(t, _)| t)
    {
        for k in 0..3 {
            let (a, b) = (tri[k], tri[(k + 1) % 3]);
            *uses.entry((a.min(b), a.max(b))).or_default() += 1;
        }
    }
    let mut out = Vec::new();
    for ((a, b), n) in uses {
        if n != 1 {
            continue;
        }
        let (pa, pb) = (mesh.vertices[a as usize], mesh.vertices[b as usize]);
        let steps = ((pb - pa).norm() / 0.25).ceil().max(1.0) as usize;
        for i in 0..=steps {
            out.push((pa + (pb - pa) * (i as f64 / steps as f64)).into());
        }
    }
    out
}

/// An area-uniform sample of the triangles `on` (one point per ≈0.25 mm², 200 to 20 000 of
/// them) and their area.
fn face_samples(mesh: &TriangleMesh, on: &[bool]) -> (Vec<[f64; 3]>, f64) {
    // the faces' own triangles and vertices, not a copy of the model's
    let mut index = std::collections::HashMap::<u32, u32>::new();
    let mut sub = TriangleMesh::default();
    for tri in mesh
        .triangles
        .iter()
        .zip(on)
        .filter(|(_, o)| **o)
        .map(|(t, _)| t)
    {
        sub.triangles.push(tri.map(|v| {
            *index.entry(v).or_insert_with(|| {
                sub.vertices.push(mesh.vertices[v as usize]);
                (sub.vertices.len() - 1) as u32
            })
        }));
    }
    let area: f64 = (0..sub.triangles.len())
        .map(|t| {
            let [a, b, c] = sub.corners(t);
            0.5 * (b - a).cross(&(c - a)).norm()
        })
        .sum();
    let n = ((area / 0.25) as usize).clamp(200, 20_000);
    let (samples, _) = super::coverage::surface_samples(&sub, n);
    (samples.into_iter().map(|(p, _)| p).collect(), area)
}

/// A measured point near the characteristics' faces: position (CAD frame), signed deviation
/// and closest CAD triangle.
struct Near {
    p: Vector3<f64>,
    dev: f64,
    triangle: u32,
}

/// How far from its nominal a point may lie and still be taken as a measurement of the
/// characteristic's surface, mm: beyond it the point belongs to something else (a floor seen
/// through a hole, a fixture).
fn gate(c: &Characteristic) -> f64 {
    (4.0 * c.spec.tolerance.unwrap_or(0.0)).max(2.0)
}

/// Measure every characteristic on `points` (CAD frame, where the registration put them).
pub fn evaluate(
    points: &[[f64; 3]],
    cad: &SignedDistance,
    characteristics: &[Characteristic],
) -> Vec<CharacteristicResult> {
    if characteristics.is_empty() {
        return Vec::new();
    }
    // Only the points in the box around the characteristics' faces are queried.
    let mesh = cad.mesh();
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    let mut reach: f64 = 0.0;
    for c in characteristics {
        let pad = gate(c)
            + c.cylinder
                .as_ref()
                .map_or(0.0, |cyl| rim_reach(cyl.radius) + cyl.radius);
        reach = reach.max(pad);
        for &t in &c.on_faces {
            for p in mesh.corners(t as usize) {
                for k in 0..3 {
                    lo[k] = lo[k].min(p[k]);
                    hi[k] = hi[k].max(p[k]);
                }
            }
        }
    }
    let near: Vec<Near> = points
        .par_iter()
        .filter(|p| (0..3).all(|k| p[k] >= lo[k] - reach && p[k] <= hi[k] + reach))
        .filter_map(|p| {
            let p = Vector3::from(*p);
            let q = cad.query(&p)?;
            (!q.beyond_boundary).then_some(Near {
                p,
                dev: q.distance,
                triangle: q.triangle,
            })
        })
        .collect();
    characteristics.iter().map(|c| measure(c, &near)).collect()
}

fn measure(c: &Characteristic, near: &[Near]) -> CharacteristicResult {
    let (name, symbol) = c.spec.kind.iso_name();
    let tol = c.spec.tolerance.unwrap_or(0.0);
    let mut result = CharacteristicResult {
        name: c.spec.name.clone(),
        characteristic: name.into(),
        symbol: symbol.into(),
        faces: c.spec.faces.clone(),
        nominal: 0.0,
        measured: None,
        lower_limit: 0.0,
        upper_limit: tol,
        in_tolerance: None,
        points: 0,
        coverage: 0.0,
        method: String::new(),
        offset_mm: None,
        not_measured: None,
    };
    if let (Kind::Diameter, Some(cyl)) = (c.spec.kind, &c.cylinder) {
        let d = 2.0 * cyl.radius;
        result.nominal = d;
        result.lower_limit = d + c.spec.lower.unwrap_or(0.0);
        result.upper_limit = d + c.spec.upper.unwrap_or(0.0);
    }
    let minimum = c.spec.min_coverage.unwrap_or(0.5);
    let filter = c.spec.filter.unwrap_or(2.5);
    let g = gate(c);
    let border = c.spec.border.unwrap_or(1.0);
    let edges = (border > 0.0 && matches!(c.spec.kind, Kind::Flatness | Kind::Profile))
        .then(|| crate::spatial::KdTree::new(&c.boundary));
    // the border's reach, less half the boundary points' spacing
    let clear = (border - 0.125).max(0.0).powi(2);
    let face: Vec<&Near> = near
        .iter()
        .filter(|n| c.role(n.triangle) == 1 && n.dev.abs() <= g)
        .collect();
    let on: Vec<&Near> = face
        .iter()
        .copied()
        .filter(|n| {
            edges
                .as_ref()
                .is_none_or(|t| t.nearest_within(&n.p.into(), clear).is_none())
        })
        .collect();
    let outcome = match c.spec.kind {
        Kind::Flatness | Kind::Profile => {
            let pts: Vec<[f64; 3]> = face.iter().map(|n| n.p.into()).collect();
            let cov =
                super::coverage::coverage_of(&c.samples, c.area, &pts, minimum, String::new());
            result.coverage = cov.fraction;
            result.points = on.len();
            if cov.fraction < minimum {
                Err(format!(
                    "{:.0} % of its {:.0} mm² was measured ({:.0} % needed)",
                    100.0 * cov.fraction,
                    c.area,
                    100.0 * minimum
                ))
            } else if c.spec.kind == Kind::Flatness {
                flatness(&on, filter).map(|(v, cells)| {
                    result.method = format!(
                        "minimum zone of {cells} cell means ({filter} mm cells) over {:.0} % of the face",
                        100.0 * cov.fraction
                    );
                    v
                })
            } else {
                profile(&on, filter).map(|(v, cells)| {
                    result.method = format!(
                        "twice the largest deviation of {cells} cell means ({filter} mm cells) from the nominal, in the datum frame, over {:.0} % of the surface",
                        100.0 * cov.fraction
                    );
                    v
                })
            }
        }
        Kind::Diameter | Kind::Position => {
            let cyl = c.cylinder.as_ref().expect("resolved with its cylinder");
            match fit_cylinder(cyl, c, near, minimum) {
                Ok(fit) => {
                    result.points = fit.points;
                    result.coverage = fit.coverage;
                    result.method = fit.method.clone();
                    if c.spec.kind == Kind::Diameter {
                        Ok(2.0 * fit.radius)
                    } else {
                        result.offset_mm = Some(fit.offset.into());
                        Ok(2.0 * fit.offset.norm())
                    }
                }
                Err((points, coverage, why)) => {
                    result.points = points;
                    result.coverage = coverage;
                    Err(why)
                }
            }
        }
    };
    match outcome {
        Ok(v) => {
            result.measured = Some(v);
            result.in_tolerance = Some(v >= result.lower_limit && v <= result.upper_limit);
        }
        Err(why) => result.not_measured = Some(why),
    }
    result
}

/// Means of `value` over square cells of `size` in the plane (u, v): (u, v, mean) of the
/// cells holding at least a quarter of the median cell's points (and 3).
fn cell_means(uvh: &[(f64, f64, f64)], size: f64) -> Vec<(f64, f64, f64)> {
    let mut cells = std::collections::HashMap::<(i64, i64), (f64, f64, f64, usize)>::new();
    for &(u, v, h) in uvh {
        let e = cells
            .entry(((u / size).floor() as i64, (v / size).floor() as i64))
            .or_default();
        e.0 += u;
        e.1 += v;
        e.2 += h;
        e.3 += 1;
    }
    let mut counts: Vec<usize> = cells.values().map(|c| c.3).collect();
    counts.sort_unstable();
    let least = (counts.get(counts.len() / 2).copied().unwrap_or(0) / 4).max(3);
    cells
        .values()
        .filter(|c| c.3 >= least)
        .map(|c| {
            let n = c.3 as f64;
            (c.0 / n, c.1 / n, c.2 / n)
        })
        .collect()
}

/// Two unit vectors spanning the plane normal to `n`.
fn basis(n: &Vector3<f64>) -> (Vector3<f64>, Vector3<f64>) {
    let seed = if n.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let e1 = (seed - n * seed.dot(n)).normalize();
    (e1, n.cross(&e1))
}

/// Fewest cells a zone is taken over.
const MIN_CELLS: usize = 8;

/// Flatness: the minimum zone of the cell means' heights over the least-squares plane (the
/// plane's tilt refined by Lawson's iteration towards the Chebyshev fit).
fn flatness(on: &[&Near], filter: f64) -> std::result::Result<(f64, usize), String> {
    let pts: Vec<Vector3<f64>> = on.iter().map(|n| n.p).collect();
    let fit = crate::verify::fit::fit_plane(&pts)
        .ok_or("fewer than 3 points on the face, or all on one line")?;
    let (c, n) = (fit.point, fit.normal);
    let (e1, e2) = basis(&n);
    let uvh: Vec<(f64, f64, f64)> = pts
        .iter()
        .map(|p| {
            let d = p - c;
            (d.dot(&e1), d.dot(&e2), d.dot(&n))
        })
        .collect();
    let cells = cell_means(&uvh, filter);
    if cells.len() < MIN_CELLS {
        return Err(format!(
            "{} cells of {filter} mm hold enough points ({MIN_CELLS} needed)",
            cells.len()
        ));
    }
    Ok((minimum_zone(&cells), cells.len()))
}

/// Width of the narrowest slab h = a + b u + c v ± w/2 holding every (u, v, h): Lawson's
/// iteratively reweighted least squares, the best zone met along the way.
fn minimum_zone(cells: &[(f64, f64, f64)]) -> f64 {
    let zone = |b: f64, c: f64| {
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for &(u, v, h) in cells {
            let r = h - b * u - c * v;
            lo = lo.min(r);
            hi = hi.max(r);
        }
        hi - lo
    };
    let mut w = vec![1.0 / cells.len() as f64; cells.len()];
    let mut best = zone(0.0, 0.0);
    for _ in 0..200 {
        let mut m = Matrix3::zeros();
        let mut rhs = Vector3::zeros();
        for (&(u, v, h), wi) in cells.iter().zip(&w) {
            let x = Vector3::new(1.0, u, v);
            m += x * x.transpose() * *wi;
            rhs += x * (h * wi);
        }
        let Some(s) = m.try_inverse().map(|i| i * rhs) else {
            break;
        };
        best = best.min(zone(s[1], s[2]));
        let mut total = 0.0;
        for (&(u, v, h), wi) in cells.iter().zip(w.iter_mut()) {
            *wi *= (h - s[0] - s[1] * u - s[2] * v).abs();
            total += *wi;
        }
        if !(total > 0.0 && total.is_finite()) {
            break;
        }
        w.iter_mut().for_each(|wi| *wi /= total);
    }
    best
}

/// Profile: twice the largest |deviation| among cell means (cubic cells of `filter` mm).
fn profile(on: &[&Near], filter: f64) -> std::result::Result<(f64, usize), String> {
    let mut cells = std::collections::HashMap::<[i64; 3], (f64, usize)>::new();
    for n in on {
        let key = [0, 1, 2].map(|k| (n.p[k] / filter).floor() as i64);
        let e = cells.entry(key).or_default();
        e.0 += n.dev;
        e.1 += 1;
    }
    let mut counts: Vec<usize> = cells.values().map(|c| c.1).collect();
    counts.sort_unstable();
    let least = (counts.get(counts.len() / 2).copied().unwrap_or(0) / 4).max(3);
    let means: Vec<f64> = cells
        .values()
        .filter(|c| c.1 >= least)
        .map(|c| c.0 / c.1 as f64)
        .collect();
    if means.len() < MIN_CELLS {
        return Err(format!(
            "{} cells of {filter} mm hold enough points ({MIN_CELLS} needed)",
            means.len()
        ));
    }
    Ok((
        2.0 * means.iter().fold(0.0f64, |m, d| m.max(d.abs())),
        means.len(),
    ))
}

/// How far outside a cylinder's radius its rim is searched, mm.
fn rim_reach(radius: f64) -> f64 {
    (0.5 * radius).clamp(2.0, 6.0)
}

/// Share of the circumference a wall must be seen over to be fitted.
const WALL_SPAN: f64 = 1.0 / 3.0;

struct CylinderFit {
    radius: f64,
    offset: Vector3<f64>,
    points: usize,
    coverage: f64,
    method: String,
}

/// The measured cylinder: fitted to the wall, else to the rim (module documentation).
#[allow(clippy::type_complexity)]
fn fit_cylinder(
    cyl: &Cylinder,
    c: &Characteristic,
    near: &[Near],
    minimum: f64,
) -> std::result::Result<CylinderFit, (usize, f64, String)> {
    let (e1, e2) = basis(&cyl.axis);
    let flat = |p: &Vector3<f64>| {
        let d = p - cyl.origin;
        (d.dot(&e1), d.dot(&e2), d.dot(&cyl.axis))
    };
    let g = (c.spec.tolerance.unwrap_or(0.0) + 1.0).min(0.5 * cyl.radius);
    // the wall away from its ends, where a moved or grown neighbour's points may lie closest
    let end = (0.25 * (cyl.extent.1 - cyl.extent.0)).min(0.5);
    let wall: Vec<(f64, f64)> = near
        .iter()
        .filter(|n| c.role(n.triangle) == 1 && n.dev.abs() <= g)
        .filter_map(|n| {
            let (u, v, h) = flat(&n.p);
            (h > cyl.extent.0 + end && h < cyl.extent.1 - end).then_some((u, v))
        })
        .collect();
    let wall_span = span(&wall);
    let result = |(cu, cv, r): (f64, f64, f64), points, coverage, method| CylinderFit {
        radius: r,
        offset: e1 * cu + e2 * cv,
        points,
        coverage,
        method,
    };
    if wall.len() >= 30 && wall_span >= WALL_SPAN {
        if let Some(fit) = circle(&wall, cyl.radius) {
            return Ok(result(
                fit,
                wall.len(),
                wall_span,
                format!(
                    "least-squares circle across the nominal axis through {} wall points over {:.0}° of the circumference",
                    wall.len(),
                    360.0 * wall_span
                ),
            ));
        }
    }
    // The rim: where the surface around the cylinder ends, sector by sector.
    let reach = rim_reach(cyl.radius);
    let inside = 1.0f64.min(0.3 * cyl.radius);
    // The entry surfaces lie beyond the cylinder face's ends; its wall lies between them.
    let margin = 0.2f64.min(0.1 * (cyl.extent.1 - cyl.extent.0));
    let (lo, hi) = (cyl.extent.0 - reach, cyl.extent.1 + reach);
    // (angle, distance beyond the nominal radius, distance from the nearer end's level)
    let mut band: Vec<(f64, f64, f64)> = Vec::new();
    for n in near
        .iter()
        .filter(|n| c.role(n.triangle) != 0 && n.dev.abs() <= 2.0)
    {
        let (u, v, h) = flat(&n.p);
        if h < lo || h > hi {
            continue;
        }
        let rho = u.hypot(v);
        let beyond = if cyl.hole {
            rho - cyl.radius
        } else {
            cyl.radius - rho
        };
        // A point closest to the wall is the wall's (left out) unless it lies nearer the
        // level of an end than the wall: the entry surface where the hole has moved.
        let into = (h - cyl.extent.0).min(cyl.extent.1 - h);
        let wall_point = if c.role(n.triangle) == 1 {
            into > beyond.abs()
        } else {
            into > margin
        };
        if !wall_point && (-inside..=reach).contains(&beyond) {
            let level = (h - cyl.extent.0).abs().min((h - cyl.extent.1).abs());
            band.push((v.atan2(u), beyond, level));
        }
    }
    // Sectors of about three point spacings of arc.
    let band_area = std::f64::consts::PI
        * ((cyl.radius + reach).powi(2) - (cyl.radius - inside).max(0.0).powi(2));
    let spacing = (band_area * 0.5 / band.len().max(1) as f64).sqrt();
    let sectors = ((std::f64::consts::TAU * cyl.radius / (3.0 * spacing).max(0.5)).round()
        as usize)
        .clamp(12, 180);
    let dtheta = std::f64::consts::TAU / sectors as f64;
    let mut per_sector: Vec<Vec<(f64, f64)>> = vec![Vec::new(); sectors];
    let mut angle = vec![0.0f64; sectors];
    for &(a, beyond, level) in &band {
        let k = (((a + std::f64::consts::PI) / dtheta) as usize).min(sectors - 1);
        per_sector[k].push((beyond, level));
        angle[k] = -std::f64::consts::PI + (k as f64 + 0.5) * dtheta;
    }
    // In each sector the edge is the lower end of the points' distance beyond the nominal:
    // the nearest point less the mean spacing g of the sorted distances (the unbiased estimate
    // of a uniform distribution's end), so the point density sets the correction. A camera
    // samples a lattice, not random points: with c of its columns crossing a sector's edge at
    // independent phases, the nearest lies c/(c + 1) g from the edge on average.
    let columns = (cyl.radius * dtheta / spacing).max(1.0);
    let lattice = columns / (columns + 1.0);
    let mut rim: Vec<(f64, f64)> = Vec::new();
    let mut hidden = 0;
    for (values, a) in per_sector.iter_mut().zip(&angle) {
        if values.len() < 3 {
            continue;
        }
        values.sort_by(|p, q| p.0.total_cmp(&q.0));
        // The nearest point is the bore's edge only where it lies at the level of the
        // cylinder's end: a countersink or chamfer turned away from the sensor hides the edge,
        // and its nearest seen point lies above it and outside.
        if values[0].1 > spacing.max(0.2) {
            hidden += 1;
            continue;
        }
        let n = values.len() as f64;
        let edge = values[0].0 - lattice * (values[values.len() - 1].0 - values[0].0) / (n - 1.0);
        let rho = if cyl.hole {
            cyl.radius + edge
        } else {
            cyl.radius - edge
        };
        rim.push((rho * a.cos(), rho * a.sin()));
    }
    let filled = rim.len() as f64 / sectors as f64;
    let need = minimum.max(0.5);
    if filled < need {
        return Err((
            wall.len().max(band.len()),
            wall_span.max(filled),
            format!(
                "its wall was seen over {:.0}° of the circumference ({:.0}° needed) and its rim over {:.0} % ({:.0} % needed)",
                360.0 * wall_span,
                360.0 * WALL_SPAN,
                100.0 * filled,
                100.0 * need
            ),
        ));
    }
    let Some(fit) = circle(&rim, cyl.radius) else {
        return Err((band.len(), filled, "the rim points fit no circle".into()));
    };
    Ok(result(
        fit,
        band.len(),
        filled,
        format!(
            "least-squares circle through the rim's edge in {} sectors ({:.0} % of the circumference{}), from {} points of the surface around it ({spacing:.2} mm apart)",
            rim.len(),
            100.0 * filled,
            if hidden > 0 {
                format!("; {hidden} sectors left out where a chamfer hid the edge")
            } else {
                String::new()
            },
            band.len()
        ),
    ))
}

/// Share of the circumference (around the origin) the points cover: one less the largest
/// angular gap between them.
fn span(uv: &[(f64, f64)]) -> f64 {
    if uv.len() < 2 {
        return 0.0;
    }
    let mut a: Vec<f64> = uv.iter().map(|(u, v)| v.atan2(*u)).collect();
    a.sort_by(f64::total_cmp);
    let mut gap = a[0] + std::f64::consts::TAU - a[a.len() - 1];
    for w in a.windows(2) {
        gap = gap.max(w[1] - w[0]);
    }
    1.0 - gap / std::f64::consts::TAU
}

/// Geometric least-squares circle (Gauss-Newton from the nominal: centre at the origin,
/// radius `r0`): (centre u, centre v, radius).
fn circle(uv: &[(f64, f64)], r0: f64) -> Option<(f64, f64, f64)> {
    if uv.len() < 3 {
        return None;
    }
    let (mut cu, mut cv, mut r) = (0.0, 0.0, r0);
    for _ in 0..50 {
        let mut m = Matrix3::zeros();
        let mut rhs = Vector3::zeros();
        for &(u, v) in uv {
            let (du, dv) = (u - cu, v - cv);
            let d = du.hypot(dv).max(1e-12);
            // residual d − r; derivatives w.r.t. (cu, cv, r)
            let j = Vector3::new(-du / d, -dv / d, -1.0);
            m += j * j.transpose();
            rhs -= j * (d - r);
        }
        let step = m.try_inverse()? * rhs;
        cu += step[0];
        cv += step[1];
        r += step[2];
        if step.norm() < 1e-9 {
            break;
        }
    }
    (r.is_finite() && r > 0.0 && cu.hypot(cv) < r0.max(1.0) * 2.0).then_some((cu, cv, r))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn minimum_zone_of_a_tilted_plane_with_a_bump() {
        // a tilted plane (its tilt is not form) with one cell raised 0.1 above it
        let mut cells = Vec::new();
        for j in 0..20 {
            for i in 0..20 {
                let (u, v) = (i as f64, j as f64);
                let bump = if i == 10 && j == 10 { 0.1 } else { 0.0 };
                cells.push((u, v, 0.01 * u - 0.02 * v + bump));
            }
        }
        let z = minimum_zone(&cells);
        assert!((z - 0.1).abs() < 1e-6, "{z}");
    }

    #[test]
    fn circle_through_an_arc() {
        let uv: Vec<(f64, f64)> = (0..60)
            .map(|k| {
                let a = 0.5 + k as f64 * 0.03;
                (0.3 + 5.2 * a.cos(), -0.1 + 5.2 * a.sin())
            })
            .collect();
        let (cu, cv, r) = circle(&uv, 5.0).expect("fit");
        assert!((cu - 0.3).abs() < 1e-9 && (cv + 0.1).abs() < 1e-9 && (r - 5.2).abs() < 1e-9);
        assert!((span(&uv) - 1.77 / std::f64::consts::TAU).abs() < 0.01);
    }
}
