//! Calibration (Ch. 3, Ch. 5.2.3): relating sensors to the cell frame with a marker gauge.

mod camera;
mod cell;
pub mod chessboard;
mod gauge;
mod homography;
mod lm;
mod precision;
mod sensor;
mod session;

pub use camera::{
    calibrate_camera, BoardView, CameraCalibration, CameraParams, DroppedView, ViewResult,
};
pub use cell::{
    fit_gauge, overlap_consistency, GaugeFit, GaugeParams, MeasuredMarker, OverlapCheck,
    RejectedCluster,
};
pub use gauge::{Gauge, GaugeFile, MarkerSection};
pub use homography::{apply as apply_homography, homography};
pub use lm::{minimize, LmReport};
pub use precision::{precision, Precision};
pub use sensor::{
    calibrate_sensor, calibrate_sensor_with, fit_height_residual, ErrorStats, Gate, LayerReport,
    SensorCalibration, SensorParams, SensorReport,
};
pub use session::{BoardSection, Layer, LayerSection, Session, SessionFile};
