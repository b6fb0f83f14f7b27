//! The adaptive projection-mask scan (SPEC §8, Ch. 4.4) through the driver traits, so the same
//! code drives the mock pair and real hardware:
//!
//! 1. flats at the base exposure → photo response; choose the exposure at which the dark parts
//!    reach the target; flats again there (dark pixels resolved), merged;
//! 2. desired level per camera pixel; first-guess crosstalk through the reference plane;
//!    the resulting mask dilated (true correspondences lie near the guess);
//! 3. advanced projection of Gray codes under that mask, decoded with extrapolation → the true
//!    camera → projector map (shifts carried into undecoded neighbours) → the final mask;
//! 4. final masked Gray codes at the chosen exposure → the capture set to decode.

use std::sync::Arc;

use ris_core::capture::CaptureSet;
use ris_core::decode::{decode, DecodeParams, Decoded};
use ris_core::mask::{feedback, CodeMap, MaskBuild, MaskParams, PhotoResponse, FLAT_LEVELS};
use ris_core::pattern::{CodeLayout, Pattern, ProjectionMask};

use crate::sequence::{acquire, Progress, SequenceError, SequenceParams};
use crate::{Camera, Projector, Slide};

/// Parameters of an adaptive scan.
#[derive(Clone, Debug, Default)]
pub struct AdaptiveParams {
    /// The mask computation.
    pub mask: MaskParams,
    /// Sequencing of every projection.
    pub sequence: SequenceParams,
    /// Decoding of the advanced projection (extrapolation is switched on for it).
    pub decode: DecodeParams,
    /// Extra advanced projections that re-measure the crosstalk under the latest mask.
    pub extra_rounds: u32,
}

/// Why an adaptive scan failed.
#[derive(Debug, thiserror::Error)]
pub enum AdaptiveError {
    /// A projection could not be recorded.
    #[error("{step}: {source}")]
    Sequence {
        /// The step of the loop.
        step: &'static str,
        /// What the sequencer said.
        #[source]
        source: SequenceError,
    },
    /// A computation had too little to work with.
    #[error("{step}: {source}")]
    Compute {
        /// The step of the loop.
        step: &'static str,
        /// What the core library said.
        #[source]
        source: ris_core::Error,
    },
    /// The camera refused the chosen exposure.
    #[error("setting the exposure to {exposure_us:.0} µs: {source}")]
    Exposure {
        /// The exposure asked for.
        exposure_us: f64,
        /// What the camera said.
        #[source]
        source: crate::DriverError,
    },
}

/// One step of the loop with its figures, for logs and state publications.
#[derive(Clone, Debug)]
pub struct StepReport {
    /// Step name.
    pub step: &'static str,
    /// Frames projected (including retries).
    pub frames: u64,
    /// Figures of the step.
    pub detail: String,
    /// Seconds of the step: its projections and the computation that follows them.
    pub seconds: f64,
}

/// The result of an adaptive scan.
#[derive(Clone, Debug)]
pub struct AdaptiveScan {
    /// The final masked capture, ready to decode.
    pub capture: CaptureSet,
    /// The final projection mask.
    pub mask: ProjectionMask,
    /// The camera → projector crosstalk the mask was built with.
    pub map: CodeMap,
    /// The per-camera-pixel levels the mask was built from (NaN: no say).
    pub levels: Vec<f32>,
    /// Exposure of the final capture, µs.
    pub exposure_us: f64,
    /// Exposure relative to the camera's setting at the start.
    pub exposure_factor: f64,
    /// Fraction of camera pixels whose crosstalk was measured (not guessed).
    pub measured_fraction: f32,
    /// Frames projected in total.
    pub frames: u64,
    /// Per step.
    pub steps: Vec<StepReport>,
}

/// Run the adaptive loop on one pair. `reference` is the decoded reference recording (with
/// row codes) that gives the first crosstalk guess. The camera's exposure is left at the
/// chosen value.
pub fn adaptive_scan(
    camera: &mut dyn Camera,
    projector: &mut dyn Projector,
    layout: &CodeLayout,
    reference: &Decoded,
    params: &AdaptiveParams,
    progress: &mut dyn FnMut(&'static str, Progress),
) -> Result<AdaptiveScan, AdaptiveError> {
    let mp = &params.mask;
    let mut steps = Vec::new();
    let mut mark = std::time::Instant::now();
    // Seconds since the previous step ended.
    let mut lap = move || {
        let now = std::time::Instant::now();
        let s = (now - mark).as_secs_f64();
        mark = now;
        s
    };
    let base_us = camera.exposure_us();
    let record = |step: &'static str,
                  camera: &mut dyn Camera,
                  projector: &mut dyn Projector,
                  slides: &[Slide],
                  progress: &mut dyn FnMut(&'static str, Progress)|
     -> Result<(CaptureSet, u64), AdaptiveError> {
        let acq = acquire(
            camera,
            projector,
            layout,
            slides,
            &params.sequence,
            &mut |p| progress(step, p),
        )
        .map_err(|source| AdaptiveError::Sequence { step, source })?;
        Ok((acq.capture, acq.report.shows))
    };
    let flats: Vec<Slide> = FLAT_LEVELS
        .iter()
        .map(|&l| Slide::plain(Pattern::Flat(l)))
        .collect();
    let response_of = |capture: &CaptureSet, exposure: f64| {
        let frames: Vec<(u8, &ris_core::image::GrayImage)> = FLAT_LEVELS
            .iter()
            .filter_map(|&l| capture.frame(Pattern::Flat(l)).map(|f| (l, f)))
            .collect();
        PhotoResponse::fit(&frames, exposure, mp.saturation)
    };

    // 1. Photo response at the base exposure, and the crosstalk wherever the camera already
    //    sees the codes there (plain Gray codes without inverses: pixel accuracy is enough).
    let (cap0, n0) = record("flats", camera, projector, &flats, progress)?;
    let r0 = response_of(&cap0, 1.0);
    let factor = r0.choose_exposure(mp);
    steps.push(StepReport {
        seconds: lap(),
        step: "flats",
        frames: n0,
        detail: format!("exposure ×{factor:.2} chosen for the dark parts"),
    });
    tracing::info!(
        exposure_factor = factor,
        "adaptive: photo response at base exposure"
    );
    let guess = CodeMap::reference_guess(reference).map_err(|source| AdaptiveError::Compute {
        step: "crosstalk guess",
        source,
    })?;
    let adv_params = DecodeParams {
        extrapolate: true,
        ..params.decode
    };
    let measure = |cap: &CaptureSet| -> Result<CodeMap, AdaptiveError> {
        let dec = decode(cap, &adv_params).map_err(|source| AdaptiveError::Compute {
            step: "crosstalk decode",
            source,
        })?;
        let mut map = CodeMap::from_decoded(&dec).map_err(|source| AdaptiveError::Compute {
            step: "crosstalk decode",
            source,
        })?;
        // Where white saturates, light spilled by inter-reflection can flip bits undetectably:
        // leave those pixels to a projection that does not saturate them.
        if let Some(white) = cap.frame(Pattern::White) {
            for (i, w) in white.to_levels().iter().enumerate() {
                if *w >= mp.saturation {
                    map.u[i] = f32::NAN;
                    map.v[i] = f32::NAN;
                }
            }
        }
        Ok(map)
    };
    let plain: Vec<Slide> = layout
        .sequence(true)
        .into_iter()
        .filter(|p| !matches!(p, Pattern::Gray { inverse: true, .. }))
        .map(Slide::plain)
        .collect();
    let (cap_a, na) = record(
        "crosstalk at base exposure",
        camera,
        projector,
        &plain,
        progress,
    )?;
    let measured_a = measure(&cap_a)?;
    let (map_a, fraction_a) = CodeMap::refined(&guess, &measured_a, mp);
    steps.push(StepReport {
        seconds: lap(),
        step: "crosstalk at base exposure",
        frames: na,
        detail: format!("measured on {:.1} % of the camera", 100.0 * fraction_a),
    });

    // 2. The chosen exposure; flats again there (the dark pixels resolved), merged.
    let exposure_us = base_us * factor;
    camera
        .set_exposure_us(exposure_us)
        .map_err(|source| AdaptiveError::Exposure {
            exposure_us,
            source,
        })?;
    let response = if (factor - 1.0).abs() > 0.1 {
        let (cap1, n1) = record("flats at exposure", camera, projector, &flats, progress)?;
        let r1 = response_of(&cap1, factor);
        steps.push(StepReport {
            seconds: lap(),
            step: "flats at exposure",
            frames: n1,
            detail: format!("{exposure_us:.0} µs"),
        });
        r0.at_exposure(factor).merged(&r1)
    } else {
        r0.at_exposure(factor)
    };
    let desired = response.desired_mask(mp);

    // 3. Advanced projection: pixels with a measured crosstalk place their level exactly; the
    //    others through the reference-plane guess over the dilation radius (their true
    //    position is near it): dark ones brighten that neighbourhood so they can be seen,
    //    bright ones darken it so they cannot saturate (saturation wins: it corrupts codes).
    let measured_a_ok: Vec<bool> = measured_a.u.iter().map(|u| u.is_finite()).collect();
    let saturated_a: Vec<bool> = match cap_a.frame(Pattern::White) {
        Some(w) => w.to_levels().iter().map(|&v| v >= mp.saturation).collect(),
        None => vec![false; desired.len()],
    };
    // Dark: unmeasured and wanting at least half the light; bright: saturated at the base
    // exposure already.
    let unmeasured = |dark: bool| -> Vec<f32> {
        (0..desired.len())
            .map(|i| {
                let d = desired[i];
                let pick = if dark {
                    !measured_a_ok[i] && d >= 0.5
                } else {
                    saturated_a[i]
                };
                if pick {
                    d
                } else {
                    f32::NAN
                }
            })
            .collect()
    };
    let mut mask = MaskBuild::splat(&map_a, &desired, layout.width, layout.height);
    let dark = MaskBuild::dilate(
        &MaskBuild::splat(&guess, &unmeasured(true), layout.width, layout.height),
        mp.dilation,
    );
    let bright = MaskBuild::splat_min(&guess, &unmeasured(false), layout.width, layout.height);
    let bright = MaskBuild::erode(&bright, mp.dilation);
    for ((m, d), b) in mask.values.iter_mut().zip(&dark.values).zip(&bright.values) {
        *m = m.max(*d).min(*b);
    }
    let gray: Vec<Pattern> = layout.sequence(true);
    let masked = |m: &ProjectionMask| -> Vec<Slide> {
        let m = Arc::new(m.clone());
        gray.iter()
            .map(|&p| Slide {
                pattern: p,
                mask: Some(m.clone()),
            })
            .collect()
    };
    let mut measured_fraction = fraction_a;
    let mut map = map_a.clone();
    for round in 0..=params.extra_rounds {
        let (cap, n) = record(
            "advanced projection",
            camera,
            projector,
            &masked(&mask),
            progress,
        )?;
        let measured_b = measure(&cap)?;
        let (refined, fraction) = CodeMap::refined(&guess, &measured_b.or(&measured_a), mp);
        measured_fraction = fraction;
        map = refined;
        mask = MaskBuild::splat(&map, &desired, layout.width, layout.height);
        let mean = mask.values.iter().sum::<f32>() / mask.values.len().max(1) as f32;
        tracing::info!(
            round,
            measured = fraction,
            mean_mask = mean,
            "adaptive: crosstalk measured"
        );
        steps.push(StepReport {
            seconds: lap(),
            step: "advanced projection",
            frames: n,
            detail: format!(
                "round {round}: crosstalk measured on {:.1} % of the camera, mean mask {mean:.3}",
                100.0 * fraction
            ),
        });
    }

    // 4. Feedback: white and black under the mask, levels corrected where the camera saturates
    //    or misses the target (inter-reflection, crosstalk errors), until few pixels saturate.
    let mut desired = desired;
    for round in 0..mp.feedback_rounds {
        let m = Arc::new(mask.clone());
        let slides = [Pattern::White, Pattern::Black].map(|p| Slide {
            pattern: p,
            mask: Some(m.clone()),
        });
        let (cap, n) = record("feedback", camera, projector, &slides, progress)?;
        let (Some(w), Some(b)) = (cap.frame(Pattern::White), cap.frame(Pattern::Black)) else {
            break;
        };
        let fb = feedback(&mut desired, w, b, mp.feedback_spread, mp);
        let saturated = fb.saturated as f32 / fb.considered.max(1) as f32;
        steps.push(StepReport {
            seconds: lap(),
            step: "feedback",
            frames: n,
            detail: format!(
                "round {round}: {:.2} % saturated, {:.1} % off target",
                100.0 * saturated,
                100.0 * fb.corrected as f32 / fb.considered.max(1) as f32
            ),
        });
        tracing::info!(
            round,
            saturated,
            corrected = fb.corrected,
            "adaptive: feedback"
        );
        if saturated < mp.saturated_fraction && fb.corrected * 20 < fb.considered {
            break;
        }
        mask = MaskBuild::splat(&map, &desired, layout.width, layout.height);
    }

    // 5. Final masked projection.
    let (capture, n) = record(
        "final projection",
        camera,
        projector,
        &masked(&mask),
        progress,
    )?;
    steps.push(StepReport {
        seconds: lap(),
        step: "final projection",
        frames: n,
        detail: format!("{} slides", gray.len()),
    });
    let frames = steps.iter().map(|s| s.frames).sum();
    tracing::info!(frames, exposure_us, "adaptive scan recorded");
    Ok(AdaptiveScan {
        capture,
        mask,
        map,
        levels: desired,
        exposure_us,
        exposure_factor: factor,
        measured_fraction,
        frames,
        steps,
    })
}
