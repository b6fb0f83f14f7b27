//! The station's figures (BENCHMARKS.md): a console over a Zenoh router, its history filled
//! with 1 000 scans of one part, a stand-in cell answering a 1.2 M-point deviation cloud.
//! Medians of repeated HTTP exchanges on loopback: the first page, a trend of 1 000 scans
//! (one characteristic, and all of them), the 3D view's points of the 1.2 M-point cloud, and
//! a scan state published on Zenoh until it reaches a browser's event stream.
//!
//! `cargo run --profile ci --example station_bench -p ris-console`

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::time::{Duration, Instant};

use ris_console::characteristic::Characteristic;
use ris_console::history::{time_of, History, ScanRecord};
use zenoh::Wait;

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("a free port")
}

/// One GET: the body's length and the milliseconds until the whole response arrived.
fn get(addr: SocketAddr, path: &str) -> (usize, f64) {
    let t = Instant::now();
    let mut s = TcpStream::connect(addr).expect("connect");
    write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n"
    )
    .expect("send");
    let mut raw = Vec::new();
    s.read_to_end(&mut raw).expect("read");
    assert!(
        raw.starts_with(b"HTTP/1.1 200"),
        "{path}: {}",
        String::from_utf8_lossy(&raw[..raw.len().min(200)])
    );
    (raw.len(), t.elapsed().as_secs_f64() * 1000.0)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let router_endpoint = format!("tcp/127.0.0.1:{}", free_port());
    let router = zenoh::open(
        ris_daemon::service::zenoh_config("router", std::slice::from_ref(&router_endpoint), &[])
            .expect("config"),
    )
    .wait()
    .expect("router");

    // 1 000 scans of part `bench`, each with the characteristics a report gives.
    let dir = tempfile::tempdir().expect("tmp");
    let db = dir.path().join("history.sqlite");
    {
        let h = History::open(&db).expect("history");
        for i in 0..1000u32 {
            let id = format!(
                "20261127T{:02}{:02}{:02}.000Z-{i}",
                i / 3600 % 24,
                i / 60 % 60,
                i % 60
            );
            let scan = ScanRecord {
                cell: "bench".into(),
                scan_id: id.clone(),
                part: Some("bench".into()),
                serial: Some(format!("SN-{i}")),
                mode: "gray".into(),
                verdict: Some("pass".into()),
                time: time_of(&id),
                ..ScanRecord::default()
            };
            let wobble = ((i as f64) * 0.37).sin();
            let values: Vec<Characteristic> =
                ["mean", "p05", "p95", "robust min", "robust max", "rms"]
                    .iter()
                    .enumerate()
                    .map(|(k, n)| Characteristic {
                        name: (*n).into(),
                        value: 0.01 * wobble + 0.05 * k as f64,
                        lower: Some(-0.5),
                        upper: Some(0.5),
                        unit: "mm",
                    })
                    .collect();
            h.record(&scan, &values).expect("record");
        }
    }

    // A stand-in cell answering a 1.2 M-point deviation cloud.
    let n = 1_200_000;
    let points: Vec<[f64; 3]> = (0..n)
        .map(|i| {
            [
                (i % 1500) as f64 * 0.7,
                (i / 1500) as f64 * 0.7,
                ((i % 977) as f64 * 0.01).sin(),
            ]
        })
        .collect();
    let devs: Vec<f64> = (0..n)
        .map(|i| ((i % 1013) as f64 * 0.003).sin() * 0.4)
        .collect();
    let ply_path = dir.path().join("deviation.ply");
    ris_core::inspect::write_deviation_ply(&ply_path, &points, &devs).expect("ply");
    let ply = std::fs::read(&ply_path).expect("ply");
    let cell = zenoh::open(
        ris_daemon::service::zenoh_config("peer", &[], std::slice::from_ref(&router_endpoint))
            .expect("config"),
    )
    .wait()
    .expect("cell session");
    let _q = cell
        .declare_queryable("ris/bench/scans/x/deviation")
        .callback(move |q| {
            let _ = q.reply(q.key_expr().clone(), ply.clone()).wait();
        })
        .wait()
        .expect("queryable");

    let runtime = tokio::runtime::Runtime::new().expect("runtime");
    let shutdown = tokio_util::sync::CancellationToken::new();
    let console = runtime
        .block_on(ris_console::start(
            ris_console::Options {
                connect: vec![router_endpoint.clone()],
                http: "127.0.0.1:0".parse().expect("addr"),
                db,
                access: None,
                zenoh_user: None,
                baseline: 20,
            },
            shutdown.clone(),
        ))
        .expect("console");
    let addr = console.addr;
    std::thread::sleep(Duration::from_millis(500));

    let mut rows = Vec::new();
    for (what, path, runs) in [
        ("first page (/)", "/", 30),
        (
            "trend of 1 000 scans, one characteristic",
            "/parts/bench?c=mean",
            30,
        ),
        (
            "trends of 1 000 scans, all 6 characteristics",
            "/parts/bench",
            10,
        ),
        (
            "3D view's points of a 1.2 M-point cloud (400 k sent)",
            "/cells/bench/scans/x/deviation.bin",
            7,
        ),
    ] {
        let mut t = Vec::new();
        let mut bytes = 0;
        for _ in 0..runs {
            let (b, ms) = get(addr, path);
            bytes = b;
            t.push(ms);
        }
        rows.push((what.to_string(), median(t), bytes));
    }

    // A state published on Zenoh until it reaches an event stream.
    let mut s = TcpStream::connect(addr).expect("connect");
    write!(
        s,
        "GET /events HTTP/1.1\r\nHost: x\r\nAccept: text/event-stream\r\n\r\n"
    )
    .expect("send");
    let (tx, rx) = std::sync::mpsc::channel::<Instant>();
    std::thread::spawn(move || {
        for line in BufReader::new(s).lines() {
            let Ok(line) = line else { return };
            if line.starts_with("data:") && line.contains("\"event\":\"state\"") {
                let _ = tx.send(Instant::now());
            }
        }
    });
    std::thread::sleep(Duration::from_millis(300));
    let mut t = Vec::new();
    for i in 0..50 {
        let sent = Instant::now();
        cell.put(
            format!("ris/bench/scans/s{i}/state"),
            r#"{"state":"merging"}"#,
        )
        .wait()
        .expect("put");
        let got = rx
            .recv_timeout(Duration::from_secs(5))
            .expect("the event arrives");
        t.push((got - sent).as_secs_f64() * 1000.0);
        std::thread::sleep(Duration::from_millis(20));
    }
    rows.push((
        "state published → browser's event stream".into(),
        median(t),
        0,
    ));

    println!("| what | median, ms | bytes |\n|---|---|---|");
    for (what, ms, bytes) in rows {
        println!("| {what} | {ms:.1} | {bytes} |");
    }
    shutdown.cancel();
    let _ = runtime.block_on(console.wait());
    let _ = cell.close().wait();
    let _ = router.close().wait();
}
