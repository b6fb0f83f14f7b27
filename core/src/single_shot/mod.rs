//! Single-shot sensing (Ch. 4.2, 7.1.2, 7.2; SPEC §10): one projected frame, the X-point
//! pattern, gives a cloud, so moving parts and a robot's surroundings can be measured.

pub mod code;
mod cut;
mod decode;
mod detect;
mod fusion;
mod pattern;
mod reconstruct;

pub use cut::{drop_kinked, CUT_INSIDE, CUT_INSIDE_MAX, CUT_SHIFT, KINK_INSIDE, KINK_STRAIGHT};
pub use decode::{
    decode, Correspondence, DecodeStats, Predict, CUT_ASYMMETRY, CUT_ELONGATION, EDGE_MARGIN,
    INNER_ASYMMETRY, INNER_OFF, MIN_SIDES, OFF_GRID, REACH, SIDE_VOTES,
};
pub use detect::{detect, DetectParams, Detection, Detector, DISC_MARGIN, WHOLE_LEVEL};
pub use fusion::{fuse, fuse_from, Fused, FusionRange};
pub use pattern::{DenseRegion, Lattice, PatternSection, Primitives, XPointPattern, MIN_STEP};
pub use reconstruct::{
    camera_spacing, decode_frame, measure, reconstruct, Measured, ReferencePrediction,
    MIN_CAMERA_SPACING,
};
