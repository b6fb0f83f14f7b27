//! `risd`: the RIS cell daemon. It serves scan requests over Zenoh (SPEC §12) until SIGTERM or
//! SIGINT; `--once` scans the cell once and exits; `--check-config` validates a configuration.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Parser;
use ris_daemon::cell::{Cell, ScanJob};
use ris_daemon::config::{CellConfig, MOCK_CELL};
use ris_daemon::protocol::ScanMode;
use ris_daemon::scan;

#[derive(Parser)]
#[command(name = "risd", version, about = "RIS cell daemon")]
struct Args {
    /// Cell configuration (TOML); without it the built-in mock cell runs.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Validate FILE (syntax, fields, referenced files) and exit.
    #[arg(long, value_name = "FILE")]
    check_config: Option<PathBuf>,
    /// Zenoh endpoint to listen on (replaces the file's).
    #[arg(long)]
    listen: Vec<String>,
    /// Zenoh endpoint to connect to (replaces the file's).
    #[arg(long)]
    connect: Vec<String>,
    /// Data directory (replaces the file's).
    #[arg(long)]
    data_dir: Option<PathBuf>,
    /// Directory of prepared pairs kept between starts (replaces the file's; default
    /// `<data dir>/cache`).
    #[arg(long)]
    cache_dir: Option<PathBuf>,
    /// Scan the cell once, write clouds under the data directory, print where, and exit.
    #[arg(long)]
    once: bool,
    /// With --once: `gray` (default), `adaptive` (the projection-mask loop per pair) or
    /// `single-shot` (one frame of the X-point pattern per pair).
    #[arg(long, default_value = "gray", value_parser = ["gray", "adaptive", "single-shot"])]
    mode: String,
    /// With --once: also keep every pair's capture set (replayable with `backend = "replay"`).
    #[arg(long)]
    keep_captures: bool,
    /// With --once: the scan's id (its directory name under `<data dir>/scans/`) instead of the
    /// time.
    #[arg(long)]
    scan_id: Option<String>,
}

fn load(args: &Args) -> Result<CellConfig> {
    let mut config = match &args.config {
        Some(path) => CellConfig::load(path)?,
        None => {
            // The built-in mock cell: its scenes live beside its configuration.
            let base = builtin_dir()?;
            CellConfig::parse(MOCK_CELL, &base, "built-in mock cell")?
        }
    };
    if !args.listen.is_empty() {
        ris_daemon::config::check_endpoints("command line", "--listen", &args.listen)?;
        config.zenoh.listen = args.listen.clone();
    }
    if !args.connect.is_empty() {
        ris_daemon::config::check_endpoints("command line", "--connect", &args.connect)?;
        config.zenoh.connect = args.connect.clone();
    }
    if let Some(d) = &args.data_dir {
        config.storage.data_dir = d.clone();
    }
    if let Some(d) = &args.cache_dir {
        config.storage.cache_dir = Some(d.clone());
    }
    Ok(config)
}

/// Where the built-in mock cell's scene files are: the source tree's `config/` (the binary is
/// run from the repository) or `/usr/share/risd/config` when installed.
fn builtin_dir() -> Result<PathBuf> {
    let candidates = [
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config"),
        PathBuf::from("/usr/share/risd/config"),
    ];
    candidates
        .into_iter()
        .find(|d| d.join("mock-cell").is_dir())
        .context("the built-in mock cell's scenes (config/mock-cell/) are not installed")
}

fn main() -> Result<()> {
    ris_daemon::logging::init("info", "error");
    let args = Args::parse();
    if let Some(path) = &args.check_config {
        let config = CellConfig::load(path)?;
        config.check_files()?;
        println!(
            "{}: cell {:?}, {} sensors in {} exposure groups, {} parts: ok",
            path.display(),
            config.name,
            config.sensors.len(),
            config.exposure_groups().len(),
            config.parts.len()
        );
        return Ok(());
    }
    let mut config = load(&args)?;
    config.storage.keep_captures |= args.keep_captures;
    if config.workers.threads > 0 {
        rayon::ThreadPoolBuilder::new()
            .num_threads(config.workers.threads)
            .build_global()
            .context("setting up the compute pool")?;
    }
    config.check_files()?;
    if !args.once {
        let shutdown = tokio_util::sync::CancellationToken::new();
        return ris_daemon::service::serve(config, shutdown, true);
    }
    let data_dir = &config.storage.data_dir;
    let _lock = ris_daemon::store::DataDirLock::acquire(data_dir)?;
    for name in ris_daemon::store::housekeeping(
        data_dir,
        config.storage.keep_scans,
        config.storage.max_age_days,
    )? {
        tracing::info!(scan = %name, "removed");
    }
    tracing::info!(cell = %config.name, sensors = config.sensors.len(), "preparing the pairs");
    let mut cell = Cell::prepare(&config, 1, &|pair, done, total| {
        tracing::info!(pair, "pair prepared ({done} of {total})")
    })?;
    let id = match &args.scan_id {
        Some(id) => {
            if id.is_empty()
                || !id
                    .chars()
                    .all(|c| c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.'))
                || id.starts_with('.')
            {
                anyhow::bail!("--scan-id {id:?}: letters, digits, -, _ and . only");
            }
            id.clone()
        }
        None => scan::new_scan_id(0),
    };
    let job = ScanJob {
        // The part is inspected when the cell defines exactly one (as a request without fields).
        // Single-shot clouds are not inspected unless asked (they are sparse and noisier).
        part: (config.parts.len() == 1 && args.mode != "single-shot").then_some(0),
        mode: ScanMode::parse(&args.mode).unwrap_or_default(),
        ..ScanJob::default()
    };
    let (report, dir) = cell.scan(
        &job,
        data_dir,
        &id,
        &|| false,
        &|s| tracing::debug!(state = ?s, "scan state"),
    )?;
    for s in &report.sensors {
        println!(
            "{}: {} points, {} frames (acquired {:.2}–{:.2} s, computed {:.2}–{:.2} s: decode {:.2} s, reconstruct {:.2} s, merge {:.2} s)",
            s.sensor,
            s.points,
            s.frames,
            s.acquire.0,
            s.acquire.1,
            s.compute.0,
            s.compute.1,
            s.stages.decode,
            s.stages.reconstruct,
            s.stages.merge
        );
    }
    println!(
        "scan {} of cell {}: {} merged points (written in {:.2}–{:.2} s), {:.2} s of computation after the last frame, {:.1} s in all",
        report.scan_id, report.cell, report.merged_points, report.merge.0, report.merge.1, report.compute_after_last_frame, report.total
    );
    for w in &report.warnings {
        println!("warning: {w}");
    }
    if let Some(i) = &report.inspection {
        println!(
            "part {}: {} (deviation mean {:+.3} mm, RMS {:.3} mm, {:.1} % within tolerance; {:.1} s)",
            i.part,
            i.verdict.to_uppercase(),
            i.mean,
            i.rms,
            100.0 * i.within_tolerance,
            i.seconds.1 - i.seconds.0
        );
        for r in &i.reasons {
            println!("  - {r}");
        }
    }
    println!("wrote {}", dir.display());
    Ok(())
}
