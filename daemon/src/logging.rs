//! Logging set-up shared by the binaries: `tracing` filtered by `RIS_LOG`, to the systemd
//! journal (structured fields, priorities) when stderr is connected to it, else to stderr.

use tracing_subscriber::layer::SubscriberExt;
use tracing_subscriber::util::SubscriberInitExt;

/// RIS's own crates: their log lines are the ones a user reads.
const OWN: [&str; 8] = [
    "risd",
    "ris",
    "ris_daemon",
    "ris_core",
    "ris_drivers",
    "ris_aravis",
    "ris_projector",
    "ris_v4l2",
];

/// The filter of `level` for RIS's crates and `libraries` for every other crate (Zenoh's INFO
/// lines are of no use to a user).
fn default_filter(level: &str, libraries: &str) -> String {
    let mut f = String::from(libraries);
    for c in OWN {
        f.push_str(&format!(",{c}={level}"));
    }
    f
}

/// Install the subscriber: `level` for RIS's crates and `libraries` for the others (risd and
/// `ris` say in their own words what went wrong and what to change, so they take only the
/// libraries' errors; Zenoh's warnings carry source paths and repeat what RIS says), unless
/// `RIS_LOG` (e.g. `debug`, `ris_core=trace,zenoh=info`) says otherwise. Colours only on a
/// terminal.
pub fn init(level: &str, libraries: &str) {
    let filter = tracing_subscriber::EnvFilter::try_from_env("RIS_LOG")
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default_filter(level, libraries)));
    if stderr_is_journal() {
        if let Ok(journal) = tracing_journald::layer() {
            let _ = tracing_subscriber::registry()
                .with(filter)
                .with(journal)
                .try_init();
            return;
        }
    }
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .with_target(false)
        .try_init();
}

/// Whether systemd connected stderr to the journal: `JOURNAL_STREAM` names the device and
/// inode of that stream, and stderr is still it (not redirected by a child's caller).
fn stderr_is_journal() -> bool {
    use std::os::unix::fs::MetadataExt;
    let Ok(value) = std::env::var("JOURNAL_STREAM") else {
        return false;
    };
    let Ok(meta) = std::fs::metadata("/proc/self/fd/2") else {
        return false;
    };
    journal_stream_is(&value, meta.dev(), meta.ino())
}

/// Whether a `JOURNAL_STREAM` value (`DEVICE:INODE`, decimal) names the stream `dev`/`ino`.
fn journal_stream_is(value: &str, dev: u64, ino: u64) -> bool {
    value
        .split_once(':')
        .and_then(|(d, i)| Some((d.parse::<u64>().ok()?, i.parse::<u64>().ok()?)))
        .is_some_and(|(d, i)| d == dev && i == ino)
}

#[cfg(test)]
mod tests {
    #[test]
    fn libraries_log_warnings_only_by_default() {
        let f = super::default_filter("info", "warn");
        assert!(
            f.starts_with("warn,") && f.contains(",ris_daemon=info") && f.contains(",risd=info")
        );
        assert!(tracing_subscriber::EnvFilter::try_new(&f).is_ok(), "{f}");
    }

    #[test]
    fn journal_stream_names_device_and_inode() {
        use super::journal_stream_is;
        assert!(journal_stream_is("9:123456", 9, 123_456));
        assert!(!journal_stream_is("9:123456", 9, 123_457));
        assert!(!journal_stream_is("8:123456", 9, 123_456));
        for bad in ["", "9", "9:", ":1", "x:1", "9:1:2"] {
            assert!(!journal_stream_is(bad, 9, 1), "{bad:?}");
        }
    }
}
