//! Calibration (Ch. 3, Ch. 5.2.3): relating sensors to the cell frame with a marker gauge.

mod cell;
pub mod chessboard;
mod gauge;

pub use cell::{
    fit_gauge, overlap_consistency, GaugeFit, GaugeParams, MeasuredMarker, OverlapCheck,
    RejectedCluster,
};
pub use gauge::{Gauge, GaugeFile, MarkerSection};
