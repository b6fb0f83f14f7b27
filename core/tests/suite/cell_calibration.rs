//! Cell calibration with a marker gauge: four simulated sensors, each looking at a quarter of a
//! curved black panel with white 5 mm markers from its own frame; the recovered sensor → cell
//! transforms are checked against the poses the scenes were rendered with.

use std::path::Path;

use ris_core::calibrate::{fit_gauge, overlap_consistency, Gauge, GaugeParams};
use ris_core::decode::{decode, DecodeParams};
use ris_core::geometry::{rotation_xyz_deg, Vec3};
use ris_core::io::read_toml;
use ris_core::mesh::{stl, TriangleMesh};
use ris_core::register::{rotation_angle_deg, Pose};
use ris_core::sensor::Reconstructor;
use ris_core::sim::{MaterialSection, ObjectSection, Scene, SceneFile, Simulator};

fn surface(x: f64, y: f64) -> f64 {
    -x * x / 5000.0 - y * y / 8000.0
}

/// One sensor's view: yaw, tilts and the panel point under the sensor.
struct View {
    rotation_deg: [f64; 3],
    target: (f64, f64),
    lift: f64,
}

fn views() -> [View; 4] {
    [
        View {
            rotation_deg: [2.0, -1.0, 7.0],
            target: (-280.0, -200.0),
            lift: 90.0,
        },
        View {
            rotation_deg: [-1.5, 2.0, 97.0],
            target: (280.0, -200.0),
            lift: 110.0,
        },
        View {
            rotation_deg: [1.0, 1.5, 183.0],
            target: (280.0, 200.0),
            lift: 100.0,
        },
        View {
            rotation_deg: [-2.0, -2.0, -88.0],
            target: (-280.0, 200.0),
            lift: 120.0,
        },
    ]
}

/// Sensor world ← cell pose of a view (how the gauge mesh is placed in the sensor's scene).
fn world_from_cell(v: &View) -> (Pose, [f64; 3]) {
    let r = rotation_xyz_deg(v.rotation_deg);
    let q = Vec3::new(v.target.0, v.target.1, surface(v.target.0, v.target.1));
    let position = -(r * q) + Vec3::new(0.0, 0.0, v.lift);
    let rot = nalgebra::UnitQuaternion::from_matrix(&r);
    (
        Pose::from_parts(nalgebra::Translation3::from(position), rot),
        [position.x, position.y, position.z],
    )
}

fn scene_for(dir: &Path, v: &View, markers: &str) -> Scene {
    let demo = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/scenes/demo.toml");
    let mut file: SceneFile = read_toml(&demo).expect("demo scene");
    file.material.clear();
    file.material.insert(
        "paint".into(),
        MaterialSection {
            albedo: 0.03,
            specular: 0.0,
            shininess: 0.0,
            interreflection: 0.0,
            interreflection_radius: 0.0,
            texture: None,
            texture_amplitude: 0.0,
            texture_period: 20.0,
        },
    );
    let (_, position) = world_from_cell(v);
    file.object = vec![ObjectSection {
        shape: "mesh".into(),
        material: "paint".into(),
        file: Some("gauge.stl".into()),
        position: Some(position),
        rotation_deg: Some(v.rotation_deg),
        markers: Some(markers.into()),
        marker_albedo: Some(0.85),
        ..Default::default()
    }];
    file.render.supersample = 3;
    Scene::from_file(file, dir, "gauge scene").expect("scene")
}

fn measure(scene: &Scene) -> ris_core::cloud::PointCloud {
    let sim = Simulator::new(scene.clone());
    let layout = sim.layout();
    let params = DecodeParams::default();
    let dec = decode(&sim.capture(&layout, 0, &|_, _| {}), &params).expect("decode");
    let reference = Simulator::new(scene.reference()).capture(&layout, 1000, &|_, _| {});
    let dec_ref = decode(&reference, &params).expect("decode reference");
    Reconstructor::parallax(&scene.camera, scene.projector.center(), &dec_ref)
        .expect("model")
        .reconstruct(&dec)
        .expect("reconstruct")
}

fn write_gauge(dir: &Path) -> Gauge {
    let mesh = TriangleMesh::height_field(224, 160, (-560.0, 560.0), (-400.0, 400.0), surface);
    stl::write_binary(&dir.join("gauge.stl"), &mesh).expect("stl");
    let gauge = Gauge::jittered_grid((-560.0, 560.0), (-400.0, 400.0), 60.0, 5.0, 7, surface);
    gauge.save(&dir.join("gauge.toml")).expect("gauge");
    gauge
}

#[test]
fn gauge_recovers_four_sensor_transforms() {
    let dir = tempfile::tempdir().expect("tmp");
    let gauge = write_gauge(dir.path());
    let loaded = Gauge::load(&dir.path().join("gauge.toml")).expect("load gauge");
    assert_eq!(loaded.centers.len(), gauge.centers.len());
    let mut fits = Vec::new();
    for (i, v) in views().iter().enumerate() {
        let cloud = measure(&scene_for(dir.path(), v, "gauge.toml"));
        let fit = fit_gauge(&cloud, &loaded, &GaugeParams::default()).expect("gauge fit");
        let truth = world_from_cell(v).0.inverse();
        let err = truth.inverse() * fit.to_common;
        let rot = rotation_angle_deg(&err);
        // Translation error where it matters: at the measured markers.
        let worst = fit
            .markers
            .iter()
            .map(|m| {
                let p = nalgebra::Point3::from(Vec3::from(m.center));
                (fit.to_common * p - truth * p).norm()
            })
            .fold(0.0f64, f64::max);
        eprintln!(
            "sensor {i}: {} points, {} markers ({} matched), {} rejected, rms {:.4} mm, max {:.4} mm; \
             rotation error {rot:.5}°, worst marker displacement {worst:.4} mm, origin {:.4} mm",
            cloud.len(),
            fit.markers.len(),
            fit.matched,
            fit.rejected.len(),
            fit.rms,
            fit.max,
            err.translation.vector.norm(),
        );
        assert!(
            fit.matched >= 15,
            "sensor {i}: {} markers matched",
            fit.matched
        );
        assert!(rot <= 0.01, "sensor {i}: rotation error {rot}°");
        assert!(worst <= 0.1, "sensor {i}: marker displacement {worst} mm");
        // Single centres scatter by ~0.2 px (pixel quantisation of a 10 mm disc at 0.9 mm/px);
        // the transform averages that out over the markers.
        assert!(fit.rms <= 0.25, "sensor {i}: rms {}", fit.rms);
        fits.push(fit);
    }
    let checks = overlap_consistency(&fits);
    for c in &checks {
        eprintln!(
            "overlap {:?}: {} shared, rms {:.4} mm",
            c.sensors, c.shared, c.rms
        );
        // Two independent centre estimates, each scattering ~0.2 mm.
        assert!(c.rms <= 0.4, "{c:?}");
    }
    assert!(
        checks.iter().filter(|c| c.shared >= 3).count() >= 4,
        "neighbouring sensors share markers: {checks:?}"
    );
}

#[test]
fn wrong_gauge_file_is_refused() {
    let dir = tempfile::tempdir().expect("tmp");
    write_gauge(dir.path());
    let cloud = measure(&scene_for(dir.path(), &views()[0], "gauge.toml"));
    // The same panel with another marker layout: the measurement must not be forced onto it.
    let other = Gauge::jittered_grid((-560.0, 560.0), (-400.0, 400.0), 60.0, 5.0, 99, surface);
    let err = fit_gauge(&cloud, &other, &GaugeParams::default()).expect_err("must refuse");
    eprintln!("{err}");
    assert!(err.to_string().contains("markers"), "{err}");
}
