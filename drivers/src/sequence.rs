//! The sensor-pair sequencer: show a slide, trigger, receive the frame and prove it belongs to
//! that slide, for every slide of a scan; retry what can be retried, fail with the pattern and
//! the reason otherwise, and never return a capture set with a frame filed under the wrong
//! pattern.
//!
//! The proofs: stale frames are drained before every trigger; a frame must arrive after its
//! trigger and after the slide was presented; frame ids must advance by exactly one per
//! exposure (a gap is a dropped frame, a repeat a duplicate). Content: the white and black
//! frames must differ, and a Gray pattern plus its inverse must add up to white plus black
//! (light conservation holds at any blur), which catches a slide shown in place of another.

use std::collections::BTreeMap;
use std::time::Duration;

use ris_core::capture::CaptureSet;
use ris_core::image::{GrayImage, Pixels};
use ris_core::pattern::{CodeLayout, Pattern};

use crate::clock::now_ns;
use crate::{Camera, DriverError, ErrorKind, Frame, Projector, Slide, TriggerMode};

/// How a pair is sequenced.
#[derive(Clone, Debug)]
pub struct SequenceParams {
    /// Frames averaged per slide (Eq. 3.23).
    pub average: u32,
    /// Longest wait for one frame.
    pub timeout: Duration,
    /// Attempts after the first for one slide (or one content check).
    pub retries: u32,
    /// Reconnects allowed per sequence after a disconnect.
    pub reconnects: u32,
    /// White − black contrast (DN) of pixels used by the content checks.
    pub min_contrast: f32,
    /// Largest contrast-weighted |P + P̄ − W − B| / (W − B) of a Gray pair.
    pub max_pair_error: f32,
    /// Wait between presentation and trigger (projector response, rolling displays). A content
    /// check that finds a wrong slide raises it for the recapture (see [`SequenceReport::settle_s`]).
    pub settle: Duration,
    /// How each exposure starts: `Software` (a trigger after the slide is presented) or
    /// `Hardware` (the projector's sync output on a camera line exposes at presentation).
    pub trigger: TriggerMode,
}

impl Default for SequenceParams {
    fn default() -> Self {
        SequenceParams {
            average: 1,
            timeout: Duration::from_secs(2),
            retries: 3,
            reconnects: 1,
            min_contrast: 12.0,
            max_pair_error: 0.2,
            settle: Duration::ZERO,
            trigger: TriggerMode::Software,
        }
    }
}

/// Why a sequence failed.
#[derive(Debug, thiserror::Error)]
pub enum SequenceError {
    /// The slides cannot form one capture set.
    #[error("invalid sequence: {0}")]
    Invalid(String),
    /// A device failed in a way retrying does not fix.
    #[error("{stage}: {source}")]
    Driver {
        /// What the sequencer was doing (`showing gray_col_03`, `starting the camera`).
        stage: String,
        /// The device error.
        #[source]
        source: DriverError,
    },
    /// A slide's frame could not be proven to belong to it within the retries.
    #[error("{slide}: {reason} (gave up after {attempts} attempts)")]
    Mismatch {
        /// The slide.
        slide: String,
        /// Attempts made.
        attempts: u32,
        /// The last check that failed.
        reason: String,
    },
}

/// What happened during a sequence, for logs and state publications.
#[derive(Clone, Debug, Default)]
pub struct SequenceReport {
    /// Exposures triggered.
    pub triggers: u64,
    /// Slides shown (including re-shows).
    pub shows: u64,
    /// Retried slides, with the reason.
    pub retries: Vec<(String, String)>,
    /// Unexpected frames drained before a trigger.
    pub stale_frames: u64,
    /// Reconnects performed.
    pub reconnects: u32,
    /// Seconds inside `Projector::show` (upload excluded: the present and its wait).
    pub present_s: f64,
    /// Seconds from each trigger (or presentation, under a hardware trigger) to its frame.
    pub frame_wait_s: f64,
    /// The settle time in use at the end, seconds: above the configured one when a late slide
    /// (a projector slower than its settle time) had to be recaptured with a longer wait.
    pub settle_s: f64,
}

/// The settle time after a recapture round found a wrong slide: tripled, at least 30 ms, at
/// most 1 s (a slide that is late by more than a second is a fault, not a latency).
fn raised_settle(settle: Duration) -> Duration {
    (settle * 3)
        .max(Duration::from_millis(30))
        .min(Duration::from_secs(1))
}

/// Progress of a sequence.
#[derive(Clone, Copy, Debug)]
pub struct Progress {
    /// Slides recorded.
    pub done: usize,
    /// Slides in the sequence.
    pub total: usize,
    /// The slide just recorded.
    pub pattern: Pattern,
}

/// A recorded capture set and how it went.
#[derive(Clone, Debug)]
pub struct Acquisition {
    /// The frames, one per slide, with the mask and metadata.
    pub capture: CaptureSet,
    /// What happened.
    pub report: SequenceReport,
}

enum Attempt {
    Retry(String),
    /// No frame (or no acknowledgement) within the timeout.
    Silent(DriverError),
    Disconnected(DriverError),
    Fatal(SequenceError),
}

/// Silent attempts in a row after which a slide's camera is reopened (when reconnects are
/// left): a camera that keeps its control channel but whose stream has stopped answers every
/// trigger and sends nothing, and only a new stream (reopening it) brings frames again.
const SILENT_BEFORE_REOPEN: u32 = 2;

struct Run<'a> {
    camera: &'a mut dyn Camera,
    projector: &'a mut dyn Projector,
    params: &'a SequenceParams,
    last_id: Option<u64>,
    reconnects_left: u32,
    settle: Duration,
    report: SequenceReport,
}

/// Record `slides` (unique patterns, one shared mask or none) with `camera` and `projector`
/// under the trigger of `params`; `progress` is called after every slide.
pub fn acquire(
    camera: &mut dyn Camera,
    projector: &mut dyn Projector,
    layout: &CodeLayout,
    slides: &[Slide],
    params: &SequenceParams,
    progress: &mut dyn FnMut(Progress),
) -> Result<Acquisition, SequenceError> {
    validate(layout, slides, projector)?;
    if params.trigger == TriggerMode::FreeRun {
        return Err(SequenceError::Invalid(
            "a free-running camera cannot be sequenced: use the software or a hardware trigger"
                .into(),
        ));
    }
    let info = camera.info().clone();
    let driver = |stage: &str| {
        let stage = stage.to_string();
        move |source| SequenceError::Driver { stage, source }
    };
    projector
        .load(slides)
        .map_err(driver("uploading the slides"))?;
    let _ = camera.stop();
    camera
        .set_trigger(params.trigger.clone())
        .map_err(driver("selecting the trigger"))?;
    camera.start().map_err(driver("starting the camera"))?;
    let mut run = Run {
        camera,
        projector,
        params,
        last_id: None,
        reconnects_left: params.reconnects,
        settle: params.settle,
        report: SequenceReport::default(),
    };
    let result = run.record(slides, progress);
    run.report.settle_s = run.settle.as_secs_f64();
    let _ = run.camera.stop();
    let (images, ids) = result?;
    let mut capture = CaptureSet::new(*layout, info.width, info.height);
    capture.mask = slides
        .first()
        .and_then(|s| s.mask.as_ref())
        .map(|m| m.to_image());
    let mut frame_ids = toml::Table::new();
    for ((slide, image), ids) in slides.iter().zip(images).zip(ids) {
        frame_ids.insert(
            slide.pattern.name(),
            toml::Value::Array(
                ids.iter()
                    .map(|&i| toml::Value::Integer(i as i64))
                    .collect(),
            ),
        );
        capture.frames.insert(slide.pattern, image);
    }
    let meta = &mut capture.meta;
    meta.insert("camera".into(), info.id.clone().into());
    meta.insert("projector".into(), run.projector.info().id.clone().into());
    meta.insert("exposure_us".into(), run.camera.exposure_us().into());
    meta.insert("average".into(), i64::from(params.average).into());
    meta.insert("frame_ids".into(), toml::Value::Table(frame_ids));
    tracing::info!(
        camera = %info.id,
        slides = slides.len(),
        triggers = run.report.triggers,
        retries = run.report.retries.len(),
        stale = run.report.stale_frames,
        reconnects = run.report.reconnects,
        settle_ms = run.report.settle_s * 1e3,
        "sequence recorded"
    );
    Ok(Acquisition {
        capture,
        report: run.report,
    })
}

fn validate(
    layout: &CodeLayout,
    slides: &[Slide],
    projector: &dyn Projector,
) -> Result<(), SequenceError> {
    let p = projector.info();
    if (p.width, p.height) != (layout.width, layout.height) {
        return Err(SequenceError::Invalid(format!(
            "the code layout is {}x{}, projector {} is {}x{}",
            layout.width, layout.height, p.id, p.width, p.height
        )));
    }
    if slides.is_empty() {
        return Err(SequenceError::Invalid("no slides".into()));
    }
    let mask = &slides[0].mask;
    let mut seen = std::collections::BTreeSet::new();
    for s in slides {
        if !seen.insert(s.pattern) {
            return Err(SequenceError::Invalid(format!(
                "`{}` appears twice",
                s.pattern.name()
            )));
        }
        if s.mask != *mask {
            return Err(SequenceError::Invalid(format!(
                "`{}` has another mask than the first slide; one capture set has one mask",
                s.name()
            )));
        }
    }
    Ok(())
}

impl Run<'_> {
    fn record(
        &mut self,
        slides: &[Slide],
        progress: &mut dyn FnMut(Progress),
    ) -> Result<(Vec<GrayImage>, Vec<Vec<u64>>), SequenceError> {
        let mut images = Vec::with_capacity(slides.len());
        let mut ids = Vec::with_capacity(slides.len());
        for (slot, slide) in slides.iter().enumerate() {
            let (img, fids) = self.slide(slot, slide)?;
            images.push(img);
            ids.push(fids);
            progress(Progress {
                done: slot + 1,
                total: slides.len(),
                pattern: slide.pattern,
            });
        }
        // Content checks; recapture what fails, bounded.
        for round in 0..=self.params.retries {
            let bad = content_failures(slides, &images, self.params);
            if bad.is_empty() {
                return Ok((images, ids));
            }
            let (slot, reason) = &bad[0];
            if round == self.params.retries {
                return Err(SequenceError::Mismatch {
                    slide: slides[*slot].name(),
                    attempts: round + 1,
                    reason: reason.clone(),
                });
            }
            let mut redo: Vec<usize> = bad.iter().map(|b| b.0).collect();
            redo.sort_unstable();
            redo.dedup();
            // A slide that was not yet on screen when its frame was taken is the usual cause:
            // the recapture waits longer after each presentation.
            self.settle = raised_settle(self.settle);
            for (slot, reason) in &bad {
                tracing::warn!(
                    slide = %slides[*slot].name(),
                    %reason,
                    settle_ms = self.settle.as_secs_f64() * 1e3,
                    "content check failed; recapturing with a longer settle time"
                );
                self.report
                    .retries
                    .push((slides[*slot].name(), reason.clone()));
            }
            for slot in redo {
                let (img, fids) = self.slide(slot, &slides[slot])?;
                images[slot] = img;
                ids[slot] = fids;
            }
        }
        unreachable!("the loop returns in its last round")
    }

    /// One slide, retried until its frames are proven or the attempts run out.
    fn slide(
        &mut self,
        slot: usize,
        slide: &Slide,
    ) -> Result<(GrayImage, Vec<u64>), SequenceError> {
        let mut attempts = 0;
        let mut silent = 0;
        loop {
            attempts += 1;
            let outcome = self.attempt(slot, slide);
            silent = match &outcome {
                Err(Attempt::Silent(_)) => silent + 1,
                _ => 0,
            };
            match outcome {
                Ok(x) => return Ok(x),
                Err(Attempt::Fatal(e)) => return Err(e),
                Err(Attempt::Silent(e))
                    if silent >= SILENT_BEFORE_REOPEN
                        && self.reconnects_left > 0
                        && attempts <= self.params.retries =>
                {
                    tracing::warn!(slide = %slide.name(), error = %e, silent, "no frame on triggers in a row; reopening the camera");
                    self.reopen(
                        slide,
                        &format!("no frame on {silent} triggers in a row ({e})"),
                    )?;
                    silent = 0;
                }
                Err(Attempt::Retry(reason)) => self.retry(slide, attempts, reason)?,
                Err(Attempt::Silent(e)) => self.retry(slide, attempts, e.to_string())?,
                Err(Attempt::Disconnected(e)) => {
                    if self.reconnects_left == 0 || attempts > self.params.retries {
                        return Err(SequenceError::Driver {
                            stage: format!("capturing {}", slide.name()),
                            source: e,
                        });
                    }
                    tracing::warn!(error = %e, "camera disconnected; reconnecting");
                    self.reopen(slide, &e.to_string())?;
                }
            }
        }
    }

    /// Records a failed attempt to be retried, or gives up once the attempts are spent.
    fn retry(&mut self, slide: &Slide, attempts: u32, reason: String) -> Result<(), SequenceError> {
        if attempts > self.params.retries {
            return Err(SequenceError::Mismatch {
                slide: slide.name(),
                attempts,
                reason,
            });
        }
        tracing::warn!(slide = %slide.name(), attempt = attempts, %reason, "retrying");
        self.report.retries.push((slide.name(), reason));
        Ok(())
    }

    /// Reconnects the camera (a new control channel and stream) and restores its trigger,
    /// spending one of the sequence's reconnects; `why` goes into the report.
    fn reopen(&mut self, slide: &Slide, why: &str) -> Result<(), SequenceError> {
        self.reconnects_left -= 1;
        let reconnect = |stage: &str| {
            let stage = stage.to_string();
            move |source| SequenceError::Driver { stage, source }
        };
        self.camera
            .reconnect()
            .map_err(reconnect(&format!("reconnecting after: {why}")))?;
        let _ = self.camera.stop();
        self.camera
            .set_trigger(self.params.trigger.clone())
            .map_err(reconnect("restoring the trigger"))?;
        self.camera
            .start()
            .map_err(reconnect("restarting the camera"))?;
        // Frame counters may restart with the device.
        self.last_id = None;
        self.report.reconnects += 1;
        self.report
            .retries
            .push((slide.name(), format!("reconnected after: {why}")));
        Ok(())
    }

    fn attempt(&mut self, slot: usize, slide: &Slide) -> Result<(GrayImage, Vec<u64>), Attempt> {
        let classify = |e: DriverError| match e.kind {
            ErrorKind::Timeout => Attempt::Silent(e),
            ErrorKind::Busy => Attempt::Retry(e.to_string()),
            ErrorKind::Disconnected => Attempt::Disconnected(e),
            _ => Attempt::Fatal(SequenceError::Driver {
                stage: format!("capturing {}", slide.name()),
                source: e,
            }),
        };
        // Drain anything left over (late or duplicated frames) before this slide's exposure.
        loop {
            match self.camera.next_frame(Duration::ZERO) {
                Ok(f) => {
                    self.report.stale_frames += 1;
                    tracing::debug!(frame_id = f.frame_id, "discarded a stale frame");
                    self.last_id = Some(newest(self.last_id, f.frame_id));
                }
                Err(e) if e.kind == ErrorKind::Timeout => break,
                Err(e) => return Err(classify(e)),
            }
        }
        let hardware = matches!(self.params.trigger, TriggerMode::Hardware { .. });
        // Under a hardware trigger the exposure starts with the presentation itself.
        let before_show = now_ns();
        let shown = self.projector.show(slot).map_err(|e| {
            Attempt::Fatal(SequenceError::Driver {
                stage: format!("showing {}", slide.name()),
                source: e,
            })
        })?;
        self.report.present_s += (now_ns() - before_show) as f64 * 1e-9;
        self.report.shows += 1;
        if shown.slot != slot {
            return Err(Attempt::Retry(format!(
                "projector reports slide {} instead of {slot}",
                shown.slot
            )));
        }
        if !self.settle.is_zero() {
            std::thread::sleep(self.settle);
        }
        let mut frames: Vec<Frame> = Vec::with_capacity(self.params.average as usize);
        for k in 0..self.params.average.max(1) {
            let t0 = if hardware {
                if k > 0 {
                    // One presentation, one exposure: show the slide again.
                    let t = now_ns();
                    self.projector.show(slot).map_err(|e| {
                        Attempt::Fatal(SequenceError::Driver {
                            stage: format!("showing {}", slide.name()),
                            source: e,
                        })
                    })?;
                    self.report.shows += 1;
                    t
                } else {
                    before_show
                }
            } else {
                let t = now_ns();
                self.camera.trigger().map_err(classify)?;
                t
            };
            self.report.triggers += 1;
            let f = self
                .camera
                .next_frame(self.params.timeout)
                .map_err(classify)?;
            self.report.frame_wait_s += now_ns().saturating_sub(t0) as f64 * 1e-9;
            let last = self.last_id;
            self.last_id = Some(newest(last, f.frame_id));
            let earliest = if hardware {
                t0
            } else {
                t0.max(shown.presented_ns)
            };
            if f.host_ns < earliest {
                return Err(Attempt::Retry(format!(
                    "frame {} arrived before its trigger (stale)",
                    f.frame_id
                )));
            }
            if let Some(l) = last {
                let step = id_advance(l, f.frame_id);
                if step <= 0 {
                    return Err(Attempt::Retry(format!(
                        "frame id {} does not advance past {l} (duplicate)",
                        f.frame_id
                    )));
                }
                if step > 1 {
                    return Err(Attempt::Retry(format!(
                        "frame id jumped from {l} to {} ({} frame(s) dropped)",
                        f.frame_id,
                        step - 1
                    )));
                }
            }
            let info = self.camera.info();
            if (f.width(), f.height()) != (info.width, info.height) {
                return Err(Attempt::Fatal(SequenceError::Driver {
                    stage: format!("capturing {}", slide.name()),
                    source: DriverError::new(
                        ErrorKind::Failed,
                        &info.id,
                        format!(
                            "frame is {}x{}, the camera reports {}x{}",
                            f.width(),
                            f.height(),
                            info.width,
                            info.height
                        ),
                    ),
                }));
            }
            frames.push(f);
        }
        let ids = frames.iter().map(|f| f.frame_id).collect();
        Ok((average(&frames), ids))
    }
}

/// How far frame id `id` is past `last`: 1 for the next exposure, ≤ 0 for a repeat. Ids that
/// fit 16 bits are taken as a wrapping counter (GigE Vision 1.x block ids run 1 … 65535 and
/// then start again at 1), so a camera that has streamed for a while is not taken for one
/// repeating old frames.
fn id_advance(last: u64, id: u64) -> i64 {
    if last <= 0xFFFF && id <= 0xFFFF {
        let d = (id as i64 - last as i64).rem_euclid(65_536);
        let d = if d >= 32_768 { d - 65_536 } else { d };
        // Across the wrap the counter skips block id 0.
        if id < last && d > 0 {
            d - 1
        } else {
            d
        }
    } else {
        id as i64 - last as i64
    }
}

/// The newer of the last id seen and `id`, in the sense of [`id_advance`].
fn newest(last: Option<u64>, id: u64) -> u64 {
    match last {
        Some(l) if id_advance(l, id) <= 0 => l,
        _ => id,
    }
}

/// Per-pixel mean of frames of one size and depth (rounded).
fn average(frames: &[Frame]) -> GrayImage {
    if frames.len() == 1 {
        return frames[0].image.clone();
    }
    let first = &frames[0].image;
    let n = first.width as usize * first.height as usize;
    let mut sum = vec![0u32; n];
    for f in frames {
        match &f.image.pixels {
            Pixels::U8(v) => sum.iter_mut().zip(v).for_each(|(s, &p)| *s += u32::from(p)),
            Pixels::U16(v) => sum.iter_mut().zip(v).for_each(|(s, &p)| *s += u32::from(p)),
        }
    }
    let m = frames.len() as u32;
    let mean = sum.iter().map(|&s| (s + m / 2) / m);
    match first.pixels {
        Pixels::U8(_) => {
            GrayImage::from_u8(first.width, first.height, mean.map(|v| v as u8).collect())
        }
        Pixels::U16(_) => {
            GrayImage::from_u16(first.width, first.height, mean.map(|v| v as u16).collect())
        }
    }
}

/// Slides whose frames fail the content checks, with the reason.
fn content_failures(
    slides: &[Slide],
    images: &[GrayImage],
    params: &SequenceParams,
) -> Vec<(usize, String)> {
    let index: BTreeMap<Pattern, usize> = slides
        .iter()
        .enumerate()
        .map(|(i, s)| (s.pattern, i))
        .collect();
    let (Some(&w), Some(&b)) = (index.get(&Pattern::White), index.get(&Pattern::Black)) else {
        return Vec::new();
    };
    let (white, black) = (images[w].to_levels(), images[b].to_levels());
    let min = params.min_contrast;
    let lit = |i: usize| white[i] - black[i] >= min;
    let lit_count = (0..white.len()).filter(|&i| lit(i)).count();
    if lit_count * 1000 < white.len() {
        let reason = format!(
            "only {} of {} pixels see the projector (white − black ≥ {} DN): projector off, \
             covered, the camera looks elsewhere, or the white or black frame is wrong",
            lit_count,
            white.len(),
            params.min_contrast
        );
        return vec![(w, reason.clone()), (b, reason)];
    }
    // Light conservation only holds where nothing clips: leave out saturated white pixels.
    let valid: Vec<usize> = (0..white.len())
        .filter(|&i| lit(i) && white[i] < 250.0)
        .collect();
    if valid.len() < 100 {
        return Vec::new();
    }
    let contrast: f64 = valid.iter().map(|&i| f64::from(white[i] - black[i])).sum();
    let mut bad = Vec::new();
    let mut pairs = 0;
    for (&p, &i) in &index {
        let Pattern::Gray {
            axis,
            bit,
            inverse: false,
        } = p
        else {
            continue;
        };
        let Some(&j) = index.get(&Pattern::Gray {
            axis,
            bit,
            inverse: true,
        }) else {
            continue;
        };
        pairs += 1;
        let (a, c) = (images[i].to_levels(), images[j].to_levels());
        let err: f64 = valid
            .iter()
            .map(|&k| f64::from(a[k] + c[k] - white[k] - black[k]).abs())
            .sum::<f64>()
            / contrast;
        if err > f64::from(params.max_pair_error) {
            let reason = format!(
                "{} + its inverse differs from white + black by {:.0} % of the contrast: a \
                 wrong slide was exposed",
                p.name(),
                err * 100.0
            );
            bad.push((i, reason.clone()));
            bad.push((j, reason));
        }
    }
    // Most pairs failing means the white or black frame itself is wrong, or every slide was
    // late: all of them are recaptured.
    if pairs > 0 && bad.len() / 2 > pairs / 2 {
        let reason = format!(
            "{} of {pairs} Gray pairs disagree with white + black: the white or black frame is wrong",
            bad.len() / 2
        );
        bad.insert(0, (b, reason.clone()));
        bad.insert(0, (w, reason));
    }
    bad
}

#[cfg(test)]
mod tests {
    #[test]
    fn frame_ids_wrap_like_gige_vision_block_ids() {
        use super::id_advance;
        assert_eq!(id_advance(7, 8), 1);
        assert_eq!(id_advance(7, 7), 0);
        assert_eq!(id_advance(8, 7), -1);
        assert_eq!(id_advance(7, 10), 3);
        assert_eq!(id_advance(65_535, 1), 1, "the wrap skips 0");
        assert_eq!(id_advance(65_534, 1), 2);
        assert!(
            id_advance(1, 65_535) < 0,
            "an old frame from before the wrap"
        );
        assert_eq!(id_advance(1 << 20, (1 << 20) + 1), 1);
        assert_eq!(id_advance(1 << 20, 5), 5 - (1 << 20));
    }
}
