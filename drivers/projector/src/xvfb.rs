//! An X screen without a monitor: an Xvfb server for the projector windows of the virtual
//! cell and of the tests. It takes a free display number (one whose lock names a process that
//! is gone counts as free: a server killed with SIGKILL leaves its lock and socket behind) and
//! removes its lock and socket when it is stopped, so that runs do not use the numbers up.

use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// Display numbers tried when none is asked for.
const DISPLAYS: std::ops::Range<u32> = 40..200;

/// Why an Xvfb server did not start.
#[derive(Debug, thiserror::Error)]
pub enum XvfbError {
    /// No display number in 40..200 is free.
    #[error("no free X display number in 40..200 (/tmp/.X<N>-lock all held by running servers)")]
    NoFreeDisplay,
    /// `Xvfb` could not be run.
    #[error("starting Xvfb (apt-get install xvfb): {0}")]
    Spawn(std::io::Error),
    /// The server ended or did not serve its socket in time.
    #[error("Xvfb on {display} did not start: {reason}")]
    NotStarted {
        /// The display asked for.
        display: String,
        /// What was seen.
        reason: String,
    },
}

/// A running Xvfb server, stopped (and its lock and socket removed) on drop.
pub struct Xvfb {
    child: Child,
    number: u32,
}

impl Xvfb {
    /// Start a server with one `width` × `height` × 24 screen on `display` (`:N`), or on the
    /// first free display number; returns once it serves its socket (at most 20 s).
    pub fn start(display: Option<&str>, width: u32, height: u32) -> Result<Xvfb, XvfbError> {
        Xvfb::start_with(display, width, height, false)
    }

    /// As [`Xvfb::start`], and the server ends (SIGTERM: it removes its lock and socket) when
    /// the thread that started it ends, however that happens: a process killed with SIGKILL
    /// runs no drop, and its server would otherwise live on. Start it from a thread that lives
    /// as long as the server is wanted (a command's main thread).
    pub fn start_tied(display: Option<&str>, width: u32, height: u32) -> Result<Xvfb, XvfbError> {
        Xvfb::start_with(display, width, height, true)
    }

    fn start_with(
        display: Option<&str>,
        width: u32,
        height: u32,
        tied: bool,
    ) -> Result<Xvfb, XvfbError> {
        let asked = display
            .map(|d| {
                d.trim_start_matches(':')
                    .parse::<u32>()
                    .map_err(|_| XvfbError::NotStarted {
                        display: d.to_string(),
                        reason: "the display is not of the form :N".into(),
                    })
            })
            .transpose()?;
        if let Some(n) = asked {
            // Clears a lock and socket left by a server that is gone; a live one makes the
            // server below exit, which is reported.
            is_free(n);
            return Xvfb::start_on(n, width, height, tied);
        }
        // Two runs can pick the same free number at once, or a number can be unusable in a
        // way its files do not show: the server that loses moves on to the next number.
        let mut last = XvfbError::NoFreeDisplay;
        let mut from = DISPLAYS.start;
        for _ in 0..8 {
            let Some(number) = (from..DISPLAYS.end).find(|&n| is_free(n)) else {
                break;
            };
            match Xvfb::start_on(number, width, height, tied) {
                Ok(x) => return Ok(x),
                Err(e @ XvfbError::Spawn(_)) => return Err(e),
                Err(e) => last = e,
            }
            from = number + 1;
        }
        Err(last)
    }

    fn start_on(number: u32, width: u32, height: u32, tied: bool) -> Result<Xvfb, XvfbError> {
        let display = format!(":{number}");
        let mut command = Command::new("Xvfb");
        command
            .args([
                &display,
                "-screen",
                "0",
                &format!("{width}x{height}x24"),
                "-nolisten",
                "tcp",
            ])
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::null());
        if tied {
            end_with_parent(&mut command);
        }
        let child = command.spawn().map_err(XvfbError::Spawn)?;
        let mut x = Xvfb { child, number };
        let deadline = Instant::now() + Duration::from_secs(20);
        loop {
            if let Ok(Some(status)) = x.child.try_wait() {
                // Not ours to clean: the display was taken by another server.
                x.number = u32::MAX;
                return Err(XvfbError::NotStarted {
                    display,
                    reason: format!("it exited ({status}); the display may be in use"),
                });
            }
            // The lock names the server before it creates its socket: a socket left by
            // another server does not pass for this one.
            if lock_pid(number) == Some(x.child.id()) && socket(number).exists() {
                return Ok(x);
            }
            if Instant::now() > deadline {
                return Err(XvfbError::NotStarted {
                    display,
                    reason: "no socket within 20 s".into(),
                });
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// The display name (`:N`).
    pub fn display(&self) -> String {
        format!(":{}", self.number)
    }

    /// The server's process id.
    pub fn pid(&self) -> u32 {
        self.child.id()
    }
}

impl Drop for Xvfb {
    fn drop(&mut self) {
        let pid = self.child.id();
        let _ = self.child.kill();
        let _ = self.child.wait();
        if self.number != u32::MAX && lock_pid(self.number) == Some(pid) {
            let _ = std::fs::remove_file(socket(self.number));
            let _ = std::fs::remove_file(lock(self.number));
        }
    }
}

/// Have the kernel send SIGTERM to `command`'s process when the thread spawning it ends. A
/// parent gone before the request is made fails the spawn instead of leaving the child
/// untied.
#[allow(unsafe_code)] // two libc calls between fork and exec: no allocation, no lock
fn end_with_parent(command: &mut Command) {
    use std::os::unix::process::CommandExt;
    let parent = std::process::id() as libc::pid_t;
    // SAFETY: the closure runs in the forked child before exec and only calls prctl and
    // getppid, which are async-signal-safe.
    unsafe {
        command.pre_exec(move || {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM) == -1 {
                return Err(std::io::Error::last_os_error());
            }
            if libc::getppid() != parent {
                return Err(std::io::Error::other(
                    "the parent ended before the server started",
                ));
            }
            Ok(())
        });
    }
}

fn lock(n: u32) -> PathBuf {
    PathBuf::from(format!("/tmp/.X{n}-lock"))
}

fn socket(n: u32) -> PathBuf {
    PathBuf::from(format!("/tmp/.X11-unix/X{n}"))
}

/// The process id written in display `n`'s lock file.
fn lock_pid(n: u32) -> Option<u32> {
    std::fs::read_to_string(lock(n)).ok()?.trim().parse().ok()
}

/// Whether display `n` can be taken: no lock, or a lock whose process is gone (its lock and
/// socket are then removed). A socket without a lock belongs to no server either.
fn is_free(n: u32) -> bool {
    match std::fs::read_to_string(lock(n)) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            let _ = std::fs::remove_file(socket(n));
            true
        }
        Err(_) => false,
        Ok(text) => match text.trim().parse::<u32>() {
            Ok(pid) if gone(pid) => {
                let _ = std::fs::remove_file(socket(n));
                std::fs::remove_file(lock(n)).is_ok()
            }
            _ => false,
        },
    }
}

/// Whether process `pid` has ended: no such process, or a zombie that nothing has reaped (a
/// server whose parent died, in a container whose first process does not reap).
fn gone(pid: u32) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/stat")).map_or(true, |s| {
        s.rsplit(')')
            .next()
            .is_some_and(|r| r.trim_start().starts_with('Z'))
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A lock naming a process that is gone or a zombie frees its display; one naming a live
    /// process (this one) does not.
    #[test]
    fn stale_locks_free_their_display_and_live_ones_do_not() {
        let n = (DISPLAYS.end..DISPLAYS.end + 800)
            .find(|&n| !lock(n).exists())
            .expect("an unused number");
        // A pid above the kernel's largest (2^22).
        std::fs::write(lock(n), "   4194399\n").expect("lock");
        assert!(is_free(n) && !lock(n).exists());
        std::fs::write(lock(n), format!("{:>10}\n", std::process::id())).expect("lock");
        assert!(!is_free(n) && lock(n).exists());
        // A zombie (ended, not yet reaped) holds its display no more than a process gone.
        let mut child = Command::new("true").spawn().expect("true");
        let t = Instant::now();
        while !gone(child.id()) {
            assert!(t.elapsed() < Duration::from_secs(10), "`true` did not end");
            std::thread::sleep(Duration::from_millis(10));
        }
        std::fs::write(lock(n), format!("{:>10}\n", child.id())).expect("lock");
        assert!(is_free(n) && !lock(n).exists());
        child.wait().expect("reaped");
    }

    /// Set in the process [`a_tied_server_ends_with_the_process_that_started_it`] runs as the
    /// server's parent.
    const PARENT: &str = "RIS_XVFB_TIED_PARENT";

    /// A server started tied, by a process then killed with SIGKILL (no drop runs), ends and
    /// leaves no lock. The test runs itself again as that process. Needs `Xvfb`.
    #[test]
    fn a_tied_server_ends_with_the_process_that_started_it() {
        if std::env::var_os(PARENT).is_some() {
            let x = Xvfb::start_tied(None, 64, 48).expect("Xvfb");
            println!("server {} {}", x.pid(), x.number);
            std::thread::sleep(Duration::from_secs(60));
            return;
        }
        use std::io::BufRead as _;
        let mut parent = Command::new(std::env::current_exe().expect("test binary"))
            .args([
                "--exact",
                "xvfb::tests::a_tied_server_ends_with_the_process_that_started_it",
                "--nocapture",
                "--test-threads",
                "1",
            ])
            .env(PARENT, "1")
            .stdout(Stdio::piped())
            .spawn()
            .expect("the parent");
        let out = parent.stdout.take().expect("its output");
        let line = std::io::BufReader::new(out)
            .lines()
            .map_while(Result::ok)
            .find_map(|l| l.split_once("server ").map(|(_, rest)| rest.to_string()))
            .expect("the server's pid");
        let mut words = line.split_whitespace();
        let pid: u32 = words.next().and_then(|w| w.parse().ok()).expect("pid");
        let n: u32 = words.next().and_then(|w| w.parse().ok()).expect("display");
        assert_eq!(lock_pid(n), Some(pid));
        parent.kill().expect("SIGKILL");
        parent.wait().expect("reaped");
        // Gone, or a zombie that no init has reaped yet. The SIGTERM normally lets it remove
        // its lock and socket; one that arrives before the server has set its handlers ends it
        // by default and leaves them, and the display is then free by its stale lock.
        let deadline = Instant::now() + Duration::from_secs(30);
        while !gone(pid) {
            assert!(
                Instant::now() < deadline,
                "Xvfb {pid} on :{n} still runs 30 s after its parent was killed"
            );
            std::thread::sleep(Duration::from_millis(50));
        }
        assert!(
            is_free(n),
            "display :{n} is not free after its server ended"
        );
        assert!(!lock(n).exists() && !socket(n).exists());
    }

    /// A display that its files call free but whose server cannot start (its socket's path is
    /// a directory) is passed over for the next number, and the server's lock and socket are
    /// gone once it is stopped. Needs `Xvfb` (`.ci/run` installs it).
    #[test]
    fn an_unusable_display_is_passed_over_and_a_stopped_server_leaves_no_files() {
        let blocked = DISPLAYS
            .clone()
            .find(|&n| is_free(n))
            .expect("a free display");
        let dir = socket(blocked);
        std::fs::create_dir_all(dir.join("in-the-way")).expect("blocker");
        let started = Xvfb::start(None, 64, 48);
        std::fs::remove_dir_all(&dir).expect("remove blocker");
        let x = started.expect("Xvfb on another display");
        let n = x.number;
        assert!(n > blocked, "display :{n}, blocked :{blocked}");
        assert_eq!(lock_pid(n), Some(x.pid()));
        drop(x);
        assert!(!lock(n).exists() && !socket(n).exists());
    }
}
