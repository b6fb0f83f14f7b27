//! The station end to end on 127.0.0.1 (issue 43): risd's service serving the one-sensor wear
//! cell in this process, `ris console`'s service beside it over Zenoh, HTTP spoken by hand
//! (no client library between the test and the server). The console finds the cell, backfills
//! a scan stored before it started, starts a scan for an operator and follows it live
//! (server-sent events), records it, serves its verdict, its 3D view's points (checked against
//! deviation.ply as risd wrote it) and the part's trend and exports (checked against every
//! report.json); a series of scans of the wearing plate fires a run rule before the plate
//! fails, the alarm reaches a Zenoh subscriber, and killing the console mid-series loses no
//! scan.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::{Path, PathBuf};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use zenoh::Wait;

#[path = "../../daemon/tests/common/mod.rs"]
mod common;
use common::{ask, cell_config, client, free_port, states, wait_end, InProcess};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// One HTTP/1.1 exchange: status, headers (lower-case names), body.
fn http(
    addr: SocketAddr,
    method: &str,
    path: &str,
    cookie: Option<&str>,
    form: Option<&str>,
) -> (u16, Vec<(String, String)>, Vec<u8>) {
    let mut s = TcpStream::connect(addr).expect("connect");
    s.set_read_timeout(Some(Duration::from_secs(60)))
        .expect("timeout");
    let mut req = format!("{method} {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n");
    if let Some(c) = cookie {
        req += &format!("Cookie: {c}\r\n");
    }
    if let Some(f) = form {
        req += &format!(
            "Content-Type: application/x-www-form-urlencoded\r\nContent-Length: {}\r\n",
            f.len()
        );
    }
    req += "\r\n";
    if let Some(f) = form {
        req += f;
    }
    s.write_all(req.as_bytes()).expect("send");
    let mut raw = Vec::new();
    s.read_to_end(&mut raw).expect("read");
    let end = raw
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .expect("header end");
    let head = String::from_utf8_lossy(&raw[..end]).into_owned();
    let mut lines = head.lines();
    let status: u16 = lines
        .next()
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|c| c.parse().ok())
        .expect("status");
    let headers: Vec<(String, String)> = lines
        .filter_map(|l| l.split_once(':'))
        .map(|(k, v)| (k.trim().to_lowercase(), v.trim().to_string()))
        .collect();
    let mut body = raw[end + 4..].to_vec();
    if headers
        .iter()
        .any(|(k, v)| k == "transfer-encoding" && v.contains("chunked"))
    {
        body = unchunk(&body);
    }
    (status, headers, body)
}

fn unchunk(mut b: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    loop {
        let Some(eol) = b.windows(2).position(|w| w == b"\r\n") else {
            return out;
        };
        let size =
            usize::from_str_radix(String::from_utf8_lossy(&b[..eol]).trim(), 16).unwrap_or(0);
        if size == 0 {
            return out;
        }
        out.extend_from_slice(&b[eol + 2..eol + 2 + size]);
        b = &b[eol + 4 + size..];
    }
}

fn header<'a>(h: &'a [(String, String)], name: &str) -> Option<&'a str> {
    h.iter().find(|(k, _)| k == name).map(|(_, v)| v.as_str())
}

/// The text between `attr="` and `"` after `marker` in `html`.
fn attribute(html: &str, marker: &str, attr: &str) -> String {
    let at = html
        .find(marker)
        .unwrap_or_else(|| panic!("{marker} not in the page"));
    let rest = &html[at..];
    let key = format!("{attr}=\"");
    let start = rest.find(&key).expect("attribute") + key.len();
    rest[start..start + rest[start..].find('"').expect("end")].to_string()
}

fn form_encode(pairs: &[(&str, &str)]) -> String {
    pairs
        .iter()
        .map(|(k, v)| {
            let enc: String = v
                .bytes()
                .map(|b| {
                    if b.is_ascii_alphanumeric() || b == b'-' || b == b'_' {
                        (b as char).to_string()
                    } else {
                        format!("%{b:02X}")
                    }
                })
                .collect();
            format!("{k}={enc}")
        })
        .collect::<Vec<_>>()
        .join("&")
}

/// A station's users and roles: operator `op` (password `opsecret`), reader `rd` (`rdsecret`).
fn access_file(dir: &Path) -> PathBuf {
    std::fs::write(dir.join("users.txt"), "op:opsecret\nrd:rdsecret\n").expect("users");
    let access = dir.join("station.toml");
    std::fs::write(
        &access,
        "[zenoh.access]\nusers = \"users.txt\"\noperators = [\"op\"]\nreaders = [\"rd\"]\n",
    )
    .expect("access");
    access
}

/// The wear cell served in this process on a free port, its data in `data`.
fn wear_cell(data: &Path) -> (InProcess, String) {
    let endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let config = cell_config(&repo().join("config/wear-cell.toml"), &endpoint, data);
    let mut risd = InProcess::start(config);
    risd.wait_ready(Duration::from_secs(180));
    (risd, endpoint)
}

struct Running {
    runtime: tokio::runtime::Runtime,
    console: Option<ris_console::Console>,
    shutdown: tokio_util::sync::CancellationToken,
    addr: SocketAddr,
}

fn console(endpoint: &str, db: &Path, baseline: usize, access: Option<PathBuf>) -> Running {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("runtime");
    let shutdown = tokio_util::sync::CancellationToken::new();
    let options = ris_console::Options {
        connect: vec![endpoint.to_string()],
        http: "127.0.0.1:0".parse().expect("addr"),
        db: db.to_path_buf(),
        access,
        zenoh_user: None,
        baseline,
    };
    let c = runtime
        .block_on(ris_console::start(options, shutdown.clone()))
        .expect("console starts");
    Running {
        addr: c.addr,
        runtime,
        console: Some(c),
        shutdown,
    }
}

impl Running {
    fn history(&self) -> &ris_console::history::History {
        &self.console.as_ref().expect("running").fabric.history
    }

    /// Wait until the history holds `id`.
    fn recorded(&self, id: &str, limit: Duration) {
        let t = Instant::now();
        while !self.history().has("wear", id).expect("history") {
            assert!(
                t.elapsed() < limit,
                "scan {id} not recorded within {limit:?}"
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    fn stop(mut self) {
        self.shutdown.cancel();
        let c = self.console.take().expect("running");
        self.runtime
            .block_on(async { tokio::time::timeout(Duration::from_secs(20), c.wait()).await })
            .expect("the console stops within 20 s")
            .expect("the console stops cleanly");
    }
}

/// Ask the cell for a scan (as any Zenoh client would) and wait for its end.
fn scan(
    session: &zenoh::Session,
    body: &str,
    rx: &mpsc::Receiver<(String, serde_json::Value)>,
) -> String {
    let r = ask(session, "ris/wear/scan", Some(body));
    let reply: serde_json::Value =
        serde_json::from_str(r[0].as_ref().expect("accepted")).expect("json");
    let id = reply["scan_id"].as_str().expect("id").to_string();
    let end = wait_end(rx, &id);
    assert_eq!(end["state"], "done", "{end}");
    id
}

/// `report.json` of a stored scan.
fn report(data: &Path, id: &str) -> serde_json::Value {
    serde_json::from_slice(
        &std::fs::read(data.join("scans").join(id).join("report.json")).expect("report"),
    )
    .expect("json")
}

/// The deviation PLY risd wrote, read here: (x, y, z, deviation) per vertex.
fn deviation_ply(path: &Path) -> Vec<[f32; 4]> {
    let bytes = std::fs::read(path).expect("deviation.ply");
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .expect("header")
        + 11;
    let head = String::from_utf8_lossy(&bytes[..end]);
    assert!(head.contains("property float deviation"), "{head}");
    let n: usize = head
        .lines()
        .find_map(|l| l.strip_prefix("element vertex "))
        .and_then(|v| v.trim().parse().ok())
        .expect("count");
    (0..n)
        .map(|i| {
            std::array::from_fn(|k| {
                let o = end + 16 * i + 4 * k;
                f32::from_le_bytes(bytes[o..o + 4].try_into().expect("4 bytes"))
            })
        })
        .collect()
}

#[test]
fn the_console_backfills_starts_follows_records_and_serves_scans() {
    let data = tempfile::tempdir().expect("tmp");
    let (risd, endpoint) = wear_cell(data.path());
    let session = client(&endpoint);
    let (_sub, rx) = states(&session, "wear");
    // A scan the cell stored before the console existed.
    let before = scan(
        &session,
        r#"{"tag": "before the console", "serial": "SN-1"}"#,
        &rx,
    );

    let db_dir = tempfile::tempdir().expect("tmp");
    let db = db_dir.path().join("history.sqlite");
    let c = console(&endpoint, &db, 20, None);
    c.recorded(&before, Duration::from_secs(60));

    // The first page lists the cell and its latest scan without any action; without access
    // control the browser is an anonymous operator with a session cookie.
    let t = Instant::now();
    let (status, headers, body) = http(c.addr, "GET", "/", None, None);
    eprintln!("first page in {:.0} ms", t.elapsed().as_secs_f64() * 1000.0);
    let page = String::from_utf8_lossy(&body).into_owned();
    assert_eq!(status, 200, "{page}");
    let set = header(&headers, "set-cookie").expect("a session cookie");
    assert!(
        set.contains("HttpOnly") && set.contains("SameSite=Strict"),
        "{set}"
    );
    let cookie = set.split(';').next().expect("cookie").to_string();
    assert!(
        page.contains("data-cell=\"wear\"") && page.contains(&before),
        "{page}"
    );
    let verdict = report(data.path(), &before)["verdict"]
        .as_str()
        .expect("verdict")
        .to_string();
    let word = match verdict.as_str() {
        "pass" => "PASS",
        "fail" => "FAIL",
        _ => "NOT MEASURED",
    };
    assert!(page.contains(word), "{verdict}: {page}");
    let csrf = attribute(&page, "class=\"start\"", "value");
    assert!(
        page.contains("<option value=\"wear\">wear</option>"),
        "the cell offered: {page}"
    );

    // Live: server-sent events while an operator starts a scan from the page.
    let (events_tx, events) = mpsc::channel::<String>();
    let sse_addr = c.addr;
    let sse_cookie = cookie.clone();
    std::thread::spawn(move || {
        let mut s = TcpStream::connect(sse_addr).expect("connect");
        let _ = write!(s, "GET /events HTTP/1.1\r\nHost: x\r\nCookie: {sse_cookie}\r\nAccept: text/event-stream\r\n\r\n");
        for line in BufReader::new(s).lines() {
            let Ok(line) = line else { return };
            if let Some(d) = line.strip_prefix("data:") {
                if events_tx.send(d.trim().to_string()).is_err() {
                    return;
                }
            }
        }
    });
    std::thread::sleep(Duration::from_millis(300));
    let tag = "<script>alert(1)</script>";
    // A stale or missing CSRF token changes nothing.
    let form = form_encode(&[
        ("csrf", "forged"),
        ("cell", "wear"),
        ("mode", "gray"),
        ("part", "plate"),
    ]);
    let (status, _, _) = http(c.addr, "POST", "/scan", Some(&cookie), Some(&form));
    assert_eq!(status, 403);
    let form = form_encode(&[
        ("csrf", &csrf),
        ("cell", "wear"),
        ("mode", "gray"),
        ("part", "plate"),
        ("serial", "SN-2"),
        ("tag", tag),
    ]);
    let (status, headers, body) = http(c.addr, "POST", "/scan", Some(&cookie), Some(&form));
    assert_eq!(status, 303, "{}", String::from_utf8_lossy(&body));
    let location = header(&headers, "location").expect("redirect").to_string();
    let id = location.rsplit('/').next().expect("id").to_string();
    assert!(location.starts_with("/cells/wear/scans/"), "{location}");
    let t = Instant::now();
    let mut saw = (false, false);
    while t.elapsed() < Duration::from_secs(120) && !saw.1 {
        if let Ok(e) = events.recv_timeout(Duration::from_millis(200)) {
            let v: serde_json::Value = serde_json::from_str(&e).expect("event json");
            if v["event"] == "state"
                && v["scan_id"] == id.as_str()
                && v["state"]["state"] == "acquiring"
            {
                saw.0 = true;
            }
            if v["event"] == "recorded" && v["scan"]["scan_id"] == id.as_str() {
                saw.1 = true;
            }
        }
    }
    assert!(
        saw.0 && saw.1,
        "the page saw acquiring {} and recorded {}",
        saw.0,
        saw.1
    );

    // The result: verdict first, the serial, the operator, the tag as text.
    let (status, _, body) = http(c.addr, "GET", &location, Some(&cookie), None);
    let page = String::from_utf8_lossy(&body).into_owned();
    assert_eq!(status, 200);
    let r = report(data.path(), &id);
    assert_eq!(
        r["verdict"], "pass",
        "the fresh plate passes: {}",
        r["reasons"]
    );
    let banner = page
        .find("id=\"verdict\">PASS<")
        .expect("the verdict first");
    assert!(
        banner < page.find("SN-2").expect("serial"),
        "verdict before details"
    );
    assert!(
        page.contains("&lt;script&gt;alert(1)&lt;/script&gt;"),
        "the tag shown as text"
    );
    assert!(!page.contains(tag), "the tag never runs");
    assert!(page.contains("anonymous"));

    // The 3D view's points are deviation.ply's, evenly taken.
    let (status, _, bin) = http(
        c.addr,
        "GET",
        &format!("{location}/deviation.bin"),
        Some(&cookie),
        None,
    );
    assert_eq!(status, 200);
    let sent = u32::from_le_bytes(bin[0..4].try_into().expect("n")) as usize;
    let total = u32::from_le_bytes(bin[4..8].try_into().expect("n")) as usize;
    let ply = deviation_ply(&data.path().join("scans").join(&id).join("deviation.ply"));
    assert_eq!(total, ply.len());
    assert_eq!(bin.len(), 8 + 16 * sent);
    let step = total.div_ceil(sent);
    for k in [0, sent / 2, sent - 1] {
        let got: [f32; 4] = std::array::from_fn(|j| {
            let o = 8 + 16 * k + 4 * j;
            f32::from_le_bytes(bin[o..o + 4].try_into().expect("f32"))
        });
        assert_eq!(got, ply[k * step], "point {k}");
    }

    // The part's trend and its exports carry report.json's numbers exactly.
    let (status, _, body) = http(c.addr, "GET", "/parts/plate", Some(&cookie), None);
    assert_eq!(status, 200);
    assert!(String::from_utf8_lossy(&body).contains("<svg class=\"chart\""));
    let (status, _, dfq) = http(
        c.addr,
        "GET",
        "/parts/plate/export.dfq",
        Some(&cookie),
        None,
    );
    assert_eq!(status, 200);
    let dfq = String::from_utf8_lossy(&dfq).into_owned();
    let k_mean = dfq
        .lines()
        .find_map(|l| {
            l.strip_suffix(" mean")
                .and_then(|h| h.strip_prefix("K2001/"))
        })
        .expect("the mean's characteristic number")
        .to_string();
    let means: Vec<f64> = dfq
        .lines()
        .filter_map(|l| l.strip_prefix(&format!("K0001/{k_mean} ")))
        .map(|v| v.parse().expect("number"))
        .collect();
    let expected: Vec<f64> = [&before, &id]
        .iter()
        .map(|i| {
            report(data.path(), i)["statistics"]["mean"]
                .as_f64()
                .expect("mean")
        })
        .collect();
    assert_eq!(means, expected, "{dfq}");
    assert!(dfq.contains("K0014/1 SN-2"), "{dfq}");

    // A stream's fusion pictures, live on the first page.
    let started = ask(
        &session,
        "ris/wear/stream",
        Some(r#"{"action": "start", "sensors": ["s1"], "rate": 5}"#),
    );
    assert!(started[0].is_ok(), "{started:?}");
    let t = Instant::now();
    loop {
        let (status, _, png) = http(
            c.addr,
            "GET",
            "/cells/wear/stream/s1.png",
            Some(&cookie),
            None,
        );
        if status == 200 {
            assert!(png.starts_with(b"\x89PNG"), "a PNG");
            break;
        }
        assert!(
            t.elapsed() < Duration::from_secs(60),
            "no fusion picture reached the console"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    let (_, _, body) = http(c.addr, "GET", "/", Some(&cookie), None);
    assert!(String::from_utf8_lossy(&body)
        .contains("class=\"fused\" data-cell=\"wear\" data-sensor=\"s1\""));
    let stopped = ask(&session, "ris/wear/stream", Some(r#"{"action": "stop"}"#));
    assert!(stopped[0].is_ok(), "{stopped:?}");

    // The same history from a terminal: `ris scans list` and `fetch` (every stored item).
    let list = common::output_within(
        std::process::Command::new(common::binary("ris")).args([
            "scans",
            "--connect",
            &endpoint,
            "--cell",
            "wear",
            "list",
        ]),
        Duration::from_secs(60),
    );
    let text = String::from_utf8_lossy(&list.stdout).into_owned();
    assert!(
        list.status.success(),
        "{text}{}",
        String::from_utf8_lossy(&list.stderr)
    );
    let line = text
        .lines()
        .find(|l| l.starts_with(&id))
        .expect("the scan listed");
    assert!(
        line.contains("SN-2") && line.contains("PASS") && line.contains("plate"),
        "{line}"
    );
    assert!(text.contains("2 scans stored by cell wear"), "{text}");
    let fetched = tempfile::tempdir().expect("tmp");
    let fetch = common::output_within(
        std::process::Command::new(common::binary("ris"))
            .args([
                "scans",
                "--connect",
                &endpoint,
                "--cell",
                "wear",
                "fetch",
                &id,
                "--out",
            ])
            .arg(fetched.path()),
        Duration::from_secs(60),
    );
    assert!(
        fetch.status.success(),
        "{}",
        String::from_utf8_lossy(&fetch.stderr)
    );
    for f in [
        "scan.json",
        "report.json",
        "s1.ply",
        "merged.ply",
        "deviation.ply",
        "deviation.png",
        "report.html",
    ] {
        let got = std::fs::read(fetched.path().join(&id).join(f))
            .unwrap_or_else(|_| panic!("{f} fetched"));
        let stored = std::fs::read(data.path().join("scans").join(&id).join(f)).expect("stored");
        assert!(got == stored, "{f} differs from the stored file");
    }

    // Killed and restarted, the console keeps what it recorded and adds nothing twice.
    c.stop();
    let c = console(&endpoint, &db, 20, None);
    std::thread::sleep(Duration::from_secs(2));
    let all = c
        .history()
        .search(&ris_console::history::Filter::default())
        .expect("search");
    assert_eq!(all.len(), 2, "{all:?}");
    c.stop();
    let _ = session.close().wait();
    risd.stop().expect("risd stops");
}

#[test]
fn a_reader_looks_but_cannot_scan_and_strangers_are_turned_away() {
    let data = tempfile::tempdir().expect("tmp");
    let (risd, endpoint) = wear_cell(data.path());
    let dir = tempfile::tempdir().expect("tmp");
    let access = access_file(dir.path());
    let c = console(&endpoint, &dir.path().join("h.sqlite"), 20, Some(access));
    let (status, headers, _) = http(c.addr, "GET", "/", None, None);
    assert_eq!(status, 303, "sign in first");
    assert_eq!(header(&headers, "location"), Some("/login"));
    let (status, _, _) = http(
        c.addr,
        "POST",
        "/login",
        None,
        Some("user=rd&password=wrong"),
    );
    assert_eq!(status, 401);
    let (status, headers, _) = http(
        c.addr,
        "POST",
        "/login",
        None,
        Some("user=rd&password=rdsecret"),
    );
    assert_eq!(status, 303);
    let cookie = header(&headers, "set-cookie")
        .expect("cookie")
        .split(';')
        .next()
        .expect("kv")
        .to_string();
    let t = Instant::now();
    let page = loop {
        let (_, _, body) = http(c.addr, "GET", "/", Some(&cookie), None);
        let page = String::from_utf8_lossy(&body).into_owned();
        if page.contains("data-cell=\"wear\"") || t.elapsed() > Duration::from_secs(30) {
            break page;
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    assert!(page.contains("data-cell=\"wear\""), "{page}");
    assert!(
        !page.contains("class=\"start\""),
        "a reader is offered no scan"
    );
    let csrf = attribute(&page, "action=\"/logout\"", "value");
    let form = form_encode(&[("csrf", &csrf), ("cell", "wear"), ("mode", "gray")]);
    let (status, _, body) = http(c.addr, "POST", "/scan", Some(&cookie), Some(&form));
    assert_eq!(status, 403, "{}", String::from_utf8_lossy(&body));
    assert!(String::from_utf8_lossy(&body).contains("reader"));
    assert!(
        !data.path().join("scans").exists()
            || std::fs::read_dir(data.path().join("scans"))
                .expect("scans")
                .count()
                == 0,
        "no scan was started"
    );
    c.stop();
    risd.stop().expect("risd stops");
}

#[test]
fn a_wearing_part_fires_a_run_rule_before_it_fails_and_no_value_is_lost() {
    let data = tempfile::tempdir().expect("tmp");
    let (risd, endpoint) = wear_cell(data.path());
    let session = client(&endpoint);
    let (_sub, rx) = states(&session, "wear");
    let (alarm_tx, alarms) = mpsc::channel::<serde_json::Value>();
    let _alarm_sub = session
        .declare_subscriber(ris_daemon::protocol::alarms_key("wear"))
        .callback(move |s| {
            if let Ok(v) = serde_json::from_slice(&s.payload().to_bytes()) {
                let _ = alarm_tx.send(v);
            }
        })
        .wait()
        .expect("alarm subscriber");
    let db_dir = tempfile::tempdir().expect("tmp");
    let db = db_dir.path().join("history.sqlite");
    let mut c = Some(console(&endpoint, &db, 8, None));
    let mut ids = Vec::new();
    let mut first_fail = None;
    for n in 1..=24 {
        // Mid-series the console is stopped; the cell goes on scanning without it.
        if n == 5 {
            c.take().expect("running").stop();
        }
        if n == 7 {
            c = Some(console(&endpoint, &db, 8, None));
        }
        let id = scan(&session, &format!(r#"{{"serial": "SN-{n}"}}"#), &rx);
        if let Some(c) = &c {
            c.recorded(&id, Duration::from_secs(60));
        }
        let verdict = report(data.path(), &id)["verdict"]
            .as_str()
            .unwrap_or_default()
            .to_string();
        ids.push(id);
        if verdict == "fail" {
            first_fail = Some(n);
            break;
        }
        assert_eq!(verdict, "pass", "scan {n}");
    }
    let first_fail = first_fail.expect("the wearing plate fails within 24 scans");
    let c = c.expect("running");
    let recorded = c
        .history()
        .search(&ris_console::history::Filter {
            limit: Some(1000),
            ..Default::default()
        })
        .expect("search");
    assert_eq!(
        recorded.len(),
        ids.len(),
        "every scan recorded, the ones while the console was down backfilled"
    );
    let raised = c.history().alarms(Some("plate"), 1000).expect("alarms");
    let scan_no = |id: &str| ids.iter().position(|i| i == id).map(|p| p + 1);
    // The dent deepens from the ninth scan on: what fired within the eight stable scans is a
    // false alarm (a few are expected of about twenty characteristics over eight scans).
    let false_alarms = raised
        .iter()
        .filter(|a| scan_no(&a.scan_id).is_some_and(|n| n <= 8))
        .count();
    // The dent's depth shows in the plate's robust minimum (the 0.01 % quantile: the dent's
    // core holds thousands of points, a stray point is left out): it must signal once the dent
    // deepens, before the part fails.
    let first_alarm = raised
        .iter()
        .filter(|a| a.characteristic == "robust min")
        .filter_map(|a| scan_no(&a.scan_id))
        .filter(|n| *n > 8)
        .min()
        .expect("the dent's depth (robust min) raised an alarm once it deepened");
    eprintln!(
        "first alarm on robust min after the stable scans at scan {first_alarm}, first failure at scan {first_fail}; {} alarms, {false_alarms} within the stable scans",
        raised.len()
    );
    assert!(
        first_alarm < first_fail,
        "the rule fires (scan {first_alarm}) before the part fails (scan {first_fail})"
    );
    assert!(
        false_alarms <= 3,
        "{false_alarms} false alarms within the stable scans: {raised:#?}"
    );
    let heard = alarms
        .recv_timeout(Duration::from_secs(10))
        .expect("an alarm on Zenoh");
    assert_eq!(heard["part"], "plate");
    assert!(heard["message"].as_str().is_some_and(|m| !m.is_empty()));

    // The AQDEF export, read back by an independent parser (Python), equals every report.json.
    let (status, _, dfq) = http(c.addr, "GET", "/parts/plate/export.dfq", None, None);
    assert_eq!(status, 200);
    let dfq_path = db_dir.path().join("plate.dfq");
    std::fs::write(&dfq_path, &dfq).expect("write dfq");
    let mut cmd = std::process::Command::new("python3");
    cmd.arg(repo().join("tests/aqdef_check.py")).arg(&dfq_path);
    for id in &ids {
        cmd.arg(data.path().join("scans").join(id).join("report.json"));
    }
    let out = common::output_within(&mut cmd, Duration::from_secs(60));
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(out.status.success(), "{text}");
    assert!(text.contains(&format!("{} scans", ids.len())), "{text}");
    c.stop();
    let _ = session.close().wait();
    risd.stop().expect("risd stops");
}

#[test]
fn a_browser_signs_in_scans_follows_picks_and_prints() {
    let have = std::process::Command::new("python3")
        .args(["-c", "import selenium"])
        .status()
        .is_ok_and(|s| s.success())
        && Path::new("/usr/bin/chromedriver").is_file();
    assert!(
        have,
        "Chromium's WebDriver or Python selenium is missing: run .ci/run (it installs chromium-driver and selenium)"
    );
    let data = tempfile::tempdir().expect("tmp");
    let (risd, endpoint) = wear_cell(data.path());
    let dir = tempfile::tempdir().expect("tmp");
    let access = access_file(dir.path());
    let c = console(&endpoint, &dir.path().join("h.sqlite"), 20, Some(access));
    let out = common::output_within(
        std::process::Command::new("python3")
            .arg(repo().join("tests/console_browser.py"))
            .arg(format!("http://{}", c.addr))
            .args(["wear", "op:opsecret", "rd:rdsecret"]),
        Duration::from_secs(400),
    );
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let seen: serde_json::Value =
        serde_json::from_str(stdout.lines().last().expect("json")).expect("json");
    eprintln!("the browser saw {seen}");
    assert_eq!(seen["verdict"], "PASS");
    assert!(
        !seen["progress"].as_array().expect("progress").is_empty(),
        "progress shown live"
    );
    assert_eq!(seen["tag_text"], true, "the tag shows as text");
    assert_eq!(seen["alert"], false, "no script ran");
    assert_eq!(seen["print_nav_hidden"], true);
    assert_eq!(seen["print_verdict_shown"], true);
    assert!(seen["pdf_bytes"].as_u64().unwrap_or(0) > 1000);
    assert_eq!(seen["reader_start_forms"], 0);
    assert_eq!(seen["reader_scan_status"], 403);
    // Every picked point is a point of deviation.ply, with its deviation.
    let id = seen["scan_id"].as_str().expect("scan id");
    let ply = deviation_ply(&data.path().join("scans").join(id).join("deviation.ply"));
    let picks = seen["picks"].as_array().expect("picks");
    assert!(!picks.is_empty(), "no point could be picked");
    for p in picks {
        let f = |k: &str| p[k].as_f64().expect("number");
        let hit = ply
            .iter()
            .find(|v| {
                f64::from(v[0]) == f("x") && f64::from(v[1]) == f("y") && f64::from(v[2]) == f("z")
            })
            .unwrap_or_else(|| panic!("picked {p} is no point of deviation.ply"));
        assert_eq!(f64::from(hit[3]), f("deviation"), "{p}");
        let text = p["text"].as_str().expect("text");
        assert!(
            text.contains(&format!("{:+.3}", hit[3])),
            "{text} shows {:+.3}",
            hit[3]
        );
    }
    c.stop();
    risd.stop().expect("risd stops");
}

#[test]
fn three_cells_behind_a_router_appear_in_one_console() {
    // The station starts first, before the line's router and its cells answer.
    let router_endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let data = tempfile::tempdir().expect("tmp");
    let db = data.path().join("history.sqlite");
    let c = console(&router_endpoint, &db, 20, None);
    // The line's router: the Zenoh runtime in router mode.
    let router = zenoh::open(
        ris_daemon::service::zenoh_config("router", std::slice::from_ref(&router_endpoint), &[])
            .expect("router config"),
    )
    .wait()
    .expect("router");
    let mut cells = Vec::new();
    for name in ["line-a", "line-b", "line-c"] {
        let endpoint = format!("tcp/127.0.0.1:{}", free_port());
        let mut config = cell_config(
            &repo().join("config/wear-cell.toml"),
            &endpoint,
            &data.path().join(name),
        );
        config.name = name.to_string();
        config.zenoh.connect = vec![router_endpoint.clone()];
        let mut risd = InProcess::start(config);
        risd.wait_ready(Duration::from_secs(180));
        cells.push(risd);
    }
    let t = Instant::now();
    let page = loop {
        let (_, _, body) = http(c.addr, "GET", "/", None, None);
        let page = String::from_utf8_lossy(&body).into_owned();
        let all = ["line-a", "line-b", "line-c"]
            .iter()
            .all(|n| page.contains(&format!("<option value=\"{n}\">")));
        if all || t.elapsed() > Duration::from_secs(30) {
            break page;
        }
        std::thread::sleep(Duration::from_millis(200));
    };
    for n in ["line-a", "line-b", "line-c"] {
        assert!(
            page.contains(&format!("data-cell=\"{n}\"")),
            "{n} missing: {page}"
        );
    }
    // A scan on one of them, started through the console and the router, lands in its history.
    let (_, headers, _) = http(c.addr, "GET", "/", None, None);
    let cookie = header(&headers, "set-cookie")
        .expect("cookie")
        .split(';')
        .next()
        .expect("kv")
        .to_string();
    let (_, _, body) = http(c.addr, "GET", "/", Some(&cookie), None);
    let csrf = attribute(&String::from_utf8_lossy(&body), "class=\"start\"", "value");
    let form = form_encode(&[("csrf", &csrf), ("cell", "line-b"), ("serial", "B-1")]);
    let (status, headers, body) = http(c.addr, "POST", "/scan", Some(&cookie), Some(&form));
    assert_eq!(status, 303, "{}", String::from_utf8_lossy(&body));
    let id = header(&headers, "location")
        .expect("location")
        .rsplit('/')
        .next()
        .expect("id")
        .to_string();
    let t = Instant::now();
    while !c.history().has("line-b", &id).expect("history") {
        assert!(
            t.elapsed() < Duration::from_secs(120),
            "scan {id} of line-b not recorded"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    let (_, _, body) = http(c.addr, "GET", "/scans?cell=line-b", Some(&cookie), None);
    let page = String::from_utf8_lossy(&body).into_owned();
    assert!(page.contains(&id) && page.contains("B-1"), "{page}");
    assert!(data
        .path()
        .join("line-b/scans")
        .join(&id)
        .join("scan.json")
        .is_file());
    c.stop();
    for risd in cells {
        risd.stop().expect("risd stops");
    }
    let _ = router.close().wait();
}
