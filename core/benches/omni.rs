//! Omnidirectional speed: decoding the ring pattern of one 2048x2048 camera frame of a rendered
//! room into its 360° cloud (crossings, arcs, ring names, triangulation), the seed's mirrors
//! with a 2048x2048 camera and projector (config/omni/seed-2k.toml); and the same at 640x480.
#![allow(missing_docs)] // criterion_group! generates an undocumented public function

use criterion::{criterion_group, criterion_main, Criterion};
use ris_core::geometry::Vec3;
use ris_core::omni::{render, Exposure, OmniSensor, RingDecoder, RingParams, Room};
use ris_core::sim::Shape;

fn room() -> Room {
    Room {
        half: [3000.0, 2500.0],
        center: [200.0, -300.0],
        floor: -1200.0,
        ceiling: 1300.0,
        albedo: [0.6, 0.4, 0.7],
        objects: vec![
            (
                Shape::Box {
                    center: Vec3::new(1500.0, 800.0, -900.0),
                    half: Vec3::new(300.0, 300.0, 300.0),
                },
                0.5,
            ),
            (
                Shape::Cylinder {
                    center: Vec3::new(-1200.0, -900.0, -300.0),
                    axis: Vec3::z(),
                    radius: 250.0,
                    half_height: 900.0,
                },
                0.5,
            ),
        ],
    }
}

fn decode(c: &mut Criterion) {
    let mut g = c.benchmark_group("omni");
    g.sample_size(10);
    for (name, file) in [("640x480", "seed.toml"), ("2048x2048", "seed-2k.toml")] {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../config/omni")
            .join(file);
        let s = OmniSensor::load(&path).expect("sensor");
        let pattern = s.rings().expect("design");
        let (img, _) =
            render(&s, &room(), &pattern.render(), &Exposure::default()).expect("render");
        let dec = RingDecoder::new(&s, &pattern, RingParams::default()).expect("decoder");
        g.bench_function(format!("ring_decode_{name}"), |b| {
            b.iter(|| dec.decode(&img).expect("decode"))
        });
    }
    g.finish();
}

criterion_group!(benches, decode);
criterion_main!(benches);
