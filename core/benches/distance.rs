//! Signed distances of 200 k points to a 483 k-triangle mesh (BVH + pseudo-normal sign), the
//! coverage of that mesh by a 50 k-point subsample, and reading it as STL, PLY and OBJ.
#![allow(missing_docs)] // criterion_group! generates an undocumented public function

use criterion::{criterion_group, criterion_main, Criterion};
use ris_core::mesh::{SignedDistance, TriangleMesh};

#[path = "../tests/common/mod.rs"]
mod common;
use common::Rng;

/// A curved panel of (n+1)² vertices and 2n² triangles over 1000 × 800 mm.
fn panel(n: usize) -> TriangleMesh {
    TriangleMesh::height_field(n, n, (-500.0, 500.0), (-400.0, 400.0), |x, y| {
        60.0 * (x / 400.0).sin() * (y / 300.0).cos()
    })
}

fn bench(c: &mut Criterion) {
    let mesh = panel(491);
    assert_eq!(mesh.triangles.len(), 482_162);
    let mut rng = Rng(9u64);
    let mut u = move || rng.uniform();
    let points: Vec<[f64; 3]> = (0..200_000)
        .map(|_| {
            let (x, y) = (-480.0 + 960.0 * u(), -380.0 + 760.0 * u());
            [
                x,
                y,
                60.0 * (x / 400.0).sin() * (y / 300.0).cos() + 4.0 * (u() - 0.5),
            ]
        })
        .collect();
    mesh_reading(c, &mesh);
    let sd = SignedDistance::new(mesh);
    let mut g = c.benchmark_group("signed_distance");
    g.sample_size(10);
    g.bench_function("200k_points_483k_triangles", |b| {
        b.iter(|| sd.query_all(&points))
    });
    g.finish();
    // Coverage of the CAD by the inspection's fit subsample (50 k points): what every
    // inspection adds for its `not_measured` check.
    let fit: Vec<[f64; 3]> = points.iter().step_by(4).copied().collect();
    let mut g = c.benchmark_group("coverage");
    g.sample_size(10);
    g.bench_function("50k_points_483k_triangles", |b| {
        b.iter(|| ris_core::inspect::coverage(sd.mesh(), &fit, 0.5))
    });
    g.finish();
}

/// Reading the mesh as a CAD file: binary STL, binary PLY and OBJ.
fn mesh_reading(c: &mut Criterion, mesh: &TriangleMesh) {
    use std::fmt::Write as _;
    let dir = tempfile::tempdir().expect("tmp");
    let stl = dir.path().join("panel.stl");
    ris_core::mesh::stl::write_binary(&stl, mesh).expect("stl");
    let mut ply = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nelement face {}\nproperty list uchar int vertex_indices\nend_header\n",
        mesh.vertices.len(),
        mesh.triangles.len()
    )
    .into_bytes();
    let mut obj = String::new();
    for v in &mesh.vertices {
        for k in 0..3 {
            ply.extend_from_slice(&(v[k] as f32).to_le_bytes());
        }
        writeln!(obj, "v {} {} {}", v[0] as f32, v[1] as f32, v[2] as f32).expect("fmt");
    }
    for t in &mesh.triangles {
        ply.push(3);
        for i in t {
            ply.extend_from_slice(&(*i as i32).to_le_bytes());
        }
        writeln!(obj, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1).expect("fmt");
    }
    std::fs::write(dir.path().join("panel.ply"), ply).expect("ply");
    std::fs::write(dir.path().join("panel.obj"), obj).expect("obj");
    let mut g = c.benchmark_group("mesh_read");
    g.sample_size(10);
    for name in ["panel.stl", "panel.ply", "panel.obj"] {
        let path = dir.path().join(name);
        g.bench_function(format!("482k_triangles_{}", name.replace('.', "_")), |b| {
            b.iter(|| TriangleMesh::load(&path).expect("mesh"))
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
