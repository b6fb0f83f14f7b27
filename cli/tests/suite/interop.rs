//! What other tools open: a scan's cloud converted by `ris convert` is read by libE57Format,
//! the E57 reference library (through the Python `pye57` package), in metres with every point
//! and its camera row and column;
//! the PLY RIS writes is loaded by CloudCompare's command line (Debian's build, which has no
//! E57 plugin) and exported with the same points. Both tools are installed by `.ci/run`.

use std::path::Path;
use std::process::Command;
use std::time::Duration;

use crate::common;
use common::output_within;

/// A helix-like test cloud with confidences, volume flags and camera pixels (every third pixel
/// of a 300 x 200 image), written as PLY.
fn cloud(path: &Path) -> ris_core::cloud::PointCloud {
    let mut c = ris_core::cloud::PointCloud {
        image: Some([300, 200]),
        ..Default::default()
    };
    for i in 0..20_000 {
        let t = f64::from(i) * 0.003;
        c.points.push([
            (400.0 * t.cos()) as f32,
            (250.0 * t.sin()) as f32,
            (900.0 + 3.0 * t) as f32,
        ]);
        c.confidence.push((i % 13) as f32 / 13.0);
        c.outside.push(i % 17 == 0);
        c.pixels.push(3 * i);
    }
    c.write_ply(path).expect("ply");
    c
}

#[test]
fn libe57format_reads_the_e57_and_cloudcompare_the_ply_ris_writes() {
    let dir = tempfile::tempdir().expect("tmp");
    let (ply, e57) = (dir.path().join("c.ply"), dir.path().join("c.e57"));
    let c = cloud(&ply);
    let o = output_within(
        Command::new(env!("CARGO_BIN_EXE_ris"))
            .arg("convert")
            .arg(&ply)
            .arg(&e57),
        Duration::from_secs(60),
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));

    // libE57Format: count, metres, and the largest difference from the PLY's points.
    let script = format!(
        "import pye57, json\n\
e = pye57.E57({:?})\n\
d = e.read_scan_raw(0, ignore_unsupported_fields=True)\n\
print(json.dumps({{'scans': e.scan_count, 'x': list(d['cartesianX']), 'y': list(d['cartesianY']), 'z': list(d['cartesianZ']), 'row': [int(v) for v in d['rowIndex']], 'column': [int(v) for v in d['columnIndex']]}}))\n",
        e57.display().to_string()
    );
    let o = output_within(
        Command::new("python3").arg("-c").arg(&script),
        Duration::from_secs(120),
    );
    assert!(
        o.status.success(),
        "pye57 (libE57Format) failed: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("json");
    assert_eq!(v["scans"], 1);
    let axis = |k: &str| -> Vec<f64> {
        v[k].as_array()
            .expect("axis")
            .iter()
            .map(|x| x.as_f64().expect("number"))
            .collect()
    };
    let (x, y, z) = (axis("x"), axis("y"), axis("z"));
    let (row, column) = (axis("row"), axis("column"));
    assert_eq!(x.len(), c.len());
    for (i, p) in c.points.iter().enumerate() {
        let (r, k) = c.row_column(i).expect("organised");
        assert_eq!(
            (row[i], column[i]),
            (f64::from(r), f64::from(k)),
            "point {i}: camera pixel"
        );
        for (m, mm) in [(x[i], p[0]), (y[i], p[1]), (z[i], p[2])] {
            assert!(
                (m * 1000.0 - f64::from(mm)).abs() < 1e-3,
                "point {i}: {m} m vs {mm} mm"
            );
        }
    }

    // CloudCompare: load the PLY, export it as ASCII, same points.
    let o = output_within(
        Command::new("CloudCompare")
            .current_dir(dir.path())
            .env("QT_QPA_PLATFORM", "offscreen")
            .args([
                "-SILENT",
                "-NO_TIMESTAMP",
                "-O",
                "c.ply",
                "-C_EXPORT_FMT",
                "ASC",
                "-SAVE_CLOUDS",
            ]),
        Duration::from_secs(120),
    );
    let log = String::from_utf8_lossy(&o.stdout).into_owned() + &String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "CloudCompare failed: {log}");
    assert!(log.contains(&format!("{} points", c.len())), "{log}");
    let asc = std::fs::read_to_string(dir.path().join("c.asc")).expect("CloudCompare's export");
    let rows: Vec<Vec<f64>> = asc
        .lines()
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            l.split_whitespace()
                .map(|t| t.parse().expect("number"))
                .collect()
        })
        .collect();
    assert_eq!(rows.len(), c.len());
    for (r, p) in rows.iter().zip(&c.points) {
        for k in 0..3 {
            assert!((r[k] - f64::from(p[k])).abs() < 1e-3, "{r:?} vs {p:?}");
        }
    }
}
