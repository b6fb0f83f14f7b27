//! risd against an unlucky or hostile network (issue "never a wrong verdict, never a silently
//! dead daemon"), with real Zenoh sessions on 127.0.0.1: requests during start-up are refused
//! with a reason, wildcard and non-object requests start nothing, a second daemon on the same
//! data directory or cell name refuses to start while the first one's scan completes, and
//! retention holds while the daemon runs.

use crate::common;

use std::ffi::OsStr;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use common::{ask, cell_config, client, free_port, states, wait_end, InProcess, Risd};

use zenoh::Wait;

fn config_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../config")
}

/// A two-sensor cell from the mock cell's scenes (preparation takes a few seconds), keeping
/// two scans.
fn cell_file(dir: &Path, name: &str) -> PathBuf {
    let scenes = config_dir().join("mock-cell");
    let mut text = format!(
        "[cell]\nname = \"{name}\"\n[storage]\nkeep_scans = 2\nmax_age_days = 0\n[workers]\nqueue = 2\n"
    );
    for s in ["s1", "s2"] {
        text += &format!(
            "[[sensor]]\nname = \"{s}\"\nbackend = \"mock\"\nscene = \"{}\"\nto_common = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]\n",
            scenes.join(format!("{s}.toml")).display()
        );
    }
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(&path, text).expect("cell file");
    path
}

/// risd on `config` with `data` as its data directory, listening on `listen`.
fn start(config: &Path, data: &Path, listen: &str, connect: Option<&str>) -> Risd {
    let mut args: Vec<&OsStr> = vec![
        "--config".as_ref(),
        config.as_os_str(),
        "--listen".as_ref(),
        listen.as_ref(),
        "--data-dir".as_ref(),
        data.as_os_str(),
    ];
    if let Some(c) = connect {
        args.extend(["--connect".as_ref(), c.as_ref()] as [&OsStr; 2]);
    }
    Risd::start(&args)
}

fn finished_scans(data: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(data.join("scans"))
        .map(|d| {
            d.flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

#[test]
fn start_up_wildcards_rivals_and_retention() {
    let tmp = tempfile::tempdir().expect("tmp");
    let data = tmp.path().join("data");
    let config = cell_file(tmp.path(), "hard");
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let first = start(&config, &data, &endpoint, None);
    let session = client(&endpoint);
    let (_sub, states) = states(&session, "hard");

    // While the pairs are prepared, a request gets an error reply that says so; no liveliness.
    let t = Instant::now();
    let mut starting = 0;
    let accepted = loop {
        assert!(
            t.elapsed() < Duration::from_secs(60),
            "risd never accepted a scan"
        );
        let replies = ask(
            &session,
            "ris/hard/scan",
            Some(r#"{"sensors": ["s1"], "tag": "first"}"#),
        );
        match replies.first() {
            Some(Ok(text)) => break text.clone(),
            Some(Err(e)) => {
                assert!(e.contains("starting"), "{e}");
                let alive = session
                    .liveliness()
                    .get("ris/hard/health")
                    .timeout(Duration::from_millis(300))
                    .wait()
                    .expect("liveliness get");
                let mut tokens = 0;
                while let Ok(r) = alive.recv() {
                    tokens += usize::from(r.result().is_ok());
                }
                // The token may appear between the reply and this look-up; only a token
                // together with a "starting" answer to the next request would be wrong.
                if tokens == 0 {
                    starting += 1;
                }
            }
            None => panic!("a scan request got no reply at all"),
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    assert!(starting > 0, "no request was made during start-up");
    let v: serde_json::Value = serde_json::from_str(&accepted).expect("json");
    let first_id = v["scan_id"].as_str().expect("scan_id").to_string();

    // A second daemon on the same data directory refuses to start; the first one's scan goes on.
    let other = format!("tcp/127.0.0.1:{}", free_port());
    let (status, log) = start(&config, &data, &other, None).exit_within(Duration::from_secs(30));
    assert!(!status.success());
    assert!(
        log.iter().any(|l| l.contains("in use by another risd")),
        "{log:#?}"
    );
    // A second daemon of the same cell on the network refuses too.
    let data2 = tmp.path().join("data2");
    let (status, log) =
        start(&config, &data2, &other, Some(&endpoint)).exit_within(Duration::from_secs(30));
    assert!(!status.success());
    assert!(
        log.iter().any(|l| l.contains("already serves cell")),
        "{log:#?}"
    );
    assert!(!data2.join("scans").exists());
    let end = wait_end(&states, &first_id);
    assert_eq!(end["state"], "done", "{end}");
    assert!(data.join("scans").join(&first_id).join("s1.ply").is_file());
    let stored: serde_json::Value = serde_json::from_slice(
        &std::fs::read(data.join("scans").join(&first_id).join("scan.json")).expect("scan.json"),
    )
    .expect("json");
    assert_eq!(stored["tag"], "first", "{stored}");

    // Wildcard queries and bodies that are not JSON objects start nothing.
    let before = finished_scans(&data);
    for key in ["ris/*/scan", "ris/hard/*", "ris/**", "**"] {
        for text in ask(&session, key, None).into_iter().flatten() {
            assert!(!text.contains("accepted"), "{key}: {text}");
        }
    }
    for body in [
        None,
        Some("[]"),
        Some(r#"["gray"]"#),
        Some("null"),
        Some("{"),
    ] {
        let replies = ask(&session, "ris/hard/scan", body);
        assert_eq!(replies.len(), 1, "{body:?}: {replies:?}");
        let e = replies[0].as_ref().expect_err("refused");
        assert!(
            e.contains("JSON object") || e.contains("malformed"),
            "{body:?}: {e}"
        );
    }
    let huge_tag = format!(r#"{{"tag": "{}"}}"#, "x".repeat(10_000));
    let replies = ask(&session, "ris/hard/scan", Some(&huge_tag));
    assert!(
        replies[0].as_ref().is_err_and(|e| e.len() < 300),
        "{replies:?}"
    );
    let unknown = format!(r#"{{"sensors": ["{}"]}}"#, "n".repeat(100_000));
    let replies = ask(&session, "ris/hard/scan", Some(&unknown));
    assert!(
        replies[0].as_ref().is_err_and(|e| e.len() < 300),
        "{replies:?}"
    );
    std::thread::sleep(Duration::from_millis(500));
    if let Ok((id, v)) = states.try_recv() {
        panic!("a refused request published a state: {id} {v}");
    }
    assert_eq!(finished_scans(&data), before);
    let health = ask(&session, "ris/hard/health", None);
    let h: serde_json::Value =
        serde_json::from_str(health[0].as_ref().expect("health")).expect("json");
    assert_eq!(h["queue"], 0, "{h}");
    assert_eq!(h["state"], "ready", "{h}");

    // Retention holds while running: keep_scans = 2.
    for k in 0..3 {
        let replies = ask(&session, "ris/hard/scan", Some(r#"{"sensors": ["s2"]}"#));
        let v: serde_json::Value =
            serde_json::from_str(replies[0].as_ref().expect("accepted")).expect("json");
        let id = v["scan_id"].as_str().expect("id").to_string();
        assert_eq!(wait_end(&states, &id)["state"], "done");
        let kept = finished_scans(&data);
        assert!(kept.len() <= 2, "scan {k}: {kept:?}");
        assert!(kept.contains(&id), "{kept:?}");
    }
    let kept: Vec<String> = finished_scans(&data)
        .into_iter()
        .filter(|n| !n.ends_with(".partial"))
        .collect();
    assert_eq!(kept.len(), 2, "{kept:?}");
    let stored: serde_json::Value = serde_json::from_slice(
        &std::fs::read(data.join("scans").join(&kept[1]).join("scan.json")).expect("scan.json"),
    )
    .expect("json");
    assert!(stored["tag"].is_null(), "{stored}");
    drop(_sub);
    let _ = session.close().wait();
    let (status, log) = first.terminate();
    assert!(status.success(), "{log:#?}");
}

/// A one-sensor cell on the tiny scene (prepared in well under a second), keeping every scan.
fn tiny_cell(dir: &Path) -> PathBuf {
    let scene = config_dir().join("scenes/tiny.toml");
    let path = dir.join("tiny.toml");
    std::fs::write(
        &path,
        format!(
            "[cell]\nname = \"tiny\"\n[storage]\nkeep_scans = 0\nmax_age_days = 0\n[[sensor]]\nname = \"s1\"\nbackend = \"mock\"\nscene = \"{}\"\nto_common = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]\n",
            scene.display()
        ),
    )
    .expect("cell file");
    path
}

#[test]
fn an_unwritable_store_fails_every_scan_with_the_reason() {
    let tmp = tempfile::tempdir().expect("tmp");
    let config = tiny_cell(tmp.path());
    // A store whose `scans` is a file: no scan can be written there (the tests run as root,
    // so permissions would not stop a write). Each scan must end `failed`, naming the path.
    let broken = tmp.path().join("broken");
    std::fs::create_dir_all(&broken).expect("mkdir");
    std::fs::write(broken.join("scans"), "not a directory").expect("file");
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let mut risd = start(&config, &broken, &endpoint, None);
    risd.wait_ready(Duration::from_secs(60));
    let session = client(&endpoint);
    let (_sub, states) = states(&session, "tiny");
    std::thread::sleep(Duration::from_millis(200));
    for _ in 0..2 {
        let replies = ask(&session, "ris/tiny/scan", Some("{}"));
        let v: serde_json::Value =
            serde_json::from_str(replies[0].as_ref().expect("accepted")).expect("json");
        let id = v["scan_id"].as_str().expect("id").to_string();
        let end = wait_end(&states, &id);
        assert_eq!(end["state"], "failed", "{end}");
        assert!(
            end["reason"].as_str().is_some_and(|r| r.contains("scans")),
            "{end}"
        );
    }
    // The daemon goes on serving, and health already says so when `failed` arrives: the
    // ending goes out after the worker's bookkeeping.
    let health = ask(&session, "ris/tiny/health", None);
    let h: serde_json::Value =
        serde_json::from_str(health[0].as_ref().expect("health")).expect("json");
    assert_eq!(h["state"], "ready", "{h}");
    assert!(
        h["last_error"]
            .as_str()
            .is_some_and(|e| e.contains("scans")),
        "{h}"
    );
    let (status, log) = risd.terminate();
    assert!(status.success(), "{log:#?}");
}

#[test]
fn sigterm_during_start_up_does_not_wait_for_preparation() {
    // The built-in mock cell prepares four 2 MP-class pairs (seconds); SIGTERM as soon as its
    // Zenoh session answers must end risd without finishing them.
    let tmp = tempfile::tempdir().expect("tmp");
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let config = config_dir().join("mock-cell.toml");
    let risd = start(&config, tmp.path(), &endpoint, None);
    let session = client(&endpoint);
    let replies = ask(&session, "ris/mock/scan", Some("{}"));
    assert!(
        replies[0].as_ref().is_err_and(|e| e.contains("starting")),
        "{replies:?}"
    );
    let _ = session.close().wait();
    let (status, log) = risd.terminate();
    assert!(status.success(), "{log:#?}");
    let prepared = log.iter().filter(|l| l.contains("mock pair ready")).count();
    assert!(
        prepared < 4 && !log.iter().any(|l| l.contains("risd ready")),
        "preparation ran to the end before the exit: {log:#?}"
    );
}

/// Two daemons of one cell started at offsets that land the second in the first one's
/// claim, preparation or readiness: exactly one serves (the first), the other ends saying
/// the cell is served, every time.
#[test]
fn two_daemons_racing_for_one_cell_leave_exactly_one_serving() {
    let rounds: u64 = if std::env::var("RIS_TIER").is_ok_and(|v| v == "long") {
        20
    } else {
        4
    };
    for round in 0..rounds {
        let tmp = tempfile::tempdir().expect("tmp");
        let (e1, e2) = (
            format!("tcp/127.0.0.1:{}", free_port()),
            format!("tcp/127.0.0.1:{}", free_port()),
        );
        let path = config_dir().join("verify-cell.toml");
        let first = cell_config(&path, &e1, &tmp.path().join("a"));
        let mut second = cell_config(&path, &e2, &tmp.path().join("b"));
        second.zenoh.connect = vec![e1.clone()];
        // Offsets spread over 0 … 1.9 s, seeded by the round.
        let offset = Duration::from_millis((round * 7919 + 311) % 1900);
        let mut a = InProcess::start(first);
        std::thread::sleep(offset);
        let mut b = InProcess::start(second);
        let t = Instant::now();
        let refused = loop {
            if let Some(outcome) = b.ended() {
                break outcome.expect_err("the second daemon must not serve");
            }
            assert!(a.ended().is_none(), "round {round}: the first daemon ended");
            assert!(
                t.elapsed() < Duration::from_secs(90),
                "round {round} (offset {offset:?}): the second daemon did not step aside"
            );
            std::thread::sleep(Duration::from_millis(50));
        };
        assert!(
            format!("{refused:#}").contains("already serves cell"),
            "round {round}: {refused:#}"
        );
        a.wait_ready(Duration::from_secs(90));
        let session = client(&e1);
        assert!(a.alive(&session), "round {round}: the first daemon serves");
        drop(session);
        a.stop().expect("the first daemon stops cleanly");
    }
}

/// VmHWM (peak resident memory) of process `pid`, kB.
fn peak_kb(pid: u32) -> u64 {
    std::fs::read_to_string(format!("/proc/{pid}/status"))
        .expect("status")
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        .expect("VmHWM")
}

#[test]
fn huge_request_bodies_are_dropped_before_they_fill_memory() {
    let tmp = tempfile::tempdir().expect("tmp");
    let config = tiny_cell(tmp.path());
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let mut risd = start(&config, &tmp.path().join("data"), &endpoint, None);
    risd.wait_ready(Duration::from_secs(120));
    let session = client(&endpoint);
    let before = peak_kb(risd.pid());
    // Three 200 MB bodies on the scan key: Zenoh drops each as its fragments pass the limit.
    let body = "x".repeat(200 << 20);
    for _ in 0..3 {
        let replies = session
            .get("ris/tiny/scan")
            .payload(body.clone())
            .timeout(Duration::from_secs(5))
            .wait()
            .expect("get");
        while replies.recv().is_ok() {}
    }
    std::thread::sleep(Duration::from_millis(500));
    let after = peak_kb(risd.pid());
    eprintln!(
        "risd's peak resident memory {before} kB before, {after} kB after three 200 MB requests"
    );
    assert!(
        after < before + 64 * 1024,
        "the peak rose by {} MB",
        (after - before) / 1024
    );
    // The daemon still answers a proper request.
    let r = ask(&session, "ris/tiny/health", None);
    assert!(r.first().is_some_and(|r| r.is_ok()), "{r:?}");
    let (status, lines) = risd.terminate();
    assert!(status.success(), "{lines:#?}");
}

/// The tiny cell with a part (the mock cell's panel) and a stage deadline of `deadline_s`.
fn tiny_cell_with_deadline(dir: &Path, deadline_s: u32) -> PathBuf {
    let path = tiny_cell(dir);
    let mut text = std::fs::read_to_string(&path).expect("cell file");
    text = text.replacen(
        "[[sensor]]",
        &format!("[workers]\nstage_deadline_s = {deadline_s}\n[[sensor]]"),
        1,
    );
    text += &format!(
        "[[part]]\nid = \"panel\"\ncad = \"{}\"\ntolerance = 0.5\n",
        config_dir().join("mock-cell/panel.stl").display()
    );
    std::fs::write(&path, text).expect("cell file");
    path
}

/// A computing stage that does not end by itself (injected: it runs until its budget stops
/// it) fails its scan naming the stage once past the cell's stage deadline, or as cancelled as
/// soon as the stop flag is raised; nothing unfinished is left and the next scan succeeds.
#[test]
fn a_hung_stage_ends_at_its_deadline_or_when_stopped_and_the_next_scan_succeeds() {
    use ris_daemon::cell::{Cell, ScanJob};
    use ris_daemon::protocol::ScanState;
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::{Arc, Mutex};
    let tmp = tempfile::tempdir().expect("tmp");
    // 3 s: the tiny cell's real stages stay well within it on a loaded machine (with 1 s,
    // a decoding slowed by the suite's other binaries failed the scan meant to be stopped).
    let config = ris_daemon::config::CellConfig::load(&tiny_cell_with_deadline(tmp.path(), 3))
        .expect("config");
    let mut cell = Cell::prepare(&config, 5, &|_, _, _| {}).expect("cell");
    let data = tmp.path().join("data");
    let inspect = ScanJob {
        part: Some(0),
        ..ScanJob::default()
    };
    // When each state was first told.
    let told = Mutex::new(Vec::<(String, Instant)>::new());
    let record = |s: &ScanState| {
        let name = serde_json::to_value(s).expect("json")["state"]
            .as_str()
            .unwrap_or_default()
            .to_string();
        let mut v = told.lock().expect("told");
        if v.last().is_none_or(|l| l.0 != name) {
            v.push((name, Instant::now()));
        }
    };
    let since = |state: &str| {
        told.lock()
            .expect("told")
            .iter()
            .find(|t| t.0 == state)
            .map(|t| t.1.elapsed())
            .unwrap_or_else(|| panic!("no {state} state"))
    };

    // Past the deadline (3 s): the reconstruction ends at its next check.
    cell.hang_in = Some("reconstruction".into());
    let e = cell
        .scan(&inspect, &data, "a", &|| false, &record)
        .expect_err("a hung reconstruction fails its scan");
    let took = since("reconstructing");
    eprintln!("hung reconstruction failed its scan {took:?} into the stage");
    let msg = format!("{e:#}");
    assert!(
        msg.contains("sensor s1: reconstruction: past its deadline of 3.0 s"),
        "{msg}"
    );
    assert!(
        took >= Duration::from_secs(3) && took < Duration::from_secs(5),
        "the stage ran {took:?} against a 3 s deadline"
    );
    assert!(!data.join("scans/a.partial").exists() && !data.join("scans/a").exists());

    // Stopped (risd stopping) 0.3 s into a hung inspection: it ends within a second.
    let stop = Arc::new(AtomicBool::new(false));
    cell.stop_with(stop.clone());
    cell.hang_in = Some("inspection".into());
    told.lock().expect("told").clear();
    let raised = Mutex::new(None::<Instant>);
    let ended = AtomicBool::new(false);
    let e = std::thread::scope(|scope| {
        scope.spawn(|| {
            while !told
                .lock()
                .expect("told")
                .iter()
                .any(|s| s.0 == "inspecting")
            {
                // (a scan that ended before its inspection fails below with its reason)
                if ended.load(Ordering::SeqCst) {
                    return;
                }
                std::thread::sleep(Duration::from_millis(10));
            }
            std::thread::sleep(Duration::from_millis(300));
            *raised.lock().expect("raised") = Some(Instant::now());
            stop.store(true, Ordering::SeqCst);
        });
        let e = cell
            .scan(&inspect, &data, "b", &|| false, &record)
            .expect_err("a stopped inspection fails its scan");
        ended.store(true, Ordering::SeqCst);
        e
    });
    let after = raised
        .lock()
        .expect("raised")
        .unwrap_or_else(|| panic!("the scan ended before its inspection: {e:#}"))
        .elapsed();
    eprintln!("hung inspection ended {after:?} after the stop flag");
    let msg = format!("{e:#}");
    assert!(msg.contains("inspection of part panel: cancelled"), "{msg}");
    assert!(
        after < Duration::from_secs(1),
        "ended {after:?} after the stop"
    );
    assert!(!data.join("scans/b.partial").exists() && !data.join("scans/b").exists());

    // The same cell scans again.
    stop.store(false, Ordering::SeqCst);
    cell.hang_in = None;
    let (report, dir) = cell
        .scan(&ScanJob::default(), &data, "c", &|| false, &record)
        .expect("the next scan succeeds");
    assert!(report.sensors[0].points > 1000, "{:?}", report.sensors);
    assert!(dir.join("merged.ply").exists());
}

/// risd with a stage stuck for good (injected in a `fault-injection` build: it never checks its
/// budget): the worker's heartbeat is fed while the stage is within its deadline and a grace
/// period, then goes quiet so the systemd watchdog starves (the only case it does); SIGTERM
/// still ends risd within 2 s, and the next start removes the unfinished scan.
#[test]
#[cfg_attr(
    not(feature = "fault-injection"),
    ignore = "needs risd built with --features fault-injection (.ci/run builds --all-features)"
)]
fn a_stuck_stage_starves_the_watchdog_and_sigterm_still_ends_risd_promptly() {
    use std::os::unix::net::UnixDatagram;
    let tmp = tempfile::tempdir().expect("tmp");
    let config = tiny_cell_with_deadline(tmp.path(), 1);
    let data = tmp.path().join("data");
    let socket = tmp.path().join("notify");
    let listener = UnixDatagram::bind(&socket).expect("notify socket");
    listener
        .set_read_timeout(Some(Duration::from_millis(200)))
        .expect("timeout");
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let args: Vec<&OsStr> = vec![
        "--config".as_ref(),
        config.as_os_str(),
        "--listen".as_ref(),
        endpoint.as_ref(),
        "--data-dir".as_ref(),
        data.as_os_str(),
    ];
    let socket_s = socket.display().to_string();
    let start_risd = |hang: &str| {
        Risd::start_env(
            &args,
            &[
                ("NOTIFY_SOCKET", &socket_s),
                // systemd's WatchdogSec=2: risd pings every second while its worker is alive.
                ("WATCHDOG_USEC", "2000000"),
                ("RISD_INJECT_HANG", hang),
            ],
        )
    };
    let mut risd = start_risd("stuck:reconstruction");
    risd.wait_ready(Duration::from_secs(120));
    // Every WATCHDOG=1 datagram's arrival.
    let pings = std::sync::Mutex::new(Vec::<Instant>::new());
    let done = std::sync::atomic::AtomicBool::new(false);
    std::thread::scope(|scope| {
        scope.spawn(|| {
            let mut buf = [0u8; 256];
            while !done.load(std::sync::atomic::Ordering::SeqCst) {
                if let Ok(n) = listener.recv(&mut buf) {
                    if buf[..n].windows(10).any(|w| w == b"WATCHDOG=1") {
                        pings.lock().expect("pings").push(Instant::now());
                    }
                }
            }
        });
        let count = |from: Instant, to: Instant| {
            pings
                .lock()
                .expect("pings")
                .iter()
                .filter(|t| **t >= from && **t < to)
                .count()
        };
        let session = client(&endpoint);
        let (_sub, states) = states(&session, "tiny");
        let idle = Instant::now();
        std::thread::sleep(Duration::from_secs(3));
        assert!(
            count(idle, Instant::now()) >= 2,
            "an idle risd feeds the watchdog"
        );
        let replies = ask(&session, "ris/tiny/scan", Some("{}"));
        let v: serde_json::Value =
            serde_json::from_str(replies[0].as_ref().expect("accepted")).expect("json");
        let id = v["scan_id"].as_str().expect("id").to_string();
        let t = Instant::now();
        let stage = loop {
            if let Ok((i, s)) = states.recv_timeout(Duration::from_millis(100)) {
                if i == id && s["state"] == "reconstructing" {
                    break Instant::now();
                }
            }
            assert!(t.elapsed() < Duration::from_secs(60), "no reconstruction");
        };
        // Deadline 1 s + grace 10 s: fed until then, starved after (two missed pings).
        std::thread::sleep(Duration::from_secs(15));
        let fed = count(stage, stage + Duration::from_secs(10));
        let starved = count(stage + Duration::from_secs(13), Instant::now());
        assert!(
            fed >= 8,
            "{fed} pings while the stage was within its deadline"
        );
        assert_eq!(starved, 0, "pings went on past the stuck stage's grace");
        assert!(data.join(format!("scans/{id}.partial")).exists());
        let _ = session.close().wait();
        let t = Instant::now();
        let (status, log) = risd.terminate();
        let took = t.elapsed();
        eprintln!("SIGTERM to exit with a stuck stage: {took:?}; pings while fed: {fed}");
        done.store(true, std::sync::atomic::Ordering::SeqCst);
        assert!(
            took < Duration::from_secs(2),
            "SIGTERM took {took:?}: {log:#?}"
        );
        assert!(status.success(), "{log:#?}");
        assert!(
            log.iter().any(|l| l.contains("did not stop in time")),
            "{log:#?}"
        );
    });
    // The next start sweeps the unfinished scan away.
    let mut risd = start_risd("");
    risd.wait_ready(Duration::from_secs(120));
    assert!(finished_scans(&data)
        .iter()
        .all(|s| !s.ends_with(".partial")));
    let (status, log) = risd.terminate();
    assert!(status.success(), "{log:#?}");
}

/// The numeric leaves of a TOML document: (path, as `a.b[2].c`).
fn numeric_leaves(v: &toml::Value, path: &str, out: &mut Vec<String>) {
    match v {
        toml::Value::Integer(_) | toml::Value::Float(_) => out.push(path.to_string()),
        toml::Value::Table(t) => {
            for (k, x) in t {
                let p = if path.is_empty() {
                    k.clone()
                } else {
                    format!("{path}.{k}")
                };
                numeric_leaves(x, &p, out);
            }
        }
        toml::Value::Array(a) => {
            for (i, x) in a.iter().enumerate() {
                numeric_leaves(x, &format!("{path}[{i}]"), out);
            }
        }
        _ => {}
    }
}

/// The leaf at `path` (as [`numeric_leaves`] names it).
fn leaf_mut<'a>(v: &'a mut toml::Value, path: &str) -> &'a mut toml::Value {
    let mut v = v;
    for part in path.split('.') {
        let (key, indices) = match part.find('[') {
            Some(i) => (&part[..i], &part[i..]),
            None => (part, ""),
        };
        v = &mut v[key];
        for index in indices.split(['[', ']']).filter(|s| !s.is_empty()) {
            v = &mut v[index.parse::<usize>().expect("index")];
        }
    }
    v
}

/// Extreme values for a leaf of this kind.
fn extremes(leaf: &toml::Value) -> Vec<toml::Value> {
    use toml::Value::{Float, Integer};
    match leaf {
        Integer(_) => vec![
            Integer(0),
            Integer(-1),
            Integer(4_294_967_296),
            Integer(i64::MAX),
            Integer(i64::MIN),
        ],
        _ => vec![
            Float(0.0),
            Float(-1.0),
            Float(1e9),
            Float(1e300),
            Float(-1e300),
            Float(f64::NAN),
            Float(f64::INFINITY),
            Float(1e-300),
        ],
    }
}

/// `risd ARGS` under a 4 GB address-space limit, at most `limit`.
fn risd_bounded(args: &[&OsStr], limit: Duration) -> std::process::Output {
    let mut command = std::process::Command::new("sh");
    command
        .arg("-c")
        .arg("ulimit -v 4000000; exec \"$0\" \"$@\"")
        .arg(common::binary("risd"))
        .args(args)
        .env("NO_COLOR", "1");
    common::output_within(&mut command, limit)
}

/// Every numeric field of a cell file, its scene and its part's datums set to extreme values
/// (zero, negative, 1e9, ±1e300, NaN, infinity, 1e-300; integers to 0, -1, 2^32 and the i64
/// limits), one field at a time, seeded (one value per field in the default tier, every value
/// in the long tier): `risd --check-config` ends within 30 s under a 4 GB address-space limit,
/// without a panic or a signal, and either accepts the files or refuses them naming the file
/// and the field. Of the accepted extreme cases a seeded handful (all in the long tier) is
/// scanned with `risd --once` under the same memory limit: it ends within 120 s, done or
/// failed with its reason, never killed.
#[test]
fn extreme_values_in_every_numeric_field_are_refused_by_name_or_run_bounded() {
    let long = std::env::var("RIS_TIER").is_ok_and(|v| v == "long");
    let tmp = tempfile::tempdir().expect("tmp");
    let dir = tmp.path();
    let files: Vec<(&str, String)> = vec![
        (
            "cell.toml",
            format!(
                "[cell]\nname = \"extreme\"\n[storage]\nkeep_scans = 2\nmax_age_days = 30\n[workers]\nthreads = 0\nqueue = 4\nstage_deadline_s = 30.0\n[[sensor]]\nname = \"s1\"\nbackend = \"mock\"\nscene = \"scene.toml\"\nexposure_us = 10000.0\nsettle_ms = 0.0\nframe_timeout_ms = 2000.0\nrange_mm = [300.0, 3000.0]\nto_common = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]\n[[part]]\nid = \"panel\"\ncad = \"{}\"\ndatums = \"datums.toml\"\ntolerance = 0.5\nmin_coverage = 0.0\n[single_shot]\nstep = [12, 12]\nseed = 7\nrange_mm = [300.0, 3000.0]\nrate_hz = 2.0\n",
                config_dir().join("mock-cell/panel.stl").display()
            ),
        ),
        (
            "scene.toml",
            std::fs::read_to_string(config_dir().join("scenes/tiny.toml")).expect("scene"),
        ),
        (
            "datums.toml",
            std::fs::read_to_string(config_dir().join("mock-cell/panel-datums.toml"))
                .expect("datums"),
        ),
    ];
    let write_all = |changed: Option<(&str, &str)>| {
        for (name, text) in &files {
            let text = match changed {
                Some((n, t)) if n == *name => t,
                _ => text.as_str(),
            };
            std::fs::write(dir.join(name), text).expect("write");
        }
    };
    write_all(None);
    let cell = dir.join("cell.toml");
    let check = |limit| risd_bounded(&["--check-config".as_ref(), cell.as_os_str()], limit);
    let base = check(Duration::from_secs(30));
    assert!(
        base.status.success(),
        "the unchanged files: {}",
        String::from_utf8_lossy(&base.stderr)
    );
    let mut rng = 0x5EED_u64;
    let mut next = move |n: usize| {
        rng = rng
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        ((rng >> 33) % n as u64) as usize
    };
    let (mut cases, mut refused) = (0usize, 0usize);
    let mut accepted: Vec<(String, String, String)> = Vec::new();
    for (name, text) in &files {
        let doc: toml::Value = toml::from_str(text).expect("toml");
        let mut leaves = Vec::new();
        numeric_leaves(&doc, "", &mut leaves);
        assert!(!leaves.is_empty(), "{name}");
        for leaf in &leaves {
            let values = extremes(leaf_mut(&mut doc.clone(), leaf));
            let chosen: Vec<toml::Value> = if long {
                values
            } else {
                vec![values[next(values.len())].clone()]
            };
            for value in chosen {
                let mut changed = doc.clone();
                *leaf_mut(&mut changed, leaf) = value.clone();
                let text = toml::to_string(&changed).expect("toml");
                write_all(Some((name, &text)));
                let out = check(Duration::from_secs(30));
                let err = String::from_utf8_lossy(&out.stderr);
                let shown = match &value {
                    toml::Value::Float(f) => format!("{f:e}"),
                    v => v.to_string(),
                };
                let case = format!("{name} {leaf} = {shown}");
                cases += 1;
                assert!(
                    out.status.code().is_some() && !err.contains("panicked"),
                    "{case}: {:?} {err}",
                    out.status
                );
                if out.status.success() {
                    accepted.push((name.to_string(), text, case));
                    continue;
                }
                refused += 1;
                // The field as the message may name it: its last key (a matrix element is
                // named by its matrix).
                let key = leaf
                    .rsplit('.')
                    .next()
                    .and_then(|k| k.split('[').next())
                    .unwrap_or(leaf);
                assert!(
                    err.contains(name) && err.contains(key),
                    "{case}: the refusal names neither the file nor `{key}`: {err}"
                );
            }
        }
        write_all(None);
    }
    eprintln!(
        "{cases} extreme cases: {refused} refused by name, {} accepted",
        accepted.len()
    );
    // Accepted extremes run: a seeded handful (every one in the long tier).
    let runs: Vec<&(String, String, String)> = if long {
        accepted.iter().collect()
    } else {
        (0..accepted.len().min(4))
            .map(|_| &accepted[next(accepted.len())])
            .collect()
    };
    for (k, (name, text, case)) in runs.into_iter().enumerate() {
        write_all(Some((name, text)));
        let data = dir.join(format!("data{k}"));
        let t = Instant::now();
        let out = risd_bounded(
            &[
                "--config".as_ref(),
                cell.as_os_str(),
                "--once".as_ref(),
                "--data-dir".as_ref(),
                data.as_os_str(),
                "--cache-dir".as_ref(),
                dir.join("cache").as_os_str(),
            ],
            Duration::from_secs(120),
        );
        let err = String::from_utf8_lossy(&out.stderr);
        eprintln!(
            "{case}: risd --once {} in {:.1} s",
            if out.status.success() {
                "done"
            } else {
                "failed"
            },
            t.elapsed().as_secs_f64()
        );
        assert!(
            out.status.code().is_some() && !err.contains("panicked"),
            "{case}: {:?} {err}",
            out.status
        );
        assert!(
            out.status.success() || err.contains("Error"),
            "{case}: failed without a reason: {err}"
        );
        write_all(None);
    }
}
