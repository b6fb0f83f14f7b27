//! Helpers shared by the daemon tests: an Xvfb display, a free loopback port, a running risd.
#![allow(dead_code)] // each test binary uses part of it

use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use zenoh::Wait;

mod process;
#[allow(unused_imports)] // each test binary uses part of it
pub use process::{free_port, output_within, Xvfb};

/// The `risd` or `ris` executable: the test's own package's (cargo names it), else the one
/// beside it in the target directory (`cargo test --workspace` builds every package's
/// binaries before it runs any test).
pub fn binary(name: &str) -> std::path::PathBuf {
    let own = match name {
        "risd" => option_env!("CARGO_BIN_EXE_risd"),
        "ris" => option_env!("CARGO_BIN_EXE_ris"),
        _ => None,
    };
    if let Some(path) = own {
        return path.into();
    }
    let dir = std::env::current_exe()
        .ok()
        .and_then(|t| t.parent()?.parent().map(|d| d.to_path_buf()))
        .expect("the target directory");
    let path = dir.join(name);
    assert!(
        path.is_file(),
        "{} is not built: run the tests with `cargo test --workspace` (or build it first)",
        path.display()
    );
    path
}

/// The prepared pairs' cache shared by the tests' risd processes.
pub fn shared_cache() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("prepared-pairs")
}

/// Scan the built-in mock cell once with `risd --once --keep-captures` into `data_dir` as scan
/// `id` (with `args` added: a mode), keeping every pair's capture set for a `replay` pair to
/// serve; the recording is `<data_dir>/scans/<id>`. Panics with risd's errors if it fails.
pub fn record(data_dir: &std::path::Path, id: &str, args: &[&str]) -> std::path::PathBuf {
    let o = Command::new(binary("risd"))
        .args(["--once", "--keep-captures", "--scan-id", id])
        .args(args)
        .arg("--data-dir")
        .arg(data_dir)
        .arg("--cache-dir")
        .arg(shared_cache())
        .output()
        .expect("risd");
    assert!(
        o.status.success(),
        "recording: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    data_dir.join("scans").join(id)
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

    /// Start `risd ARGS` with extra environment variables (e.g. `DISPLAY`). Unless ARGS name
    /// one, the prepared pairs' cache is the one every test's risd shares, so only the first
    /// start of a cell prepares its pairs from scratch.
    pub fn start_env(args: &[&std::ffi::OsStr], env: &[(&str, &str)]) -> Risd {
        use std::io::BufRead;
        let mut command = Command::new(binary("risd"));
        command.args(args);
        if !args.iter().any(|a| *a == "--cache-dir") {
            command.arg("--cache-dir").arg(shared_cache());
        }
        let mut child = command
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

    /// The process id.
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Wait for "risd ready" in the log (panics with the log if it does not come).
    pub fn wait_ready(&mut self, limit: Duration) {
        if self.ready.recv_timeout(limit).is_err() {
            let _ = self.child.kill();
            let log = self.take_log();
            panic!("risd never became ready: {log:#?}");
        }
    }

    /// Wait for the process to exit by itself: its status and log.
    pub fn exit_within(mut self, limit: Duration) -> (std::process::ExitStatus, Vec<String>) {
        let t = Instant::now();
        loop {
            if let Some(s) = self.child.try_wait().expect("wait") {
                let log = self.take_log();
                return (s, log);
            }
            if t.elapsed() > limit {
                let _ = self.child.kill();
                let log = self.take_log();
                panic!("risd did not exit within {limit:?}: {log:#?}");
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// Kill the process and return the last `n` lines of its log: what a failed check shows of
    /// what risd was doing.
    pub fn kill_for_log(mut self, n: usize) -> String {
        let _ = self.child.kill();
        let _ = self.child.wait();
        let log = self.take_log();
        log[log.len().saturating_sub(n)..].join("\n")
    }

    /// The log collected so far, once the process has ended (its stderr closed).
    fn take_log(&mut self) -> Vec<String> {
        self.log
            .take()
            .and_then(|h| h.join().ok())
            .unwrap_or_default()
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

/// A Zenoh client session connected to `endpoint` (retried for 30 s while risd starts; an
/// open that never returns fails the test after 60 s).
pub fn client(endpoint: &str) -> zenoh::Session {
    let config = ris_daemon::service::zenoh_config("client", &[], &[endpoint.to_string()])
        .expect("client config");
    let (tx, rx) = std::sync::mpsc::channel();
    let target = endpoint.to_string();
    std::thread::spawn(move || {
        let t = Instant::now();
        let session = loop {
            match zenoh::open(config.clone()).wait() {
                Ok(s) => break Ok(s),
                Err(e) if t.elapsed() > Duration::from_secs(30) => {
                    break Err(format!("no risd at {target}: {e}"))
                }
                Err(_) => std::thread::sleep(Duration::from_millis(50)),
            }
        };
        let _ = tx.send(session);
    });
    match rx.recv_timeout(Duration::from_secs(60)) {
        Ok(Ok(s)) => s,
        Ok(Err(e)) => panic!("{e}"),
        Err(_) => panic!("opening a Zenoh session to {endpoint} did not return in 60 s"),
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
        .declare_subscriber(ris_daemon::protocol::scan_states_key(cell))
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

/// Ends a test that stalls: past its limit it prints the stage it was in (uncaptured, so the CI
/// log shows it), kills the processes it watches and exits the test process with failure.
pub struct Watchdog {
    state: std::sync::Arc<(std::sync::Mutex<Watched>, std::sync::Condvar)>,
    started: Instant,
}

struct Watched {
    stage: String,
    pids: Vec<u32>,
    done: bool,
}

impl Watchdog {
    /// Start watching `test` for at most `limit`.
    pub fn arm(test: &str, limit: Duration) -> Watchdog {
        let state = std::sync::Arc::new((
            std::sync::Mutex::new(Watched {
                stage: "start".into(),
                pids: Vec::new(),
                done: false,
            }),
            std::sync::Condvar::new(),
        ));
        let shared = state.clone();
        let test = test.to_string();
        std::thread::spawn(move || {
            let (lock, cv) = &*shared;
            let Ok(guard) = lock.lock() else { return };
            let Ok((w, timeout)) = cv.wait_timeout_while(guard, limit, |w| !w.done) else {
                return;
            };
            if !timeout.timed_out() {
                return;
            }
            uncaptured(&format!(
                "{test}: stalled in stage \"{}\" for longer than {limit:?}; killing {:?} and ending the test process",
                w.stage, w.pids
            ));
            for pid in &w.pids {
                let _ = Command::new("kill")
                    .args(["-KILL", &pid.to_string()])
                    .status();
            }
            std::process::exit(101);
        });
        Watchdog {
            state,
            started: Instant::now(),
        }
    }

    /// Name the stage the test enters (also printed, with the time since the start).
    pub fn stage(&self, stage: &str) {
        uncaptured(&format!(
            "[{:6.1} s] {stage}",
            self.started.elapsed().as_secs_f64()
        ));
        if let Ok(mut w) = self.state.0.lock() {
            w.stage = stage.to_string();
        }
    }

    /// Kill process `pid` too if the test stalls.
    pub fn watch(&self, pid: u32) {
        if let Ok(mut w) = self.state.0.lock() {
            w.pids.push(pid);
        }
    }
}

impl Drop for Watchdog {
    fn drop(&mut self) {
        if let Ok(mut w) = self.state.0.lock() {
            w.done = true;
        }
        self.state.1.notify_all();
    }
}

/// A line on the test process's stderr that libtest does not capture.
fn uncaptured(line: &str) {
    use std::io::Write;
    let _ = writeln!(std::io::stderr(), "{line}");
}

/// `path`'s cell configured as a test runs it: listening on `endpoint`, scans under `data`, the
/// shared prepared-pairs cache.
pub fn cell_config(
    path: &std::path::Path,
    endpoint: &str,
    data: &std::path::Path,
) -> ris_daemon::config::CellConfig {
    let mut config = ris_daemon::config::CellConfig::load(path).expect("cell configuration");
    config.zenoh.listen = vec![endpoint.to_string()];
    config.storage.data_dir = data.to_path_buf();
    config.storage.cache_dir = Some(shared_cache());
    config.check_files().expect("the cell's files");
    config
}

/// risd's service run in this process (`service::serve` on a thread of its own, as `risd`
/// runs it, without the signal handler), for tests of what it answers and publishes; a test of
/// signals, systemd notification, the data-directory lock or a second daemon starts the
/// process instead ([`Risd`]). Stopped (shutdown cancelled, thread joined) on drop.
pub struct InProcess {
    shutdown: tokio_util::sync::CancellationToken,
    thread: Option<std::thread::JoinHandle<anyhow::Result<()>>>,
    cell: String,
    endpoint: String,
}

impl InProcess {
    /// Start serving `config` (whose first listen endpoint clients use).
    pub fn start(config: ris_daemon::config::CellConfig) -> InProcess {
        let shutdown = tokio_util::sync::CancellationToken::new();
        let stop = shutdown.clone();
        let cell = config.name.clone();
        let endpoint = config
            .zenoh
            .listen
            .first()
            .cloned()
            .expect("a listen endpoint");
        let thread = std::thread::Builder::new()
            .name("risd-in-process".into())
            .spawn(move || ris_daemon::service::serve(config, stop, false))
            .expect("service thread");
        InProcess {
            shutdown,
            thread: Some(thread),
            cell,
            endpoint,
        }
    }

    /// Wait until the cell's health token is alive (every pair prepared), as a client would.
    pub fn wait_ready(&mut self, limit: Duration) {
        let session = client(&self.endpoint);
        let key = ris_daemon::protocol::health_key(&self.cell);
        let t = Instant::now();
        loop {
            if let Some(thread) = &self.thread {
                if thread.is_finished() {
                    let ended = self.thread.take().map(|t| t.join());
                    panic!("the service ended before it was ready: {ended:?}");
                }
            }
            let alive = session
                .liveliness()
                .get(&key)
                .timeout(Duration::from_millis(500))
                .wait()
                .ok()
                .and_then(|replies| replies.recv().ok())
                .is_some_and(|r| r.result().is_ok());
            if alive {
                break;
            }
            assert!(
                t.elapsed() < limit,
                "the service was not ready within {limit:?}"
            );
            std::thread::sleep(Duration::from_millis(100));
        }
        let _ = session.close().wait();
    }

    /// The service's outcome if it has ended (without waiting).
    pub fn ended(&mut self) -> Option<anyhow::Result<()>> {
        if !self.thread.as_ref()?.is_finished() {
            return None;
        }
        match self.thread.take().map(|t| t.join()) {
            Some(Ok(outcome)) => Some(outcome),
            Some(Err(_)) => Some(Err(anyhow::anyhow!("the service thread panicked"))),
            None => None,
        }
    }

    /// Whether the cell's health token is alive, seen through `session`.
    pub fn alive(&self, session: &zenoh::Session) -> bool {
        session
            .liveliness()
            .get(ris_daemon::protocol::health_key(&self.cell))
            .timeout(Duration::from_millis(500))
            .wait()
            .ok()
            .and_then(|replies| replies.recv().ok())
            .is_some_and(|r| r.result().is_ok())
    }

    /// Cancel the service and wait for it: its outcome.
    pub fn stop(mut self) -> anyhow::Result<()> {
        self.shutdown.cancel();
        match self.thread.take().map(|t| t.join()) {
            Some(Ok(outcome)) => outcome,
            Some(Err(_)) => Err(anyhow::anyhow!("the service thread panicked")),
            None => Ok(()),
        }
    }
}

impl Drop for InProcess {
    fn drop(&mut self) {
        self.shutdown.cancel();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
