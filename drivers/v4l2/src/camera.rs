//! A V4L2 capture device as a RIS [`Camera`]: the most faithful pixel format it offers (Y16,
//! GREY, YUYV, then MJPEG), manual exposure and gain through its controls, mmap streaming.
//!
//! UVC cameras have no trigger input: they run free. [`TriggerMode::Software`] is therefore
//! emulated: a trigger discards the frames already captured and the one in flight (its exposure
//! may have begun before the trigger), and the next frame is the triggered one. The cost is up
//! to two frame periods per trigger; the guarantee is that no frame exposed before the trigger
//! is delivered for it.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use ris_drivers::clock::now_ns;
use ris_drivers::{Camera, CameraInfo, DriverError, ErrorKind, Frame, Result, TriggerMode};
use v4l::buffer::Type;
use v4l::control::{Control, Value};
use v4l::io::mmap::Stream as MmapStream;
use v4l::io::traits::{CaptureStream, Stream};
use v4l::video::Capture;
use v4l::{Device, FourCC};

use crate::controls::{self, ControlRange};
use crate::convert::{to_gray, PixelFormat};

/// Buffers of the mmap stream.
const BUFFERS: u32 = 4;

/// The V4L2 capture devices present (`/dev/video*` nodes that capture), with their names.
pub fn devices() -> Vec<(PathBuf, String)> {
    v4l::context::enum_devices()
        .into_iter()
        .filter_map(|node| {
            let path = node.path().to_path_buf();
            let dev = Device::with_path(&path).ok()?;
            let caps = dev.query_caps().ok()?;
            caps.capabilities
                .contains(v4l::capability::Flags::VIDEO_CAPTURE)
                .then(|| (path, format!("{} ({})", caps.card, caps.driver)))
        })
        .collect()
}

/// A V4L2 camera.
pub struct V4l2Camera {
    path: PathBuf,
    device: Device,
    info: CameraInfo,
    format: PixelFormat,
    stride: usize,
    stream: Option<MmapStream<'static>>,
    trigger: TriggerMode,
    /// Frames to discard before the triggered one, per pending trigger.
    pending: Vec<u32>,
    exposure_us: f64,
    gain_db: f64,
    db_per_unit: Option<f64>,
    frame_id: u64,
}

fn err(kind: ErrorKind, path: &Path, message: impl Into<String>) -> DriverError {
    DriverError::new(kind, path.display().to_string(), message)
}

fn io_err(path: &Path, what: &str, e: std::io::Error) -> DriverError {
    let kind = match e.raw_os_error() {
        Some(19) | Some(6) => ErrorKind::Disconnected, // ENODEV, ENXIO: unplugged
        Some(16) => ErrorKind::Busy,                   // EBUSY: another process streams
        Some(22) | Some(34) => ErrorKind::InvalidArgument,
        _ if e.kind() == std::io::ErrorKind::TimedOut => ErrorKind::Timeout,
        _ if e.kind() == std::io::ErrorKind::NotFound => ErrorKind::Disconnected,
        _ => ErrorKind::Failed,
    };
    err(kind, path, format!("{what}: {e}"))
}

impl V4l2Camera {
    /// Open `path` (e.g. `/dev/video0`) at `size` (default: the device's current size) in the
    /// most faithful gray-convertible format it offers. `db_per_unit` gives its gain control a
    /// unit (see [`controls::gain_value`]).
    pub fn open(
        path: &Path,
        size: Option<(u32, u32)>,
        db_per_unit: Option<f64>,
    ) -> Result<V4l2Camera> {
        let device = Device::with_path(path).map_err(|e| io_err(path, "opening", e))?;
        let caps = device
            .query_caps()
            .map_err(|e| io_err(path, "querying capabilities", e))?;
        let offered = device
            .enum_formats()
            .map_err(|e| io_err(path, "listing formats", e))?;
        let format = offered
            .iter()
            .filter_map(|d| PixelFormat::from_fourcc(&d.fourcc.repr))
            .min_by_key(|f| f.rank())
            .ok_or_else(|| {
                let names: Vec<String> = offered.iter().map(|d| d.fourcc.to_string()).collect();
                err(
                    ErrorKind::Unsupported,
                    path,
                    format!("none of GREY, Y16, YUYV, MJPG among {names:?}"),
                )
            })?;
        let mut fmt = device
            .format()
            .map_err(|e| io_err(path, "reading the format", e))?;
        fmt.fourcc = FourCC::new(&format.fourcc());
        if let Some((w, h)) = size {
            fmt.width = w;
            fmt.height = h;
        }
        let fmt = device
            .set_format(&fmt)
            .map_err(|e| io_err(path, "setting the format", e))?;
        if fmt.fourcc.repr != format.fourcc() {
            return Err(err(
                ErrorKind::Unsupported,
                path,
                format!("asked for {:?}, the device chose {}", format, fmt.fourcc),
            ));
        }
        if let Some((w, h)) = size {
            if (fmt.width, fmt.height) != (w, h) {
                return Err(err(
                    ErrorKind::InvalidArgument,
                    path,
                    format!(
                        "asked for {w}x{h}, the device offers {}x{}",
                        fmt.width, fmt.height
                    ),
                ));
            }
        }
        let mut cam = V4l2Camera {
            path: path.to_path_buf(),
            info: CameraInfo {
                id: path.display().to_string(),
                model: format!("{} ({})", caps.card, caps.driver),
                width: fmt.width,
                height: fmt.height,
                bit_depth: format.bit_depth(),
            },
            device,
            format,
            stride: fmt.stride as usize,
            stream: None,
            trigger: TriggerMode::FreeRun,
            pending: Vec::new(),
            exposure_us: 0.0,
            gain_db: 0.0,
            db_per_unit,
            frame_id: 0,
        };
        // Manual exposure and gain: measurement needs them fixed. Devices without these
        // controls keep their own; reading the exposure back tells what it is.
        let _ = cam.set_control(controls::CID_EXPOSURE_AUTO, controls::EXPOSURE_MANUAL);
        let _ = cam.set_control(controls::CID_AUTOGAIN, 0);
        if let Ok(c) = cam.device.control(controls::CID_EXPOSURE_ABSOLUTE) {
            if let Value::Integer(v) = c.value {
                cam.exposure_us = controls::exposure_us(v);
            }
        }
        tracing::info!(device = %cam.info.id, model = %cam.info.model, format = ?format,
            width = cam.info.width, height = cam.info.height, "V4L2 camera open");
        Ok(cam)
    }

    fn range(&self, id: u32) -> Result<ControlRange> {
        let controls = self
            .device
            .query_controls()
            .map_err(|e| io_err(&self.path, "listing controls", e))?;
        let d = controls.iter().find(|d| d.id == id).ok_or_else(|| {
            err(
                ErrorKind::Unsupported,
                &self.path,
                format!("no control {id:#x}"),
            )
        })?;
        Ok(ControlRange {
            min: d.minimum,
            max: d.maximum,
            step: d.step.max(1) as i64,
        })
    }

    fn set_control(&self, id: u32, value: i64) -> Result<()> {
        self.device
            .set_control(Control {
                id,
                value: Value::Integer(value),
            })
            .map_err(|e| io_err(&self.path, &format!("setting control {id:#x}"), e))
    }

    /// Dequeue one frame within `timeout`, converted.
    fn dequeue(&mut self, timeout: Duration) -> Result<Frame> {
        let path = self.path.clone();
        let stream = self
            .stream
            .as_mut()
            .ok_or_else(|| err(ErrorKind::Busy, &path, "not streaming"))?;
        stream.set_timeout(timeout);
        let (buf, meta) = stream
            .next()
            .map_err(|e| io_err(&path, "waiting for a frame", e))?;
        let used = (meta.bytesused as usize).min(buf.len());
        let image = to_gray(
            self.format,
            self.info.width,
            self.info.height,
            self.stride,
            &buf[..used],
        )
        .map_err(|e| err(ErrorKind::Failed, &path, e.to_string()))?;
        let device_ns =
            (meta.timestamp.sec as u64) * 1_000_000_000 + (meta.timestamp.usec as u64) * 1_000;
        self.frame_id = u64::from(meta.sequence);
        Ok(Frame {
            image,
            bit_depth: self.info.bit_depth,
            frame_id: self.frame_id,
            host_ns: now_ns(),
            device_ns,
            exposure_us: self.exposure_us,
            gain_db: self.gain_db,
        })
    }
}

impl Camera for V4l2Camera {
    fn info(&self) -> &CameraInfo {
        &self.info
    }

    fn set_exposure_us(&mut self, us: f64) -> Result<()> {
        if !(us.is_finite() && us > 0.0) {
            return Err(err(
                ErrorKind::InvalidArgument,
                &self.path,
                format!("exposure {us} µs"),
            ));
        }
        let range = self.range(controls::CID_EXPOSURE_ABSOLUTE)?;
        let v = controls::exposure_value(us, &range)
            .map_err(|m| err(ErrorKind::InvalidArgument, &self.path, m))?;
        self.set_control(controls::CID_EXPOSURE_ABSOLUTE, v)?;
        self.exposure_us = controls::exposure_us(v);
        Ok(())
    }

    fn exposure_us(&self) -> f64 {
        self.exposure_us
    }

    fn set_gain_db(&mut self, db: f64) -> Result<()> {
        let range = self.range(controls::CID_GAIN)?;
        let v = controls::gain_value(db, &range, self.db_per_unit)
            .map_err(|m| err(ErrorKind::InvalidArgument, &self.path, m))?;
        self.set_control(controls::CID_GAIN, v)?;
        self.gain_db = db;
        Ok(())
    }

    fn set_trigger(&mut self, mode: TriggerMode) -> Result<()> {
        if self.stream.is_some() {
            return Err(err(
                ErrorKind::Busy,
                &self.path,
                "trigger mode while streaming",
            ));
        }
        if let TriggerMode::Hardware { source } = &mode {
            return Err(err(
                ErrorKind::Unsupported,
                &self.path,
                format!("V4L2 cameras have no trigger line ({source}); use software"),
            ));
        }
        self.trigger = mode;
        Ok(())
    }

    fn start(&mut self) -> Result<()> {
        if self.stream.is_some() {
            return Ok(());
        }
        let stream = MmapStream::with_buffers(&self.device, Type::VideoCapture, BUFFERS)
            .map_err(|e| io_err(&self.path, "allocating stream buffers", e))?;
        self.stream = Some(stream);
        self.pending.clear();
        Ok(())
    }

    fn stop(&mut self) -> Result<()> {
        if let Some(mut s) = self.stream.take() {
            Stream::stop(&mut s).map_err(|e| io_err(&self.path, "stopping the stream", e))?;
        }
        self.pending.clear();
        Ok(())
    }

    fn trigger(&mut self) -> Result<()> {
        if self.stream.is_none() {
            return Err(err(
                ErrorKind::Busy,
                &self.path,
                "trigger while not streaming",
            ));
        }
        if self.trigger != TriggerMode::Software {
            return Err(err(
                ErrorKind::Unsupported,
                &self.path,
                format!("software trigger in {:?} mode", self.trigger),
            ));
        }
        // Frames captured before now are not this trigger's; the one in flight may have been
        // exposed before it: discard what is ready, then one more.
        while self.dequeue(Duration::ZERO).is_ok() {}
        self.pending.push(1);
        Ok(())
    }

    fn next_frame(&mut self, timeout: Duration) -> Result<Frame> {
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if self.trigger == TriggerMode::Software && self.pending.is_empty() {
                // Free-running underneath: nothing is delivered without a trigger.
                std::thread::sleep(left);
                return Err(err(ErrorKind::Timeout, &self.path, "no trigger pending"));
            }
            let frame = self.dequeue(left)?;
            if self.trigger != TriggerMode::Software {
                return Ok(frame);
            }
            match self.pending.first_mut() {
                Some(skip) if *skip > 0 => *skip -= 1,
                _ => {
                    self.pending.remove(0);
                    return Ok(frame);
                }
            }
        }
    }

    fn reconnect(&mut self) -> Result<()> {
        let size = Some((self.info.width, self.info.height));
        let exposure = self.exposure_us;
        let trigger = self.trigger.clone();
        let fresh = V4l2Camera::open(&self.path, size, self.db_per_unit)?;
        *self = fresh;
        self.trigger = trigger;
        if exposure > 0.0 {
            self.set_exposure_us(exposure)?;
        }
        Ok(())
    }
}
