//! Logging set-up shared by the binaries: `tracing` to stderr, filtered by `RIS_LOG`.

/// Install a stderr subscriber; `RIS_LOG` (e.g. `debug`, `ris_core=trace`) overrides `default`.
pub fn init(default: &str) {
    let filter = tracing_subscriber::EnvFilter::try_from_env("RIS_LOG")
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_target(false)
        .try_init();
}
