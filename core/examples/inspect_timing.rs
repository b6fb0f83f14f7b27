//! Time the inspection of the mock cell's part as risd runs it (the inspect bench's 1.2 M
//! points from the cell frame) and print a checksum of its result, so that a change meant to
//! leave the result alone can be checked to do so: `cargo run --profile ci -p ris-core
//! --example inspect_timing [runs]` (`RIS_LOG=ris_core::inspect=debug` for the steps' times).
use ris_core::inspect::{inspect, InspectParams};
use ris_core::mesh::{SignedDistance, TriangleMesh};
use ris_core::register::Pose;

#[path = "../tests/common/mod.rs"]
mod common;

fn main() {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::from_env("RIS_LOG"))
        .with_writer(std::io::stderr)
        .init();
    let runs: usize = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(3);
    let stl =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/mock-cell/panel.stl");
    let mesh = TriangleMesh::load(&stl).expect("panel.stl");
    let cloud = common::panel_cloud(&mesh, 1_200_000);
    let cad = SignedDistance::new(mesh);
    let params = InspectParams {
        tolerance: 0.5,
        init: Some(Pose::identity()),
        ..InspectParams::default()
    };
    for _ in 0..runs {
        let t = std::time::Instant::now();
        let out = inspect(&cloud, &cad, &params).expect("inspection");
        let s = t.elapsed().as_secs_f64();
        let sum: f64 = out.deviations.iter().filter(|d| d.is_finite()).sum();
        println!(
            "{s:.3} s: {} (deviation sum {sum:.9}, stability {:?}, transform {:?})",
            out.report.verdict,
            out.report
                .registration
                .stability
                .as_ref()
                .map(|s| s.shift_mm),
            out.report.transform
        );
    }
}
