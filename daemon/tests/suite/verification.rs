//! The acceptance test through risd (issue 41 item 3 and 5) on 127.0.0.1: the one-sensor
//! verification cell (a ball bar and a probing sphere on its table, as the shipped artefacts
//! file calibrates them) is verified position by position with `mode: verify` scans, the
//! session finished into certificates that risd stores and publishes, health reports the
//! last verification; a restart reloads the history, a quick check with a miscalibrated bar
//! fails and drifts, and from then on health and every inspection report say so.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use ris_core::verify::Status;
use ris_daemon::protocol::{VerificationRecord, VerifyPosition};
use zenoh::Wait;

use crate::common;
use common::{ask, cell_config, client, free_port, output_within, states, wait_end, InProcess};

fn config_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../config")
}

/// The table (z = 0) as the part's CAD: the cell's inspection runs on every plain scan.
fn table_part(dir: &Path) -> ris_daemon::config::PartConfig {
    let cad = dir.join("table.stl");
    let (a, b) = (400.0, 300.0);
    let tri = |p: [[f64; 2]; 3]| {
        let mut s = String::from("facet normal 0 0 1\nouter loop\n");
        for v in p {
            s += &format!("vertex {} {} 0\n", v[0], v[1]);
        }
        s + "endloop\nendfacet\n"
    };
    let stl = format!(
        "solid table\n{}{}endsolid table\n",
        tri([[-a, -b], [a, -b], [a, b]]),
        tri([[-a, -b], [a, b], [-a, b]])
    );
    std::fs::write(&cad, stl).expect("table.stl");
    ris_daemon::config::PartConfig {
        id: "table".into(),
        cad,
        datums: None,
        tolerance: 0.5,
        min_coverage: 0.0,
        pose: ris_daemon::config::PartPose::Fit,
        inspected: ris_daemon::config::PartSurface::Whole,
        faces: Vec::new(),
        characteristics: None,
    }
}

/// Ask for a scan: its id, or the refusal.
fn scan(session: &zenoh::Session, body: &str) -> Result<String, String> {
    let r = ask(session, "ris/verify/scan", Some(body));
    match r.first() {
        Some(Ok(reply)) => {
            let v: serde_json::Value = serde_json::from_str(reply).expect("reply json");
            Ok(v["scan_id"].as_str().expect("scan id").to_string())
        }
        Some(Err(e)) => Err(e.clone()),
        None => panic!("no reply to {body}"),
    }
}

fn verify(session: &zenoh::Session, body: &str) -> Result<serde_json::Value, String> {
    match ask(session, "ris/verify/verify", Some(body)).first() {
        Some(Ok(r)) => Ok(serde_json::from_str(r).expect("json")),
        Some(Err(e)) => Err(e.clone()),
        None => panic!("no reply to {body}"),
    }
}

fn health(session: &zenoh::Session) -> serde_json::Value {
    let r = ask(session, "ris/verify/health", None);
    serde_json::from_str(r[0].as_ref().expect("health")).expect("health json")
}

/// The inspection report's warnings of a finished scan.
fn report_warnings(data: &Path, id: &str) -> Vec<String> {
    let text = std::fs::read_to_string(data.join("scans").join(id).join("report.json"))
        .expect("report.json");
    let v: serde_json::Value = serde_json::from_str(&text).expect("report json");
    v["warnings"]
        .as_array()
        .expect("warnings")
        .iter()
        .map(|w| w.as_str().unwrap_or_default().to_string())
        .collect()
}

#[test]
fn a_cell_is_verified_through_risd_and_a_failed_check_shows_in_health_and_reports() {
    let watchdog = common::Watchdog::arm("verification", Duration::from_secs(600));
    let tmp = tempfile::tempdir().expect("tmp");
    let data = tmp.path().join("data");
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let mut config = cell_config(&config_dir().join("verify-cell.toml"), &endpoint, &data);
    config.parts.push(table_part(tmp.path()));
    let first = config.clone();
    watchdog.stage("preparing");
    let mut risd = InProcess::start(first);
    risd.wait_ready(Duration::from_secs(300));
    let session = client(&endpoint);
    let (_sub, states_rx) = states(&session, "verify");

    // Never verified: health and the first inspection report say so.
    let h = health(&session);
    assert!(h["verification"]["last"].is_null(), "{h}");
    let never = h["verification"]["warnings"][0]
        .as_str()
        .unwrap_or_default();
    assert!(never.contains("no verification on record"), "{h}");
    watchdog.stage("a plain scan, inspected");
    let id = scan(&session, "{}").expect("plain scan");
    let done = wait_end(&states_rx, &id);
    assert_eq!(done["state"], "done", "{done}");
    let w = report_warnings(&data, &id);
    assert!(
        w.iter().any(|w| w.contains("no verification on record")),
        "{w:?}"
    );

    // Refusals name what to change, and start nothing.
    for (body, says) in [
        (r#"{"mode": "verify", "position": "p"}"#, "artefact"),
        (r#"{"mode": "verify", "artefact": "ball_bar"}"#, "position"),
        (
            r#"{"mode": "verify", "artefact": "ball_bar", "position": "../x"}"#,
            "position",
        ),
        (r#"{"artefact": "sphere", "position": "p"}"#, "verify"),
        (
            r#"{"mode": "verify", "artefact": "sphere", "position": "p", "part": "table"}"#,
            "part",
        ),
    ] {
        let e = scan(&session, body).expect_err(body);
        assert!(e.contains(says), "{body}: {e}");
    }
    let e = verify(&session, r#"{"action": "finish"}"#).expect_err("nothing open");
    assert!(e.contains("no verification is open"), "{e}");
    let e = verify(&session, r#"{"action": "launch"}"#).expect_err("unknown action");
    assert!(e.contains("malformed request"), "{e}");

    // The acceptance test, position by position (the first opens the session).
    let measure = |artefact: &str, position: &str| -> VerifyPosition {
        watchdog.stage(&format!("measuring {artefact} at {position}"));
        let id = scan(
            &session,
            &format!(r#"{{"mode": "verify", "artefact": "{artefact}", "position": "{position}"}}"#),
        )
        .expect("verify scan");
        let done = wait_end(&states_rx, &id);
        assert_eq!(done["state"], "done", "{done}");
        serde_json::from_value(done["verification"].clone()).expect("the position's figures")
    };
    let bar = measure("ball_bar", "bar-1");
    let sphere = measure("sphere", "sphere-1");
    for scope in ["s1", "merged"] {
        // Truth: the scene's bar is 300 mm exactly, its sphere 40 mm; the sensor model is the
        // scene's own, so the figures are the sensor's noise and fit only.
        let sd = &bar.scopes[scope][0];
        assert_eq!(sd.status, Status::Pass, "{scope}: {sd:?}");
        assert!(
            sd.error.expect("SD").abs() <= 0.08,
            "{scope}: SD {:?}",
            sd.error
        );
        assert!((sd.measured.expect("spacing") - 300.0).abs() <= 0.08);
        let (pf, ps) = (&sphere.scopes[scope][0], &sphere.scopes[scope][1]);
        assert!(
            ps.error.expect("PS").abs() <= 0.06,
            "{scope}: PS {:?}",
            ps.error
        );
        assert!(pf.error.expect("PF") <= 0.4, "{scope}: PF {:?}", pf.error);
        assert!(pf.points >= 1000 && sd.points >= 1000, "{pf:?} {sd:?}");
        assert_eq!(pf.position.label, "sphere-1");
    }
    let open = health(&session)["verification"]["open"].clone();
    assert_eq!(open["positions"], 2, "{open}");
    assert_eq!(open["kind"], "acceptance", "{open}");

    // Finished: the certificates are published, stored and answered from the store.
    let (tx, published) = std::sync::mpsc::channel();
    let _certs = session
        .declare_subscriber("ris/verify/verifications/**")
        .callback(move |s| {
            let _ = tx.send((
                s.key_expr().to_string(),
                s.payload().to_bytes().into_owned(),
            ));
        })
        .wait()
        .expect("subscriber");
    watchdog.stage("finishing");
    let summary = verify(&session, r#"{"action": "finish"}"#).expect("finish");
    assert_eq!(summary["verdict"], "pass", "{summary}");
    assert_eq!(summary["scopes"]["merged"], "pass", "{summary}");
    let accepted = summary["id"].as_str().expect("id").to_string();
    let mut got = std::collections::BTreeMap::new();
    while got.len() < 2 {
        let (k, v) = published
            .recv_timeout(Duration::from_secs(10))
            .expect("certificate and page published");
        got.insert(k, v);
    }
    let record: VerificationRecord =
        serde_json::from_slice(&got[&format!("ris/verify/verifications/{accepted}/certificate")])
            .expect("certificate");
    assert_eq!(record.positions.len(), 2);
    let merged = &record.certificates["merged"];
    assert_eq!(merged.sphere_spacing.len(), 1);
    assert_eq!(merged.probing_size.len(), 1);
    // Two positions are a spot check, not the guideline's acceptance test; it says so.
    assert!(!merged.coverage.acceptance_test && !merged.coverage.missing.is_empty());
    let page = String::from_utf8_lossy(&got[&format!("ris/verify/verifications/{accepted}/page")])
        .into_owned();
    assert!(page.contains("data:image/png;base64,") && page.contains("sphere-1"));
    let stored = ask(
        &session,
        &format!("ris/verify/verifications/{accepted}/certificate"),
        None,
    );
    assert_eq!(stored.len(), 1, "{stored:?}");
    let h = health(&session);
    assert_eq!(h["verification"]["last"]["verdict"], "pass", "{h}");
    assert!(h["verification"]["age_days"].as_f64().expect("age") < 0.01);
    assert!(h["verification"]["open"].is_null());
    assert!(
        !h["verification"]["warnings"]
            .as_array()
            .expect("warnings")
            .iter()
            .any(|w| w.as_str().unwrap_or_default().contains("no verification")),
        "{h}"
    );
    drop(session);
    risd.stop().expect("stopped");

    // Restarted with a bar whose calibration is 0.5 mm off (the certificate's spacing
    // 300.5 mm): the history is reloaded; a quick check fails and drifts.
    let artefacts = std::fs::read_to_string(config_dir().join("verify/demo-artefacts.toml"))
        .expect("artefacts")
        .replace("spacing = 300.0", "spacing = 300.5");
    assert!(artefacts.contains("300.5"));
    let wrong = tmp.path().join("wrong-bar.toml");
    std::fs::write(&wrong, artefacts).expect("write");
    let mut second = config.clone();
    second.verify.as_mut().expect("[verify]").artefacts = wrong;
    watchdog.stage("restarting with a miscalibrated bar");
    let mut risd = InProcess::start(second);
    risd.wait_ready(Duration::from_secs(300));
    let session = client(&endpoint);
    let (_sub, states_rx) = states(&session, "verify");
    let h = health(&session);
    assert_eq!(h["verification"]["last"]["id"], accepted.as_str(), "{h}");
    watchdog.stage("ris verify --check");
    let out = tmp.path().join("check");
    let check = output_within(
        Command::new(common::binary("ris"))
            .args(["verify", "--connect", &endpoint, "--cell", "verify"])
            .args(["--check", "ball_bar:bar-1", "--out"])
            .arg(&out),
        Duration::from_secs(240),
    );
    let text = String::from_utf8_lossy(&check.stdout).into_owned();
    assert_eq!(
        check.status.code(),
        Some(3),
        "{text}{}",
        String::from_utf8_lossy(&check.stderr)
    );
    assert!(
        text.contains("verification: FAIL") && text.contains("moved by"),
        "{text}"
    );
    let fetched: VerificationRecord =
        serde_json::from_slice(&std::fs::read(out.join("certificate.json")).expect("fetched"))
            .expect("certificate.json");
    let sd = &fetched.certificates["merged"].sphere_spacing[0];
    assert!((sd.error.expect("SD") + 0.5).abs() <= 0.08, "{sd:?}");
    assert!(std::fs::read_to_string(out.join("verify.html"))
        .expect("page")
        .contains("FAIL"));

    let h = health(&session);
    assert_eq!(h["verification"]["last"]["verdict"], "fail", "{h}");
    assert_eq!(h["verification"]["last"]["kind"], "check", "{h}");
    let warnings = h["verification"]["warnings"].to_string();
    assert!(
        warnings.contains("failed") && warnings.contains("moved by"),
        "{warnings}"
    );
    watchdog.stage("a plain scan after the failed check");
    let id = scan(&session, "{}").expect("plain scan");
    let done = wait_end(&states_rx, &id);
    assert_eq!(done["state"], "done", "{done}");
    let w = report_warnings(&data, &id);
    assert!(
        w.iter()
            .any(|w| w.contains("last verification") && w.contains("failed")),
        "{w:?}"
    );
    // The history: the acceptance test and the failed check, per scope.
    let history = verify(&session, r#"{"action": "history"}"#).expect("history");
    let entries = history.as_array().expect("entries");
    assert_eq!(entries.len(), 4, "{history}");
    assert!(entries
        .iter()
        .any(|e| e["kind"] == "check" && e["scope"] == "s1" && e["verdict"] == "fail"));
    drop(session);
    risd.stop().expect("stopped");
}
