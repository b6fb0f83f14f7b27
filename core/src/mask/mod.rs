//! The adaptive projection mask (SPEC §8, Ch. 4.4): per camera pixel, how much projector light
//! makes the camera read a target level (photo response from flat projections, Eq. 4.15), and
//! where in the projector that light must go (crosstalk: first through the reference plane,
//! Eq. 4.16, then from an advanced masked projection). These are the pure computations; the
//! loop that projects and captures runs through the driver traits.

mod crosstalk;
pub(crate) mod field;
mod response;

pub use crosstalk::{CodeMap, MaskBuild};
pub use field::{max_filter, min_filter};
pub use response::{feedback, Feedback, PhotoResponse};

/// Parameters of the mask computation.
#[derive(Clone, Debug)]
pub struct MaskParams {
    /// Camera level the bright stripe should reach (8-bit DN).
    pub target: f32,
    /// Camera level treated as saturated.
    pub saturation: f32,
    /// Smallest response to full projector white (DN above ambient) of a pixel that sees the
    /// projector at all.
    pub min_response: f32,
    /// Low percentile of the responses that the exposure is chosen for (the dark parts).
    pub exposure_percentile: f32,
    /// Highest exposure factor over the base exposure.
    pub max_exposure: f64,
    /// Lowest exposure factor.
    pub min_exposure: f64,
    /// Largest ambient level allowed at the chosen exposure, as a fraction of `target`
    /// (ambient light cannot be masked).
    pub ambient_limit: f32,
    /// Radius (projector pixels) the first-guess mask is dilated by: the largest shift of a
    /// correspondence off the reference plane (parts standing on it).
    pub dilation: u32,
    /// How far (camera pixels) a measured crosstalk shift is carried into pixels the advanced
    /// projection did not decode.
    pub fill_radius: u32,
    /// Most white/black feedback rounds under the mask before the final projection.
    pub feedback_rounds: u32,
    /// Feedback stops once fewer than this fraction of the pixels saturate.
    pub saturated_fraction: f32,
    /// Camera pixels around a saturated one whose levels feedback lowers too.
    pub feedback_spread: u32,
}

impl Default for MaskParams {
    fn default() -> Self {
        MaskParams {
            target: 200.0,
            saturation: 250.0,
            min_response: 3.0,
            exposure_percentile: 0.02,
            max_exposure: 32.0,
            min_exposure: 0.125,
            ambient_limit: 0.5,
            dilation: 40,
            fill_radius: 48,
            feedback_rounds: 4,
            saturated_fraction: 0.002,
            feedback_spread: 6,
        }
    }
}

/// Flat levels projected for the photo response (level 12 resolves highlights that saturate
/// at 50).
pub const FLAT_LEVELS: [u8; 7] = [0, 12, 50, 100, 150, 200, 250];
