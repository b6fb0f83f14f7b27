//! One scan of the cell: exposure groups take turns (pairs of a group project at the same
//! time), each pair is sequenced on its own thread, and its capture is decoded and reconstructed
//! on the compute pool while the next group acquires; the sensor clouds are merged into the
//! cell frame. Results are written under a temporary name and renamed when complete, so a
//! crash never leaves a scan that looks finished.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::mpsc;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{anyhow, Context, Result};
use ris_core::budget::{self, Budget};
use ris_core::capture::CaptureSet;
use ris_core::cloud::{Merger, PointCloud};
use ris_core::decode::{decode, DecodeParams};
use ris_core::inspect::{
    inspect, load_characteristics, load_datums, write_deviation_ply, write_deviation_png,
    Characteristic, Datum, InspectParams, InspectedSurface, MapTitle,
};
use ris_core::mesh::{step, SignedDistance, TriangleMesh};
use ris_core::pattern::Pattern;
use ris_core::sensor::Reconstructor;
use ris_drivers::adaptive::{adaptive_scan, AdaptiveParams};
use ris_drivers::sequence::acquire;
use ris_drivers::Slide;
use serde::Serialize;

use crate::config::SensorKind;
use crate::config::{PartConfig, PartSurface};
pub use crate::pair::Pair;
use crate::protocol::{ScanMode, ScanState};
use crate::single_shot::OneShot;

/// Radius (mm) within which points of different sensors are duplicates in the merge.
const MERGE_RADIUS: f64 = 0.5;

/// Seconds spent in each stage of one sensor.
#[derive(Clone, Debug, Default, Serialize)]
pub struct SensorTiming {
    /// Sensor.
    pub sensor: String,
    /// Acquisition start and end, s since the scan started.
    pub acquire: (f64, f64),
    /// Decoding, reconstruction and merge start and end, s since the scan started.
    pub compute: (f64, f64),
    /// Seconds decoding, reconstructing and merging into the cell cloud.
    pub stages: StageSeconds,
    /// Points reconstructed.
    pub points: usize,
    /// Of those, points outside the sensor's calibrated volume: flagged `outside_volume` in
    /// the clouds and left out of the inspection.
    pub outside_volume: usize,
    /// Slides projected (retries and every step of an adaptive scan included).
    pub frames: u64,
    /// Seconds presenting slides (Gray scans).
    pub present_seconds: f64,
    /// Seconds from triggers to their frames (Gray scans).
    pub frame_wait_seconds: f64,
    /// The steps of an adaptive scan.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub phases: Vec<PhaseTiming>,
}

/// One step of an adaptive scan.
#[derive(Clone, Debug, Default, Serialize)]
pub struct PhaseTiming {
    /// Step.
    pub phase: String,
    /// Slides projected.
    pub frames: u64,
    /// Seconds (projection and the computation after it).
    pub seconds: f64,
    /// Figures of the step.
    pub detail: String,
}

/// Seconds of one sensor's compute stages.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct StageSeconds {
    /// Gray-code decoding to sub-pixel correspondences.
    pub decode: f64,
    /// Parallax reconstruction.
    pub reconstruct: f64,
    /// Merge into the cell cloud.
    pub merge: f64,
}

/// The result of a scan.
#[derive(Clone, Debug, Serialize)]
pub struct ScanReport {
    /// Scan id.
    pub scan_id: String,
    /// The request's tag.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tag: Option<String>,
    /// The part's serial number.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub serial: Option<String>,
    /// Who started the scan.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub operator: Option<String>,
    /// Cell.
    pub cell: String,
    /// How the pairs acquired.
    pub mode: ScanMode,
    /// Per sensor.
    pub sensors: Vec<SensorTiming>,
    /// Merge start and end, s since the scan started.
    pub merge: (f64, f64),
    /// Points in the merged cloud.
    pub merged_points: usize,
    /// Compute time after the last frame until the merged cloud is written, s.
    pub compute_after_last_frame: f64,
    /// The inspection, when the scan inspected a part.
    pub inspection: Option<InspectionSummary>,
    /// What the scan's consumer should know before trusting it (a sensor that gave no
    /// points); also in the inspection report's warnings.
    pub warnings: Vec<String>,
    /// Total, s.
    pub total: f64,
    /// Every cloud as written (sensors, then `merged`): binary PLY in memory, to publish
    /// without reading the files back.
    #[serde(skip)]
    pub clouds: Vec<(String, Arc<Vec<u8>>)>,
}

/// The verdict of a scan's inspection (the full report is `report.json` beside the clouds).
#[derive(Clone, Debug, Serialize)]
pub struct InspectionSummary {
    /// Part id.
    pub part: String,
    /// `pass`, `fail` or `not_measured`.
    pub verdict: String,
    /// Why it failed.
    pub reasons: Vec<String>,
    /// Mean signed deviation, mm.
    pub mean: f64,
    /// RMS deviation, mm.
    pub rms: f64,
    /// Fraction of points within tolerance.
    pub within_tolerance: f64,
    /// Inspection start and end, s since the scan started.
    pub seconds: (f64, f64),
}

/// A part ready to inspect: its CAD surface indexed for distance queries (built once).
pub struct Part {
    /// Id.
    pub id: String,
    cad: SignedDistance,
    datums: Vec<Datum>,
    tolerance: f64,
    min_coverage: f64,
    fit_pose: bool,
    /// The inspected surface: the whole CAD or named faces (`Whole` also for `seen`, which
    /// each scan makes from its sensors).
    surface: InspectedSurface,
    seen: bool,
    characteristics: Vec<Characteristic>,
}

impl Part {
    /// The CAD of `config`, the inspected surface its `faces` make (a STEP model's faces by
    /// entity number) and its characteristics (on the STEP model's faces).
    pub fn load_cad(
        config: &PartConfig,
    ) -> Result<(TriangleMesh, InspectedSurface, Vec<Characteristic>)> {
        let what = || format!("part {}: CAD {}", config.id, config.cad.display());
        if config.faces.is_empty() && config.characteristics.is_none() {
            let mesh = TriangleMesh::load(&config.cad).with_context(what)?;
            return Ok((mesh, InspectedSurface::Whole, Vec::new()));
        }
        let model = step::read(&config.cad, &step::StepOptions::default()).with_context(|| {
            format!(
                "{} (`{}` needs a STEP model)",
                what(),
                if config.faces.is_empty() {
                    "characteristics"
                } else {
                    "faces"
                }
            )
        })?;
        let surface = if config.faces.is_empty() {
            InspectedSurface::Whole
        } else {
            InspectedSurface::of_faces(&model, &config.faces, &what())?
        };
        let characteristics = match &config.characteristics {
            Some(p) => load_characteristics(p, &model)
                .with_context(|| format!("part {}: characteristics", config.id))?,
            None => Vec::new(),
        };
        Ok((model.mesh, surface, characteristics))
    }

    /// Load the CAD model and datums of `config` and index the surface.
    pub fn prepare(config: &PartConfig) -> Result<Part> {
        let (mesh, surface, characteristics) = Part::load_cad(config)?;
        let datums = match &config.datums {
            Some(d) => load_datums(d).with_context(|| format!("part {}: datums", config.id))?,
            None => Vec::new(),
        };
        Ok(Part {
            id: config.id.clone(),
            cad: SignedDistance::new(mesh),
            datums,
            tolerance: config.tolerance,
            min_coverage: config.min_coverage,
            fit_pose: config.pose == crate::config::PartPose::Fit,
            surface,
            seen: config.inspected == PartSurface::Seen,
            characteristics,
        })
    }
}

/// What one scan does besides acquiring every selected pair.
#[derive(Clone, Copy, Default)]
pub struct ScanOptions<'a> {
    /// Sensors to scan (`None`: all).
    pub only: Option<&'a [String]>,
    /// Keep the captured images under `captures/`.
    pub keep_captures: bool,
    /// Also write every cloud as E57 beside its PLY.
    pub e57: bool,
    /// Inspect the merged cloud against this part.
    pub part: Option<&'a Part>,
    /// Free text of the request, stored in `scan.json`.
    pub tag: Option<&'a str>,
    /// The part's serial number, stored in `scan.json`.
    pub serial: Option<&'a str>,
    /// Who started the scan, stored in `scan.json`.
    pub operator: Option<&'a str>,
    /// How the pairs acquire.
    pub mode: ScanMode,
    /// What the inspection report must carry besides the scan's own warnings.
    pub notes: &'a [String],
    /// Longest a computing stage may run (`None`: [`STAGE_DEADLINE`]).
    pub stage_deadline: Option<Duration>,
    /// Raised when the running stage must stop (risd stopping): it ends at its next iteration.
    pub stop: Option<&'a Arc<AtomicBool>>,
    /// Fault injection for tests: the named stage (`reconstruction`, `inspection`) runs until
    /// its budget ends it, as a stage whose parameters ask for endless work would; prefixed
    /// `stuck:`, it never ends (a loop without a check, a driver call that never returns).
    #[doc(hidden)]
    pub hang_in: Option<&'a str>,
}

impl ScanOptions<'_> {
    /// The budget of `stage`: the scan's stage deadline and stop flag.
    fn budget(&self, stage: String) -> Budget {
        let b = Budget::new(stage).deadline(self.stage_deadline());
        match self.stop {
            Some(stop) => b.stop_flag(stop.clone()),
            None => b,
        }
    }

    fn stage_deadline(&self) -> Duration {
        self.stage_deadline.unwrap_or(STAGE_DEADLINE)
    }

    /// The injected hang of `stage`, if this scan has one: work that never ends by itself.
    fn injected_hang(&self, stage: &str) -> ris_core::Result<()> {
        let Some(hang) = self.hang_in else {
            return Ok(());
        };
        if hang.strip_prefix("stuck:") == Some(stage) {
            tracing::warn!(stage, "injected fault: the stage never ends");
            loop {
                std::thread::park();
            }
        }
        if hang == stage {
            tracing::warn!(stage, "injected fault: the stage runs until its deadline");
            loop {
                budget::check()?;
                std::thread::sleep(Duration::from_millis(10));
            }
        }
        Ok(())
    }
}

/// Scan with the pairs `options` selects and write the result into
/// `<data_dir>/scans/<scan_id>`; `state` is told every stage; `cancelled` is asked between
/// exposure groups. On failure the `.partial` directory is removed.
pub fn run(
    cell: &str,
    pairs: &mut [Pair],
    options: ScanOptions,
    data_dir: &Path,
    scan_id: &str,
    cancelled: &(dyn Fn() -> bool + Sync),
    state: &(dyn Fn(&ScanState) + Sync),
) -> Result<(ScanReport, PathBuf)> {
    let scans = data_dir.join("scans");
    let dir = scans.join(scan_id);
    let partial = scans.join(format!("{scan_id}.partial"));
    // Every way out of a scan publishes its end state: the directory checks, the scan itself
    // (a panic in any stage included) and the final rename.
    let result = (|| -> Result<ScanReport> {
        std::fs::create_dir_all(&scans).with_context(|| format!("creating {}", scans.display()))?;
        if dir.exists() || partial.exists() {
            return Err(anyhow!(
                "scan {scan_id} exists already in {}",
                scans.display()
            ));
        }
        std::fs::create_dir(&partial).with_context(|| format!("creating {}", partial.display()))?;
        let selected: Vec<bool> = pairs
            .iter()
            .map(|p| options.only.is_none_or(|names| names.contains(&p.name)))
            .collect();
        let report = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            scan_into(
                cell, pairs, &selected, &partial, scan_id, options, cancelled, state,
            )
        }))
        .map_err(|panic| anyhow!("internal error: {}", panic_message(&*panic)))??;
        std::fs::rename(&partial, &dir).with_context(|| format!("finishing {}", dir.display()))?;
        Ok(report)
    })();
    match result {
        Ok(report) => {
            state(&ScanState::Done);
            Ok((report, dir))
        }
        Err(e) => {
            if partial.exists() {
                if let Err(rm) = std::fs::remove_dir_all(&partial) {
                    tracing::warn!(path = %partial.display(), error = %rm, "cannot remove the unfinished scan");
                }
            }
            state(&ScanState::Failed {
                reason: format!("{e:#}"),
            });
            Err(e)
        }
    }
}

/// The text of a caught panic.
pub fn panic_message(panic: &(dyn std::any::Any + Send)) -> String {
    panic
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| panic.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "a panic without a message".into())
}

#[allow(clippy::too_many_arguments)]
fn scan_into(
    cell: &str,
    pairs: &mut [Pair],
    selected: &[bool],
    dir: &Path,
    scan_id: &str,
    options: ScanOptions,
    cancelled: &(dyn Fn() -> bool + Sync),
    state: &(dyn Fn(&ScanState) + Sync),
) -> Result<ScanReport> {
    let t0 = Instant::now();
    let secs = move || t0.elapsed().as_secs_f64();
    let mut groups: Vec<u32> = pairs
        .iter()
        .zip(selected)
        .filter(|(_, s)| **s)
        .map(|(p, _)| p.group)
        .collect();
    groups.sort_unstable();
    groups.dedup();
    // Captures go to the compute worker through a bounded channel; it decodes, reconstructs,
    // writes and merges each sensor while the next group acquires.
    let (tx, rx) = mpsc::sync_channel::<(usize, CaptureSet)>(pairs.len().max(1));
    type PairCompute = (
        String,
        Option<Arc<Reconstructor>>,
        nalgebra::Matrix4<f64>,
        Option<Arc<OneShot>>,
        Option<[f64; 2]>,
    );
    let recs: Vec<PairCompute> = pairs
        .iter()
        .map(|p| {
            (
                p.name.clone(),
                p.reconstructor.clone(),
                p.to_common,
                p.single_shot.as_ref().ok().cloned(),
                p.range_mm,
            )
        })
        .collect();
    let mut timings: Vec<SensorTiming> = pairs
        .iter()
        .map(|p| SensorTiming {
            sensor: p.name.clone(),
            ..Default::default()
        })
        .collect();
    let mut last_frame = 0.0f64;
    // Per sensor: index, (points, outside the calibrated volume), compute span, stages.
    type Computed = (
        Merger,
        Vec<(usize, (usize, usize), (f64, f64), StageSeconds)>,
    );
    let (merged, done, merge_time, clouds) = std::thread::scope(|scope| {
        let recs = &recs;
        // Sensor clouds are written (and synced) on their own thread, off the critical path:
        // the merge needs them only in memory.
        let (wtx, wrx) = mpsc::channel::<(String, PointCloud)>();
        let writer = scope.spawn(move || -> Result<Vec<(String, Arc<Vec<u8>>)>> {
            let mut written = Vec::new();
            for (name, cloud) in wrx {
                let bytes = cloud.to_ply();
                if options.e57 {
                    write_e57(&cloud, dir, &name)?;
                }
                drop(cloud);
                ris_core::io::write_atomic(&dir.join(format!("{name}.ply")), &bytes)
                    .with_context(|| format!("writing the cloud of {name}"))?;
                written.push((name, Arc::new(bytes)));
            }
            Ok(written)
        });
        let worker = scope.spawn(move || -> Result<Computed> {
            let mut merger = Merger::new(MERGE_RADIUS);
            let mut done = Vec::new();
            for (i, capture) in rx {
                let (name, rec, to_common, single, range_mm) = &recs[i];
                state(&ScanState::Reconstructing {
                    sensor: name.clone(),
                });
                let c0 = secs();
                // One frame: a single-shot scan, or any scan of an omni sensor.
                let one = single
                    .as_ref()
                    .filter(|o| options.mode == ScanMode::SingleShot || o.is_omni());
                let stage = format!("sensor {name}: reconstruction");
                let reconstructing = ScanState::Reconstructing {
                    sensor: name.clone(),
                };
                // Its state told every STAGE_BEAT while it runs (the worker's heartbeat), as
                // long as the stage keeps within its deadline.
                let (cloud, c1) = while_running(
                    &stage,
                    &|| state(&reconstructing),
                    STAGE_BEAT,
                    options.stage_deadline() + STAGE_GRACE,
                    || {
                        budget::within(options.budget(stage.clone()), || -> Result<_> {
                            options.injected_hang("reconstruction")?;
                            Ok(if let Some(one) = one {
                                let image = capture.frame(Pattern::White).ok_or_else(|| {
                                    anyhow!("sensor {name}: the single frame is missing")
                                })?;
                                let f = one.measure(image).with_context(|| {
                                    format!("sensor {name}: decoding its one frame")
                                })?;
                                // What an operator looks at: the fusion image, or an omni sensor's panorama.
                                let (png, _) = one
                                    .picture(image, &f, *range_mm)
                                    .with_context(|| format!("sensor {name}: its picture"))?;
                                ris_core::io::write_atomic(&dir.join(format!("{name}.png")), &png)
                                    .with_context(|| format!("writing the picture of {name}"))?;
                                (f.cloud, c0 + f.decode_s)
                            } else if options.mode == ScanMode::SingleShot {
                                return Err(anyhow!("sensor {name}: no single-shot set-up"));
                            } else {
                                let rec = rec.as_ref().ok_or_else(|| {
                                    anyhow!("sensor {name}: no Gray-code sensor model")
                                })?;
                                let decoded = decode(&capture, &DecodeParams::default())
                                    .with_context(|| format!("sensor {name}: decoding"))?;
                                let c1 = secs();
                                budget::check()?;
                                let cloud = rec
                                    .reconstruct(&decoded)
                                    .with_context(|| format!("sensor {name}: reconstruction"))?;
                                (cloud, c1)
                            })
                        })
                    },
                )?;
                drop(capture);
                let c2 = secs();
                merger.add(&cloud, to_common);
                let c3 = secs();
                let stages = StageSeconds {
                    decode: c1 - c0,
                    reconstruct: c2 - c1,
                    merge: c3 - c2,
                };
                done.push((i, (cloud.len(), cloud.outside_count()), (c0, c3), stages));
                if wtx.send((name.clone(), cloud)).is_err() {
                    // The writer stopped on an error; it is reported when joined.
                    break;
                }
            }
            Ok((merger, done))
        });
        let acquired = (|| -> Result<()> {
            for g in &groups {
                if cancelled() {
                    return Err(anyhow!("cancelled: risd is stopping"));
                }
                let mut results = Vec::new();
                std::thread::scope(|inner| {
                    let handles: Vec<_> = pairs
                        .iter_mut()
                        .enumerate()
                        .filter(|(i, p)| p.group == *g && selected[*i])
                        .map(|(i, p)| {
                            inner.spawn(move || {
                                let a0 = secs();
                                let acq = acquire_pair(p, options.mode, state)
                                    .with_context(|| format!("sensor {}: acquisition", p.name));
                                (i, acq, a0, secs())
                            })
                        })
                        .collect();
                    for h in handles {
                        results.push(h.join());
                    }
                });
                for r in results {
                    let (i, acq, a0, a1) =
                        r.map_err(|_| anyhow!("an acquisition thread panicked"))?;
                    let acq = match acq {
                        Ok(a) => a,
                        Err(e) => {
                            pairs[i].note_failure(&e);
                            return Err(e);
                        }
                    };
                    timings[i].acquire = (a0, a1);
                    timings[i].frames = acq.frames;
                    timings[i].present_seconds = acq.present_s;
                    timings[i].frame_wait_seconds = acq.frame_wait_s;
                    timings[i].phases = acq.phases;
                    last_frame = last_frame.max(a1);
                    if options.keep_captures {
                        acq.capture
                            .save(&dir.join("captures").join(&pairs[i].name))
                            .with_context(|| {
                                format!("sensor {}: saving the capture", pairs[i].name)
                            })?;
                    }
                    if tx.send((i, acq.capture)).is_err() {
                        // The worker stopped on an error; it is reported below.
                        return Ok(());
                    }
                }
            }
            Ok(())
        })();
        drop(tx);
        let computed = worker
            .join()
            .map_err(|_| anyhow!("the compute worker panicked"));
        let merged = (|| -> Result<_> {
            acquired?;
            let (merger, done) = computed??;
            state(&ScanState::Merging);
            let m0 = secs();
            let (merged, _) = merger.finish();
            let bytes = merged.to_ply();
            ris_core::io::write_atomic(&dir.join("merged.ply"), &bytes)
                .context("writing the merged cloud")?;
            if options.e57 {
                write_e57(&merged, dir, "merged")?;
            }
            Ok((merged, done, (m0, secs()), bytes))
        })();
        let mut clouds = writer
            .join()
            .map_err(|_| anyhow!("the cloud writer panicked"))??;
        merged.map(|(m, d, t, bytes)| {
            clouds.push(("merged".to_string(), Arc::new(bytes)));
            (m, d, t, clouds)
        })
    })?;
    for (i, (points, outside), compute, stages) in done {
        timings[i].compute = compute;
        timings[i].stages = stages;
        timings[i].points = points;
        timings[i].outside_volume = outside;
        if outside > 0 {
            tracing::warn!(
                sensor = %timings[i].sensor,
                outside,
                points,
                "points outside the sensor's calibrated volume"
            );
        }
    }
    let warnings = empty_views(
        timings
            .iter()
            .zip(selected)
            .filter(|(_, s)| **s)
            .map(|(t, _)| t),
    );
    for w in &warnings {
        tracing::warn!("{w}");
    }
    let mut warnings = warnings;
    warnings.extend(options.notes.iter().cloned());
    let viewpoints: Vec<_> = pairs
        .iter()
        .zip(selected)
        .filter(|(_, s)| **s)
        .filter_map(|(p, _)| p.viewpoint())
        .collect();
    let inspection = match options.part {
        Some(part) => Some(inspect_part(
            part,
            &merged,
            &viewpoints,
            dir,
            &secs,
            state,
            &options,
            &warnings,
        )?),
        None => None,
    };
    let report = ScanReport {
        scan_id: scan_id.to_string(),
        tag: options.tag.map(str::to_string),
        serial: options.serial.map(str::to_string),
        operator: options.operator.map(str::to_string),
        cell: cell.to_string(),
        mode: options.mode,
        sensors: timings
            .into_iter()
            .zip(selected)
            .filter(|(_, s)| **s)
            .map(|(t, _)| t)
            .collect(),
        merge: merge_time,
        merged_points: merged.len(),
        compute_after_last_frame: merge_time.1 - last_frame,
        inspection,
        warnings,
        total: secs(),
        clouds,
    };
    ris_core::io::write_atomic(
        &dir.join("scan.json"),
        serde_json::to_string_pretty(&report)?.as_bytes(),
    )
    .context("writing scan.json")?;
    if report.inspection.is_some() {
        crate::page::write_report_page(dir)?;
    }
    Ok(report)
}

/// A warning for each sensor that reconstructed no points: its view is missing from the
/// merged cloud, which nothing else in the report would show.
pub fn empty_views<'a>(sensors: impl IntoIterator<Item = &'a SensorTiming>) -> Vec<String> {
    sensors
        .into_iter()
        .filter(|t| t.points == 0)
        .map(|t| {
            format!(
                "sensor {} reconstructed no points: the merged cloud lacks its view (a covered lens or projector, nothing in view, or a pattern finer than its camera resolves)",
                t.sensor
            )
        })
        .collect()
}

/// A pair's recorded capture set and how it was made.
struct Recorded {
    capture: CaptureSet,
    frames: u64,
    phases: Vec<PhaseTiming>,
    present_s: f64,
    frame_wait_s: f64,
}

/// Record one pair: the Gray sequence, or the adaptive loop (its exposure restored after).
/// Write `<dir>/<name>.e57` (metres; an organised cloud keeps its camera pixels).
fn write_e57(cloud: &PointCloud, dir: &Path, name: &str) -> Result<()> {
    cloud
        .write_e57(&dir.join(format!("{name}.e57")))
        .with_context(|| format!("writing the E57 cloud of {name}"))
}

fn acquire_pair(
    p: &mut Pair,
    mode: ScanMode,
    state: &(dyn Fn(&ScanState) + Sync),
) -> Result<Recorded> {
    let name = p.name.clone();
    // An omni sensor takes its one ring frame whatever the scan's mode.
    let mode = if p.kind == SensorKind::Omni {
        ScanMode::SingleShot
    } else {
        mode
    };
    match mode {
        ScanMode::Gray | ScanMode::Verify | ScanMode::SingleShot => {
            // The Gray sequence with inverses, or the pair's one X-point or ring slide.
            let slides: Vec<Slide> = if mode != ScanMode::SingleShot {
                p.layout
                    .sequence(true)
                    .into_iter()
                    .map(Slide::plain)
                    .collect()
            } else {
                let single = p.single_shot.clone().map_err(|why| anyhow!(why))?;
                vec![single.slide().clone()]
            };
            let acq = acquire(
                &mut *p.camera,
                &mut *p.projector,
                &p.layout,
                &slides,
                &p.sequence,
                &mut |pr| {
                    state(&ScanState::Acquiring {
                        sensor: name.clone(),
                        phase: None,
                        frame: pr.done,
                        frames: pr.total,
                    })
                },
            )?;
            Ok(Recorded {
                capture: acq.capture,
                frames: acq.report.shows,
                phases: Vec::new(),
                present_s: acq.report.present_s,
                frame_wait_s: acq.report.frame_wait_s,
            })
        }
        ScanMode::Adaptive => {
            let reference = p.reference.clone().ok_or_else(|| {
                anyhow!(
                    "an adaptive scan needs the pair's reference recording; its sensor file has no [reference]"
                )
            })?;
            let params = AdaptiveParams {
                sequence: p.sequence.clone(),
                ..AdaptiveParams::default()
            };
            let scan = adaptive_scan(
                &mut *p.camera,
                &mut *p.projector,
                &p.layout,
                &reference,
                &params,
                &mut |step, pr| {
                    state(&ScanState::Acquiring {
                        sensor: name.clone(),
                        phase: Some(step.to_string()),
                        frame: pr.done,
                        frames: pr.total,
                    })
                },
            );
            // The next scan starts from the configured exposure, whatever this one chose.
            let restored = p.camera.set_exposure_us(p.exposure_us);
            let scan = scan?;
            restored.context("restoring the exposure")?;
            Ok(Recorded {
                capture: scan.capture,
                frames: scan.frames,
                phases: scan
                    .steps
                    .into_iter()
                    .map(|s| PhaseTiming {
                        phase: s.step.to_string(),
                        frames: s.frames,
                        seconds: s.seconds,
                        detail: s.detail,
                    })
                    .collect(),
                present_s: 0.0,
                frame_wait_s: 0.0,
            })
        }
    }
}

/// How often a stage that cannot be interrupted tells its state again.
pub const STAGE_BEAT: std::time::Duration = std::time::Duration::from_secs(2);
/// The default deadline of a computing stage (`[workers] stage_deadline_s`): past it the stage
/// stops at its next iteration and the scan fails naming it.
pub const STAGE_DEADLINE: std::time::Duration = std::time::Duration::from_secs(600);
/// How long past its deadline a stage keeps telling its state: a stage still running then did
/// not stop by itself (a loop without a budget check, a stuck driver) and counts as hung; its
/// state goes quiet, and the worker's heartbeat with it (systemd's watchdog restarts risd).
pub const STAGE_GRACE: std::time::Duration = std::time::Duration::from_secs(10);

/// Run `work` on this thread while another calls `tell` every `every`, until `work` returns or
/// `deadline` passes (then `stage` is logged as overdue and `tell` is no longer called).
pub fn while_running<T: Send>(
    stage: &str,
    tell: &(dyn Fn() + Sync),
    every: std::time::Duration,
    deadline: std::time::Duration,
    work: impl FnOnce() -> T + Send,
) -> T {
    let done = std::sync::atomic::AtomicBool::new(false);
    let start = Instant::now();
    std::thread::scope(|scope| {
        let teller = scope.spawn(|| loop {
            std::thread::park_timeout(every);
            if done.load(std::sync::atomic::Ordering::SeqCst) {
                return;
            }
            if start.elapsed() > deadline {
                tracing::error!(
                    stage,
                    deadline_s = deadline.as_secs(),
                    "the stage is past its deadline: its progress and the worker's heartbeat stop"
                );
                return;
            }
            tell();
        });
        let out = work();
        done.store(true, std::sync::atomic::Ordering::SeqCst);
        teller.thread().unpark();
        out
    })
}

/// Register the merged cloud (cell frame, which the cell calibration puts on the part's
/// nominal pose) to the part and write `deviation.ply`, `deviation.png` and `report.json`.
#[allow(clippy::too_many_arguments)]
fn inspect_part(
    part: &Part,
    merged: &PointCloud,
    viewpoints: &[ris_core::inspect::Viewpoint],
    dir: &Path,
    secs: &dyn Fn() -> f64,
    state: &(dyn Fn(&ScanState) + Sync),
    options: &ScanOptions,
    notes: &[String],
) -> Result<InspectionSummary> {
    let mode = options.mode;
    state(&ScanState::Inspecting {
        part: part.id.clone(),
    });
    let i0 = secs();
    // Points outside a sensor's calibrated volume are not trusted to measure deviations.
    let flagged = merged.outside.len() == merged.points.len();
    let points: Vec<[f64; 3]> = merged
        .points
        .iter()
        .enumerate()
        .filter(|(i, _)| !(flagged && merged.outside[*i]))
        .map(|(_, p)| p.map(f64::from))
        .collect();
    let outside = merged.len() - points.len();
    let params = InspectParams {
        tolerance: part.tolerance,
        datums: part.datums.clone(),
        init: Some(ris_core::register::Pose::identity()),
        min_coverage: part.min_coverage,
        fit_pose: part.fit_pose,
        // an omni-only scan has no viewpoint of a projector and camera pair: the whole CAD
        surface: if part.seen && !viewpoints.is_empty() {
            InspectedSurface::SeenFrom(viewpoints.to_vec())
        } else {
            part.surface.clone()
        },
        characteristics: part.characteristics.clone(),
        ..InspectParams::default()
    };
    // While the inspection runs its state is told again every STAGE_BEAT, which keeps the
    // worker's heartbeat and the clients' progress alive; it stops at its next iteration once
    // past the stage deadline or told to stop. One that does not (a loop without a check)
    // goes quiet a grace period later, and the watchdog restarts risd.
    let inspecting = ScanState::Inspecting {
        part: part.id.clone(),
    };
    let stage = format!("inspection of part {}", part.id);
    let mut r = while_running(
        "inspection",
        &|| state(&inspecting),
        STAGE_BEAT,
        options.stage_deadline() + STAGE_GRACE,
        || {
            budget::within(options.budget(stage), || {
                options.injected_hang("inspection")?;
                inspect(&points, &part.cad, &params)
            })
        },
    )
    .with_context(|| {
        let mut why = format!("inspecting part {}", part.id);
        for n in notes {
            why.push_str("; ");
            why.push_str(n);
        }
        why
    })?;
    if outside > 0 {
        r.report.warnings.push(format!(
            "{outside} of {} merged points lie outside their sensor's calibrated volume and were not inspected",
            merged.len()
        ));
    }
    r.report.warnings.extend(notes.iter().cloned());
    if mode == ScanMode::SingleShot {
        r.report.warnings.push(format!(
            "a single-shot scan: {} sparse points, each from one X-point of one frame, noisier than a Gray-code scan; weigh the verdict against that before acting on it",
            merged.len()
        ));
    }
    let title = MapTitle {
        part: part.id.clone(),
        // The scan is written into `<id>.partial` and renamed when complete.
        scan: dir.file_name().map_or_else(String::new, |n| {
            n.to_string_lossy().trim_end_matches(".partial").to_string()
        }),
        time: utc_time(),
    };
    // The cloud's file and the map's picture side by side (each mostly one thread's work).
    let (ply, png) = rayon::join(
        || write_deviation_ply(&dir.join("deviation.ply"), &r.points, &r.deviations),
        || {
            write_deviation_png(
                &dir.join("deviation.png"),
                &r.points,
                &r.deviations,
                &r.report,
                &part.datums,
                &title,
            )
        },
    );
    ply?;
    png?;
    ris_core::io::write_atomic(
        &dir.join("report.json"),
        serde_json::to_string_pretty(&r.report)?.as_bytes(),
    )
    .context("writing report.json")?;
    let s = &r.report.statistics;
    tracing::info!(part = %part.id, verdict = %r.report.verdict, rms = s.rms, "inspected");
    Ok(InspectionSummary {
        part: part.id.clone(),
        verdict: r.report.verdict.clone(),
        reasons: r.report.reasons.clone(),
        mean: s.mean,
        rms: s.rms,
        within_tolerance: s.within_tolerance,
        seconds: (i0, secs()),
    })
}

/// A new scan id: UTC time to the millisecond plus a counter (`20261122T084921.028Z-0`), so
/// ids sort by time.
pub fn new_scan_id(counter: u64) -> String {
    let (year, month, day, h, m, s, ms) = utc_now();
    format!("{year:04}{month:02}{day:02}T{h:02}{m:02}{s:02}.{ms:03}Z-{counter}")
}

/// The UTC time now as people read it (`2026-11-22 08:49:21 UTC`).
pub fn utc_time() -> String {
    let (year, month, day, h, m, s, _) = utc_now();
    format!("{year:04}-{month:02}-{day:02} {h:02}:{m:02}:{s:02} UTC")
}

/// UTC civil time: year, month, day, hours, minutes, seconds, milliseconds.
fn utc_now() -> (i64, i64, i64, u64, u64, u64, u32) {
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap_or_default();
    let secs = now.as_secs();
    let (days, rem) = ((secs / 86_400) as i64, secs % 86_400);
    // Civil date from days since 1970-01-01 (Howard Hinnant's algorithm).
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = yoe + era * 400 + i64::from(month <= 2);
    (
        year,
        month,
        day,
        rem / 3600,
        rem / 60 % 60,
        rem % 60,
        now.subsec_millis(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_long_stage_tells_its_state_until_it_ends_or_passes_its_deadline() {
        use std::sync::atomic::{AtomicUsize, Ordering};
        use std::time::Duration;
        let told = AtomicUsize::new(0);
        let tell = || {
            told.fetch_add(1, Ordering::SeqCst);
        };
        let ms = Duration::from_millis;
        let t = Instant::now();
        let out = while_running("test", &tell, ms(50), ms(10_000), || {
            std::thread::sleep(ms(520));
            7
        });
        assert_eq!(out, 7);
        let n = told.load(Ordering::SeqCst);
        assert!((8..=11).contains(&n), "{n} tellings in 520 ms at 50 ms");
        assert!(
            t.elapsed() < ms(700),
            "the teller does not hold the stage up"
        );
        std::thread::sleep(ms(150));
        assert_eq!(told.load(Ordering::SeqCst), n, "none after the stage ended");
        // Past the deadline the stage goes quiet (a hung stage starves the watchdog).
        told.store(0, Ordering::SeqCst);
        while_running("test", &tell, ms(50), ms(200), || {
            std::thread::sleep(ms(600))
        });
        let n = told.load(Ordering::SeqCst);
        assert!(
            (2..=4).contains(&n),
            "{n} tellings before a 200 ms deadline at 50 ms"
        );
    }

    #[test]
    fn scan_ids_are_utc_timestamps() {
        let id = new_scan_id(3);
        assert_eq!(id.len(), "20261122T084921.028Z-3".len(), "{id}");
        assert!(id.starts_with("20") && id.ends_with("Z-3"), "{id}");
    }
}
