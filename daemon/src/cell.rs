//! The cell as one thing that scans: its pairs opened through their backends and its parts
//! indexed, prepared once; the service's worker and `risd --once` both scan through it.

use std::path::{Path, PathBuf};

use anyhow::Result;

use crate::config::CellConfig;
use crate::pair::{self, Pair};
use crate::prepared::Cache;
use crate::protocol::{Artefact, PairStatus, ScanMode, ScanState};
use crate::scan::{self, Part, ScanOptions, ScanReport};

/// What one scan of the cell is asked to do.
#[derive(Clone, Debug, Default)]
pub struct ScanJob {
    /// Sensors to scan (`None`: all).
    pub sensors: Option<Vec<String>>,
    /// Index of the part to inspect.
    pub part: Option<usize>,
    /// The request's free text.
    pub tag: Option<String>,
    /// The part's serial number.
    pub serial: Option<String>,
    /// Who started the scan.
    pub operator: Option<String>,
    /// How the pairs acquire.
    pub mode: ScanMode,
    /// What a `verify` scan measures: the artefact and its position.
    pub verify: Option<(Artefact, String)>,
    /// What the scan's inspection report must carry (the cell's verification warnings).
    pub notes: Vec<String>,
}

/// A prepared cell.
pub struct Cell {
    /// Cell name.
    pub name: String,
    /// Pairs in configuration order.
    pub pairs: Vec<Pair>,
    /// Parts in configuration order.
    pub parts: Vec<Part>,
    keep_captures: bool,
    e57: bool,
    stage_deadline: std::time::Duration,
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    /// Fault injection for tests: the named computing stage of every scan runs until its
    /// deadline ends it (set from `RISD_INJECT_HANG` in a build with `fault-injection`).
    #[doc(hidden)]
    pub hang_in: Option<String>,
}

impl Cell {
    /// Open every pair (see [`pair::open_all`], with the configured cache of prepared pairs)
    /// and index every part of `config`; `seed` varies simulated noise; `progress(pair, done,
    /// total)` is called as each pair's model is ready.
    pub fn prepare(
        config: &CellConfig,
        seed: u64,
        progress: &(dyn Fn(&str, usize, usize) + Sync),
    ) -> Result<Cell> {
        let parts = config
            .parts
            .iter()
            .map(Part::prepare)
            .collect::<Result<Vec<_>>>()?;
        let cache = Cache::new(Some(config.storage.cache_dir()));
        Ok(Cell {
            name: config.name.clone(),
            pairs: pair::open_all(config, seed, &cache, progress)?,
            parts,
            keep_captures: config.storage.keep_captures,
            e57: config.storage.e57,
            stage_deadline: config.workers.stage_deadline(),
            stop: Default::default(),
            hang_in: injected_hang(),
        })
    }

    /// Stop a running scan's computing stage at its next iteration once `flag` is raised (risd
    /// raises it when stopping); the scan then fails as cancelled.
    pub fn stop_with(&mut self, flag: std::sync::Arc<std::sync::atomic::AtomicBool>) {
        self.stop = flag;
    }

    /// Scan into `<data_dir>/scans/<scan_id>` (see [`scan::run`]). Pairs whose camera was
    /// lost try to reconnect first.
    pub fn scan(
        &mut self,
        job: &ScanJob,
        data_dir: &Path,
        scan_id: &str,
        cancelled: &(dyn Fn() -> bool + Sync),
        state: &(dyn Fn(&ScanState) + Sync),
    ) -> Result<(ScanReport, PathBuf)> {
        self.reconnect();
        // A mock cell's wearing part deepens its dent with every scan.
        for p in &self.pairs {
            if let Some(f) = &p.faults {
                f.next_scan();
            }
        }
        let options = ScanOptions {
            only: job.sensors.as_deref(),
            keep_captures: self.keep_captures,
            e57: self.e57,
            part: job.part.and_then(|i| self.parts.get(i)),
            tag: job.tag.as_deref(),
            serial: job.serial.as_deref(),
            operator: job.operator.as_deref(),
            mode: job.mode,
            notes: &job.notes,
            stage_deadline: Some(self.stage_deadline),
            stop: Some(&self.stop),
            hang_in: self.hang_in.as_deref(),
        };
        scan::run(
            &self.name,
            &mut self.pairs,
            options,
            data_dir,
            scan_id,
            cancelled,
            state,
        )
    }

    /// Try once to reopen every lost camera; true when every pair is connected.
    pub fn reconnect(&mut self) -> bool {
        // Every lost pair gets its try, not only those before the first failure.
        let tried: Vec<bool> = self.pairs.iter_mut().map(Pair::try_reconnect).collect();
        tried.into_iter().all(|ok| ok)
    }

    /// Every pair's drivers, for health.
    pub fn status(&self) -> Vec<PairStatus> {
        self.pairs
            .iter()
            .map(|p| {
                let (camera, projector) = p.devices();
                PairStatus {
                    sensor: p.name.clone(),
                    backend: p.backend.to_string(),
                    kind: p.kind,
                    camera,
                    projector,
                    driver: p.state.clone(),
                    single_shot: p.single_shot.as_ref().err().cloned(),
                }
            })
            .collect()
    }
}

#[cfg(feature = "fault-injection")]
fn injected_hang() -> Option<String> {
    std::env::var("RISD_INJECT_HANG").ok()
}

#[cfg(not(feature = "fault-injection"))]
fn injected_hang() -> Option<String> {
    None
}
