//! Access control on a cell (`[zenoh.access]`), with real Zenoh sessions on 127.0.0.1: a
//! client without credentials (or with a wrong password) can neither start a scan nor read a
//! cloud nor publish under the cell's keys; a reader reads but cannot scan or forge states; an
//! operator scans.

use crate::common;

use std::path::Path;
use std::sync::mpsc;

use common::{free_port, Risd};
use std::time::{Duration, Instant};

use ris_daemon::service::client_config;
use zenoh::Wait;

fn open(endpoint: &str, user: Option<(&str, &str)>) -> Option<zenoh::Session> {
    let config = client_config(&[endpoint.to_string()], user).expect("client config");
    zenoh::open(config).wait().ok()
}

/// Ok replies and error replies to a query.
fn ask(session: &zenoh::Session, key: &str, payload: &str) -> (Vec<String>, Vec<String>) {
    let replies = session
        .get(key)
        .payload(payload.to_string())
        .timeout(Duration::from_secs(3))
        .wait()
        .expect("get");
    let (mut ok, mut err) = (Vec::new(), Vec::new());
    while let Ok(r) = replies.recv() {
        match r.result() {
            Ok(s) => ok.push(String::from_utf8_lossy(&s.payload().to_bytes()).into_owned()),
            Err(e) => err.push(String::from_utf8_lossy(&e.payload().to_bytes()).into_owned()),
        }
    }
    (ok, err)
}

#[test]
fn only_authorised_users_scan_read_or_publish() {
    let tmp = tempfile::tempdir().expect("tmp");
    let users = tmp.path().join("users.txt");
    std::fs::write(&users, "plc:s3cret-plc\nviewer:s3cret-view\n").expect("users");
    let scene = Path::new(env!("CARGO_MANIFEST_DIR")).join("../config/scenes/tiny.toml");
    let config = tmp.path().join("cell.toml");
    std::fs::write(
        &config,
        format!(
            "[cell]\nname = \"sec\"\n[zenoh.access]\nusers = \"users.txt\"\noperators = [\"plc\"]\nreaders = [\"viewer\"]\n[[sensor]]\nname = \"s1\"\nbackend = \"mock\"\nscene = \"{}\"\nto_common = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]\n",
            scene.display()
        ),
    )
    .expect("cell");
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let data = tmp.path().join("data");
    let mut risd = Risd::start(&[
        "--config".as_ref(),
        config.as_os_str(),
        "--listen".as_ref(),
        endpoint.as_ref(),
        "--data-dir".as_ref(),
        data.as_os_str(),
    ]);
    risd.wait_ready(Duration::from_secs(60));

    // The operator scans and follows the states; a reader follows them too.
    let plc = open(&endpoint, Some(("plc", "s3cret-plc"))).expect("the operator connects");
    let viewer = open(&endpoint, Some(("viewer", "s3cret-view"))).expect("the reader connects");
    let (tx, states) = mpsc::channel::<(String, String)>();
    let tx2 = tx.clone();
    let _plc_sub = plc
        .declare_subscriber("ris/sec/scans/*/state")
        .callback(move |s| {
            let _ = tx.send((
                "plc".into(),
                String::from_utf8_lossy(&s.payload().to_bytes()).into_owned(),
            ));
        })
        .wait()
        .expect("subscriber");
    let _viewer_sub = viewer
        .declare_subscriber("ris/sec/scans/*/state")
        .callback(move |s| {
            let _ = tx2.send((
                "viewer".into(),
                String::from_utf8_lossy(&s.payload().to_bytes()).into_owned(),
            ));
        })
        .wait()
        .expect("subscriber");
    std::thread::sleep(Duration::from_millis(300));

    // Without credentials, or with a wrong password: no session, or one that gets nothing.
    for user in [None, Some(("plc", "wrong")), Some(("mallory", "x"))] {
        if let Some(anon) = open(&endpoint, user) {
            let (ok, _) = ask(&anon, "ris/sec/scan", "{}");
            assert!(ok.is_empty(), "{user:?} started a scan: {ok:?}");
            let (ok, _) = ask(&anon, "ris/sec/health", "");
            assert!(ok.is_empty(), "{user:?} read health: {ok:?}");
            let _ = anon
                .put(
                    "ris/sec/scans/forged/state",
                    r#"{"state":"failed","reason":"forged"}"#,
                )
                .wait();
            let _ = anon.close().wait();
        }
    }
    // A reader reads health but cannot scan, nor publish a forged state.
    let (ok, _) = ask(&viewer, "ris/sec/health", "");
    assert_eq!(ok.len(), 1, "the reader reads health");
    let (ok, _) = ask(&viewer, "ris/sec/scan", "{}");
    assert!(ok.is_empty(), "the reader started a scan: {ok:?}");
    viewer
        .put(
            "ris/sec/scans/forged/state",
            r#"{"state":"failed","reason":"forged"}"#,
        )
        .wait()
        .expect("put");
    // The operator scans.
    let (ok, err) = ask(&plc, "ris/sec/scan", "{}");
    assert_eq!(ok.len(), 1, "the operator's scan: {ok:?} {err:?}");
    let v: serde_json::Value = serde_json::from_str(&ok[0]).expect("json");
    assert_eq!(v["state"], "accepted");
    let t = Instant::now();
    let mut done = (false, false);
    while t.elapsed() < Duration::from_secs(60) && !(done.0 && done.1) {
        if let Ok((who, text)) = states.recv_timeout(Duration::from_millis(200)) {
            // (A session delivers its own puts to its own subscribers: the reader's forgery
            // reaching the reader itself says nothing; it must not reach anyone else.)
            assert!(
                who == "viewer" || !text.contains("forged"),
                "{who} received a forged state: {text}"
            );
            if text.contains("\"done\"") {
                if who == "plc" {
                    done.0 = true;
                } else {
                    done.1 = true;
                }
            }
        }
    }
    assert!(
        done.0 && done.1,
        "both users follow the scan to done: {done:?}"
    );
    // Stored clouds: the reader gets them.
    let (ok, _) = ask(&viewer, "ris/sec/scans/*/cloud/merged", "");
    assert_eq!(ok.len(), 1, "the reader reads the stored merged cloud");
    drop((_plc_sub, _viewer_sub));
    let _ = plc.close().wait();
    let _ = viewer.close().wait();
    let (status, lines) = risd.terminate();
    assert!(status.success(), "{lines:#?}");
}
