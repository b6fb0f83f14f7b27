//! The inspected surface in risd (issue 42 item 2): a closed block whose top is the wear cell's
//! plate, scanned from above by one sensor. Over the whole closed CAD the scan is NOT MEASURED
//! (its bottom and sides are never seen); with `inspected = "seen"` the surface is what the
//! scanning sensor's camera and projector see inside the camera's image, the coverage counts
//! over it and the block gets a verdict, and report.json says which surface the coverage is of.
//! `faces` needs a STEP model and names a face the model has, or the configuration is refused. A
//! STEP block's characteristics come out of risd as out of `ris_core::inspect` on the stored
//! merged cloud.

use std::io::Write as _;
use std::path::Path;

use ris_daemon::cell::{Cell, ScanJob};
use ris_daemon::config::CellConfig;

/// A closed box (outward triangles) as ASCII STL.
fn box_stl(lo: [f64; 3], hi: [f64; 3]) -> String {
    let c = |i: usize| {
        [
            if i & 1 == 0 { lo[0] } else { hi[0] },
            if i & 2 == 0 { lo[1] } else { hi[1] },
            if i & 4 == 0 { lo[2] } else { hi[2] },
        ]
    };
    // quads counter-clockwise seen from outside
    let quads = [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ];
    let mut s = String::from("solid block\n");
    for q in quads {
        for t in [[q[0], q[1], q[2]], [q[0], q[2], q[3]]] {
            s.push_str("facet normal 0 0 0\nouter loop\n");
            for v in t {
                let p = c(v);
                s.push_str(&format!("vertex {} {} {}\n", p[0], p[1], p[2]));
            }
            s.push_str("endloop\nendfacet\n");
        }
    }
    s.push_str("endsolid block\n");
    s
}

#[test]
fn a_one_sided_scan_of_a_closed_block_gets_a_verdict_over_what_the_sensor_sees() {
    let dir = tempfile::tempdir().expect("tmp");
    // the plate's top is z = 3 (config/wear-cell/s1.toml); the block reaches 40 mm below it
    std::fs::File::create(dir.path().join("block.stl"))
        .and_then(|mut f| {
            f.write_all(box_stl([-450.0, -350.0, -37.0], [450.0, 350.0, 3.0]).as_bytes())
        })
        .expect("block.stl");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/wear-cell/s1.toml");
    let text = format!(
        "[cell]\nname = \"surface\"\n[[sensor]]\nname = \"s1\"\nbackend = \"mock\"\nscene = {:?}\n\
         to_common = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]\n\
         [[part]]\nid = \"whole\"\ncad = \"block.stl\"\ntolerance = 0.3\npose = \"known\"\n\
         [[part]]\nid = \"seen\"\ncad = \"block.stl\"\ntolerance = 0.3\npose = \"known\"\ninspected = \"seen\"\n",
        scene.display().to_string()
    );
    let config = CellConfig::parse(&text, dir.path(), "test cell").expect("config");
    config.check_files().expect("files");
    let mut cell = Cell::prepare(&config, 5, &|_, _, _| {}).expect("cell");
    let data = tempfile::tempdir().expect("tmp");
    let mut scan = |part: usize, id: &str| {
        let job = ScanJob {
            part: Some(part),
            ..ScanJob::default()
        };
        let (report, dir) = cell
            .scan(&job, data.path(), id, &|| false, &|_| {})
            .expect("scan");
        let json: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(dir.join("report.json")).expect("report.json"),
        )
        .expect("json");
        (report.inspection.expect("inspected"), json)
    };
    let (whole, whole_json) = scan(0, "whole");
    assert_eq!(whole.verdict, "not_measured", "{:?}", whole.reasons);
    let fraction = whole_json["coverage"]["fraction"]
        .as_f64()
        .expect("fraction");
    assert!(fraction < 0.5, "{fraction}");
    assert!(
        whole
            .reasons
            .iter()
            .any(|r| r.contains("name the inspected faces")),
        "{:?}",
        whole.reasons
    );

    let (seen, seen_json) = scan(1, "seen");
    assert_eq!(seen.verdict, "pass", "{:?}", seen.reasons);
    let c = &seen_json["coverage"];
    let area = c["cad_area_mm2"].as_f64().expect("area");
    // what the sensor sees of the block is the part of its top inside the camera's image (the
    // sides face away, the bottom is hidden): the 800 x 600 px image at f = 1778 px from
    // 1597 mm is 718.6 x 538.9 mm (s1.toml), within the sampling's 3 % and the lens distortion
    let footprint = (800.0 / 1778.0 * 1597.0) * (600.0 / 1778.0 * 1597.0);
    assert!(
        (area - footprint).abs() < 0.03 * footprint,
        "inspected area {area} mm² against the image's footprint {footprint:.0}"
    );
    let fraction = c["fraction"].as_f64().expect("fraction");
    assert!(fraction > 0.9, "{c}");
    assert!(
        c["surface"]
            .as_str()
            .is_some_and(|s| s.contains("1 sensor can see")),
        "{c}"
    );
    let whole_area = whole_json["coverage"]["cad_area_mm2"]
        .as_f64()
        .expect("area");
    eprintln!(
        "whole CAD: {:.1} % of {whole_area:.0} mm², not measured; seen: {:.1} % of {area:.0} mm², {}",
        100.0 * whole_json["coverage"]["fraction"].as_f64().unwrap_or(0.0),
        100.0 * fraction,
        seen.verdict
    );
}

#[test]
fn faces_need_a_step_model_that_has_them() {
    let dir = tempfile::tempdir().expect("tmp");
    std::fs::write(
        dir.path().join("block.stl"),
        box_stl([0.0, 0.0, 0.0], [10.0, 10.0, 10.0]),
    )
    .expect("stl");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/wear-cell/s1.toml");
    let config = |part: &str| {
        format!(
            "[cell]\nname = \"surface\"\n[[sensor]]\nname = \"s1\"\nbackend = \"mock\"\nscene = {:?}\n\
             to_common = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]\n\
             [[part]]\nid = \"p\"\ntolerance = 0.3\n{part}\n",
            scene.display().to_string()
        )
    };
    // faces and seen together: refused by field
    let err = CellConfig::parse(
        &config("cad = \"block.stl\"\nfaces = [17]\ninspected = \"seen\""),
        dir.path(),
        "test cell",
    )
    .expect_err("both")
    .to_string();
    assert!(err.contains("faces"), "{err}");
    // faces of an STL: no faces to name
    let c = CellConfig::parse(
        &config("cad = \"block.stl\"\nfaces = [17]"),
        dir.path(),
        "test cell",
    )
    .expect("parses");
    let err = format!("{:#}", c.check_files().expect_err("an STL has no faces"));
    assert!(err.contains("STEP"), "{err}");
}

/// Characteristics in risd (issue 42 item 3): the same closed block as a STEP model (written by
/// the independent OpenCASCADE wheel), its top face's flatness and profile toleranced in a
/// characteristics file of the part. risd's report carries them, and `ris_core::inspect` of the
/// scan's stored merged cloud with the same files gives the same figures and verdict: one
/// pipeline.
#[cfg(feature = "step")]
#[test]
fn risd_measures_a_parts_characteristics_as_ris_inspect_does() {
    use ris_core::inspect::{inspect, load_characteristics, InspectParams};
    use ris_core::mesh::step::{self, FaceSurface, StepOptions};
    let dir = tempfile::tempdir().expect("tmp");
    let cad = dir.path().join("block.step");
    let script = format!(
        "from OCP.BRepPrimAPI import BRepPrimAPI_MakeBox\n\
         from OCP.STEPControl import STEPControl_Writer, STEPControl_AsIs\n\
         from OCP.gp import gp_Pnt\n\
         w = STEPControl_Writer()\n\
         w.Transfer(BRepPrimAPI_MakeBox(gp_Pnt(-450, -350, -37), 900, 700, 40).Shape(), STEPControl_AsIs)\n\
         assert w.Write({:?}) == 1\n",
        cad.display().to_string()
    );
    let o = std::process::Command::new("python3")
        .args(["-c", &script])
        .output()
        .expect("python3 with cadquery-ocp (installed by .ci/run)");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let model = step::read(&cad, &StepOptions::default()).expect("block.step");
    let top = model
        .faces
        .iter()
        .find(|f| matches!(f.surface, FaceSurface::Plane { normal, .. } if normal.z > 0.99))
        .expect("the top face")
        .entity;
    let gdt = dir.path().join("block-gdt.toml");
    std::fs::write(
        &gdt,
        format!(
            "[[characteristic]]\nname = \"top\"\nkind = \"flatness\"\nfaces = [{top}]\ntolerance = 0.5\n\n\
             [[characteristic]]\nname = \"top\"\nkind = \"profile\"\nfaces = [{top}]\ntolerance = 1.0\nmin_coverage = 0.3\n"
        ),
    )
    .expect("gdt");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/wear-cell/s1.toml");
    let text = format!(
        "[cell]\nname = \"surface\"\n[[sensor]]\nname = \"s1\"\nbackend = \"mock\"\nscene = {:?}\n\
         to_common = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]\n\
         [[part]]\nid = \"block\"\ncad = \"block.step\"\ntolerance = 0.3\npose = \"known\"\nmin_coverage = 0.0\n\
         characteristics = \"block-gdt.toml\"\n",
        scene.display().to_string()
    );
    let config = CellConfig::parse(&text, dir.path(), "test cell").expect("config");
    config.check_files().expect("files");
    let mut cell = Cell::prepare(&config, 5, &|_, _, _| {}).expect("cell");
    let data = tempfile::tempdir().expect("tmp");
    let job = ScanJob {
        part: Some(0),
        ..ScanJob::default()
    };
    let (report, scan_dir) = cell
        .scan(&job, data.path(), "gdt", &|| false, &|_| {})
        .expect("scan");
    let risd = report.inspection.expect("inspected");
    let json: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(scan_dir.join("report.json")).expect("report.json"),
    )
    .expect("json");
    let characteristics: Vec<ris_core::inspect::CharacteristicResult> =
        serde_json::from_value(json["characteristics"].clone()).expect("characteristics");
    assert_eq!(characteristics.len(), 2, "{json}");
    for c in &characteristics {
        assert!(c.measured.is_some(), "{c:?}");
    }
    // the same files through ris_core::inspect, on the stored merged cloud
    let merged = ris_core::cloud::PointCloud::read_ply(&scan_dir.join("merged.ply")).expect("ply");
    let points: Vec<[f64; 3]> = merged
        .points
        .iter()
        .map(|p| [p[0].into(), p[1].into(), p[2].into()])
        .collect();
    let direct = inspect(
        &points,
        &ris_core::mesh::SignedDistance::new(model.mesh.clone()),
        &InspectParams {
            tolerance: 0.3,
            init: Some(ris_core::register::Pose::identity()),
            fit_pose: false,
            min_coverage: 0.0,
            characteristics: load_characteristics(&gdt, &model).expect("gdt"),
            ..InspectParams::default()
        },
    )
    .expect("inspect")
    .report;
    assert_eq!(
        direct.verdict, risd.verdict,
        "{:?} / {:?}",
        direct.reasons, risd.reasons
    );
    for (a, b) in direct.characteristics.iter().zip(&characteristics) {
        let (x, y) = (a.measured.expect("direct"), b.measured.expect("risd"));
        assert!(
            (x - y).abs() < 1e-3,
            "{}: {x} against risd's {y}",
            a.characteristic
        );
        assert_eq!(a.in_tolerance, b.in_tolerance, "{}", a.characteristic);
    }
    eprintln!(
        "risd: {}",
        characteristics
            .iter()
            .map(|c| format!(
                "{} {:.4} mm",
                c.characteristic,
                c.measured.unwrap_or(f64::NAN)
            ))
            .collect::<Vec<_>>()
            .join(", ")
    );
}
