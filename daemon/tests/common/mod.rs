//! Helpers shared by the daemon tests: an Xvfb display, a free loopback port, a running risd.
#![allow(dead_code)] // each test binary uses part of it

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use zenoh::Wait;

/// An Xvfb server on a free display, killed on drop.
pub struct Xvfb {
    child: Child,
    /// The display name (`:N`).
    pub display: String,
}

impl Xvfb {
    /// Start a server of one `width` × `height` × 24 screen.
    pub fn start(width: u32, height: u32) -> Xvfb {
        let n = (90..200)
            .find(|n| {
                !std::path::Path::new(&format!("/tmp/.X11-unix/X{n}")).exists()
                    && !std::path::Path::new(&format!("/tmp/.X{n}-lock")).exists()
            })
            .expect("a free X display number");
        let display = format!(":{n}");
        let child = Command::new("Xvfb")
            .args([
                &display,
                "-screen",
                "0",
                &format!("{width}x{height}x24"),
                "-nolisten",
                "tcp",
            ])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("Xvfb (apt-get install xvfb; .ci/run installs it)");
        let socket = format!("/tmp/.X11-unix/X{n}");
        let t = Instant::now();
        while !std::path::Path::new(&socket).exists() {
            assert!(
                t.elapsed() < Duration::from_secs(10),
                "Xvfb {display} did not start"
            );
            std::thread::sleep(Duration::from_millis(50));
        }
        Xvfb { child, display }
    }
}

impl Drop for Xvfb {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A free TCP port on 127.0.0.1.
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("a free port on 127.0.0.1")
}

/// A risd process whose stderr is collected on a thread; killed on drop.
pub struct Risd {
    child: Child,
    log: Option<std::thread::JoinHandle<Vec<String>>>,
    ready: std::sync::mpsc::Receiver<()>,
}

impl Risd {
    /// Start `risd ARGS` (logging at info, no colour).
    pub fn start(args: &[&std::ffi::OsStr]) -> Risd {
        Risd::start_env(args, &[])
    }

    /// Start `risd ARGS` with extra environment variables (e.g. `DISPLAY`).
    pub fn start_env(args: &[&std::ffi::OsStr], env: &[(&str, &str)]) -> Risd {
        use std::io::BufRead;
        let mut child = Command::new(env!("CARGO_BIN_EXE_risd"))
            .args(args)
            .envs(env.iter().copied())
            .env("RIS_LOG", "info")
            .env("NO_COLOR", "1")
            .stderr(Stdio::piped())
            .spawn()
            .expect("risd");
        let stderr = child.stderr.take().expect("stderr");
        let (tx, ready) = std::sync::mpsc::channel();
        let log = std::thread::spawn(move || {
            let mut lines = Vec::new();
            for line in std::io::BufReader::new(stderr)
                .lines()
                .map_while(Result::ok)
            {
                if line.contains("risd ready") {
                    let _ = tx.send(());
                }
                lines.push(line);
            }
            lines
        });
        Risd {
            child,
            log: Some(log),
            ready,
        }
    }

    /// Wait for "risd ready" in the log (panics with the log if it does not come).
    pub fn wait_ready(&mut self, limit: Duration) {
        if self.ready.recv_timeout(limit).is_err() {
            let _ = self.child.kill();
            let log = self.log.take().and_then(|h| h.join().ok());
            panic!("risd never became ready: {log:#?}");
        }
    }

    /// Wait for the process to exit by itself: its status and log.
    pub fn exit_within(mut self, limit: Duration) -> (std::process::ExitStatus, Vec<String>) {
        let t = Instant::now();
        loop {
            if let Some(s) = self.child.try_wait().expect("wait") {
                let log = self
                    .log
                    .take()
                    .and_then(|h| h.join().ok())
                    .unwrap_or_default();
                return (s, log);
            }
            if t.elapsed() > limit {
                let _ = self.child.kill();
                let log = self
                    .log
                    .take()
                    .and_then(|h| h.join().ok())
                    .unwrap_or_default();
                panic!("risd did not exit within {limit:?}: {log:#?}");
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// SIGTERM, then wait up to 20 s for the exit.
    pub fn terminate(self) -> (std::process::ExitStatus, Vec<String>) {
        let ok = Command::new("kill")
            .args(["-TERM", &self.child.id().to_string()])
            .status()
            .is_ok_and(|s| s.success());
        assert!(ok, "kill -TERM");
        self.exit_within(Duration::from_secs(20))
    }
}

impl Drop for Risd {
    fn drop(&mut self) {
        let _ = self.child.kill();
    }
}

/// A Zenoh client session connected to `endpoint` (retried for 30 s while risd starts).
pub fn client(endpoint: &str) -> zenoh::Session {
    let config = ris_daemon::service::zenoh_config("client", &[], &[endpoint.to_string()])
        .expect("client config");
    let t = Instant::now();
    loop {
        match zenoh::open(config.clone()).wait() {
            Ok(s) => return s,
            Err(e) if t.elapsed() > Duration::from_secs(30) => panic!("no risd at {endpoint}: {e}"),
            Err(_) => std::thread::sleep(Duration::from_millis(50)),
        }
    }
}

/// Replies to a query: Ok(payload) or Err(error payload).
pub fn ask(
    session: &zenoh::Session,
    key: &str,
    payload: Option<&str>,
) -> Vec<Result<String, String>> {
    let mut get = session.get(key).timeout(Duration::from_secs(5));
    if let Some(p) = payload {
        get = get.payload(p.to_string());
    }
    let replies = get.wait().expect("get");
    let mut out = Vec::new();
    while let Ok(r) = replies.recv() {
        out.push(match r.result() {
            Ok(s) => Ok(String::from_utf8_lossy(&s.payload().to_bytes()).into_owned()),
            Err(e) => Err(String::from_utf8_lossy(&e.payload().to_bytes()).into_owned()),
        });
    }
    out
}

/// Wait for `done` or `failed` of `scan_id` among the state publications.
pub fn wait_end(
    states: &std::sync::mpsc::Receiver<(String, serde_json::Value)>,
    scan_id: &str,
) -> serde_json::Value {
    let t = Instant::now();
    while t.elapsed() < Duration::from_secs(120) {
        if let Ok((id, v)) = states.recv_timeout(Duration::from_millis(200)) {
            if id == scan_id && (v["state"] == "done" || v["state"] == "failed") {
                return v;
            }
        }
    }
    panic!("scan {scan_id} did not end");
}

/// Subscribe to the state publications of `cell`: (scan id, state JSON) on the receiver.
pub fn states(
    session: &zenoh::Session,
    cell: &str,
) -> (
    zenoh::pubsub::Subscriber<()>,
    std::sync::mpsc::Receiver<(String, serde_json::Value)>,
) {
    let (tx, rx) = std::sync::mpsc::channel();
    let sub = session
        .declare_subscriber(format!("ris/{cell}/scans/*/state"))
        .callback(move |s| {
            let id = s
                .key_expr()
                .as_str()
                .split('/')
                .nth(3)
                .unwrap_or_default()
                .to_string();
            if let Ok(v) = serde_json::from_slice(&s.payload().to_bytes()) {
                let _ = tx.send((id, v));
            }
        })
        .wait()
        .expect("subscriber");
    (sub, rx)
}
