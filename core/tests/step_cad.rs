//! STEP CAD (issue 42 item 1): seeded families of parts (filleted blocks with through holes and a
//! countersink: planes, cylinders, spheres, a cone; shafts with a chamfer and a turned groove:
//! cylinders, planes, a cone, a torus; random sizes, random poses) written by an independent
//! OpenCASCADE (the cadquery-ocp wheel, `tests/step_parts.py`) are read by RIS (Debian's OCCT 7.6):
//! every face kept with its STEP entity number and surface kind; every vertex on the true surface;
//! every triangle within the chordal tolerance of it; each face's area and the solid's volume
//! against the exact B-rep values; the mesh closed and outward. Bad files are refused by name,
//! in bounded time.

#![cfg(feature = "step")]

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use ris_core::geometry::Vec3;
use ris_core::mesh::step::{self, CadModel, FaceSurface, StepOptions};
use ris_core::mesh::TriangleMesh;
use serde_json::Value;

mod common;

const CHORDAL: f64 = 0.01;

fn v3(v: &Value) -> Vec3 {
    Vec3::new(
        v[0].as_f64().expect("x"),
        v[1].as_f64().expect("y"),
        v[2].as_f64().expect("z"),
    )
}

/// Distance of `p` from the analytic surface of a truth face (`None` for other kinds).
fn surface_distance(face: &Value, p: &Vec3) -> Option<f64> {
    let o = v3(&face["origin"]);
    let a = v3(&face["axis"]);
    let r = face["radius"].as_f64().unwrap_or(0.0);
    let r2 = face["radius2"].as_f64().unwrap_or(0.0);
    let d = p - o;
    let axial = d.dot(&a);
    let radial = (d - a * axial).norm();
    Some(match face["kind"].as_str()? {
        "plane" => axial.abs(),
        "cylinder" => (radial - r).abs(),
        "sphere" => (d.norm() - r).abs(),
        "cone" => {
            // the cone's radius at this height, then the distance normal to its side
            let rho = r + axial * r2.tan();
            (radial - rho).abs() * r2.cos()
        }
        "torus" => ((radial - r).hypot(axial) - r2).abs(),
        _ => return None,
    })
}

fn parts(dir: &Path, seed: u64, count: usize) -> Vec<(PathBuf, Value)> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/step_parts.py");
    let out = Command::new("python3")
        .arg(&script)
        .arg(dir)
        .arg(seed.to_string())
        .arg(count.to_string())
        .output()
        .expect("python3 runs tests/step_parts.py (cadquery-ocp, installed by .ci/run)");
    assert!(
        out.status.success(),
        "step_parts.py failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    (0..count)
        .map(|k| {
            let json = std::fs::read_to_string(dir.join(format!("part_{k}.json"))).expect("truth");
            (
                dir.join(format!("part_{k}.step")),
                serde_json::from_str(&json).expect("truth json"),
            )
        })
        .collect()
}

fn area(m: &TriangleMesh, t: usize) -> f64 {
    let [a, b, c] = m.corners(t);
    0.5 * (b - a).cross(&(c - a)).norm()
}

/// Signed volume of a closed mesh (positive when its triangles face outward).
fn volume(m: &TriangleMesh) -> f64 {
    (0..m.triangles.len())
        .map(|t| {
            let [a, b, c] = m.corners(t);
            a.dot(&b.cross(&c)) / 6.0
        })
        .sum()
}

/// Edges used by other than exactly two triangles (a closed, manifold mesh has none).
fn open_edges(m: &TriangleMesh) -> usize {
    let mut count = std::collections::HashMap::<(u32, u32), u32>::new();
    for t in &m.triangles {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            *count.entry((a.min(b), a.max(b))).or_default() += 1;
        }
    }
    count.values().filter(|&&n| n != 2).count()
}

fn check_part(path: &Path, truth: &Value, model: &CadModel) -> (f64, f64) {
    let name = path.display();
    let faces = truth["faces"].as_array().expect("faces");
    assert_eq!(model.faces.len(), faces.len(), "{name}: face count");
    assert_eq!(model.untriangulated, 0, "{name}: untriangulated faces");
    let mut worst_chord: f64 = 0.0;
    let mut worst_area: f64 = 0.0;
    for tf in faces {
        let entity = tf["entity"].as_u64().expect("entity") as u32;
        let (index, face) = model
            .faces
            .iter()
            .enumerate()
            .find(|(_, f)| f.entity == entity)
            .unwrap_or_else(|| panic!("{name}: face #{entity} not read"));
        assert_eq!(
            face.surface.kind(),
            tf["kind"].as_str().expect("kind"),
            "{name}: face #{entity}"
        );
        let tris: Vec<usize> = (0..model.mesh.triangles.len())
            .filter(|&t| model.face_of[t] as usize == index)
            .collect();
        assert!(!tris.is_empty(), "{name}: face #{entity} has no triangle");
        assert_eq!(tris.len(), face.triangles, "{name}: face #{entity} count");
        let scale = 1000.0;
        for &t in &tris {
            let c = model.mesh.corners(t);
            for p in &c {
                let d = surface_distance(tf, p).expect("analytic");
                assert!(
                    d <= 1e-6 * scale,
                    "{name}: face #{entity}: a vertex {d:.2e} mm off its surface"
                );
            }
            // the chord: centroid and edge midpoints against the surface
            for p in [
                (c[0] + c[1] + c[2]) / 3.0,
                (c[0] + c[1]) / 2.0,
                (c[1] + c[2]) / 2.0,
                (c[0] + c[2]) / 2.0,
            ] {
                worst_chord = worst_chord.max(surface_distance(tf, &p).expect("analytic"));
            }
        }
        let ours: f64 = tris.iter().map(|&t| area(&model.mesh, t)).sum();
        let exact = tf["area"].as_f64().expect("area");
        let rel = (ours - exact).abs() / exact;
        worst_area = worst_area.max(rel);
        assert!(
            rel <= 0.01,
            "{name}: face #{entity} ({}) area {ours:.4} against exact {exact:.4} mm²",
            face.surface.kind()
        );
        // and against the independent tessellation of the same face (OCCT 8 in the wheel)
        let theirs = tf["mesh_area"].as_f64().expect("mesh_area");
        assert!(
            (ours - theirs).abs() / theirs <= 0.01,
            "{name}: face #{entity} area {ours:.4} against the independent mesh's {theirs:.4}"
        );
        if let (FaceSurface::Plane { normal, .. }, "plane") =
            (&face.surface, tf["kind"].as_str().unwrap_or(""))
        {
            assert!(
                normal.dot(&v3(&tf["axis"])) > 0.999_999,
                "{name}: face #{entity}: plane normal {normal:?} against {}",
                tf["axis"]
            );
        }
    }
    assert_eq!(open_edges(&model.mesh), 0, "{name}: the mesh is not closed");
    let vol = volume(&model.mesh);
    let exact = truth["volume"].as_f64().expect("volume");
    assert!(
        (vol - exact).abs() / exact < 0.002,
        "{name}: volume {vol:.3} against exact {exact:.3} mm³ (negative: faces inward)"
    );
    let (lo, hi) = model.mesh.bounds().expect("bounds");
    let (tlo, thi) = (v3(&truth["bounds"][0]), v3(&truth["bounds"][1]));
    for k in 0..3 {
        assert!((lo[k] - tlo[k]).abs() < 0.05, "{name}: bounds");
        assert!((hi[k] - thi[k]).abs() < 0.05, "{name}: bounds");
    }
    (worst_chord, worst_area)
}

#[test]
fn seeded_parts_read_with_their_faces_within_the_chordal_tolerance() {
    let dir = tempfile::tempdir().expect("tmp");
    let count = if common::long_tier() { 24 } else { 6 };
    let options = StepOptions {
        chordal: CHORDAL,
        ..StepOptions::default()
    };
    let mut worst: f64 = 0.0;
    for (path, truth) in parts(dir.path(), 42, count) {
        let t = Instant::now();
        let model = step::read(&path, &options).unwrap_or_else(|e| panic!("{e}"));
        let (chord, area) = check_part(&path, &truth, &model);
        eprintln!(
            "{}: {} faces, {} triangles, worst chord {chord:.4} mm, worst face area {:.3} %, {:.0} ms",
            path.display(),
            model.faces.len(),
            model.mesh.triangles.len(),
            area * 100.0,
            t.elapsed().as_secs_f64() * 1e3
        );
        worst = worst.max(chord);
        // the same file through the format-blind loader
        let mesh = TriangleMesh::load(&path).expect("load");
        assert_eq!(mesh.triangles.len(), model.mesh.triangles.len());
    }
    // OpenCASCADE's mesher bounds the chord of edges and faces to the deflection asked for
    // (24 seeded parts of the long tier: at most 0.0092 mm for 0.01 asked)
    assert!(
        worst <= CHORDAL,
        "worst chord {worst} mm against the {CHORDAL} mm asked for"
    );
}

#[test]
fn bad_step_files_are_refused_by_name_in_bounded_time() {
    let dir = tempfile::tempdir().expect("tmp");
    let (good, _) = parts(dir.path(), 7, 1).remove(0);
    let text = std::fs::read_to_string(&good).expect("good");
    let data = text.find("DATA;").expect("DATA");
    let cases: Vec<(&str, String, &str)> = vec![
        ("text.step", "solid nothing\n".into(), "not a STEP file"),
        ("empty.step", String::new(), "not a STEP file"),
        (
            "truncated.step",
            text[..text.len() * 2 / 3].into(),
            "truncated",
        ),
        (
            "nodata.step",
            "ISO-10303-21;\nHEADER;\nENDSEC;\nEND-ISO-10303-21;\n".into(),
            "no DATA section",
        ),
        (
            "noshape.step",
            format!("{}DATA;\nENDSEC;\nEND-ISO-10303-21;\n", &text[..data]),
            "no shape",
        ),
        (
            "garbage.step",
            format!(
                "{}DATA;\n#1=((((;\n#2=FOO(#1,,);\nENDSEC;\nEND-ISO-10303-21;\n",
                &text[..data]
            ),
            "",
        ),
    ];
    for (name, body, expected) in cases {
        let p = dir.path().join(name);
        std::fs::write(&p, body).expect("write");
        let t = Instant::now();
        let err = step::read(&p, &StepOptions::default())
            .expect_err(name)
            .to_string();
        assert!(
            err.contains(name),
            "{name}: the error names the file: {err}"
        );
        assert!(err.contains(expected), "{name}: {err}");
        assert!(
            !err.contains(".cxx") && !err.contains(".rs:"),
            "{name}: {err}"
        );
        assert!(
            t.elapsed() < Duration::from_secs(30),
            "{name}: bounded time"
        );
        // the format-blind loader refuses it the same way
        assert!(TriangleMesh::load(&p).is_err(), "{name}");
    }
    // a tessellation over its budget and a deadline already passed: refused, not run to the end
    let budget = StepOptions {
        max_triangles: 500,
        ..StepOptions::default()
    };
    let err = step::read(&good, &budget).expect_err("budget").to_string();
    assert!(err.contains("500 triangles"), "{err}");
    let late = StepOptions {
        deadline: Duration::ZERO,
        ..StepOptions::default()
    };
    let err = step::read(&good, &late).expect_err("deadline").to_string();
    assert!(err.contains("longer than the time allowed"), "{err}");
    for chordal in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        let o = StepOptions {
            chordal,
            ..StepOptions::default()
        };
        let err = step::read(&good, &o).expect_err("chordal").to_string();
        assert!(err.contains("chordal tolerance"), "{err}");
    }
}
