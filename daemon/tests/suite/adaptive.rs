//! Adaptive scans in risd: a mock cell over the challenge scene (a black box, a dark dome, a
//! shiny sphere and box with specular lobes and inter-reflection) scanned with
//! `mode = adaptive` through the cell (the same path as a Zenoh request) recovers, per
//! material, what a powder-sprayed part gives, where the plain Gray scan of the same cell loses
//! most of the black part. Points are attributed to materials by projecting them into the
//! camera and reading the simulator's ground truth at that pixel.

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;

use ris_core::cloud::PointCloud;
use ris_core::decode::{decode, DecodeParams};
use ris_core::geometry::Vec3;
use ris_core::sensor::Reconstructor;
use ris_core::sim::{Scene, Simulator};
use ris_daemon::cell::{Cell, ScanJob};
use ris_daemon::config::CellConfig;
use ris_daemon::protocol::ScanMode;
use ris_drivers::mock::simulated_pair;
use ris_drivers::sequence::{acquire, SequenceParams};
use ris_drivers::Slide;

fn scene_path() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/scenes/challenge.toml")
}

/// Points per material: each point's pixel is where it projects in the camera.
fn per_material(cloud: &PointCloud, scene: &Scene, material: &[u8]) -> BTreeMap<String, usize> {
    let (w, h) = (scene.camera.width as i64, scene.camera.height as i64);
    let mut counts = BTreeMap::new();
    for p in &cloud.points {
        let Some((u, v)) = scene.camera.project(&Vec3::new(
            f64::from(p[0]),
            f64::from(p[1]),
            f64::from(p[2]),
        )) else {
            continue;
        };
        let (x, y) = (u.round() as i64, v.round() as i64);
        if x < 0 || y < 0 || x >= w || y >= h {
            continue;
        }
        let m = material[(y * w + x) as usize] as usize;
        if let Some(mat) = scene.materials.get(m) {
            *counts.entry(mat.name.clone()).or_insert(0) += 1;
        }
    }
    counts
}

#[test]
fn adaptive_scans_in_the_cell_match_the_sprayed_part_per_material() {
    let scene = Scene::load(&scene_path()).expect("challenge scene");
    let truth = Simulator::new(scene.clone()).cache.truth.clone();
    let text = format!(
        "[cell]\nname = \"adaptive\"\n[[sensor]]\nname = \"c\"\nbackend = \"mock\"\nscene = {:?}\n\
         to_common = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]\n",
        scene_path().display().to_string()
    );
    let config = CellConfig::parse(&text, Path::new("."), "test cell").expect("config");
    let mut cell = Cell::prepare(&config, 5, &|_, _, _| {}).expect("cell");
    let data = tempfile::tempdir().expect("tmp");
    let mut phases = std::sync::Mutex::new(Vec::<String>::new());
    let scan = |cell: &mut Cell, mode: ScanMode, id: &str| {
        let job = ScanJob {
            mode,
            ..ScanJob::default()
        };
        let (report, dir) = cell
            .scan(&job, data.path(), id, &|| false, &|s| {
                if let ris_daemon::protocol::ScanState::Acquiring { phase: Some(p), .. } = s {
                    let mut v = phases.lock().expect("phases");
                    if v.last() != Some(p) {
                        v.push(p.clone());
                    }
                }
            })
            .expect("scan");
        let cloud = PointCloud::read_ply(&dir.join("c.ply")).expect("cloud");
        (report, dir, per_material(&cloud, &scene, &truth.material))
    };
    let (adaptive, dir, adaptive_counts) = scan(&mut cell, ScanMode::Adaptive, "adaptive");
    let (gray, _, gray_counts) = scan(&mut cell, ScanMode::Gray, "gray");

    // The sprayed reference: the same pair geometry over the sprayed part, the same model.
    let board = Simulator::new(scene.sprayed().reference());
    let layout = board.layout();
    let params = DecodeParams::default();
    let reference =
        decode(&board.capture(&layout, 7, &|_, _| {}), &params).expect("reference decode");
    let rec = Reconstructor::parallax(&scene.camera, scene.projector.center(), &reference)
        .expect("model");
    let slides: Vec<Slide> = layout
        .sequence(true)
        .into_iter()
        .map(Slide::plain)
        .collect();
    let (mut cam, mut proj, _) =
        simulated_pair(Arc::new(Simulator::new(scene.sprayed())), "sprayed", 9);
    let acq = acquire(
        &mut cam,
        &mut proj,
        &layout,
        &slides,
        &SequenceParams::default(),
        &mut |_| {},
    )
    .expect("sprayed scan");
    let sprayed = rec
        .reconstruct(&decode(&acq.capture, &params).expect("decode"))
        .expect("reconstruct");
    let sprayed_counts = per_material(&sprayed, &scene, &truth.material);

    for (name, &n) in &sprayed_counts {
        let a = adaptive_counts.get(name).copied().unwrap_or(0);
        let g = gray_counts.get(name).copied().unwrap_or(0);
        eprintln!(
            "{name:>12}: sprayed {n:>7}, adaptive {a:>7} ({:.1} %), gray {g:>7} ({:.1} %)",
            100.0 * a as f64 / n as f64,
            100.0 * g as f64 / n as f64
        );
        if n < 5000 {
            continue;
        }
        assert!(
            a as f64 >= 0.97 * n as f64,
            "{name}: adaptive {a} < 97 % of sprayed {n}"
        );
    }
    for m in ["black", "dark", "shiny"] {
        assert!(
            sprayed_counts.get(m).copied().unwrap_or(0) >= 5000,
            "{m}: {sprayed_counts:?}"
        );
    }
    let black = sprayed_counts["black"] as f64;
    let black_gray = gray_counts.get("black").copied().unwrap_or(0) as f64;
    assert!(
        black_gray <= 0.8 * black,
        "the plain Gray scan keeps {black_gray} of {black} black points: the scene is not a challenge"
    );

    // What the scan records about itself.
    let s = &adaptive.sensors[0];
    assert_eq!(adaptive.mode, ScanMode::Adaptive);
    assert!(
        s.frames > gray.sensors[0].frames,
        "adaptive {} frames, gray {}",
        s.frames,
        gray.sensors[0].frames
    );
    let names: Vec<&str> = s.phases.iter().map(|p| p.phase.as_str()).collect();
    assert_eq!(names.first(), Some(&"flats"), "{names:?}");
    assert_eq!(names.last(), Some(&"final projection"), "{names:?}");
    assert_eq!(
        s.phases.iter().map(|p| p.frames).sum::<u64>(),
        s.frames,
        "the phases account for every frame"
    );
    assert!(s.phases.iter().all(|p| p.seconds > 0.0));
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("scan.json")).expect("scan.json"))
            .expect("json");
    assert_eq!(json["mode"], "adaptive");
    assert_eq!(
        json["sensors"][0]["phases"].as_array().map(Vec::len),
        Some(s.phases.len())
    );
    let published = phases.get_mut().expect("phases").clone();
    assert!(
        published.iter().any(|p| p == "advanced projection"),
        "state publications name the loop's phases: {published:?}"
    );
}
