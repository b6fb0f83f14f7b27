//! How a pair measures from one frame: the X-point pattern of a structured-light pair
//! (generated once from the cell's `[single_shot]`, decoded with the Gray-code reference that
//! predicts where each X-point lies, reconstructed through the pair's sensor model), or the
//! ring pattern of an omnidirectional sensor; the slide that projects it, the computation of a
//! frame into a cloud, and the picture an operator watches (fusion image or panorama).

use std::sync::{Arc, Mutex};

use anyhow::{anyhow, Context, Result};
use ris_core::cloud::PointCloud;
use ris_core::decode::Decoded;
use ris_core::image::GrayImage;
use ris_core::omni::{panorama, OmniSensor, RingDecode, RingDecoder, RingParams};
use ris_core::sensor::Reconstructor;
use ris_core::single_shot::{
    self, fuse, DetectParams, Detector, FusionRange, ReferencePrediction, XPointPattern,
};
use ris_drivers::Slide;

use crate::config::SingleShotSection;

/// What a structured-light pair needs to measure from one frame.
pub struct PairSingleShot {
    /// The projected pattern.
    pub pattern: XPointPattern,
    /// The slide showing it.
    pub slide: Slide,
    reference: Arc<Decoded>,
    reconstructor: Arc<Reconstructor>,
    /// Kept from frame to frame: its working images are frame-sized.
    detector: Box<Mutex<Detector>>,
}

impl PairSingleShot {
    /// The pattern for a `width × height` projector; `reference` must carry row codes (they
    /// choose the code's repeat along the rows).
    pub fn new(
        sensor: &str,
        (width, height): (u32, u32),
        config: &SingleShotSection,
        reference: Arc<Decoded>,
        reconstructor: Arc<Reconstructor>,
    ) -> Result<PairSingleShot> {
        if reference.row.is_none() {
            return Err(anyhow!(
                "sensor {sensor}: its reference recording has no row codes, which single-shot decoding needs"
            ));
        }
        let pattern =
            XPointPattern::with_dense(width, height, config.step, &config.dense, 3, config.seed)
                .with_context(|| format!("sensor {sensor}: the X-point pattern"))?;
        // A step the camera cannot resolve gives empty clouds: refused here, with the reason,
        // so health names it instead of scans returning nothing. The finest step (a dense
        // region's, if any) is the one the detector must resolve.
        let finest = pattern.finest_step();
        let spacing = single_shot::camera_spacing(&reference, finest);
        if let Some(spacing) = spacing {
            let least = spacing[0].min(spacing[1]);
            if least < single_shot::MIN_CAMERA_SPACING {
                let scale = single_shot::MIN_CAMERA_SPACING / least;
                let what = if config.dense.is_empty() {
                    "[single_shot] step"
                } else {
                    "the finest step ([single_shot] step and dense regions)"
                };
                return Err(anyhow!(
                    "sensor {sensor}: X-points {:.1} × {:.1} camera pixels apart at {what} {finest:?}; the detector needs {} or more: a step of at least [{}, {}]",
                    spacing[0],
                    spacing[1],
                    single_shot::MIN_CAMERA_SPACING,
                    (f64::from(finest[0]) * scale).ceil(),
                    (f64::from(finest[1]) * scale).ceil()
                ));
            }
        }
        let slide = Slide::picture(width, height, &pattern.render());
        Ok(PairSingleShot {
            pattern,
            slide,
            reference,
            reconstructor,
            detector: Box::new(Mutex::new(Detector::new(
                spacing.map_or_else(DetectParams::default, DetectParams::for_spacing),
            ))),
        })
    }
}

/// What an omnidirectional sensor needs to measure from one frame: its sensor model, its ring
/// pattern's decoder (built once) and the slide showing the rings.
pub struct PairRings {
    sensor: OmniSensor,
    decoder: RingDecoder,
    /// The slide showing the rings.
    pub slide: Slide,
}

impl PairRings {
    /// The sensor's default ring pattern ([`OmniSensor::rings`]) and its decoder.
    pub fn new(name: &str, sensor: OmniSensor) -> Result<PairRings> {
        let rings = sensor
            .rings()
            .with_context(|| format!("sensor {name}: designing its ring pattern"))?;
        let decoder = RingDecoder::new(&sensor, &rings, RingParams::default())
            .with_context(|| format!("sensor {name}: the ring decoder"))?;
        let (w, h) = (sensor.projector.lens.width, sensor.projector.lens.height);
        let slide = Slide::picture(w, h, &rings.render());
        Ok(PairRings {
            sensor,
            decoder,
            slide,
        })
    }
}

/// How a pair measures from one frame.
pub enum OneShot {
    /// The X-point pattern of a structured-light pair.
    XPoint(Box<PairSingleShot>),
    /// The ring pattern of an omnidirectional sensor.
    Rings(Box<PairRings>),
}

/// One frame's cloud (sensor frame, mm) and what made it.
pub struct FrameCloud {
    /// The points.
    pub cloud: PointCloud,
    /// Seconds to detect and decode (reconstruction is the rest of the measurement).
    pub decode_s: f64,
    /// Primitives (X-points) or ring crossings found.
    pub detected: usize,
    rings: Option<RingDecode>,
}

impl OneShot {
    /// The slide to project.
    pub fn slide(&self) -> &Slide {
        match self {
            OneShot::XPoint(x) => &x.slide,
            OneShot::Rings(r) => &r.slide,
        }
    }

    /// Whether this is an omnidirectional sensor (every scan of it is one frame).
    pub fn is_omni(&self) -> bool {
        matches!(self, OneShot::Rings(_))
    }

    /// Detect, decode and reconstruct one camera `image`.
    pub fn measure(&self, image: &GrayImage) -> Result<FrameCloud> {
        match self {
            OneShot::XPoint(x) => {
                let predict = ReferencePrediction::new(&x.reference)
                    .ok_or_else(|| anyhow!("the reference has no row codes"))?;
                let at = |u: f64, v: f64| predict.at(u, v);
                let m = single_shot::measure(
                    &mut x.detector.lock().unwrap_or_else(|e| e.into_inner()),
                    image,
                    &x.pattern,
                    Some(&at),
                    &x.reconstructor,
                );
                tracing::debug!(detected = m.detected, stats = ?m.stats, "single-shot frame");
                Ok(FrameCloud {
                    cloud: m.cloud,
                    decode_s: m.decode_s,
                    detected: m.detected,
                    rings: None,
                })
            }
            OneShot::Rings(r) => {
                let d = r.decoder.decode(image).context("decoding the rings")?;
                tracing::debug!(
                    crossings = d.peaks,
                    arcs = d.arcs,
                    named = d.arcs_named,
                    ambiguous = d.ambiguous.len(),
                    points = d.points.len(),
                    "ring frame"
                );
                Ok(FrameCloud {
                    cloud: d.cloud(),
                    decode_s: d.decode_s,
                    detected: d.peaks,
                    rings: Some(d),
                })
            }
        }
    }

    /// The operator's picture of `frame` (measured from `image`) as PNG: the fusion image over
    /// the camera picture (X-points) or the unrolled panorama (rings), distances coloured by
    /// `range` (default: the frame's own spread); and the range used.
    pub fn picture(
        &self,
        image: &GrayImage,
        frame: &FrameCloud,
        range: Option<[f64; 2]>,
    ) -> Result<(Vec<u8>, FusionRange)> {
        let range = self.fusion_range(frame, range)?;
        Ok((self.picture_in(image, frame, range)?, range))
    }

    /// The range [`OneShot::picture`] colours `frame` by: `range`, or the frame's own spread.
    pub fn fusion_range(&self, frame: &FrameCloud, range: Option<[f64; 2]>) -> Result<FusionRange> {
        Ok(match range {
            Some([near, far]) => FusionRange::new(near, far, "[single_shot] range_mm")?,
            None => FusionRange::covering(&frame.cloud, self.eye()),
        })
    }

    /// The camera centre in the frame's cloud frame (the omnidirectional sensor's origin).
    fn eye(&self) -> [f64; 3] {
        match self {
            OneShot::XPoint(x) => {
                let c = x.reconstructor.camera().center();
                [c.x, c.y, c.z]
            }
            OneShot::Rings(_) => [0.0; 3],
        }
    }

    /// [`OneShot::picture`] coloured by a given `range`.
    pub fn picture_in(
        &self,
        image: &GrayImage,
        frame: &FrameCloud,
        range: FusionRange,
    ) -> Result<Vec<u8>> {
        let eye = self.eye();
        let png = match (self, &frame.rings) {
            (OneShot::XPoint(_), _) => fuse(image, &frame.cloud, eye, range, None)?.png()?,
            (OneShot::Rings(r), Some(d)) => panorama(&r.sensor, &r.decoder, image, d, range)?
                .fused
                .png()?,
            (OneShot::Rings(_), None) => return Err(anyhow!("the frame has no ring decoding")),
        };
        Ok(png)
    }
}
