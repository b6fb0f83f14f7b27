//! A pair's single-shot set-up: its X-point pattern (generated once from the cell's
//! `[single_shot]`), the slide that projects it, and the decoded Gray-code reference that
//! predicts where each X-point lies; and the computation of one frame into a cloud.

use std::sync::Arc;

use anyhow::{anyhow, Context, Result};
use ris_core::decode::Decoded;
use ris_core::image::GrayImage;
use ris_core::sensor::Reconstructor;
use ris_core::single_shot::{self, Measured, ReferencePrediction, XPointPattern};
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
    pub fn cloud(&self, image: &GrayImage, rec: &Reconstructor) -> Result<Measured> {
        let predict = ReferencePrediction::new(&self.reference)
            .ok_or_else(|| anyhow!("the reference has no row codes"))?;
        let at = |x: f64, y: f64| predict.at(x, y);
        Ok(single_shot::measure(image, &self.pattern, Some(&at), rec))
    }
}
