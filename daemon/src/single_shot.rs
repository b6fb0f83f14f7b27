//! A pair's single-shot set-up: its X-point pattern (generated once from the cell's
//! `[single_shot]`), the slide that projects it, and the decoded Gray-code reference that
//! predicts where each X-point lies; and the computation of one frame into a cloud.

use std::sync::Arc;

use anyhow::{anyhow, Context, Result};
use ris_core::cloud::PointCloud;
use ris_core::decode::Decoded;
use ris_core::image::GrayImage;
use ris_core::sensor::Reconstructor;
use ris_core::single_shot::{self, DecodeStats, DetectParams, ReferencePrediction, XPointPattern};
use ris_drivers::Slide;

use crate::config::SingleShotSection;

/// What a pair needs to measure from one frame.
pub struct PairSingleShot {
    /// The projected pattern.
    pub pattern: XPointPattern,
    /// The slide showing it.
    pub slide: Slide,
    reference: Arc<Decoded>,
}

/// One frame's result.
pub struct FrameCloud {
    /// The cloud in the sensor's frame, organised on the camera's pixels.
    pub cloud: PointCloud,
    /// X-points detected.
    pub detected: usize,
    /// How decoding went.
    pub stats: DecodeStats,
    /// Seconds detecting and decoding the X-points.
    pub decode_s: f64,
    /// Seconds reconstructing them.
    pub reconstruct_s: f64,
}

impl PairSingleShot {
    /// The pattern for a `width × height` projector; `reference` must carry row codes (they
    /// choose the code's repeat along the rows).
    pub fn new(
        sensor: &str,
        (width, height): (u32, u32),
        config: &SingleShotSection,
        reference: Arc<Decoded>,
    ) -> Result<PairSingleShot> {
        if reference.row.is_none() {
            return Err(anyhow!(
                "sensor {sensor}: its reference recording has no row codes, which single-shot decoding needs"
            ));
        }
        let pattern = XPointPattern::generate(width, height, config.step, 3, config.seed)
            .with_context(|| format!("sensor {sensor}: the X-point pattern"))?;
        let slide = Slide::picture(width, height, &pattern.render());
        Ok(PairSingleShot {
            pattern,
            slide,
            reference,
        })
    }

    /// Detect, decode and reconstruct one camera `image` through `rec`.
    pub fn cloud(&self, image: &GrayImage, rec: &Reconstructor) -> Result<FrameCloud> {
        let predict = ReferencePrediction::new(&self.reference)
            .ok_or_else(|| anyhow!("the reference has no row codes"))?;
        let t = std::time::Instant::now();
        let levels = image.to_levels();
        let found = single_shot::detect(
            &levels,
            image.width as usize,
            image.height as usize,
            &DetectParams::default(),
        );
        let at = |x: f64, y: f64| predict.at(x, y);
        let (matches, stats) = single_shot::decode(&found, &self.pattern, Some(&at));
        let decode_s = t.elapsed().as_secs_f64();
        let cloud = single_shot::reconstruct(&matches, rec);
        Ok(FrameCloud {
            cloud,
            detected: found.len(),
            stats,
            decode_s,
            reconstruct_s: t.elapsed().as_secs_f64() - decode_s,
        })
    }
}
