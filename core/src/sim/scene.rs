//! Simulator scenes (SPEC §11): devices with photometry, materials and objects.

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use super::shapes::{Object, Shape};
use super::texture::{MarkerPaint, Texture};
use crate::calibrate::Gauge;
use crate::geometry::{rotation_xyz_deg, Mat3, Pinhole, Vec3};
use crate::io::read_toml;
use crate::mesh::{Bvh, TriangleMesh};
use crate::sensor::{CameraSection, SensorFile};
use crate::{Error, Result};

/// `[camera]`: a sensor-file camera plus photometry.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimCamera {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Intrinsics.
    pub k: [[f64; 3]; 3],
    /// Distortion.
    #[serde(default)]
    pub dist: [f64; 5],
    /// World → camera rotation.
    pub r: [[f64; 3]; 3],
    /// World → camera translation.
    pub t: [f64; 3],
    /// Relative exposure: signal = 255 × exposure × radiance.
    #[serde(default = "one")]
    pub exposure: f64,
    /// Read noise σ, DN.
    #[serde(default)]
    pub noise: f64,
    /// Shot-noise variance per DN of signal.
    #[serde(default)]
    pub shot_noise: f64,
}

/// `[projector]`: the full projector model of the simulator.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimProjector {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Intrinsics.
    pub k: [[f64; 3]; 3],
    /// Distortion.
    #[serde(default)]
    pub dist: [f64; 5],
    /// World → projector rotation.
    pub r: [[f64; 3]; 3],
    /// World → projector translation.
    pub t: [f64; 3],
    /// Ambient light, fraction of full projector white.
    #[serde(default)]
    pub ambient: f64,
    /// Projector defocus (Gaussian σ), projector pixels.
    #[serde(default)]
    pub blur: f64,
}

/// `[material.NAME]`.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialSection {
    /// Lambertian reflectance.
    pub albedo: f64,
    /// Blinn-Phong lobe strength.
    #[serde(default)]
    pub specular: f64,
    /// Blinn-Phong exponent.
    #[serde(default)]
    pub shininess: f64,
    /// Fraction of nearby direct light re-scattered.
    #[serde(default)]
    pub interreflection: f64,
    /// Inter-reflection radius, mm.
    #[serde(default)]
    pub interreflection_radius: f64,
    /// Albedo texture: "noise" (smooth random) or "checker"; none when absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub texture: Option<String>,
    /// Relative albedo modulation of the texture, 0..1.
    #[serde(default)]
    pub texture_amplitude: f64,
    /// Texture period, mm.
    #[serde(default = "twenty")]
    pub texture_period: f64,
}

/// `[[object]]`.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObjectSection {
    /// plane, box, sphere, dome, cylinder, mesh or panel (a doubly curved sheet such as a
    /// windshield; meshes and panels take `position`, `rotation_deg`, `scale`).
    pub shape: String,
    /// Material name.
    pub material: String,
    /// Centre (box, sphere, cylinder: centroid; dome: centre of its base).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub center: Option<[f64; 3]>,
    /// Box size.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub size: Option<[f64; 3]>,
    /// Sphere, dome (base) or cylinder radius.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radius: Option<f64>,
    /// Dome or cylinder height.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub height: Option<f64>,
    /// Cylinder axis direction (any length; default [0, 0, 1], upright).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub axis: Option<[f64; 3]>,
    /// STL file, relative to the scene file.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub file: Option<String>,
    /// Mesh translation (moves the painted markers too).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub position: Option<[f64; 3]>,
    /// Mesh rotation, XYZ Euler degrees.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rotation_deg: Option<[f64; 3]>,
    /// Mesh scale.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scale: Option<f64>,
    /// Panel curvatures (1/mm) along x and y: z = −(cx x² + cy y²) / 2 over `size` (x, y).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub curvature: Option<[f64; 2]>,
    /// Velocity, mm/s: the object moves on a line (`Scene::at`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub velocity: Option<[f64; 3]>,
    /// Gauge file whose markers are painted on this object; centres are in the object's own
    /// frame and move with its pose.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub markers: Option<String>,
    /// Albedo of the painted markers (default 0.85).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub marker_albedo: Option<f64>,
    /// A dent worn into a panel that deepens scan by scan (a wearing press tool): the mock
    /// cell's planted drift for trends and run rules.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wear: Option<WearSection>,
}

/// `wear = { center = [x, y], radius = R, depth = d0, growth = g, after = a }` of a panel: a
/// smooth dent `(d0 + g·max(0, n − a)) (1 − (ρ/R)²)²` deep (mm, into the panel, along its −z)
/// at `center` (the panel's own x, y, mm) in the n-th scan of the cell.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WearSection {
    /// Centre in the panel's own frame, mm.
    pub center: [f64; 2],
    /// Radius, mm.
    pub radius: f64,
    /// Depth before the first scan, mm.
    #[serde(default)]
    pub depth: f64,
    /// Depth added by each scan, mm.
    #[serde(default)]
    pub growth: f64,
    /// Scans before the dent starts to deepen.
    #[serde(default)]
    pub after: u64,
}

/// A panel's shape parameters, kept to rebuild it with its dent at another depth.
#[derive(Clone, Debug)]
pub struct PanelWear {
    size: [f64; 2],
    curvature: [f64; 2],
    rotation: Mat3,
    scale: f64,
    position: Vec3,
    wear: WearSection,
}

impl PanelWear {
    /// The panel's mesh with the dent as deep as after `scans` scans.
    pub fn mesh(&self, scans: u64) -> TriangleMesh {
        let depth =
            self.wear.depth + self.wear.growth * scans.saturating_sub(self.wear.after) as f64;
        panel_mesh(
            self.size,
            self.curvature,
            Some((self.wear, depth)),
            &self.rotation,
            self.scale,
            &self.position,
        )
    }
}

/// A doubly curved panel `size` (x, y) with `curvature` (z = −(cx x² + cy y²) / 2), triangulated
/// on a 4 mm grid, with an optional dent (and its depth), posed by `r`, `scale`, `position`.
fn panel_mesh(
    size: [f64; 2],
    [cx, cy]: [f64; 2],
    dent: Option<(WearSection, f64)>,
    r: &Mat3,
    scale: f64,
    position: &Vec3,
) -> TriangleMesh {
    let (hx, hy) = (size[0] / 2.0, size[1] / 2.0);
    let cells = |len: f64| ((len / 4.0).ceil() as usize).clamp(1, 2000);
    let mut mesh = TriangleMesh::height_field(
        cells(size[0]),
        cells(size[1]),
        (-hx, hx),
        (-hy, hy),
        |x, y| {
            let mut z = -(cx * x * x + cy * y * y) / 2.0;
            if let Some((w, depth)) = dent {
                let q =
                    ((x - w.center[0]).powi(2) + (y - w.center[1]).powi(2)) / (w.radius * w.radius);
                if q < 1.0 {
                    z -= depth * (1.0 - q).powi(2);
                }
            }
            z
        },
    );
    mesh.transform(r, scale, position);
    mesh
}

/// `[render]`: simulator settings (optional).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RenderSection {
    /// Sub-samples per pixel side (footprint anti-aliasing).
    #[serde(default = "four")]
    pub supersample: u32,
    /// Noise seed.
    #[serde(default = "one_u64")]
    pub seed: u64,
    /// Render row codes too.
    #[serde(default = "yes")]
    pub rows: bool,
}

impl Default for RenderSection {
    fn default() -> Self {
        RenderSection {
            supersample: 4,
            seed: 1,
            rows: true,
        }
    }
}

fn one() -> f64 {
    1.0
}
fn one_u64() -> u64 {
    1
}
fn twenty() -> f64 {
    20.0
}
fn four() -> u32 {
    4
}
fn yes() -> bool {
    true
}

/// A scene file.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneFile {
    /// The camera.
    pub camera: SimCamera,
    /// The projector.
    pub projector: SimProjector,
    /// Materials by name.
    #[serde(default)]
    pub material: BTreeMap<String, MaterialSection>,
    /// Objects.
    #[serde(default)]
    pub object: Vec<ObjectSection>,
    /// Simulator settings.
    #[serde(default)]
    pub render: RenderSection,
    /// Render a multi-layer calibration session instead of the objects (SPEC §7).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub calibration: Option<CalibrationSection>,
}

/// `[calibration]`: a chessboard on a table, lifted to each height in turn.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationSection {
    /// Inner corners along x and y.
    pub inner_corners: [usize; 2],
    /// Square size, mm.
    pub square: f64,
    /// Board surface heights, the first 0.
    pub heights: Vec<f64>,
    /// Material of the board (its albedo is that of the light squares).
    pub board_material: String,
    /// Material of the table the board is lifted from.
    pub table_material: String,
    /// Albedo factor of the dark squares.
    #[serde(default = "tenth")]
    pub dark: f64,
    /// White border around the squares, mm.
    #[serde(default = "twenty")]
    pub margin: f64,
    /// Board thickness, mm (its surface at layer 0 is z = 0, the table below).
    #[serde(default = "four_mm")]
    pub thickness: f64,
}

fn tenth() -> f64 {
    0.1
}

fn four_mm() -> f64 {
    4.0
}

/// A material ready for shading.
#[derive(Clone, Debug)]
pub struct Material {
    /// Name from the scene file.
    pub name: String,
    /// Lambertian reflectance.
    pub albedo: f64,
    /// Blinn-Phong lobe strength.
    pub specular: f64,
    /// Blinn-Phong exponent.
    pub shininess: f64,
    /// Inter-reflection fraction.
    pub interreflection: f64,
    /// Inter-reflection radius, mm.
    pub interreflection_radius: f64,
    /// Albedo texture.
    pub texture: Texture,
}

/// A validated scene.
#[derive(Clone, Debug)]
pub struct Scene {
    /// Camera geometry.
    pub camera: Pinhole,
    /// Relative exposure.
    pub exposure: f64,
    /// Read noise σ, DN.
    pub noise: f64,
    /// Shot-noise variance per DN.
    pub shot_noise: f64,
    /// Projector geometry.
    pub projector: Pinhole,
    /// Ambient light fraction.
    pub ambient: f64,
    /// Projector blur σ, pixels.
    pub blur: f64,
    /// Materials.
    pub materials: Vec<Material>,
    /// Objects.
    pub objects: Vec<Object>,
    /// Simulator settings.
    pub render: RenderSection,
    /// The file as parsed (for writing sensor files).
    pub file: SceneFile,
}

impl Scene {
    /// Read and validate a scene file; mesh paths resolve against its directory.
    pub fn load(path: &Path) -> Result<Scene> {
        let file: SceneFile = read_toml(path)?;
        Scene::from_file(
            file,
            path.parent().unwrap_or(Path::new(".")),
            &path.display().to_string(),
        )
    }

    /// Validate a parsed scene.
    pub fn from_file(file: SceneFile, base: &Path, ctx: &str) -> Result<Scene> {
        let c = &file.camera;
        let cam_section = CameraSection {
            width: c.width,
            height: c.height,
            k: c.k,
            dist: c.dist,
            r: c.r,
            t: c.t,
        };
        let p = &file.projector;
        let sensor = SensorFile {
            camera: cam_section,
            projector: crate::sensor::ProjectorSection {
                width: p.width,
                height: p.height,
                center: None,
                k: Some(p.k),
                dist: Some(p.dist),
                r: Some(p.r),
                t: Some(p.t),
            },
            reference: None,
            residual: None,
            to_common: None,
            volume: None,
        };
        let s = crate::sensor::Sensor::from_file(&sensor, base, ctx)?;
        let projector = s
            .projector
            .clone()
            .ok_or_else(|| Error::invalid(ctx, "projector", "incomplete"))?;
        for (field, v, lo) in [
            ("camera.exposure", c.exposure, 0.0),
            ("camera.noise", c.noise, 0.0),
            ("camera.shot_noise", c.shot_noise, 0.0),
            ("projector.ambient", p.ambient, 0.0),
            ("projector.blur", p.blur, 0.0),
        ] {
            if !v.is_finite() || v < lo {
                return Err(Error::invalid(
                    ctx,
                    field,
                    format!("{v} must be a finite number ≥ {lo}"),
                ));
            }
        }
        // The blur sizes the light profiles (their kernel spans several σ): bounded by the
        // projector it blurs.
        let max_blur = f64::from(p.width.min(p.height)) / 8.0;
        if p.blur > max_blur {
            return Err(Error::invalid(
                ctx,
                "projector.blur",
                format!(
                    "{} px is beyond an eighth of the {} x {} projector ({max_blur} px): a projector that blurred so much would show no stripes",
                    p.blur, p.width, p.height
                ),
            ));
        }
        if file.render.supersample == 0 || file.render.supersample > 16 {
            return Err(Error::invalid(ctx, "render.supersample", "must be 1..=16"));
        }
        let mut materials = Vec::new();
        let mut index = BTreeMap::new();
        for (name, m) in &file.material {
            let f = |field: &str| format!("material.{name}.{field}");
            if !(0.0..=1.0).contains(&m.albedo) {
                return Err(Error::invalid(
                    ctx,
                    f("albedo"),
                    format!("{} is outside 0..1", m.albedo),
                ));
            }
            for (field, v) in [
                ("specular", m.specular),
                ("shininess", m.shininess),
                ("interreflection", m.interreflection),
                ("interreflection_radius", m.interreflection_radius),
                ("texture_amplitude", m.texture_amplitude),
            ] {
                if !v.is_finite() || v < 0.0 {
                    return Err(Error::invalid(ctx, f(field), format!("{v} must be ≥ 0")));
                }
            }
            if m.interreflection > 0.0 && m.interreflection_radius <= 0.0 {
                return Err(Error::invalid(
                    ctx,
                    f("interreflection_radius"),
                    "must be positive when interreflection is set",
                ));
            }
            let texture =
                Texture::parse(m.texture.as_deref(), m.texture_amplitude, m.texture_period)
                    .map_err(|msg| Error::invalid(ctx, f("texture"), msg))?;
            index.insert(name.clone(), materials.len());
            materials.push(Material {
                name: name.clone(),
                albedo: m.albedo,
                specular: m.specular,
                shininess: m.shininess,
                interreflection: m.interreflection,
                interreflection_radius: m.interreflection_radius,
                texture,
            });
        }
        let mut objects = Vec::new();
        for (i, o) in file.object.iter().enumerate() {
            let f = |field: &str| format!("object[{i}].{field}");
            let material = *index.get(&o.material).ok_or_else(|| {
                Error::invalid(
                    ctx,
                    f("material"),
                    format!("no [material.{}] in the scene", o.material),
                )
            })?;
            let need3 = |v: Option<[f64; 3]>, field: &str| {
                v.filter(|a| a.iter().all(|x| x.is_finite()))
                    .ok_or_else(|| {
                        Error::invalid(
                            ctx,
                            f(field),
                            format!("`{}` needs a finite {field}", o.shape),
                        )
                    })
            };
            let need1 = |v: Option<f64>, field: &str| {
                v.filter(|x| x.is_finite() && *x > 0.0).ok_or_else(|| {
                    Error::invalid(
                        ctx,
                        f(field),
                        format!("`{}` needs a positive {field}", o.shape),
                    )
                })
            };
            let r: Mat3 = rotation_xyz_deg(o.rotation_deg.unwrap_or([0.0; 3]));
            let scale = o.scale.unwrap_or(1.0);
            let position = Vec3::from(o.position.unwrap_or([0.0; 3]));
            let markers = match &o.markers {
                None => None,
                Some(file) => {
                    let gauge = Gauge::load(&base.join(file))?;
                    let albedo = o.marker_albedo.unwrap_or(0.85);
                    if !(0.0..=1.0).contains(&albedo) {
                        return Err(Error::invalid(
                            ctx,
                            f("marker_albedo"),
                            format!("{albedo} is outside 0..1"),
                        ));
                    }
                    let centers: Vec<Vec3> = gauge
                        .centers
                        .iter()
                        .map(|c| r * (c * scale) + position)
                        .collect();
                    Some(MarkerPaint::new(&centers, gauge.radius * scale, albedo))
                }
            };
            let mut wear = None;
            if o.wear.is_some() && o.shape != "panel" {
                return Err(Error::invalid(ctx, f("wear"), "only a panel wears"));
            }
            let shape = match o.shape.as_str() {
                "plane" => Shape::Plane,
                "box" => {
                    let size = need3(o.size, "size")?;
                    if size.iter().any(|s| *s <= 0.0) {
                        return Err(Error::invalid(ctx, f("size"), "must be positive"));
                    }
                    Shape::Box {
                        center: Vec3::from(need3(o.center, "center")?),
                        half: Vec3::from(size) / 2.0,
                    }
                }
                "sphere" => Shape::Sphere {
                    center: Vec3::from(need3(o.center, "center")?),
                    radius: need1(o.radius, "radius")?,
                },
                "dome" => Shape::dome(
                    Vec3::from(need3(o.center, "center")?),
                    need1(o.radius, "radius")?,
                    need1(o.height, "height")?,
                ),
                "cylinder" => {
                    let axis = Vec3::from(o.axis.unwrap_or([0.0, 0.0, 1.0]));
                    let length = axis.norm();
                    if !(length.is_finite() && length > 1e-12) {
                        return Err(Error::invalid(
                            ctx,
                            f("axis"),
                            "must be a finite, non-zero direction",
                        ));
                    }
                    Shape::Cylinder {
                        center: Vec3::from(need3(o.center, "center")?),
                        axis: axis / length,
                        radius: need1(o.radius, "radius")?,
                        half_height: need1(o.height, "height")? / 2.0,
                    }
                }
                "mesh" => {
                    let file_name = o.file.as_ref().ok_or_else(|| {
                        Error::invalid(ctx, f("file"), "a mesh needs an STL file")
                    })?;
                    let mut mesh = TriangleMesh::load(&base.join(file_name))?;
                    mesh.transform(&r, scale, &position);
                    Shape::Mesh(Box::new(Bvh::new(mesh)))
                }
                "panel" => {
                    let size = need3(o.size, "size")?;
                    if size[0] <= 0.0 || size[1] <= 0.0 {
                        return Err(Error::invalid(ctx, f("size"), "x and y must be positive"));
                    }
                    let curvature = o.curvature.unwrap_or([0.0, 0.0]);
                    if !(curvature[0].is_finite() && curvature[1].is_finite()) {
                        return Err(Error::invalid(ctx, f("curvature"), "must be finite"));
                    }
                    if let Some(w) = &o.wear {
                        let ok = w.center.iter().all(|c| c.is_finite())
                            && w.radius.is_finite()
                            && w.radius >= 8.0
                            && w.radius <= size[0].max(size[1])
                            && w.depth.is_finite()
                            && w.growth.is_finite()
                            && w.depth.abs() <= 100.0
                            && w.growth.abs() <= 10.0;
                        if !ok {
                            return Err(Error::invalid(
                                ctx,
                                f("wear"),
                                "center finite, radius within 8 mm … the panel's size, |depth| ≤ 100 mm, |growth| ≤ 10 mm per scan",
                            ));
                        }
                    }
                    let size = [size[0], size[1]];
                    wear = o.wear.map(|w| PanelWear {
                        size,
                        curvature,
                        rotation: r,
                        scale,
                        position,
                        wear: w,
                    });
                    let mesh = match &wear {
                        Some(w) => w.mesh(0),
                        None => panel_mesh(size, curvature, None, &r, scale, &position),
                    };
                    Shape::Mesh(Box::new(Bvh::new(mesh)))
                }
                other => {
                    return Err(Error::invalid(
                        ctx,
                        f("shape"),
                        format!(
                        "unknown shape `{other}` (plane, box, sphere, dome, cylinder, mesh, panel)"
                    ),
                    ))
                }
            };
            let velocity = match o.velocity {
                None => Vec3::zeros(),
                Some(v) if v.iter().all(|x| x.is_finite() && x.abs() <= 1e6) => {
                    if matches!(shape, Shape::Plane) && v.iter().any(|x| *x != 0.0) {
                        return Err(Error::invalid(
                            ctx,
                            f("velocity"),
                            "the reference plane does not move",
                        ));
                    }
                    Vec3::new(v[0], v[1], v[2])
                }
                Some(v) => {
                    return Err(Error::invalid(
                        ctx,
                        f("velocity"),
                        format!("{v:?}: each component must be a number of mm/s within ±1e6"),
                    ))
                }
            };
            let mut object = Object::still(shape, material, markers);
            object.velocity = velocity;
            object.wear = wear;
            objects.push(object);
        }
        if objects.is_empty() && file.calibration.is_none() {
            return Err(Error::invalid(ctx, "object", "the scene has no objects"));
        }
        Ok(Scene {
            camera: s.camera,
            exposure: c.exposure,
            noise: c.noise,
            shot_noise: c.shot_noise,
            projector,
            ambient: p.ambient,
            blur: p.blur,
            materials,
            objects,
            render: file.render.clone(),
            file,
        })
    }

    /// The same scene with every material replaced by a diffuse, untextured albedo of 0.7 and
    /// painted markers removed: the part powder-sprayed, the reference of the completeness
    /// experiment (Table 7.1). Material indices and names are kept.
    pub fn sprayed(&self) -> Scene {
        let mut s = self.clone();
        for m in &mut s.materials {
            m.albedo = 0.7;
            m.specular = 0.0;
            m.shininess = 0.0;
            m.interreflection = 0.0;
            m.interreflection_radius = 0.0;
            m.texture = Texture::None;
        }
        for o in &mut s.objects {
            o.markers = None;
        }
        s
    }

    /// The same cell with only its reference plane (z = 0): the scene's plane objects, or a
    /// diffuse plane of albedo 0.7 if it has none.
    pub fn reference(&self) -> Scene {
        let mut s = self.clone();
        s.objects.retain(|o| matches!(o.shape, Shape::Plane));
        if s.objects.is_empty() {
            s.materials.push(Material {
                name: "reference_plane".into(),
                albedo: 0.7,
                specular: 0.0,
                shininess: 0.0,
                interreflection: 0.0,
                interreflection_radius: 0.0,
                texture: Texture::None,
            });
            s.objects
                .push(Object::still(Shape::Plane, s.materials.len() - 1, None));
        }
        s
    }

    /// Albedo of object `obj` at surface point `p` (material, texture, painted markers; they
    /// move with the object).
    pub fn albedo(&self, obj: usize, p: &Vec3) -> f64 {
        let o = &self.objects[obj];
        let p = p - o.offset;
        if let Some(m) = o.markers.as_ref().filter(|m| m.covers(&p)) {
            return m.albedo;
        }
        let mat = &self.materials[o.material];
        (mat.albedo * mat.texture.factor(&p)).clamp(0.0, 1.0)
    }

    /// The scene `t` seconds after the pose its file gives: every object displaced by its
    /// velocity × `t`.
    pub fn at(&self, t: f64) -> Scene {
        let mut s = self.clone();
        for o in &mut s.objects {
            o.offset = o.velocity * t;
        }
        s
    }

    /// The scene as it is in the cell's `scans`-th scan: every wearing panel's dent that deep.
    pub fn worn(&self, scans: u64) -> Scene {
        let mut s = self.clone();
        for o in &mut s.objects {
            if let Some(w) = &o.wear {
                o.shape = Shape::Mesh(Box::new(Bvh::new(w.mesh(scans))));
            }
        }
        s
    }

    /// Whether any object wears scan by scan.
    pub fn wears(&self) -> bool {
        self.objects.iter().any(|o| o.wear.is_some())
    }

    /// Whether any object moves.
    pub fn moving(&self) -> bool {
        self.objects.iter().any(|o| o.velocity.norm() > 0.0)
    }

    /// Nearest hit along `o + t d`, `t` in `(t_min, t_max)`: (t, outward unit normal, object).
    pub fn intersect(
        &self,
        o: &Vec3,
        d: &Vec3,
        t_min: f64,
        t_max: f64,
    ) -> Option<(f64, Vec3, usize)> {
        let mut best: Option<(f64, Vec3, usize)> = None;
        let mut limit = t_max;
        for (i, obj) in self.objects.iter().enumerate() {
            // A displaced object: the ray moved the other way.
            let from = o - obj.offset;
            if let Some((t, n)) = obj.shape.intersect(&from, d, t_min, limit) {
                limit = t;
                best = Some((t, n, i));
            }
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_blur_beyond_the_projector_is_refused_by_field() {
        let tiny = include_str!("../../../config/scenes/tiny.toml");
        let parse = |blur: &str| {
            let text = tiny.replace("blur = 0.5", &format!("blur = {blur}"));
            assert!(text.contains(&format!("blur = {blur}")));
            let file: SceneFile = toml::from_str(&text).expect("toml");
            Scene::from_file(file, Path::new("."), "tiny.toml")
        };
        assert!(parse("2.0").is_ok());
        for blur in ["100000.0", "1e300"] {
            let e = parse(blur).expect_err(blur).to_string();
            assert!(
                e.contains("tiny.toml") && e.contains("projector.blur"),
                "{e}"
            );
        }
    }

    #[test]
    fn a_wearing_panel_deepens_its_dent_scan_by_scan_and_bad_wear_is_refused() {
        let scene = include_str!("../../../config/wear-cell/s1.toml");
        let load = |text: &str| {
            let file: SceneFile = toml::from_str(text).expect("toml");
            Scene::from_file(file, Path::new("."), "s1.toml")
        };
        let s = load(scene).expect("the wear cell's scene");
        assert!(s.wears() && !s.moving());
        // Straight down onto the dent's centre (60, -40) and onto an untouched spot.
        let height = |sc: &Scene, x: f64, y: f64| {
            let (t, _, _) = sc
                .intersect(
                    &Vec3::new(x, y, 100.0),
                    &Vec3::new(0.0, 0.0, -1.0),
                    0.0,
                    1e3,
                )
                .expect("hit");
            100.0 - t
        };
        for (scans, depth) in [(0, 0.0), (8, 0.0), (9, 0.05), (20, 0.6)] {
            let w = s.worn(scans);
            // The centre lies between the 4 mm grid's vertices: within 1 % of the depth.
            let h = height(&w, 60.0, -40.0);
            assert!(
                (h - (3.0 - depth)).abs() <= 0.01 * depth + 1e-9,
                "scan {scans}: {h}"
            );
            assert!(
                (height(&w, -200.0, 100.0) - 3.0).abs() < 1e-9,
                "scan {scans}"
            );
        }
        for (bad, field) in [
            ("radius = 40.0", "radius = 1e9"),
            ("growth = 0.05", "growth = 1e6"),
        ] {
            let e = load(&scene.replace(bad, field))
                .expect_err(field)
                .to_string();
            assert!(e.contains("wear"), "{e}");
        }
        let plane = scene.replace(
            "shape = \"panel\"\nmaterial = \"plate\"",
            "shape = \"box\"\nmaterial = \"plate\"\ncenter = [0.0, 0.0, 0.0]",
        );
        let e = load(&plane).expect_err("only a panel wears").to_string();
        assert!(e.contains("only a panel wears"), "{e}");
    }
}
