//! STEP CAD (ISO 10303-21: AP203, AP214, AP242) read through OpenCASCADE (feature `step`, Debian's
//! `libocct-data-exchange-dev`) and tessellated face by face to a chordal tolerance, so that every
//! triangle keeps the B-rep face it came from: faces are what datums, features and tolerances
//! name. Each face carries its STEP entity number (`#n` in the file), its name and, for the
//! analytic surfaces, their parameters.
//!
//! The file is checked before OpenCASCADE sees it (size, the ISO 10303-21 header and trailer, a
//! DATA section); transfer and meshing stop at a deadline and the tessellation at a triangle
//! budget, so a hostile or broken file is refused by name in bounded time and memory.

use super::TriangleMesh;
use crate::geometry::Vec3;
use crate::{Error, Result};
use std::path::Path;
use std::time::Duration;

/// How a STEP model is tessellated and bounded.
#[derive(Clone, Debug)]
pub struct StepOptions {
    /// Largest distance between a triangle and the surface it stands for, mm.
    pub chordal: f64,
    /// Largest angle between the normals of neighbouring triangles on a curved face, radians.
    pub angular: f64,
    /// Most triangles the tessellation may have; a finer one is refused (raise `chordal`).
    pub max_triangles: usize,
    /// Most time the transfer and the meshing may take.
    pub deadline: Duration,
    /// Largest file read, bytes.
    pub max_bytes: u64,
}

impl Default for StepOptions {
    fn default() -> Self {
        StepOptions {
            chordal: 0.01,
            angular: 0.35,
            max_triangles: 10_000_000,
            deadline: Duration::from_secs(120),
            max_bytes: 1 << 30,
        }
    }
}

/// The surface under one B-rep face, in the model's frame (mm, unit vectors).
#[derive(Clone, Debug, PartialEq)]
pub enum FaceSurface {
    /// A plane through `origin` with outward `normal` (the face's orientation applied).
    Plane {
        /// A point of the plane.
        origin: Vec3,
        /// Outward unit normal.
        normal: Vec3,
    },
    /// A circular cylinder.
    Cylinder {
        /// A point of the axis.
        origin: Vec3,
        /// Unit axis direction.
        axis: Vec3,
        /// Radius, mm.
        radius: f64,
    },
    /// A circular cone: radius `radius` at `origin`, growing by `tan(half_angle)` along `axis`.
    Cone {
        /// The point of the axis where the radius is `radius`.
        origin: Vec3,
        /// Unit axis direction.
        axis: Vec3,
        /// Radius at `origin`, mm.
        radius: f64,
        /// Half the apex angle, radians (negative when the cone narrows along `axis`).
        half_angle: f64,
    },
    /// A sphere.
    Sphere {
        /// Centre.
        centre: Vec3,
        /// Radius, mm.
        radius: f64,
    },
    /// A torus (fillets of round edges, grooves).
    Torus {
        /// Centre.
        centre: Vec3,
        /// Unit axis direction.
        axis: Vec3,
        /// Distance of the tube's centre line from the axis, mm.
        major: f64,
        /// Radius of the tube, mm.
        minor: f64,
    },
    /// A B-spline or Bézier surface.
    Freeform,
    /// A surface of revolution or extrusion, or an offset surface.
    Swept,
    /// Any other surface.
    Other,
}

impl FaceSurface {
    /// The surface kind in one word (`plane`, `cylinder`, …).
    pub fn kind(&self) -> &'static str {
        match self {
            FaceSurface::Plane { .. } => "plane",
            FaceSurface::Cylinder { .. } => "cylinder",
            FaceSurface::Cone { .. } => "cone",
            FaceSurface::Sphere { .. } => "sphere",
            FaceSurface::Torus { .. } => "torus",
            FaceSurface::Freeform => "freeform",
            FaceSurface::Swept => "swept",
            FaceSurface::Other => "other",
        }
    }
}

/// One B-rep face of a STEP model.
#[derive(Clone, Debug)]
pub struct CadFace {
    /// The face's STEP entity number (`#n` of its ADVANCED_FACE), 0 when OpenCASCADE could not
    /// tell it.
    pub entity: u32,
    /// The entity's name in the file (often empty).
    pub name: String,
    /// The surface under the face.
    pub surface: FaceSurface,
    /// How many triangles of the mesh belong to the face.
    pub triangles: usize,
}

/// A CAD model: its tessellation, each triangle's face and the faces.
#[derive(Clone, Debug)]
pub struct CadModel {
    /// The tessellation (vertices welded across faces where they coincide).
    pub mesh: TriangleMesh,
    /// Per triangle of `mesh`: the index of its face in `faces`.
    pub face_of: Vec<u32>,
    /// The B-rep faces, in the order OpenCASCADE explores the shape.
    pub faces: Vec<CadFace>,
    /// Faces that have no triangles (degenerate, or the mesher failed on them).
    pub untriangulated: usize,
}

impl CadModel {
    /// Index in [`CadModel::faces`] of the face whose ADVANCED_FACE is entity `#entity`.
    pub fn face(&self, entity: u32) -> Option<usize> {
        self.faces.iter().position(|f| f.entity == entity)
    }

    /// Per triangle of the mesh, whether it belongs to one of the faces `#entities`; `ctx`
    /// names where the list came from in the error that names a face the model lacks.
    pub fn triangles_of(&self, entities: &[u32], ctx: &str) -> Result<Vec<bool>> {
        let mut index = Vec::with_capacity(entities.len());
        for &n in entities {
            let Some(i) = self.face(n) else {
                let mut known: Vec<String> = self
                    .faces
                    .iter()
                    .map(|f| format!("#{}", f.entity))
                    .collect();
                let more = if known.len() > 12 { ", …" } else { "" };
                known.truncate(12);
                return Err(Error::invalid(
                    ctx,
                    "faces",
                    format!(
                        "the STEP model has no face #{n} (its faces are {}{more})",
                        known.join(", ")
                    ),
                ));
            };
            index.push(i as u32);
        }
        Ok(self.face_of.iter().map(|f| index.contains(f)).collect())
    }
}

/// Whether `bytes` begin like a STEP file (the ISO 10303-21 header keyword).
pub fn looks_like(bytes: &[u8]) -> bool {
    let head = &bytes[..bytes.len().min(256)];
    let start = head
        .iter()
        .position(|b| !b.is_ascii_whitespace() && *b != 0xEF && *b != 0xBB && *b != 0xBF)
        .unwrap_or(head.len());
    head[start..]
        .get(..12)
        .is_some_and(|s| s.eq_ignore_ascii_case(b"ISO-10303-21"))
}

/// Check the file's framing before OpenCASCADE parses it: size, header, DATA section, trailer.
fn check_framing(path: &Path, options: &StepOptions) -> Result<()> {
    let bad = |message: String| Error::Format {
        path: path.to_path_buf(),
        message,
    };
    let size = std::fs::metadata(path)
        .map_err(|e| Error::io(path, e))?
        .len();
    if size > options.max_bytes {
        return Err(bad(format!(
            "STEP file of {size} bytes is larger than the {} bytes read",
            options.max_bytes
        )));
    }
    // The header, the DATA keyword and the trailer are checked in a bounded buffer: OpenCASCADE
    // reads the file next, and a copy of it here would double the memory a large model costs.
    use std::io::{Read, Seek, SeekFrom};
    let mut file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let mut chunk = vec![0u8; 1 << 20];
    let mut carry: Vec<u8> = Vec::new();
    let (mut first, mut data) = (true, false);
    loop {
        let n = file.read(&mut chunk).map_err(|e| Error::io(path, e))?;
        if n == 0 {
            break;
        }
        let mut window = std::mem::take(&mut carry);
        window.extend_from_slice(&chunk[..n]);
        if first && !looks_like(&window) {
            return Err(bad(
                "not a STEP file: it does not begin with ISO-10303-21;".into()
            ));
        }
        first = false;
        if window.windows(5).any(|w| w == b"DATA;") {
            data = true;
            break;
        }
        carry = window[window.len().saturating_sub(4)..].to_vec();
    }
    if first {
        return Err(bad(
            "not a STEP file: it does not begin with ISO-10303-21;".into()
        ));
    }
    if !data {
        return Err(bad("STEP file has no DATA section".into()));
    }
    let back = size.min(4096);
    file.seek(SeekFrom::Start(size - back))
        .map_err(|e| Error::io(path, e))?;
    let mut tail = Vec::with_capacity(back as usize);
    file.read_to_end(&mut tail)
        .map_err(|e| Error::io(path, e))?;
    let tail = String::from_utf8_lossy(&tail);
    let tail = tail.trim_end();
    if !tail
        .get(tail.len().saturating_sub(40)..)
        .unwrap_or(tail)
        .contains("END-ISO-10303-21;")
    {
        return Err(bad(
            "STEP file is truncated: it does not end with END-ISO-10303-21;".into(),
        ));
    }
    Ok(())
}

/// Read and tessellate the STEP model at `path`.
pub fn read(path: &Path, options: &StepOptions) -> Result<CadModel> {
    let bad = |message: String| Error::Format {
        path: path.to_path_buf(),
        message,
    };
    if !(options.chordal.is_finite() && options.chordal > 0.0) {
        return Err(bad(format!(
            "chordal tolerance {} mm: give a positive number",
            options.chordal
        )));
    }
    if !(options.angular.is_finite() && options.angular > 0.0 && options.angular < 1.6) {
        return Err(bad(format!(
            "angular tolerance {} rad: give a value in (0, 1.6)",
            options.angular
        )));
    }
    check_framing(path, options)?;
    let raw = occt::read(path, options).map_err(bad)?;
    finish(path, raw)
}

/// What the OpenCASCADE side hands back, before welding.
#[cfg_attr(not(feature = "step"), allow(dead_code))]
struct Raw {
    vertices: Vec<Vec3>,
    triangles: Vec<[u32; 3]>,
    face_of: Vec<u32>,
    faces: Vec<CadFace>,
    untriangulated: usize,
}

/// Weld the faces' vertices where they coincide and drop zero-area triangles, keeping each
/// triangle's face.
fn finish(path: &Path, raw: Raw) -> Result<CadModel> {
    let tris: Vec<[Vec3; 3]> = raw
        .triangles
        .iter()
        .map(|t| t.map(|i| raw.vertices[i as usize]))
        .collect();
    let (mesh, kept) = super::stl::weld_tagged(tris);
    if mesh.triangles.is_empty() {
        return Err(Error::Format {
            path: path.to_path_buf(),
            message: "STEP model has no usable triangle".into(),
        });
    }
    let face_of: Vec<u32> = kept.iter().map(|&i| raw.face_of[i]).collect();
    let mut faces = raw.faces;
    for f in &mut faces {
        f.triangles = 0;
    }
    for &f in &face_of {
        faces[f as usize].triangles += 1;
    }
    Ok(CadModel {
        mesh,
        face_of,
        faces,
        untriangulated: raw.untriangulated,
    })
}

#[cfg(not(feature = "step"))]
mod occt {
    use super::{Raw, StepOptions};
    use std::path::Path;

    pub(super) fn read(_: &Path, _: &StepOptions) -> Result<Raw, String> {
        Err(
            "this build of RIS reads no STEP: build it with the `step` feature \
             (cargo build --features step; needs Debian's libocct-data-exchange-dev), \
             or export the CAD as STL, PLY or OBJ"
                .into(),
        )
    }
}

#[cfg(feature = "step")]
#[allow(unsafe_code)] // the C interface of core/src/mesh/step.cpp: one call in, one free
mod occt {
    use super::{CadFace, FaceSurface, Raw, StepOptions};
    use crate::geometry::Vec3;
    use std::ffi::{c_char, CStr, CString};
    use std::path::Path;
    use std::sync::Mutex;

    #[repr(C)]
    struct RisStepFace {
        kind: i32,
        reversed: i32,
        origin: [f64; 3],
        axis: [f64; 3],
        radius: f64,
        radius2: f64,
        entity: i32,
        triangles: i32,
    }

    #[repr(C)]
    struct RisStepMesh {
        vertices: *mut f64,
        n_vertices: usize,
        triangles: *mut u32,
        face_of: *mut u32,
        n_triangles: usize,
        faces: *mut RisStepFace,
        n_faces: usize,
        names: *mut c_char,
        untriangulated: usize,
        lo: [f64; 3],
        hi: [f64; 3],
        error: *mut c_char,
    }

    extern "C" {
        fn ris_step_read(
            path: *const c_char,
            chordal: f64,
            angular: f64,
            max_triangles: usize,
            seconds: f64,
            out: *mut RisStepMesh,
        ) -> i32;
        fn ris_step_free(m: *mut RisStepMesh);
    }

    /// OpenCASCADE's STEP settings are process-wide: one read at a time.
    static LOCK: Mutex<()> = Mutex::new(());

    /// A slice from a pointer and a length that may be null and zero.
    fn slice<'a, T>(p: *const T, n: usize) -> &'a [T] {
        if p.is_null() || n == 0 {
            &[]
        } else {
            // SAFETY: the C side allocated `n` elements at `p` and frees them only in
            // `ris_step_free`, after the last use of the slice.
            unsafe { std::slice::from_raw_parts(p, n) }
        }
    }

    pub(super) fn read(path: &Path, options: &StepOptions) -> Result<Raw, String> {
        let c_path = CString::new(path.as_os_str().as_encoded_bytes())
            .map_err(|_| "path holds a NUL byte".to_string())?;
        let _guard = LOCK.lock().unwrap_or_else(|e| e.into_inner());
        // SAFETY: RisStepMesh is plain data; the C side fills it (all null on entry).
        let mut m: RisStepMesh = unsafe { std::mem::zeroed() };
        // SAFETY: `c_path` is a NUL-terminated string alive for the call; `m` is writable.
        let rc = unsafe {
            ris_step_read(
                c_path.as_ptr(),
                options.chordal,
                options.angular,
                options.max_triangles,
                options.deadline.as_secs_f64(),
                &mut m,
            )
        };
        let result = if rc != 0 {
            let message = if m.error.is_null() {
                "OpenCASCADE failed without a message".to_string()
            } else {
                // SAFETY: the C side wrote a NUL-terminated string.
                unsafe { CStr::from_ptr(m.error) }
                    .to_string_lossy()
                    .into_owned()
            };
            Err(message)
        } else {
            Ok(copy(&m))
        };
        // SAFETY: `m` was filled by `ris_step_read` and is freed once.
        unsafe { ris_step_free(&mut m) };
        result
    }

    fn copy(m: &RisStepMesh) -> Raw {
        let vertices = slice(m.vertices, m.n_vertices * 3)
            .chunks_exact(3)
            .map(|c| Vec3::new(c[0], c[1], c[2]))
            .collect();
        let triangles = slice(m.triangles, m.n_triangles * 3)
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect();
        let face_of = slice(m.face_of, m.n_triangles).to_vec();
        let names: Vec<String> = if m.names.is_null() {
            Vec::new()
        } else {
            // SAFETY: the C side wrote a NUL-terminated string.
            unsafe { CStr::from_ptr(m.names) }
                .to_string_lossy()
                .split('\n')
                .map(str::to_string)
                .collect()
        };
        let faces = slice(m.faces, m.n_faces)
            .iter()
            .enumerate()
            .map(|(i, f)| {
                let o = Vec3::from(f.origin);
                let a = Vec3::from(f.axis);
                let surface = match f.kind {
                    1 => FaceSurface::Plane {
                        origin: o,
                        normal: a,
                    },
                    2 => FaceSurface::Cylinder {
                        origin: o,
                        axis: a,
                        radius: f.radius,
                    },
                    3 => FaceSurface::Cone {
                        origin: o,
                        axis: a,
                        radius: f.radius,
                        half_angle: f.radius2,
                    },
                    4 => FaceSurface::Sphere {
                        centre: o,
                        radius: f.radius,
                    },
                    5 => FaceSurface::Torus {
                        centre: o,
                        axis: a,
                        major: f.radius,
                        minor: f.radius2,
                    },
                    6 => FaceSurface::Freeform,
                    7 | 8 => FaceSurface::Swept,
                    _ => FaceSurface::Other,
                };
                CadFace {
                    entity: u32::try_from(f.entity).unwrap_or(0),
                    name: names.get(i).cloned().unwrap_or_default(),
                    surface,
                    triangles: usize::try_from(f.triangles).unwrap_or(0),
                }
            })
            .collect();
        Raw {
            vertices,
            triangles,
            face_of,
            faces,
            untriangulated: m.untriangulated,
        }
    }
}
