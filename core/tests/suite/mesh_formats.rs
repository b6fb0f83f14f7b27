//! CAD formats (issue 17): the same panel written as binary STL, ASCII and binary PLY (quads,
//! extra properties and elements) and OBJ (quads, `v/vt/vn` references, negative indices) reads
//! to the same surface and gives the same inspection; malformed files are refused naming what
//! is wrong.

use std::fmt::Write as _;
use std::path::Path;

use ris_core::inspect::{inspect, InspectParams};
use ris_core::mesh::{stl, SignedDistance, TriangleMesh};

use crate::common;
use common::Rng;

const NX: usize = 40;
const NY: usize = 30;

/// The grid vertices (f32-exact, as STL stores them) of a doubly curved panel, row-major.
fn grid() -> Vec<[f32; 3]> {
    let mut v = Vec::new();
    for j in 0..=NY {
        for i in 0..=NX {
            let (x, y) = (-200.0 + 10.0 * i as f64, -150.0 + 10.0 * j as f64);
            v.push([
                x as f32,
                y as f32,
                (-(x * x) / 3000.0 + y * y / 5000.0) as f32,
            ]);
        }
    }
    v
}

/// Quads (counter-clockwise from +z) of the grid.
fn quads() -> Vec<[usize; 4]> {
    let id = |i: usize, j: usize| j * (NX + 1) + i;
    let mut q = Vec::new();
    for j in 0..NY {
        for i in 0..NX {
            q.push([id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    q
}

fn write_all(dir: &Path) {
    let (v, q) = (grid(), quads());
    // STL: each quad as the fan the other readers make of it.
    let mut mesh = TriangleMesh {
        vertices: v
            .iter()
            .map(|p| ris_core::geometry::Vec3::new(p[0].into(), p[1].into(), p[2].into()))
            .collect(),
        triangles: Vec::new(),
    };
    for f in &q {
        let f = f.map(|i| i as u32);
        mesh.triangles.push([f[0], f[1], f[2]]);
        mesh.triangles.push([f[0], f[2], f[3]]);
    }
    stl::write_binary(&dir.join("panel.stl"), &mesh).expect("stl");

    // ASCII PLY with normals and a colour on the vertices, and an edge element after the faces.
    let mut t = format!(
        "ply\nformat ascii 1.0\ncomment made by a test\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nproperty float nx\nproperty float ny\nproperty float nz\nproperty uchar red\nelement face {}\nproperty list uchar int vertex_indices\nelement edge 1\nproperty int vertex1\nproperty int vertex2\nend_header\n",
        v.len(),
        q.len()
    );
    for p in &v {
        writeln!(t, "{} {} {} 0 0 1 200", p[0], p[1], p[2]).expect("fmt");
    }
    for f in &q {
        writeln!(t, "4 {} {} {} {}", f[0], f[1], f[2], f[3]).expect("fmt");
    }
    t.push_str("0 1\n");
    std::fs::write(dir.join("panel_ascii.ply"), t).expect("ply");

    // Binary little-endian PLY with double coordinates and an int-counted list.
    let mut b = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty double x\nproperty double y\nproperty double z\nelement face {}\nproperty list int uint vertex_index\nproperty uchar flags\nend_header\n",
        v.len(),
        q.len()
    )
    .into_bytes();
    for p in &v {
        for c in p {
            b.extend_from_slice(&f64::from(*c).to_le_bytes());
        }
    }
    for f in &q {
        b.extend_from_slice(&4i32.to_le_bytes());
        for i in f {
            b.extend_from_slice(&(*i as u32).to_le_bytes());
        }
        b.push(7);
    }
    std::fs::write(dir.join("panel_binary.ply"), b).expect("ply");

    // OBJ: quads, texture and normal references, and negative indices for the second half.
    let mut o = String::from("# a test panel\nmtllib none.mtl\no panel\n");
    for p in &v {
        writeln!(o, "v {} {} {}", p[0], p[1], p[2]).expect("fmt");
    }
    o.push_str("vt 0 0\nvn 0 0 1\ns off\n");
    let n = v.len() as i64;
    for (k, f) in q.iter().enumerate() {
        if k % 2 == 0 {
            writeln!(
                o,
                "f {}/1/1 {}/1/1 {}//1 {}",
                f[0] + 1,
                f[1] + 1,
                f[2] + 1,
                f[3] + 1
            )
        } else {
            let r = |i: usize| i as i64 - n;
            writeln!(o, "f {} {} {} {}", r(f[0]), r(f[1]), r(f[2]), r(f[3]))
        }
        .expect("fmt");
    }
    std::fs::write(dir.join("panel.obj"), o).expect("obj");
}

#[test]
fn stl_ply_and_obj_meshes_read_to_the_same_surface_and_inspection() {
    let dir = tempfile::tempdir().expect("tmp");
    write_all(dir.path());
    let stl = TriangleMesh::load(&dir.path().join("panel.stl")).expect("stl");
    assert_eq!(stl.triangles.len(), 2 * NX * NY);
    let reference = SignedDistance::new(stl);
    // A measured cloud: the panel with a dent, noise, slightly off its nominal pose.
    let mut r = Rng(5);
    let cloud: Vec<[f64; 3]> = (0..20_000)
        .map(|_| {
            let (x, y) = (r.range(-195.0, 195.0), r.range(-145.0, 145.0));
            let dent = -0.8 * (-((x - 40.0).powi(2) + (y + 30.0).powi(2)) / 200.0).exp();
            [
                x + 0.2,
                y - 0.1,
                -(x * x) / 3000.0 + y * y / 5000.0 + dent + 0.02 * r.gauss() + 0.1,
            ]
        })
        .collect();
    // From the nominal pose, as a cell does (a saddle alone would not pin its slide).
    let params = InspectParams {
        tolerance: 0.3,
        init: Some(ris_core::register::Pose::identity()),
        ..InspectParams::default()
    };
    let want = inspect(&cloud, &reference, &params).expect("inspection");
    for name in ["panel_ascii.ply", "panel_binary.ply", "panel.obj"] {
        let mesh = TriangleMesh::load(&dir.path().join(name)).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(mesh.triangles.len(), 2 * NX * NY, "{name}");
        assert_eq!(mesh.vertices.len(), (NX + 1) * (NY + 1), "{name}");
        let sd = SignedDistance::new(mesh);
        // The same surface: signed distances agree to float precision.
        for _ in 0..2000 {
            let p = ris_core::geometry::Vec3::new(
                r.range(-250.0, 250.0),
                r.range(-200.0, 200.0),
                r.range(-30.0, 30.0),
            );
            let (a, b) = (
                reference.query(&p).expect("query").distance,
                sd.query(&p).expect("query").distance,
            );
            assert!((a - b).abs() < 1e-4, "{name}: {a} vs {b} at {p:?}");
        }
        let got = inspect(&cloud, &sd, &params).expect("inspection");
        assert_eq!(got.report.verdict, want.report.verdict, "{name}");
        let (s, w) = (&got.report.statistics, &want.report.statistics);
        assert!(
            (s.rms - w.rms).abs() < 1e-4 && (s.mean - w.mean).abs() < 1e-4,
            "{name}: rms {} vs {}, mean {} vs {}",
            s.rms,
            w.rms,
            s.mean,
            w.mean
        );
        assert_eq!(
            got.report.regions_out_of_tolerance.len(),
            want.report.regions_out_of_tolerance.len(),
            "{name}"
        );
    }
    assert_eq!(want.report.verdict, "fail", "the dent is out of tolerance");
}

#[test]
fn malformed_meshes_are_refused_naming_what_is_wrong() {
    let dir = tempfile::tempdir().expect("tmp");
    let cases: [(&str, &[u8], &str); 10] = [
        (
            "missing.ply",
            b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n",
            "face 0 refers to vertex 7",
        ),
        (
            "cloud.ply",
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nproperty float z\nend_header\n0 0 0\n",
            "no face element",
        ),
        (
            "huge.ply",
            b"ply\nformat binary_little_endian 1.0\nelement vertex 18446744073709551615\nproperty float x\nproperty float y\nproperty float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n\x00\x00",
            "truncated",
        ),
        (
            // 1000 binary vertices need 12 000 bytes; 16 are there.
            "claims.ply",
            b"ply\nformat binary_little_endian 1.0\nelement vertex 1000\nproperty float x\nproperty float y\nproperty float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00",
            "truncated",
        ),
        (
            // The vertices are whole; the face's list stops after one of its three indices.
            "short.ply",
            b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x03\x00\x00\x00\x00",
            "ends early",
        ),
        (
            "letters.ply",
            b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 zero\n1 0 0\n0 1 0\n3 0 1 2\n",
            "`zero` is not a number",
        ),
        ("zero.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", "line 4: vertex 0 does not exist"),
        ("far.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -9\n", "line 4: vertex -9 does not exist"),
        ("two.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", "line 4: a face needs at least three"),
        ("points.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\n", "no faces"),
    ];
    for (name, bytes, needle) in cases {
        let p = dir.path().join(name);
        std::fs::write(&p, bytes).expect("write");
        let err = TriangleMesh::load(&p).expect_err(name).to_string();
        assert!(err.contains(needle) && err.contains(name), "{name}: {err}");
    }
    // Something that is none of the formats names the formats read.
    let p = dir.path().join("blob.bin");
    std::fs::write(&p, [0xffu8, 0xfe, 0x00, 0x01, 0x02]).expect("write");
    let err = TriangleMesh::load(&p).expect_err("blob").to_string();
    assert!(
        err.contains("STL") && err.contains("PLY") && err.contains("OBJ"),
        "{err}"
    );
}
