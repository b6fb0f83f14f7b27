//! The acceptance figures of the foundation issue on variations of the demo cell: the decoder and
//! the parallax model must not depend on the particulars of one scene.

use std::path::Path;

use ris_core::decode::{decode, DecodeParams};
use ris_core::geometry::{look_at, Mat3, Vec3};
use ris_core::mesh::{stl, TriangleMesh};
use ris_core::sensor::Reconstructor;
use ris_core::sim::accuracy::{evaluate, Accuracy};
use ris_core::sim::{ObjectSection, Scene, SceneFile, Simulator};

fn demo_file() -> SceneFile {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/scenes/demo.toml");
    toml::from_str(&std::fs::read_to_string(path).expect("read")).expect("parse")
}

fn rows(m: &Mat3) -> [[f64; 3]; 3] {
    [
        [m[(0, 0)], m[(0, 1)], m[(0, 2)]],
        [m[(1, 0)], m[(1, 1)], m[(1, 2)]],
        [m[(2, 0)], m[(2, 1)], m[(2, 2)]],
    ]
}

fn run(file: SceneFile, base: &Path) -> Accuracy {
    let scene = Scene::from_file(file, base, "variation").expect("scene");
    let sim = Simulator::new(scene.clone());
    let layout = sim.layout();
    let params = DecodeParams::default();
    let dec = decode(&sim.capture(&layout, 0, &|_, _| {}), &params).expect("decode");
    let dec_ref = decode(
        &Simulator::new(scene.reference()).capture(&layout, 1000, &|_, _| {}),
        &params,
    )
    .expect("reference");
    let rec =
        Reconstructor::parallax(&scene.camera, scene.projector.center(), &dec_ref).expect("model");
    evaluate(
        &rec.reconstruct(&dec).expect("reconstruct"),
        &sim.cache.truth,
        0.999,
    )
}

fn check(name: &str, acc: &Accuracy) {
    eprintln!("{name}: {acc}");
    assert!(acc.completeness >= 0.97, "{name}: {acc}");
    assert!(acc.mean_abs_error_mm <= 0.06, "{name}: {acc}");
    assert!(acc.rms_error_mm <= 0.10, "{name}: {acc}");
    assert!(acc.outlier_fraction <= 0.005, "{name}: {acc}");
}

#[test]
fn projector_lens_distortion_is_absorbed_by_the_reference() {
    let mut f = demo_file();
    f.projector.dist = [-0.12, 0.05, 0.001, -0.001, 0.0];
    check("projector distortion", &run(f, Path::new(".")));
}

#[test]
fn fine_strong_texture_and_heavy_defocus() {
    let mut f = demo_file();
    for m in f.material.values_mut() {
        m.texture_amplitude = 0.5;
        m.texture_period = 2.0;
    }
    f.projector.blur = 1.0;
    check("fine texture, blur 1.0", &run(f, Path::new(".")));
}

#[test]
fn projector_on_the_other_side_and_a_tilted_camera_viewing_a_mesh() {
    let mut f = demo_file();
    let (rc, tc) = look_at(
        Vec3::new(-80.0, 120.0, 1590.0),
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::new(0.3, 1.0, 0.0),
    );
    f.camera.r = rows(&rc);
    f.camera.t = [tc.x, tc.y, tc.z];
    let (rp, tp) = look_at(
        Vec3::new(-450.0, -150.0, 1550.0),
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::y(),
    );
    f.projector.r = rows(&rp);
    f.projector.t = [tp.x, tp.y, tp.z];
    // A faceted part from an STL file: an octahedron-like cap of 8 triangles.
    let dir = tempfile::tempdir().expect("tempdir");
    let v = [
        Vec3::new(0.0, 0.0, 60.0),
        Vec3::new(70.0, 0.0, 0.0),
        Vec3::new(0.0, 70.0, 0.0),
        Vec3::new(-70.0, 0.0, 0.0),
        Vec3::new(0.0, -70.0, 0.0),
    ];
    let mesh = TriangleMesh {
        vertices: v.to_vec(),
        triangles: vec![
            [0, 1, 2],
            [0, 2, 3],
            [0, 3, 4],
            [0, 4, 1],
            [1, 4, 3],
            [1, 3, 2],
        ],
    };
    stl::write_binary(&dir.path().join("cap.stl"), &mesh).expect("stl");
    f.object.push(ObjectSection {
        shape: "mesh".into(),
        material: "part".into(),
        file: Some("cap.stl".into()),
        position: Some([40.0, 20.0, 0.0]),
        rotation_deg: Some([0.0, 0.0, 20.0]),
        ..Default::default()
    });
    check(
        "mirrored projector, tilted camera, STL part",
        &run(f, dir.path()),
    );
}

#[test]
fn residual_field_from_the_sensor_file_is_applied() {
    // A constant residual C = 0.5 mm (A = B = 0) must lower every height by 0.5 mm.
    let dir = tempfile::tempdir().expect("tempdir");
    let mut f = demo_file();
    f.camera.width = 200;
    f.camera.height = 150;
    f.camera.k = [[444.5, 0.0, 99.5], [0.0, 444.5, 74.5], [0.0, 0.0, 1.0]];
    // The projector scaled down with the camera, so its stripes stay resolvable.
    f.projector.width = 256;
    f.projector.height = 192;
    f.projector.k = [[450.0, 0.0, 127.5], [0.0, 450.0, 95.5], [0.0, 0.0, 1.0]];
    let scene = Scene::from_file(f, Path::new("."), "small demo").expect("scene");
    let out = dir.path().join("sim");
    let o = ris_core::sim::simulate(&scene, &out, None, &|_, _, _| {}).expect("simulate");
    let params = DecodeParams::default();
    let sensor = ris_core::sensor::Sensor::load(&o.sensor).expect("sensor");
    let capture = ris_core::capture::CaptureSet::load(&o.capture).expect("capture");
    let dec = decode(&capture, &params).expect("decode");
    let plain = Reconstructor::new(&sensor, ris_core::sensor::ModelChoice::Parallax, &params)
        .expect("model")
        .reconstruct(&dec)
        .expect("points");
    let residual: Vec<f32> = (0..200 * 150).flat_map(|_| [0.0, 0.0, 0.5]).collect();
    ris_core::io::npy::write(&out.join("residual.npy"), &[150, 200, 3], &residual).expect("npy");
    let text = std::fs::read_to_string(&o.sensor).expect("read")
        + "\n[residual]\nfile = \"residual.npy\"\n";
    std::fs::write(&o.sensor, text).expect("write");
    let sensor = ris_core::sensor::Sensor::load(&o.sensor).expect("sensor with residual");
    let corrected = Reconstructor::new(&sensor, ris_core::sensor::ModelChoice::Parallax, &params)
        .expect("model")
        .reconstruct(&dec)
        .expect("points");
    assert_eq!(plain.len(), corrected.len());
    for (a, b) in plain.points.iter().zip(&corrected.points) {
        assert!((a[2] - b[2] - 0.5).abs() < 1e-3, "z {} -> {}", a[2], b[2]);
    }
    // A residual of the wrong shape is refused with the file named.
    ris_core::io::npy::write(&out.join("residual.npy"), &[10, 10, 3], &vec![0f32; 300])
        .expect("npy");
    let err = Reconstructor::new(&sensor, ris_core::sensor::ModelChoice::Parallax, &params)
        .err()
        .expect("shape error")
        .to_string();
    assert!(
        err.contains("residual.npy") && err.contains("shape"),
        "{err}"
    );
}
