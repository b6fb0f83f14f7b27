//! [`AravisCamera`]: the [`Camera`] trait over an Aravis `ArvCamera` and its stream.

use std::net::{IpAddr, UdpSocket};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use aravis::prelude::*;
use aravis::{AcquisitionMode, Buffer, BufferStatus, FakeDevice, GvDevice, PixelFormat, Stream};
use ris_core::image::GrayImage;
use ris_drivers::{Camera, CameraInfo, DriverError, ErrorKind, Frame, Result, TriggerMode};

/// Which device to open.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum DeviceSpec {
    /// A GigE Vision camera at this address, opened directly (no discovery broadcast).
    Ip(IpAddr),
    /// Aravis's in-process fake camera (no network at all).
    Fake,
    /// A device id as Aravis lists it (`Vendor-Serial`, USB3 Vision ids); looked up through
    /// Aravis's interfaces, which may send a discovery broadcast.
    Id(String),
}

impl DeviceSpec {
    /// `fake` / `Fake_1` → the fake camera; an IP address → direct GigE Vision; anything else is
    /// a device id.
    pub fn parse(text: &str) -> DeviceSpec {
        let t = text.trim();
        if t.eq_ignore_ascii_case("fake") || t == "Fake_1" {
            DeviceSpec::Fake
        } else if let Ok(ip) = t.parse::<IpAddr>() {
            DeviceSpec::Ip(ip)
        } else {
            DeviceSpec::Id(t.to_string())
        }
    }

    fn name(&self) -> String {
        match self {
            DeviceSpec::Ip(ip) => ip.to_string(),
            DeviceSpec::Fake => "Fake_1".into(),
            DeviceSpec::Id(id) => id.clone(),
        }
    }
}

/// The GigE Vision bootstrap register of the control channel privilege (GigE Vision 2.0,
/// table 28-1), and its control and exclusive-access bits.
const CONTROL_CHANNEL_PRIVILEGE: u64 = 0x0A00;
const CONTROL_BITS: u32 = 0b11;

/// Sample depth of the stream.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PixelDepth {
    /// Mono8.
    Mono8,
    /// Mono16 (stored as 16-bit frames).
    Mono16,
}

/// Settings applied at open and restored on reconnect.
#[derive(Clone, Debug)]
pub struct OpenOptions {
    /// Pixel format.
    pub depth: PixelDepth,
    /// Region of interest (x, y, width, height); `None` keeps the device's.
    pub roi: Option<(i32, i32, i32, i32)>,
    /// GigE Vision packet size, bytes (jumbo frames where the link allows).
    pub packet_size: Option<u32>,
    /// GigE Vision inter-packet delay, ns (four cameras sharing one link).
    pub packet_delay_ns: Option<i64>,
    /// Buffers in the stream's pool.
    pub buffers: usize,
    /// Acquisition frame rate to request, Hz (the fake camera polls its software trigger at
    /// this rate).
    pub frame_rate: Option<f64>,
}

impl Default for OpenOptions {
    fn default() -> Self {
        OpenOptions {
            depth: PixelDepth::Mono8,
            roi: None,
            packet_size: None,
            packet_delay_ns: None,
            buffers: 8,
            frame_rate: None,
        }
    }
}

/// Aravis's global state is initialised once per process.
pub(crate) fn library() -> Option<&'static aravis::Aravis> {
    static LIBRARY: OnceLock<Option<aravis::Aravis>> = OnceLock::new();
    LIBRARY
        .get_or_init(|| aravis::Aravis::initialize().ok())
        .as_ref()
}

/// Devices Aravis finds on every interface. This broadcasts a GigE Vision discovery on every
/// network interface of the machine: call it only when the user asks for discovery.
pub fn discover() -> Vec<(String, String, String)> {
    match library() {
        Some(lib) => lib
            .get_device_list()
            .into_iter()
            .map(|d| {
                (
                    d.id.to_string_lossy().into_owned(),
                    format!(
                        "{} {}",
                        d.vendor.to_string_lossy(),
                        d.model.to_string_lossy()
                    ),
                    d.address.to_string_lossy().into_owned(),
                )
            })
            .collect(),
        None => Vec::new(),
    }
}

/// A GigE Vision / USB3 Vision camera.
pub struct AravisCamera {
    spec: DeviceSpec,
    options: OpenOptions,
    camera: aravis::Camera,
    stream: Option<Stream>,
    payload: usize,
    info: CameraInfo,
    exposure_us: f64,
    gain_db: f64,
    trigger: TriggerMode,
}

fn failed(device: &str, what: &str, e: impl std::fmt::Display) -> DriverError {
    DriverError::new(ErrorKind::Failed, device, format!("{what}: {e}"))
}

/// The local address the system would use to reach `ip` (a connected UDP socket sends nothing).
fn interface_address(ip: IpAddr) -> Result<IpAddr> {
    let bind = if ip.is_ipv4() { "0.0.0.0:0" } else { "[::]:0" };
    let s = UdpSocket::bind(bind).map_err(|e| failed(&ip.to_string(), "route lookup", e))?;
    s.connect((ip, 3956))
        .map_err(|e| failed(&ip.to_string(), "no route to the camera", e))?;
    Ok(s.local_addr()
        .map_err(|e| failed(&ip.to_string(), "route lookup", e))?
        .ip())
}

fn open_device(spec: &DeviceSpec) -> Result<aravis::Camera> {
    let name = spec.name();
    // The token is only needed for discovery; initialising here keeps one init per process.
    let _ = library();
    let camera = match spec {
        DeviceSpec::Fake => {
            let dev = FakeDevice::new("1").map_err(|e| failed(&name, "fake device", e))?;
            aravis::Camera::with_device(&dev)
        }
        DeviceSpec::Ip(ip) => {
            let local = interface_address(*ip)?;
            let inet = |a: IpAddr| {
                gio::InetAddress::from_string(&a.to_string())
                    .ok_or_else(|| failed(&name, "address", a))
            };
            let dev = GvDevice::new(&inet(local)?, &inet(*ip)?).map_err(|e| {
                DriverError::new(
                    ErrorKind::Disconnected,
                    &name,
                    format!("no GigE Vision camera answers at {ip}: {e}"),
                )
            })?;
            aravis::Camera::with_device(&dev)
        }
        DeviceSpec::Id(id) => aravis::Camera::new(Some(id)),
    };
    camera.map_err(|e| {
        DriverError::new(
            ErrorKind::Disconnected,
            &name,
            format!("cannot open the camera: {e}"),
        )
    })
}

impl AravisCamera {
    /// Open `spec` and apply `options`.
    pub fn open(spec: DeviceSpec, options: OpenOptions) -> Result<AravisCamera> {
        let camera = open_device(&spec)?;
        let mut cam = AravisCamera {
            info: CameraInfo {
                id: spec.name(),
                model: String::new(),
                width: 0,
                height: 0,
                bit_depth: 8,
            },
            spec,
            options,
            camera,
            stream: None,
            payload: 0,
            exposure_us: 0.0,
            gain_db: 0.0,
            trigger: TriggerMode::FreeRun,
        };
        cam.configure()?;
        Ok(cam)
    }

    fn name(&self) -> String {
        self.info.id.clone()
    }

    /// Apply the open options and read back the format.
    fn configure(&mut self) -> Result<()> {
        let name = self.name();
        let c = &self.camera;
        // An acquisition that an earlier connection left running (this client's before a
        // reconnect, or a crashed one's) may stream to that connection's port; stopping it
        // makes the camera take the new stream's destination when this one starts. A camera
        // that refuses the command has nothing running.
        let _ = c.stop_acquisition();
        let format = match self.options.depth {
            PixelDepth::Mono8 => PixelFormat::MONO_8,
            PixelDepth::Mono16 => PixelFormat::MONO_16,
        };
        c.set_pixel_format(format).map_err(|e| {
            DriverError::new(
                ErrorKind::Unsupported,
                &name,
                format!("pixel format {:?}: {e}", self.options.depth),
            )
        })?;
        if let Some((x, y, w, h)) = self.options.roi {
            c.set_region(x, y, w, h).map_err(|e| {
                DriverError::new(
                    ErrorKind::InvalidArgument,
                    &name,
                    format!("region {x},{y} {w}x{h}: {e}"),
                )
            })?;
        }
        if c.is_gv_device() {
            if let Some(size) = self.options.packet_size {
                c.gv_set_packet_size(size as i32)
                    .map_err(|e| failed(&name, "packet size", e))?;
            }
            if let Some(delay) = self.options.packet_delay_ns {
                c.gv_set_packet_delay(delay)
                    .map_err(|e| failed(&name, "packet delay", e))?;
            }
        }
        if let Some(rate) = self.options.frame_rate {
            c.set_frame_rate(rate)
                .map_err(|e| failed(&name, "frame rate", e))?;
        }
        let (_, _, w, h) = c.region().map_err(|e| failed(&name, "region", e))?;
        let vendor = c.vendor_name().map(|s| s.to_string()).unwrap_or_default();
        let model = c.model_name().map(|s| s.to_string()).unwrap_or_default();
        self.info.model = format!("{vendor} {model}").trim().to_string();
        self.info.width = w.max(0) as u32;
        self.info.height = h.max(0) as u32;
        self.info.bit_depth = match self.options.depth {
            PixelDepth::Mono8 => 8,
            PixelDepth::Mono16 => 16,
        };
        self.payload = c.payload().map_err(|e| failed(&name, "payload", e))? as usize;
        self.exposure_us = c.exposure_time().unwrap_or(0.0);
        self.gain_db = c.gain().unwrap_or(0.0);
        Ok(())
    }

    /// Why a silent stream is a lost camera rather than a late frame: its control channel no
    /// longer answers, or (GigE Vision) it answers but this client no longer holds control. A
    /// camera that misses its controller's heartbeats for its timeout (a stalled host, a
    /// network hiccup) gives control up and stops streaming while its registers still read,
    /// so retrying the trigger never brings a frame; only reopening it (which takes control
    /// again) does.
    fn lost(&self) -> Option<&'static str> {
        if self.camera.exposure_time().is_err() {
            return Some("the camera stopped answering (control channel lost)");
        }
        let gv = self
            .camera
            .device()
            .and_then(|d| gio::glib::object::Cast::downcast::<GvDevice>(d).ok())?;
        match gv.read_register(CONTROL_CHANNEL_PRIVILEGE) {
            Ok((_, privilege)) if privilege & CONTROL_BITS == 0 => Some(
                "the camera gave up this client's control (a heartbeat timeout) and stopped streaming",
            ),
            Ok(_) => None,
            Err(_) => Some("the camera stopped answering (control channel lost)"),
        }
    }

    fn to_frame(&self, buffer: &Buffer, waited: Duration) -> Result<Frame> {
        let name = self.name();
        let (w, h) = (buffer.image_width(), buffer.image_height());
        let data = buffer.image_data();
        let (w, h) = (w.max(0) as u32, h.max(0) as u32);
        let n = (w * h) as usize;
        let image = match buffer.image_pixel_format() {
            f if f == PixelFormat::MONO_8 && data.len() >= n => {
                GrayImage::from_u8(w, h, data[..n].to_vec())
            }
            f if f == PixelFormat::MONO_16 && data.len() >= 2 * n => GrayImage::from_u16(
                w,
                h,
                data[..2 * n]
                    .chunks_exact(2)
                    .map(|b| u16::from_le_bytes([b[0], b[1]]))
                    .collect(),
            ),
            f => {
                return Err(DriverError::new(
                    ErrorKind::Unsupported,
                    &name,
                    format!(
                        "frame of {w}x{h} in pixel format 0x{:08x} with {} bytes; Mono8 and Mono16 are supported",
                        f.raw(),
                        data.len()
                    ),
                ))
            }
        };
        tracing::trace!(camera = %name, frame = buffer.frame_id(), ?waited, "frame");
        Ok(Frame {
            bit_depth: self.info.bit_depth,
            image,
            frame_id: buffer.frame_id(),
            // The sequencer's monotonic clock (Aravis's system timestamp is wall-clock time,
            // which no trigger time can be compared with).
            host_ns: ris_drivers::clock::now_ns(),
            device_ns: buffer.timestamp(),
            exposure_us: self.exposure_us,
            gain_db: self.gain_db,
        })
    }
}

impl Camera for AravisCamera {
    fn info(&self) -> &CameraInfo {
        &self.info
    }

    fn set_exposure_us(&mut self, us: f64) -> Result<()> {
        if !(us.is_finite() && us > 0.0) {
            return Err(DriverError::new(
                ErrorKind::InvalidArgument,
                self.name(),
                format!("exposure {us} µs must be positive"),
            ));
        }
        self.camera
            .set_exposure_time(us)
            .map_err(|e| failed(&self.name(), "exposure", e))?;
        self.exposure_us = self.camera.exposure_time().unwrap_or(us);
        Ok(())
    }

    fn exposure_us(&self) -> f64 {
        self.exposure_us
    }

    fn set_gain_db(&mut self, db: f64) -> Result<()> {
        self.camera
            .set_gain(db)
            .map_err(|e| failed(&self.name(), "gain", e))?;
        self.gain_db = self.camera.gain().unwrap_or(db);
        Ok(())
    }

    fn set_trigger(&mut self, mode: TriggerMode) -> Result<()> {
        if self.stream.is_some() {
            return Err(DriverError::new(
                ErrorKind::Busy,
                self.name(),
                "the trigger mode changes only while not streaming",
            ));
        }
        let name = self.name();
        let c = &self.camera;
        match &mode {
            TriggerMode::FreeRun => c
                .clear_triggers()
                .map_err(|e| failed(&name, "clear triggers", e))?,
            TriggerMode::Software => c.set_trigger("Software").map_err(|e| {
                DriverError::new(
                    ErrorKind::Unsupported,
                    &name,
                    format!("software trigger: {e}"),
                )
            })?,
            TriggerMode::Hardware { source } => c.set_trigger(source).map_err(|e| {
                DriverError::new(
                    ErrorKind::Unsupported,
                    &name,
                    format!("hardware trigger on {source}: {e}"),
                )
            })?,
        }
        self.trigger = mode;
        Ok(())
    }

    fn start(&mut self) -> Result<()> {
        if self.stream.is_some() {
            return Ok(());
        }
        let name = self.name();
        let stream = self
            .camera
            .create_stream()
            .map_err(|e| failed(&name, "stream", e))?;
        for _ in 0..self.options.buffers.max(2) {
            stream.push_buffer(Buffer::new_allocate(self.payload));
        }
        self.camera
            .set_acquisition_mode(AcquisitionMode::Continuous)
            .map_err(|e| failed(&name, "acquisition mode", e))?;
        self.camera
            .start_acquisition()
            .map_err(|e| failed(&name, "start acquisition", e))?;
        self.stream = Some(stream);
        Ok(())
    }

    fn stop(&mut self) -> Result<()> {
        if let Some(stream) = self.stream.take() {
            let r = self.camera.stop_acquisition();
            drop(stream);
            r.map_err(|e| {
                DriverError::new(ErrorKind::Disconnected, self.name(), format!("stop: {e}"))
            })?;
        }
        Ok(())
    }

    fn trigger(&mut self) -> Result<()> {
        if self.trigger != TriggerMode::Software {
            return Err(DriverError::new(
                ErrorKind::InvalidArgument,
                self.name(),
                "trigger() needs TriggerMode::Software",
            ));
        }
        self.camera.software_trigger().map_err(|e| {
            DriverError::new(
                ErrorKind::Disconnected,
                self.name(),
                format!("software trigger: {e}"),
            )
        })
    }

    fn next_frame(&mut self, timeout: Duration) -> Result<Frame> {
        let name = self.name();
        let Some(stream) = self.stream.as_ref() else {
            return Err(DriverError::new(
                ErrorKind::InvalidArgument,
                name,
                "next_frame() before start()",
            ));
        };
        let t0 = Instant::now();
        let deadline = t0 + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            let popped = if left.is_zero() {
                stream.try_pop_buffer()
            } else {
                stream.timeout_pop_buffer(left.as_micros() as u64)
            };
            let Some(buffer) = popped else {
                // A silent stream is a timeout while the camera still answers to this client,
                // a disconnect when its control channel, or its control, is gone.
                return Err(match self.lost() {
                    None => DriverError::new(
                        ErrorKind::Timeout,
                        name,
                        format!("no frame within {} ms", timeout.as_millis()),
                    ),
                    Some(why) => DriverError::new(ErrorKind::Disconnected, name, why),
                });
            };
            let status = buffer.status();
            let result = if status == BufferStatus::Success {
                Some(self.to_frame(&buffer, t0.elapsed()))
            } else {
                tracing::warn!(camera = %name, ?status, frame = buffer.frame_id(), "incomplete frame dropped");
                None
            };
            stream.push_buffer(buffer);
            if let Some(r) = result {
                return r;
            }
            if Instant::now() >= deadline {
                return Err(DriverError::new(
                    ErrorKind::Timeout,
                    name,
                    format!("only incomplete frames within {} ms", timeout.as_millis()),
                ));
            }
        }
    }

    fn reconnect(&mut self) -> Result<()> {
        let streaming = self.stream.is_some();
        self.stream = None;
        // A camera that still answers and still takes this client for its controller (its
        // stream stopped under a live control channel) admits no second controller: control is
        // given up first, so that the new channel takes it and opens a new stream.
        if let Some(gv) = self
            .camera
            .device()
            .and_then(|d| gio::glib::object::Cast::downcast::<GvDevice>(d).ok())
            .filter(|gv| gv.is_controller())
        {
            let _ = gv.leave_control();
        }
        self.camera = open_device(&self.spec)?;
        self.configure()?;
        let (exposure, gain, trigger) = (self.exposure_us, self.gain_db, self.trigger.clone());
        if exposure > 0.0 {
            self.set_exposure_us(exposure)?;
        }
        self.set_gain_db(gain).ok();
        self.trigger = TriggerMode::FreeRun;
        self.set_trigger(trigger)?;
        if streaming {
            self.start()?;
        }
        tracing::info!(camera = %self.name(), "reconnected");
        Ok(())
    }
}

impl Drop for AravisCamera {
    fn drop(&mut self) {
        let _ = self.stop();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn device_specs_parse() {
        assert_eq!(DeviceSpec::parse("fake"), DeviceSpec::Fake);
        assert_eq!(DeviceSpec::parse("Fake_1"), DeviceSpec::Fake);
        assert_eq!(
            DeviceSpec::parse("127.0.0.1"),
            DeviceSpec::Ip("127.0.0.1".parse().expect("ip"))
        );
        assert_eq!(
            DeviceSpec::parse("Basler-21234567"),
            DeviceSpec::Id("Basler-21234567".into())
        );
    }

    #[test]
    fn the_fake_camera_streams_triggered_frames() {
        let _one = crate::FAKE_CAMERAS
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        let mut cam = AravisCamera::open(
            DeviceSpec::Fake,
            OpenOptions {
                frame_rate: Some(200.0),
                ..OpenOptions::default()
            },
        )
        .expect("fake camera");
        assert_eq!((cam.info().width, cam.info().height), (512, 512));
        cam.set_exposure_us(2000.0).expect("exposure");
        assert!(
            (cam.exposure_us() - 2000.0).abs() < 1.0,
            "{}",
            cam.exposure_us()
        );
        cam.set_trigger(TriggerMode::Software)
            .expect("trigger mode");
        cam.start().expect("start");
        assert_eq!(
            cam.set_trigger(TriggerMode::FreeRun)
                .expect_err("busy")
                .kind,
            ErrorKind::Busy
        );
        for _ in 0..3 {
            cam.trigger().expect("trigger");
            let f = cam.next_frame(Duration::from_secs(2)).expect("frame");
            assert_eq!((f.width(), f.height(), f.bit_depth), (512, 512, 8));
            assert!(f.device_ns > 0 && f.host_ns > 0);
        }
        cam.stop().expect("stop");
        let e = cam
            .next_frame(Duration::from_millis(10))
            .map(|f| f.frame_id)
            .expect_err("not streaming");
        assert_eq!(e.kind, ErrorKind::InvalidArgument, "{e}");
    }
}
