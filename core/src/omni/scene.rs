//! Omnidirectional room scenes (`ris simulate` of a file with `[room]`): the sensor file, the
//! room and what stands in it, and the exposure; and writing a rendered frame with its truth.

use std::path::{Path, PathBuf};

use serde::Deserialize;

use super::{render, Exposure, OmniSensor, OmniTruth, RingPattern, Room};
use crate::geometry::Vec3;
use crate::image::GrayImage;
use crate::io::{npy, read_toml, write_toml};
use crate::sim::Shape;
use crate::{Error, Result};

/// The file as written.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OmniSceneFile {
    /// The omnidirectional sensor file (SPEC §13), relative to the scene file.
    pub sensor: PathBuf,
    /// The room.
    pub room: RoomSection,
    /// What stands in it.
    #[serde(default)]
    pub object: Vec<RoomObject>,
    /// Exposure and noise.
    #[serde(default)]
    pub render: RenderSection,
}

/// `[room]`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RoomSection {
    /// Size along x and y, mm.
    pub size: [f64; 2],
    /// Centre (x, y) in the sensor frame, mm (default the sensor's axis).
    #[serde(default)]
    pub center: [f64; 2],
    /// Floor height in the sensor frame, mm.
    pub floor: f64,
    /// Ceiling height, mm.
    pub ceiling: f64,
    /// Albedo of the walls, the floor and the ceiling (default 0.6, 0.4, 0.7).
    #[serde(default = "room_albedo")]
    pub albedo: [f64; 3],
}

/// `[[object]]`: a box or a cylinder (a person-sized one stands for a person).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RoomObject {
    /// `box` or `cylinder`.
    pub shape: String,
    /// Centroid, mm.
    pub center: [f64; 3],
    /// Box size, mm.
    #[serde(default)]
    pub size: Option<[f64; 3]>,
    /// Cylinder radius, mm.
    #[serde(default)]
    pub radius: Option<f64>,
    /// Cylinder height, mm.
    #[serde(default)]
    pub height: Option<f64>,
    /// Albedo (default 0.5).
    #[serde(default = "half")]
    pub albedo: f64,
}

/// `[render]`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RenderSection {
    /// Grey level of a white surface lit head on by the projector's white.
    #[serde(default = "gain")]
    pub gain: f64,
    /// Ambient light as a fraction of the projector's white.
    #[serde(default = "ambient")]
    pub ambient: f64,
    /// Read noise σ, grey levels.
    #[serde(default = "one")]
    pub noise: f64,
    /// Noise seed.
    #[serde(default = "one_u")]
    pub seed: u64,
}

impl Default for RenderSection {
    fn default() -> Self {
        RenderSection {
            gain: gain(),
            ambient: ambient(),
            noise: one(),
            seed: one_u(),
        }
    }
}

fn room_albedo() -> [f64; 3] {
    [0.6, 0.4, 0.7]
}
fn half() -> f64 {
    0.5
}
fn gain() -> f64 {
    230.0
}
fn ambient() -> f64 {
    0.03
}
fn one() -> f64 {
    1.0
}
fn one_u() -> u64 {
    1
}

/// A validated room scene.
#[derive(Clone, Debug)]
pub struct OmniScene {
    /// The sensor.
    pub sensor: OmniSensor,
    /// Where its file is.
    pub sensor_path: PathBuf,
    /// The room.
    pub room: Room,
    /// The exposure.
    pub exposure: Exposure,
}

impl OmniScene {
    /// Whether the TOML file at `path` is a room scene (it has a `[room]` table).
    pub fn is_room_scene(path: &Path) -> bool {
        std::fs::read_to_string(path)
            .ok()
            .and_then(|t| t.parse::<toml::Table>().ok())
            .is_some_and(|t| t.contains_key("room"))
    }

    /// Read and validate `path`; errors name the file and the field.
    pub fn load(path: &Path) -> Result<OmniScene> {
        let file: OmniSceneFile = read_toml(path)?;
        let ctx = path.display().to_string();
        let bad = |field: &str, message: String| Error::invalid(&ctx, field, message);
        let base = path.parent().unwrap_or(Path::new("."));
        let sensor_path = base.join(&file.sensor);
        let sensor = OmniSensor::load(&sensor_path)?;
        let r = &file.room;
        if !(r.size.iter().all(|s| s.is_finite() && *s > 0.0)
            && r.center.iter().all(|c| c.is_finite()))
        {
            return Err(bad(
                "room.size",
                format!("{:?}: positive sizes in mm", r.size),
            ));
        }
        if !(r.floor.is_finite() && r.ceiling.is_finite() && r.floor < r.ceiling) {
            return Err(bad(
                "room.floor",
                format!("floor {} must be below ceiling {}", r.floor, r.ceiling),
            ));
        }
        if !r.albedo.iter().all(|a| (0.0..=1.0).contains(a)) {
            return Err(bad(
                "room.albedo",
                format!("{:?}: each within 0 … 1", r.albedo),
            ));
        }
        let inside = |p: &Vec3| {
            (p.x - r.center[0]).abs() < r.size[0] / 2.0
                && (p.y - r.center[1]).abs() < r.size[1] / 2.0
                && p.z > r.floor
                && p.z < r.ceiling
        };
        let mut objects = Vec::new();
        for (i, o) in file.object.iter().enumerate() {
            let f = |k: &str| format!("object[{i}].{k}");
            let center = Vec3::new(o.center[0], o.center[1], o.center[2]);
            if !(o.center.iter().all(|c| c.is_finite()) && inside(&center)) {
                return Err(bad(
                    &f("center"),
                    format!("{:?} is not inside the room", o.center),
                ));
            }
            if !(0.0..=1.0).contains(&o.albedo) {
                return Err(bad(
                    &f("albedo"),
                    format!("{} must be within 0 … 1", o.albedo),
                ));
            }
            let shape = match o.shape.as_str() {
                "box" => {
                    let s = o
                        .size
                        .filter(|s| s.iter().all(|v| v.is_finite() && *v > 0.0))
                        .ok_or_else(|| {
                            bad(&f("size"), "a box needs three positive sizes".into())
                        })?;
                    Shape::Box {
                        center,
                        half: Vec3::new(s[0], s[1], s[2]) / 2.0,
                    }
                }
                "cylinder" => {
                    let (Some(radius), Some(height)) = (o.radius, o.height) else {
                        return Err(bad(
                            &f("radius"),
                            "a cylinder needs radius and height".into(),
                        ));
                    };
                    if !(radius.is_finite() && radius > 0.0 && height.is_finite() && height > 0.0) {
                        return Err(bad(
                            &f("radius"),
                            "radius and height must be positive".into(),
                        ));
                    }
                    Shape::Cylinder {
                        center,
                        axis: Vec3::z(),
                        radius,
                        half_height: height / 2.0,
                    }
                }
                other => {
                    return Err(bad(
                        &f("shape"),
                        format!(
                            "`{}` is not box or cylinder",
                            other.chars().take(32).collect::<String>()
                        ),
                    ))
                }
            };
            objects.push((shape, o.albedo));
        }
        let e = &file.render;
        if !(e.gain.is_finite()
            && e.gain > 0.0
            && (0.0..=1.0).contains(&e.ambient)
            && e.noise.is_finite()
            && e.noise >= 0.0)
        {
            return Err(bad(
                "render",
                "gain > 0, ambient within 0 … 1, noise ≥ 0".into(),
            ));
        }
        Ok(OmniScene {
            sensor,
            sensor_path,
            room: Room {
                half: [r.size[0] / 2.0, r.size[1] / 2.0],
                center: r.center,
                floor: r.floor,
                ceiling: r.ceiling,
                albedo: r.albedo,
                objects,
            },
            exposure: Exposure {
                gain: e.gain,
                ambient: e.ambient,
                noise: e.noise,
                seed: e.seed,
            },
        })
    }

    /// The ring pattern for this sensor's projector (about its principal point).
    pub fn rings(&self) -> Result<RingPattern> {
        self.sensor.rings()
    }

    /// The camera image of the projector showing `picture`, and its truth.
    pub fn render(&self, picture: &[u8]) -> Result<(GrayImage, OmniTruth)> {
        render(&self.sensor, &self.room, picture, &self.exposure)
    }
}

/// Write `truth` into `dir`: `xyz.npy` (float32 H × W × 3, sensor frame, NaN where nothing is
/// seen), `lit.npy` (uint8 H × W, 1 where the projector lights the point) and `projector.npy`
/// (float32 H × W × 2, the projector pixel lighting it, NaN where unlit).
pub fn write_truth(truth: &OmniTruth, width: u32, height: u32, dir: &Path) -> Result<()> {
    crate::io::create_dir(dir)?;
    let (h, w) = (height as usize, width as usize);
    let xyz: Vec<f32> = truth.xyz.iter().flatten().copied().collect();
    npy::write(&dir.join("xyz.npy"), &[h, w, 3], &xyz)?;
    let lit: Vec<u8> = truth.lit.iter().map(|&l| u8::from(l)).collect();
    npy::write(&dir.join("lit.npy"), &[h, w], &lit)?;
    let proj: Vec<f32> = truth.projector.iter().flatten().copied().collect();
    npy::write(&dir.join("projector.npy"), &[h, w, 2], &proj)?;
    #[derive(serde::Serialize)]
    struct About {
        frame: &'static str,
        units: &'static str,
    }
    write_toml(
        &dir.join("truth.toml"),
        &About {
            frame: "sensor (SPEC §13, z up)",
            units: "mm",
        },
    )
}
