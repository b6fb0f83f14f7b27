//! Datums as inspection planners write them: surface regions (Ch. 5.3.3–5.3.5: fitted, weighted,
//! never absorbing the deformation elsewhere), and a 3-2-1 / RPS datum reference frame whose
//! levels each pin a number of rigid degrees of freedom from features measured in the cloud
//! (surface patches, RPS surface points, hole centres, slots, edge lines).

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::io::read_toml;
use crate::{Error, Result};

/// What a datum is measured from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Feature {
    /// The measured surface within `radius` of `position`, point-to-plane against the CAD: pins
    /// along its normals (a patch: one translation and, if wide, two tilts).
    #[default]
    Surface,
    /// An RPS surface point: where the measured surface crosses the line through `position`
    /// along `direction` (default the CAD normal there); pins that one direction.
    Point,
    /// A hole's centre from its edge in the cloud (`diameter`; axis `direction`, default the
    /// CAD normal): pins the two directions across the axis.
    Hole,
    /// A slot's centre line (`width`, `length`, long axis `direction`): pins the direction
    /// across the slot.
    Slot,
    /// An outer edge line of the part (`direction`: outward, in the surface): pins that
    /// direction.
    Edge,
}

impl Feature {
    /// Directions one datum of this kind pins (for the default of each level).
    pub fn pins(self) -> usize {
        match self {
            Feature::Surface => 3,
            Feature::Point | Feature::Slot | Feature::Edge => 1,
            Feature::Hole => 2,
        }
    }
}

/// A datum: a feature of the part near `position` (CAD frame, mm).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Datum {
    /// Name used in the report.
    pub name: String,
    /// Nominal position, CAD frame: a region's centre, an RPS point, a hole's or slot's
    /// centre, a point on an edge.
    pub position: [f64; 3],
    /// Neighbourhood of the datum, mm: a region's radius, the patch an RPS point is fitted on,
    /// how far around a hole, slot or edge the cloud is searched.
    pub radius: f64,
    /// What it is measured from.
    #[serde(default)]
    pub feature: Feature,
    /// Level in the datum reference frame: 1 primary, 2 secondary, 3 tertiary. Without any
    /// order, the surface regions are fitted together (6 DOF, no hierarchy).
    #[serde(default)]
    pub order: Option<u8>,
    /// Direction: an RPS point's pinned direction, a hole's axis, a slot's long axis, an
    /// edge's outward normal (CAD frame; normalised on load).
    #[serde(default)]
    pub direction: Option<[f64; 3]>,
    /// A hole's diameter, mm.
    #[serde(default)]
    pub diameter: Option<f64>,
    /// A slot's width, mm.
    #[serde(default)]
    pub width: Option<f64>,
    /// A slot's length, mm (end to end).
    #[serde(default)]
    pub length: Option<f64>,
    /// Degrees of freedom this datum's level pins (default: primary 3, secondary 2, tertiary
    /// 1); stated on any datum of the level.
    #[serde(default)]
    pub dofs: Option<usize>,
}

impl Datum {
    /// A surface region datum (the pre-3-2-1 form: fitted with the others, no order).
    pub fn region(name: &str, position: [f64; 3], radius: f64) -> Datum {
        Datum {
            name: name.into(),
            position,
            radius,
            feature: Feature::Surface,
            order: None,
            direction: None,
            diameter: None,
            width: None,
            length: None,
            dofs: None,
        }
    }

    /// Whether `p` (CAD frame) lies in this datum's neighbourhood.
    pub fn contains(&self, p: &[f64; 3]) -> bool {
        (0..3)
            .map(|k| (p[k] - self.position[k]).powi(2))
            .sum::<f64>()
            <= self.radius * self.radius
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct DatumsFile {
    datum: Vec<Datum>,
}

/// Read a datums file (`[[datum]]` tables, see [`Datum`]) and check it: values finite and
/// positive, what each feature needs present, and, for a datum reference frame, every datum
/// with an order 1–3 and at most 6 degrees of freedom pinned in all.
pub fn load_datums(path: &Path) -> Result<Vec<Datum>> {
    let f: DatumsFile = read_toml(path)?;
    validate(&path.display().to_string(), f.datum)
}

/// How many times its CAD's diagonal a datum's radius may be: a datum "covering everything"
/// is often given a round radius well beyond the part.
const MAX_RADIUS_DIAGONALS: f64 = 100.0;

/// Refuse datums that cannot belong to a part whose CAD spans `lo … hi`: a radius beyond
/// 100 times the box's diagonal, or a centre farther than a diagonal outside
/// it. Such a datum is a typing error, and its radius sizes work (the circle drawn for it).
pub fn check_against(ctx: &str, datums: &[Datum], (lo, hi): ([f64; 3], [f64; 3])) -> Result<()> {
    let diagonal = (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt();
    for (i, d) in datums.iter().enumerate() {
        if d.radius > MAX_RADIUS_DIAGONALS * diagonal {
            return Err(Error::invalid(
                ctx,
                format!("datum[{i}].radius"),
                format!(
                    "{} mm is beyond {MAX_RADIUS_DIAGONALS} times the part's size (its CAD's diagonal is {diagonal:.0} mm)",
                    d.radius
                ),
            ));
        }
        let outside = (0..3)
            .map(|k| {
                (lo[k] - d.position[k])
                    .max(d.position[k] - hi[k])
                    .max(0.0)
                    .powi(2)
            })
            .sum::<f64>()
            .sqrt();
        if outside > diagonal {
            return Err(Error::invalid(
                ctx,
                format!("datum[{i}].position"),
                format!(
                    "{:?} lies {outside:.0} mm outside the part's CAD (whose diagonal is {diagonal:.0} mm): is it in the CAD's frame?",
                    d.position
                ),
            ));
        }
    }
    Ok(())
}

/// Check datums (see [`load_datums`]); `ctx` names their source in errors.
pub fn validate(ctx: &str, mut datums: Vec<Datum>) -> Result<Vec<Datum>> {
    let bad = |i: usize, field: &str, msg: String| {
        Error::invalid(ctx, format!("datum[{i}].{field}"), msg)
    };
    let positive = |i: usize, field: &str, v: Option<f64>, needed: bool| -> Result<()> {
        match v {
            Some(x) if !(x.is_finite() && x > 0.0) => {
                Err(bad(i, field, format!("{x} must be positive")))
            }
            None if needed => Err(bad(i, field, "is required for this feature".into())),
            _ => Ok(()),
        }
    };
    let framed = datums.iter().any(|d| d.order.is_some());
    for (i, d) in datums.iter_mut().enumerate() {
        positive(i, "radius", Some(d.radius), true)?;
        if d.position.iter().any(|v| !v.is_finite()) {
            return Err(bad(i, "position", "must be finite".into()));
        }
        if let Some(v) = d.direction {
            let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            if !(n.is_finite() && n > 1e-9) {
                return Err(bad(i, "direction", format!("{v:?} is not a direction")));
            }
            d.direction = Some([v[0] / n, v[1] / n, v[2] / n]);
        }
        positive(i, "diameter", d.diameter, d.feature == Feature::Hole)?;
        positive(i, "width", d.width, d.feature == Feature::Slot)?;
        positive(i, "length", d.length, d.feature == Feature::Slot)?;
        if matches!(d.feature, Feature::Slot | Feature::Edge) && d.direction.is_none() {
            return Err(bad(i, "direction", "is required for this feature".into()));
        }
        if let (Some(w), Some(l)) = (d.width, d.length) {
            if l <= w {
                return Err(bad(i, "length", format!("{l} must exceed the width {w}")));
            }
        }
        if d.feature == Feature::Hole && d.radius <= 0.5 * d.diameter.unwrap_or(0.0) {
            return Err(bad(
                i,
                "radius",
                format!("{} must exceed the hole's radius", d.radius),
            ));
        }
        match d.order {
            Some(1..=3) => {}
            Some(o) => return Err(bad(i, "order", format!("{o} must be 1, 2 or 3"))),
            None if framed => {
                return Err(bad(
                    i,
                    "order",
                    "is missing: when one datum has an order, all need one".into(),
                ))
            }
            None if d.feature != Feature::Surface => {
                return Err(bad(
                    i,
                    "order",
                    "is required for a feature datum (1, 2 or 3)".into(),
                ))
            }
            None => {}
        }
        if let Some(k) = d.dofs {
            if !(1..=6).contains(&k) {
                return Err(bad(i, "dofs", format!("{k} must be 1 … 6")));
            }
        }
    }
    if framed {
        let total: usize = (1..=3u8).map(|o| level_dofs(&datums, o)).sum();
        if total > 6 {
            return Err(Error::invalid(
                ctx,
                "datum.dofs",
                format!("the levels pin {total} degrees of freedom; a rigid part has 6"),
            ));
        }
    }
    Ok(datums)
}

/// Degrees of freedom level `order` pins: its stated `dofs`, else 3, 2, 1 for the primary,
/// secondary and tertiary, never more than its features can pin (0 for an empty level).
pub fn level_dofs(datums: &[Datum], order: u8) -> usize {
    let level: Vec<&Datum> = datums.iter().filter(|d| d.order == Some(order)).collect();
    if level.is_empty() {
        return 0;
    }
    let stated = level.iter().find_map(|d| d.dofs);
    let capacity: usize = level.iter().map(|d| d.feature.pins()).sum();
    stated.unwrap_or(4 - order as usize).min(capacity.max(1))
}

/// Whether `p` lies in any datum's neighbourhood.
pub(super) fn in_datums(p: &[f64; 3], datums: &[Datum]) -> bool {
    datums.iter().any(|d| d.contains(p))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<Vec<Datum>> {
        let f: DatumsFile =
            toml::from_str(text).map_err(|e| Error::invalid("d.toml", "toml", e.to_string()))?;
        validate("d.toml", f.datum)
    }

    #[test]
    fn a_3_2_1_frame_loads_and_counts_its_degrees_of_freedom() {
        let d = parse(
            r#"
            [[datum]]
            name = "A"
            position = [0, 0, 0]
            radius = 20
            order = 1
            [[datum]]
            name = "B"
            feature = "hole"
            position = [100, 0, 0]
            radius = 15
            diameter = 10
            order = 2
            [[datum]]
            name = "C"
            feature = "slot"
            position = [-100, 0, 0]
            radius = 15
            width = 8
            length = 30
            direction = [2, 0, 0]
            order = 3
            "#,
        )
        .expect("valid");
        assert_eq!(
            (level_dofs(&d, 1), level_dofs(&d, 2), level_dofs(&d, 3)),
            (3, 2, 1)
        );
        assert_eq!(d[2].direction, Some([1.0, 0.0, 0.0]));
    }

    #[test]
    fn bad_frames_name_the_datum_and_field() {
        let cases = [
            // A hole without a diameter.
            ("feature = \"hole\"\norder = 2", "datum[0].diameter"),
            // A feature without an order.
            (
                "feature = \"edge\"\ndirection = [1, 0, 0]",
                "datum[0].order",
            ),
            // An order out of range.
            ("order = 4", "datum[0].order"),
            // A slot without a direction.
            (
                "feature = \"slot\"\nwidth = 8\nlength = 30\norder = 3",
                "datum[0].direction",
            ),
            // A hole wider than the neighbourhood searched.
            (
                "feature = \"hole\"\ndiameter = 50\norder = 2",
                "datum[0].radius",
            ),
        ];
        for (extra, field) in cases {
            let text =
                format!("[[datum]]\nname = \"X\"\nposition = [0, 0, 0]\nradius = 20\n{extra}\n");
            let e = parse(&text).expect_err(field).to_string();
            assert!(e.contains(field), "{extra}: {e}");
        }
        let mixed = "[[datum]]\nname = \"A\"\nposition = [0, 0, 0]\nradius = 20\norder = 1\n[[datum]]\nname = \"B\"\nposition = [1, 0, 0]\nradius = 20\n";
        assert!(parse(mixed)
            .expect_err("mixed")
            .to_string()
            .contains("datum[1].order"));
        let seven = "[[datum]]\nname = \"A\"\nposition = [0, 0, 0]\nradius = 20\norder = 1\ndofs = 5\n[[datum]]\nname = \"A2\"\nposition = [50, 0, 0]\nradius = 20\norder = 1\n[[datum]]\nname = \"B\"\nposition = [1, 0, 0]\nradius = 20\norder = 2\n";
        assert!(parse(seven)
            .expect_err("seven")
            .to_string()
            .contains("a rigid part has 6"));
    }

    #[test]
    fn a_datum_larger_than_its_part_or_far_from_it_is_refused_by_field() {
        let datum = |radius: f64, position: [f64; 3]| Datum {
            position,
            radius,
            ..toml::from_str::<Datum>("name = \"A\"\nposition = [0.0, 0.0, 0.0]\nradius = 1.0\n")
                .expect("datum")
        };
        let part = ([-500.0, -400.0, -50.0], [500.0, 400.0, 50.0]);
        check_against("d.toml", &[datum(40.0, [100.0, 0.0, 0.0])], part).expect("a sane datum");
        check_against("d.toml", &[datum(1e4, [0.0; 3])], part).expect("a datum over everything");
        for (d, field) in [
            (datum(1e9, [0.0; 3]), "datum[0].radius"),
            (datum(1e300, [0.0; 3]), "datum[0].radius"),
            (datum(f64::MAX, [0.0; 3]), "datum[0].radius"),
            (datum(10.0, [1e7, 0.0, 0.0]), "datum[0].position"),
        ] {
            let e = check_against("d.toml", &[d], part)
                .expect_err(field)
                .to_string();
            assert!(e.contains("d.toml") && e.contains(field), "{e}");
        }
    }
}
