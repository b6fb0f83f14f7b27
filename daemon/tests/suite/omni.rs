//! risd with an omnidirectional sensor (issue 16 item 5) over Zenoh on 127.0.0.1: an `omni`
//! sensor of a cell beside a structured-light pair is scanned in the same request (one ring
//! frame while the pair runs its Gray codes), then streamed; clouds are checked against the
//! room the mock renders, the panoramas decoded, and the pixel query asked.

use std::path::Path;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use ris_core::cloud::PointCloud;
use ris_core::geometry::Vec3;
use ris_core::omni::scene::OmniScene;
use zenoh::Wait;

use crate::common;
use common::{ask, cell_config, client, free_port, states, wait_end, InProcess};

fn config_dir() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../config")
}

/// Per point of a sensor-frame `cloud` carrying its camera pixel (`u`, `v`): the distance to
/// where that pixel's ray meets the room, mm, sorted.
fn errors(cloud: &PointCloud, scene: &OmniScene) -> Vec<f64> {
    let column = |name: &str| {
        cloud
            .scalars
            .iter()
            .find(|s| s.name == name)
            .unwrap_or_else(|| panic!("the cloud has no `{name}`"))
            .values
            .clone()
    };
    let (u, v) = (column("u"), column("v"));
    let mut e: Vec<f64> = cloud
        .points
        .iter()
        .zip(u.iter().zip(&v))
        .filter_map(|(p, (&u, &v))| {
            let ray = scene.sensor.camera_ray(f64::from(u), f64::from(v))?;
            let (t, _, _) = scene.room.intersect(&ray.origin, &ray.direction)?;
            let truth = ray.origin + ray.direction * t;
            let p = Vec3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
            Some((p - truth).norm())
        })
        .collect();
    e.sort_by(f64::total_cmp);
    e
}

fn quantile(e: &[f64], f: f64) -> f64 {
    e[((e.len() - 1) as f64 * f) as usize]
}

/// `cloud` moved by `dz` along z (the omni sensor's sensor → cell transform is a lift).
fn lowered(cloud: &PointCloud, dz: f32) -> PointCloud {
    PointCloud {
        points: cloud
            .points
            .iter()
            .map(|p| [p[0], p[1], p[2] - dz])
            .collect(),
        ..cloud.clone()
    }
}

#[test]
fn risd_scans_and_streams_an_omni_sensor_beside_a_pair() {
    let dir = tempfile::tempdir().expect("tmp");
    let cfg = config_dir();
    let omni = std::fs::read_to_string(cfg.join("omni-cell.toml"))
        .expect("omni cell")
        .replace("\"scenes/", &format!("\"{}/scenes/", cfg.display()));
    // The first pair of the mock cell joins the omni sensor.
    let mock = std::fs::read_to_string(cfg.join("mock-cell.toml")).expect("mock cell");
    let start = mock.find("[[sensor]]").expect("a sensor");
    let end = start
        + 1
        + mock[start + 1..]
            .find("[[sensor]]")
            .expect("a second sensor");
    let pair = mock[start..end].replace("\"mock-cell/", &format!("\"{}/mock-cell/", cfg.display()));
    let at = omni.find("[single_shot]").expect("single shot section");
    let config = format!("{}{pair}{}", &omni[..at], &omni[at..]);
    let config_path = dir.path().join("cell.toml");
    std::fs::write(&config_path, &config).expect("config");
    let scene = OmniScene::load(&cfg.join("scenes/room.toml")).expect("room");

    let data = dir.path().join("data");
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    // The service in this process: what it answers and publishes is under test, not the process.
    let mut risd = InProcess::start(cell_config(&config_path, &endpoint, &data));
    risd.wait_ready(Duration::from_secs(120));
    let session = client(&endpoint);

    // Health tells what each sensor is.
    let health = ask(&session, "ris/omni/health", None);
    let h: serde_json::Value = match health.first() {
        Some(Ok(t)) => serde_json::from_str(t).expect("json"),
        other => panic!("health: {other:?}"),
    };
    let kinds: Vec<(String, String)> = h["pairs"]
        .as_array()
        .unwrap_or_else(|| panic!("pairs in {h}"))
        .iter()
        .map(|p| {
            (
                p["sensor"].as_str().unwrap_or_default().to_string(),
                p["kind"].as_str().unwrap_or_default().to_string(),
            )
        })
        .collect();
    assert_eq!(
        kinds,
        [
            ("o1".to_string(), "omni".to_string()),
            ("s1".to_string(), "structured-light".to_string())
        ],
        "{h}"
    );

    // A Gray-code scan of the cell: the pair runs its sequence, the omni sensor one ring frame.
    let (_states_sub, states_rx) = states(&session, "omni");
    let r = ask(&session, "ris/omni/scan", Some("{}"));
    let id = match r.first() {
        Some(Ok(t)) => serde_json::from_str::<serde_json::Value>(t).expect("json")["scan_id"]
            .as_str()
            .expect("scan id")
            .to_string(),
        other => panic!("scan: {other:?}"),
    };
    let done = wait_end(&states_rx, &id);
    assert_eq!(done["state"], "done", "{done}");
    let scan = data.join("scans").join(&id);
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(scan.join("scan.json")).expect("scan.json"))
            .expect("json");
    let frames = |s: &str| {
        report["sensors"]
            .as_array()
            .and_then(|a| a.iter().find(|t| t["sensor"] == s))
            .and_then(|t| t["frames"].as_u64())
    };
    assert_eq!(frames("o1"), Some(1), "{report}");
    assert!(frames("s1") > Some(20), "{report}");
    // The omni cloud: sensor frame, on the room's walls, floor, ceiling and objects. The
    // analysis (Sec. 6.3) gives 170 mm per camera pixel at 2.5 m for this 640x480 camera; the
    // ring centres are found to a small fraction of a pixel.
    let o1 = PointCloud::read_ply(&scan.join("o1.ply")).expect("o1 cloud");
    assert_eq!(o1.organised(), Some([640, 480]));
    let e = errors(&o1, &scene);
    assert!(
        o1.len() > 15_000 && e.len() == o1.len(),
        "{} points, {} with truth",
        o1.len(),
        e.len()
    );
    let (median, q90) = (quantile(&e, 0.5), quantile(&e, 0.9));
    eprintln!(
        "scan: {} omni points, median {median:.1} mm, 90 % {q90:.1} mm",
        o1.len()
    );
    assert!(
        median < 30.0 && q90 < 150.0,
        "median {median:.1} mm, 90 % {q90:.1} mm"
    );
    // The merged cloud holds both sensors in the cell frame (the omni sensor lifted 1.2 m).
    let merged = PointCloud::read_ply(&scan.join("merged.ply")).expect("merged");
    let s1 = PointCloud::read_ply(&scan.join("s1.ply")).expect("s1 cloud");
    assert!(
        merged.len() > o1.len() + s1.len() / 2,
        "merged {} of {} + {}",
        merged.len(),
        o1.len(),
        s1.len()
    );
    let far: Vec<[f32; 3]> = merged
        .points
        .iter()
        .filter(|p| p[0].hypot(p[1]) > 1500.0)
        .copied()
        .collect();
    let floor = far.iter().filter(|p| p[2].abs() < 60.0).count();
    assert!(
        floor > 1000,
        "the floor is at cell z = 0: {floor} of {} far points",
        far.len()
    );
    // The panorama beside the cloud.
    let pano = image::open(scan.join("o1.png"))
        .expect("the panorama")
        .into_rgb8();
    assert!(
        pano.width() > 1600 && pano.height() > 150,
        "{:?}",
        pano.dimensions()
    );

    // Stream the omni sensor: clouds in the cell frame and panoramas, stamped in order.
    let (tx, rx) = mpsc::channel::<(String, serde_json::Value, Vec<u8>)>();
    let _sub = session
        .declare_subscriber("ris/omni/stream/o1/*")
        .callback(move |s| {
            let what = s.key_expr().as_str().rsplit('/').next().unwrap_or_default();
            let meta = s
                .attachment()
                .and_then(|a| serde_json::from_slice(&a.to_bytes()).ok())
                .unwrap_or_default();
            let _ = tx.send((what.to_string(), meta, s.payload().to_bytes().into_owned()));
        })
        .wait()
        .expect("subscriber");
    let r = ask(
        &session,
        "ris/omni/stream",
        Some(r#"{"action": "start", "sensors": ["o1"]}"#),
    );
    assert!(matches!(r.first(), Some(Ok(_))), "{r:?}");
    let mut got = Vec::new();
    let t = Instant::now();
    // Six clouds and a panorama: the pictures are drawn on a thread of lower priority, so under
    // load the first may come after several clouds.
    let count = |got: &[(String, serde_json::Value, Vec<u8>)], what: &str| {
        got.iter().filter(|s| s.0 == what).count()
    };
    while count(&got, "cloud") < 6 || count(&got, "fused") == 0 {
        assert!(
            t.elapsed() < Duration::from_secs(90),
            "{} stream samples in 90 s",
            got.len()
        );
        if let Ok(s) = rx.recv_timeout(Duration::from_millis(200)) {
            got.push(s);
        }
    }
    let clouds: Vec<_> = got.iter().filter(|s| s.0 == "cloud").collect();
    let ts: Vec<u64> = clouds
        .iter()
        .map(|c| c.1["timestamp_ns"].as_u64().expect("timestamp"))
        .collect();
    assert!(ts.windows(2).all(|w| w[1] > w[0]), "{ts:?}");
    for c in clouds.iter().step_by(3) {
        let cloud = PointCloud::from_ply(&c.2, Path::new("stream")).expect("PLY");
        assert_eq!(cloud.len() as u64, c.1["points"].as_u64().expect("points"));
        let e = errors(&lowered(&cloud, 1200.0), &scene);
        let median = quantile(&e, 0.5);
        assert!(
            cloud.len() > 15_000 && median < 30.0,
            "stream frame {}: {} points, median {median:.1} mm",
            c.1["frame"],
            cloud.len()
        );
    }
    let pano = got
        .iter()
        .rfind(|s| s.0 == "fused")
        .expect("a panorama in the stream");
    assert_eq!(pano.1["range_mm"], serde_json::json!([2000.0, 4000.0]));
    let picture = image::load_from_memory(&pano.2).expect("PNG").into_rgb8();
    assert!(picture.width() > 1600, "{:?}", picture.dimensions());

    // The pixel query: pick the pixel of a streamed point; the answer is that point, in the
    // cell frame, on the room.
    let last = PointCloud::from_ply(&clouds[clouds.len() - 1].2, Path::new("stream")).expect("PLY");
    let k = last.len() / 3;
    let (row, col) = last.row_column(k).expect("organised");
    let answer = ask(
        &session,
        &format!("ris/omni/stream/o1/point?u={col}&v={row}"),
        None,
    );
    let v: serde_json::Value = match answer.first() {
        Some(Ok(text)) => serde_json::from_str(text).expect("json"),
        other => panic!("point query: {other:?}"),
    };
    assert!(v["pixel_distance"].as_f64() < Some(1.5), "{v}");
    let p = [
        v["point_mm"][0].as_f64().expect("x"),
        v["point_mm"][1].as_f64().expect("y"),
        v["point_mm"][2].as_f64().expect("z") - 1200.0,
    ];
    let ray = scene
        .sensor
        .camera_ray(f64::from(col), f64::from(row))
        .expect("a mirror pixel");
    let (t, _, _) = scene
        .room
        .intersect(&ray.origin, &ray.direction)
        .expect("the room");
    let truth = ray.origin + ray.direction * t;
    let off = (Vec3::new(p[0], p[1], p[2]) - truth).norm();
    // One pixel of the 640x480 camera spans up to ~200 mm at the walls.
    assert!(off < 400.0, "{v}: {off:.0} mm from the room at its pixel");

    let r = ask(&session, "ris/omni/stream", Some(r#"{"action": "stop"}"#));
    assert!(
        matches!(r.first(), Some(Ok(t)) if t.contains("stopped")),
        "{r:?}"
    );
    risd.stop().expect("the service stops cleanly");
}
