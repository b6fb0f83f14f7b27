//! The acceptance test's artefacts as simulator objects, and the positions of a whole
//! acceptance set through a calibrated volume: a sphere on its post, a two-sphere bar on a
//! rod with a stand, a flat slab on a post. A sensor's scene with one artefact placed is
//! rendered, decoded and reconstructed like any scan, so the test runs through the real sensor
//! model without hardware (and a deliberately wrong sensor model shows which figure catches
//! which fault).

use super::{Artefacts, Volume};
use crate::decode::{decode, DecodeParams, Decoded};
use crate::geometry::{Mat3, Vec3};
use crate::mesh::{Bvh, TriangleMesh};
use crate::sim::{Material, Object, Scene, Shape, Simulator, Texture};

/// Where one artefact stands, in the sensor's world frame, mm.
#[derive(Clone, Debug, PartialEq)]
pub enum Placement {
    /// A sphere on a post, by its centre.
    Sphere {
        /// Centre.
        centre: Vec3,
    },
    /// A ball bar, by the centres of its spheres A and B.
    Bar {
        /// Centre of sphere A.
        a: Vec3,
        /// Centre of sphere B.
        b: Vec3,
    },
    /// A flat, by the centre of its measured face, the face's outward normal and its long
    /// axis.
    Flat {
        /// Centre of the measured face.
        centre: Vec3,
        /// Outward unit normal of the face.
        normal: Vec3,
        /// Unit direction of the flat's length (perpendicular to `normal`).
        along: Vec3,
    },
}

/// One position of an acceptance set.
#[derive(Clone, Debug, PartialEq)]
pub struct Placed {
    /// `bar-1`, `flat-3`, `sphere-10`: a file stem for its cloud.
    pub label: String,
    /// Where the artefact stands.
    pub placement: Placement,
}

/// Radius of a sphere's post as a share of the sphere's radius.
const POST_SHARE: f64 = 0.3;
/// Radius of a bar's rod as a share of its smaller sphere's radius.
const ROD_SHARE: f64 = 0.3;
/// Thickness of a flat's slab, mm.
const SLAB: f64 = 12.0;

/// The simulator objects of `artefacts`' artefact at `placement`, all of `material`: the
/// artefact and what holds it up from the table (z = 0). An artefact the file does not
/// describe gives none.
pub fn objects(artefacts: &Artefacts, placement: &Placement, material: usize) -> Vec<Object> {
    let still = |shape| Object::still(shape, material, None);
    let post = |top: Vec3, radius: f64| {
        (top.z > 0.0).then(|| {
            still(Shape::Cylinder {
                center: Vec3::new(top.x, top.y, top.z / 2.0),
                axis: Vec3::z(),
                radius,
                half_height: top.z / 2.0,
            })
        })
    };
    let mut out = Vec::new();
    match placement {
        Placement::Sphere { centre } => {
            let Some(s) = &artefacts.sphere else {
                return out;
            };
            let r = s.diameter / 2.0;
            out.push(still(Shape::Sphere {
                center: *centre,
                radius: r,
            }));
            out.extend(post(*centre - Vec3::z() * (0.8 * r), POST_SHARE * r));
        }
        Placement::Bar { a, b } => {
            let Some(bar) = &artefacts.ball_bar else {
                return out;
            };
            let (ra, rb) = (bar.diameter_a / 2.0, bar.diameter_b / 2.0);
            out.push(still(Shape::Sphere {
                center: *a,
                radius: ra,
            }));
            out.push(still(Shape::Sphere {
                center: *b,
                radius: rb,
            }));
            let axis = b - a;
            let length = axis.norm();
            let rod = ROD_SHARE * ra.min(rb);
            out.push(still(Shape::Cylinder {
                center: (a + b) / 2.0,
                axis: axis / length,
                radius: rod,
                half_height: length / 2.0,
            }));
            out.extend(post((a + b) / 2.0 - Vec3::z() * (0.8 * rod), rod));
        }
        Placement::Flat {
            centre,
            normal,
            along,
        } => {
            let Some(p) = &artefacts.plane else {
                return out;
            };
            let n = normal.normalize();
            let u = (along - n * along.dot(&n)).normalize();
            let v = n.cross(&u);
            out.push(still(Shape::Mesh(Box::new(Bvh::new(slab(
                *centre,
                [u, v, n],
                p.length,
                p.width,
            ))))));
            let back = centre - n * SLAB;
            out.extend(post(back, 0.15 * p.width));
        }
    }
    out
}

/// A box of `length` × `width` × [`SLAB`] whose face +n is centred on `centre`, axes
/// `[u, v, n]`, as 12 outward triangles.
fn slab(centre: Vec3, [u, v, n]: [Vec3; 3], length: f64, width: f64) -> TriangleMesh {
    let (hl, hw) = (length / 2.0, width / 2.0);
    let mut vertices = Vec::with_capacity(8);
    for k in 0..8 {
        let su = if k & 1 == 0 { -hl } else { hl };
        let sv = if k & 2 == 0 { -hw } else { hw };
        let sn = if k & 4 == 0 { -SLAB } else { 0.0 };
        vertices.push(centre + u * su + v * sv + n * sn);
    }
    // Faces of the unit cube by corner bits (u = 1, v = 2, n = 4), counter-clockwise outside.
    let quads: [[u32; 4]; 6] = [
        [4, 5, 7, 6], // +n (the measured face)
        [0, 2, 3, 1], // −n
        [1, 3, 7, 5], // +u
        [0, 4, 6, 2], // −u
        [2, 6, 7, 3], // +v
        [0, 1, 5, 4], // −v
    ];
    let triangles = quads
        .iter()
        .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
        .collect();
    TriangleMesh {
        vertices,
        triangles,
    }
}

/// `base` (a sensor's scene: its optics and table) with a uniform matte material and the
/// artefact at `placement` added, as calibrated artefacts are (no texture).
pub fn scene(base: &Scene, artefacts: &Artefacts, placement: &Placement) -> Scene {
    let mut s = base.clone();
    let material = s.materials.len();
    s.materials.push(Material {
        name: "artefact".into(),
        albedo: 0.6,
        specular: 0.0,
        shininess: 0.0,
        interreflection: 0.0,
        interreflection_radius: 0.0,
        texture: Texture::None,
    });
    s.objects.extend(objects(artefacts, placement, material));
    s
}

/// The positions of a whole acceptance set through `volume` after VDI/VDE 2634-2: seven bar
/// positions (the four space diagonals, the x and y axes and a diagonal of the lower face,
/// each centred in the volume), six flat positions (level at three heights, tilted 25° about
/// either axis and about a diagonal) and ten sphere positions (the eight corners of the
/// volume's inner half and its centre and top centre). Artefacts the file does not describe
/// are left out.
pub fn acceptance_set(artefacts: &Artefacts, volume: &Volume) -> Vec<Placed> {
    let lo = Vec3::from(volume.min);
    let hi = Vec3::from(volume.max);
    let mid = (lo + hi) / 2.0;
    let size = hi - lo;
    let at = |f: [f64; 3]| lo + size.component_mul(&Vec3::from(f));
    let mut out = Vec::new();
    if let Some(bar) = &artefacts.ball_bar {
        let directions = [
            Vec3::new(size.x, size.y, size.z),
            Vec3::new(-size.x, size.y, size.z),
            Vec3::new(size.x, -size.y, size.z),
            Vec3::new(-size.x, -size.y, size.z),
            Vec3::x(),
            Vec3::y(),
            Vec3::new(size.x, size.y, 0.0),
        ];
        for (i, d) in directions.iter().enumerate() {
            let half = d.normalize() * (bar.spacing / 2.0);
            // Axis-parallel bars at mid height, the lower-face diagonal at a quarter.
            let centre = if i == 6 { at([0.5, 0.5, 0.25]) } else { mid };
            out.push(Placed {
                label: format!("bar-{}", i + 1),
                placement: Placement::Bar {
                    a: centre - half,
                    b: centre + half,
                },
            });
        }
    }
    if artefacts.plane.is_some() {
        let tilt = |axis: Vec3, deg: f64| {
            nalgebra::Rotation3::from_axis_angle(
                &nalgebra::Unit::new_normalize(axis),
                deg.to_radians(),
            )
            .into_inner()
        };
        let level: Mat3 = Mat3::identity();
        let poses = [
            (0.25, level),
            (0.5, level),
            (0.75, level),
            (0.5, tilt(Vec3::x(), 25.0)),
            (0.5, tilt(Vec3::y(), -25.0)),
            (0.5, tilt(Vec3::new(1.0, 1.0, 0.0), 25.0)),
        ];
        for (i, (h, r)) in poses.iter().enumerate() {
            out.push(Placed {
                label: format!("flat-{}", i + 1),
                placement: Placement::Flat {
                    centre: at([0.5, 0.5, *h]),
                    normal: r * Vec3::z(),
                    along: r * Vec3::x(),
                },
            });
        }
    }
    if artefacts.sphere.is_some() {
        let mut corners: Vec<[f64; 3]> = (0..8)
            .map(|k| {
                let f = |bit: usize| if k & bit == 0 { 0.25 } else { 0.75 };
                [f(1), f(2), f(4)]
            })
            .collect();
        corners.push([0.5, 0.5, 0.5]);
        corners.push([0.5, 0.5, 0.9]);
        for (i, f) in corners.iter().enumerate() {
            out.push(Placed {
                label: format!("sphere-{}", i + 1),
                placement: Placement::Sphere { centre: at(*f) },
            });
        }
    }
    out
}

/// The decoded frames of a rendered acceptance set: the sensor's reference plane and each
/// position of the set, in order.
#[derive(Clone, Debug)]
pub struct DecodedSet {
    /// The reference plane of `base` (what the parallax model is fitted to).
    pub reference: Decoded,
    /// One per position.
    pub positions: Vec<Decoded>,
}

/// Render each position of `set` through `base`'s sensor (its optics, table and noise) with
/// the artefact placed, and decode it with `params`; `progress(done, total)` after each.
pub fn decode_set(
    base: &Scene,
    artefacts: &Artefacts,
    set: &[Placed],
    params: &DecodeParams,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> crate::Result<DecodedSet> {
    let total = set.len() + 1;
    let reference = {
        let sim = Simulator::new(base.reference());
        decode(&sim.capture(&sim.layout(), 1000, &|_, _| {}), params)?
    };
    progress(1, total);
    let mut positions = Vec::with_capacity(set.len());
    for (i, p) in set.iter().enumerate() {
        let sim = Simulator::new(scene(base, artefacts, &p.placement));
        let capture = sim.capture(&sim.layout(), 7 + i as u64, &|_, _| {});
        positions.push(decode(&capture, params)?);
        progress(i + 2, total);
    }
    Ok(DecodedSet {
        reference,
        positions,
    })
}
