//! The inspected surface: the part of the CAD that coverage and the verdict are about. A cell sees
//! a closed part from one side; its bottom, the faces against the fixture and the inside of a
//! deep pocket are never measured, so "measured 34 % of the CAD" says nothing about whether the
//! inspection is complete. The part file names the inspected faces (STEP face entity numbers),
//! or the cell's sensors say what they can see: a surface point counts when, from at least one
//! sensor, the camera and the projector both see it unoccluded and within the grazing limit, and
//! it lies inside the camera's image when the camera's model is known.

use rayon::prelude::*;

use crate::geometry::{Pinhole, Vec3};
use crate::mesh::{Bvh, TriangleMesh};

/// Largest angle between a surface normal and the direction to a camera or projector for the
/// surface to count as seen, degrees: structured light measures nothing at grazing incidence.
pub const GRAZING_LIMIT_DEG: f64 = 80.0;

/// Where one sensor looks from: its camera's and (for structured light) its projector's
/// centre, in the cloud's frame, mm, and the camera's model when it is known.
#[derive(Clone, Debug, PartialEq)]
pub struct Viewpoint {
    /// Camera centre.
    pub camera: [f64; 3],
    /// Projector centre (`None`: a point where only the camera must see the surface).
    pub projector: Option<[f64; 3]>,
    /// The camera with the cloud's frame as its world frame: a surface point outside its image
    /// is not seen (`None`: only the centres count).
    pub image: Option<Pinhole>,
}

impl Viewpoint {
    /// This viewpoint after the rigid motion `pose` (the cloud moved into the CAD's frame).
    pub fn moved(&self, pose: &crate::register::Pose) -> Viewpoint {
        let at = |p: [f64; 3]| -> [f64; 3] { (pose * nalgebra::Point3::from(p)).coords.into() };
        let image = self.image.as_ref().map(|cam| {
            // X_cam = R X_cloud + t and X_cloud = pose⁻¹ X_cad
            let inv = pose.inverse();
            let r = inv.rotation.to_rotation_matrix().into_inner();
            Pinhole {
                r: cam.r * r,
                t: cam.r * inv.translation.vector + cam.t,
                ..cam.clone()
            }
        });
        Viewpoint {
            camera: at(self.camera),
            projector: self.projector.map(at),
            image,
        }
    }
}

/// Which part of the CAD surface an inspection is about.
#[derive(Clone, Debug, Default)]
pub enum InspectedSurface {
    /// Every triangle of the CAD.
    #[default]
    Whole,
    /// Named faces: per triangle of the CAD mesh, whether it belongs to them; points whose
    /// closest CAD triangle is not one of them are left out of the verdict.
    Faces {
        /// Per triangle of the CAD mesh.
        triangles: Vec<bool>,
        /// The faces in words (`faces #17, #137`), for the report.
        label: String,
    },
    /// What these sensors can see, in the cloud's frame (moved into the CAD's by the pose).
    SeenFrom(Vec<Viewpoint>),
}

impl InspectedSurface {
    /// The faces `#entities` of a STEP model; `ctx` names where the list came from in errors.
    pub fn of_faces(
        model: &crate::mesh::step::CadModel,
        entities: &[u32],
        ctx: &str,
    ) -> crate::Result<InspectedSurface> {
        let triangles = model.triangles_of(entities, ctx)?;
        let label = format!(
            "face{} {}",
            if entities.len() == 1 { "" } else { "s" },
            entities
                .iter()
                .map(|n| format!("#{n}"))
                .collect::<Vec<_>>()
                .join(", ")
        );
        Ok(InspectedSurface::Faces { triangles, label })
    }

    /// The surface in words, for the report.
    pub fn describe(&self) -> String {
        match self {
            InspectedSurface::Whole => "the whole CAD surface".into(),
            InspectedSurface::Faces { label, .. } => label.clone(),
            InspectedSurface::SeenFrom(v) => format!(
                "the CAD surface the cell's {} sensor{} can see (camera and projector both, within {GRAZING_LIMIT_DEG}° of the normal{})",
                v.len(),
                if v.len() == 1 { "" } else { "s" },
                if v.iter().all(|v| v.image.is_some()) {
                    ", inside the camera's image"
                } else {
                    ""
                }
            ),
        }
    }

    /// The per-triangle mask of named faces, checked against the mesh.
    pub fn triangle_mask(&self, mesh: &TriangleMesh) -> crate::Result<Option<&[bool]>> {
        match self {
            InspectedSurface::Faces { triangles, .. } => {
                if triangles.len() != mesh.triangles.len() {
                    return Err(crate::Error::invalid(
                        "inspection",
                        "inspected faces",
                        format!(
                            "the face mask has {} entries for a CAD of {} triangles",
                            triangles.len(),
                            mesh.triangles.len()
                        ),
                    ));
                }
                if !triangles.iter().any(|t| *t) {
                    return Err(crate::Error::invalid(
                        "inspection",
                        "inspected faces",
                        "no triangle of the CAD belongs to the inspected faces",
                    ));
                }
                Ok(Some(triangles))
            }
            _ => Ok(None),
        }
    }
}

/// Whether each surface sample (a point on the CAD and its triangle) is seen from at least one
/// viewpoint (CAD frame): every centre of that viewpoint in front of the sample's triangle within
/// [`GRAZING_LIMIT_DEG`], no CAD triangle in between, and the sample inside the camera's image
/// where the camera's model is given.
pub fn seen(bvh: &Bvh, samples: &[([f64; 3], u32)], viewpoints: &[Viewpoint]) -> Vec<bool> {
    let mesh = bvh.mesh();
    let (lo, hi) = bvh.bounds();
    let scale = (Vec3::from(hi) - Vec3::from(lo)).norm().max(1.0);
    let cos_limit = GRAZING_LIMIT_DEG.to_radians().cos();
    samples
        .par_iter()
        .map(|(p, t)| {
            let [a, b, c] = mesh.corners(*t as usize);
            let n = (b - a).cross(&(c - a));
            let len = n.norm();
            if len == 0.0 {
                return false;
            }
            let n = n / len;
            let p = Vec3::from(*p);
            let origin = p + n * (1e-6 * scale);
            viewpoints.iter().any(|v| {
                let in_image = v.image.as_ref().is_none_or(|cam| {
                    cam.project(&p).is_some_and(|(u, w)| {
                        (-0.5..f64::from(cam.width) - 0.5).contains(&u)
                            && (-0.5..f64::from(cam.height) - 0.5).contains(&w)
                    })
                });
                in_image
                    && std::iter::once(v.camera).chain(v.projector).all(|centre| {
                        let to = Vec3::from(centre) - origin;
                        let dist = to.norm();
                        if dist == 0.0 {
                            return false;
                        }
                        let dir = to / dist;
                        n.dot(&dir) > cos_limit && bvh.intersect(&origin, &dir, 0.0, dist).is_none()
                    })
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A closed axis-aligned box (two triangles a side, outward).
    fn cube(s: f64) -> TriangleMesh {
        let v = |x: f64, y: f64, z: f64| Vec3::new(x * s, y * s, z * s);
        let vertices = vec![
            v(0., 0., 0.),
            v(1., 0., 0.),
            v(1., 1., 0.),
            v(0., 1., 0.),
            v(0., 0., 1.),
            v(1., 0., 1.),
            v(1., 1., 1.),
            v(0., 1., 1.),
        ];
        let quads = [
            [0, 3, 2, 1],
            [4, 5, 6, 7],
            [0, 1, 5, 4],
            [1, 2, 6, 5],
            [2, 3, 7, 6],
            [3, 0, 4, 7],
        ];
        let mut triangles = Vec::new();
        for q in quads {
            triangles.push([q[0], q[1], q[2]]);
            triangles.push([q[0], q[2], q[3]]);
        }
        TriangleMesh {
            vertices,
            triangles,
        }
    }

    #[test]
    fn a_box_seen_from_above_shows_its_top_and_not_its_bottom() {
        let bvh = Bvh::new(cube(100.0));
        let top = ([50.0, 50.0, 100.0], 2);
        let bottom = ([50.0, 50.0, 0.0], 0);
        let side = ([50.0, 0.0, 50.0], 4);
        let above = Viewpoint {
            camera: [50.0, 50.0, 1000.0],
            projector: Some([250.0, 50.0, 1000.0]),
            image: None,
        };
        let s = seen(&bvh, &[top, bottom, side], &[above]);
        assert_eq!(s, vec![true, false, false]);
        // from the side, in front of the y = 0 face and above the box: the side and the top
        let oblique = Viewpoint {
            camera: [50.0, -800.0, 600.0],
            projector: None,
            image: None,
        };
        assert_eq!(
            seen(&bvh, &[top, bottom, side], &[oblique]),
            vec![true, false, true]
        );
        // a projector behind the box's top plane: the camera alone does not make it seen
        let hidden_projector = Viewpoint {
            camera: [50.0, 50.0, 1000.0],
            projector: Some([50.0, 50.0, 50.0]),
            image: None,
        };
        assert_eq!(seen(&bvh, &[top], &[hidden_projector]), vec![false]);
        // a camera looking straight down with a narrow image: the top's centre is in it, a
        // point of the top near its corner is not
        let camera = Pinhole {
            width: 100,
            height: 100,
            k: crate::geometry::Mat3::new(1000.0, 0.0, 49.5, 0.0, 1000.0, 49.5, 0.0, 0.0, 1.0),
            dist: Default::default(),
            r: crate::geometry::Mat3::new(1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0),
            t: Vec3::new(-50.0, 50.0, 1000.0),
        };
        assert!((camera.center() - Vec3::new(50.0, 50.0, 1000.0)).norm() < 1e-9);
        let narrow = Viewpoint {
            camera: [50.0, 50.0, 1000.0],
            projector: None,
            image: Some(camera),
        };
        let corner = ([99.0, 99.0, 100.0], 2);
        assert_eq!(
            seen(&bvh, &[top, corner], std::slice::from_ref(&narrow)),
            vec![true, false]
        );
        // moved with the cloud: the same answer in the moved frame
        let pose = crate::register::Pose::from_parts(
            nalgebra::Translation3::new(10.0, -20.0, 30.0),
            nalgebra::UnitQuaternion::from_euler_angles(0.1, -0.2, 0.3),
        );
        let moved_mesh = {
            let mut m = cube(100.0);
            for v in &mut m.vertices {
                *v = (pose * nalgebra::Point3::from(*v)).coords;
            }
            m
        };
        let at = |p: [f64; 3]| -> [f64; 3] { (pose * nalgebra::Point3::from(p)).coords.into() };
        let moved = seen(
            &Bvh::new(moved_mesh),
            &[(at(top.0), top.1), (at(corner.0), corner.1)],
            &[narrow.moved(&pose)],
        );
        assert_eq!(moved, vec![true, false]);
    }
}
