//! A GigE Vision camera on loopback whose images come from the caller: Aravis's own device-side
//! GigE Vision implementation (`ArvGvFakeCamera`, the one behind `arv-fake-gv-camera-0.8`) runs
//! in this process, and a fill callback replaces its test ramp. [`AravisCamera`] opens it by
//! address like any camera, so a scan through it exercises the real GigE Vision control and
//! stream protocol, the software trigger included, with simulated images.
//!
//! [`AravisCamera`]: crate::AravisCamera
#![allow(unsafe_code)] // one FFI call and its callback: Aravis's fill-pattern hook is unwrapped

use std::ffi::c_void;

use aravis::glib::translate::ToGlibPtr;
use ris_drivers::{DriverError, ErrorKind, Result};

/// Writes one frame: the buffer (width × height bytes, Mono8) to fill, width, height, and
/// the exposure the camera is set to (µs).
pub type Fill = dyn Fn(&mut [u8], u32, u32, f64) + Send + Sync;

/// The fake camera, serving on `interface` until dropped.
pub struct LoopbackCamera {
    /// Keeps the device side serving.
    _gv: aravis::GvFakeCamera,
    fake: aravis::FakeCamera,
    fill: *mut Box<Fill>,
}

// SAFETY: the GObjects are thread-safe reference-counted handles (Aravis drives them from its
// own threads); `fill` is owned by this value, `Send + Sync`, and only read by the callback.
unsafe impl Send for LoopbackCamera {}

impl LoopbackCamera {
    /// Serve a GigE Vision camera on `interface` (an address such as `127.0.0.1`, or an
    /// interface name), polling its software trigger at `trigger_hz`, with frames from `fill`.
    pub fn start(interface: &str, trigger_hz: f64, fill: Box<Fill>) -> Result<LoopbackCamera> {
        let device = format!("loopback:{interface}");
        crate::camera::library()
            .ok_or_else(|| DriverError::new(ErrorKind::Failed, &device, "Aravis did not start"))?;
        let gv = aravis::GvFakeCamera::new(Some(interface), Some("RIS-loopback"));
        let fake = gv.fake_camera().ok_or_else(|| {
            DriverError::new(ErrorKind::Failed, &device, "the fake has no camera model")
        })?;
        if trigger_hz.is_finite() && trigger_hz > 0.0 {
            fake.set_trigger_frequency(trigger_hz);
        }
        let fill = Box::into_raw(Box::new(fill));
        let raw: *mut aravis_sys::ArvFakeCamera = fake.to_glib_none().0;
        // SAFETY: `raw` is a live ArvFakeCamera (held by `fake`); `fill` stays valid until
        // `Drop` restores the default pattern (under the same mutex the callback runs in)
        // before freeing it.
        unsafe {
            aravis_sys::arv_fake_camera_set_fill_pattern(raw, Some(fill_frame), fill.cast());
        }
        if !gv.is_running() {
            // SAFETY: as above; nothing was filled, restore and free.
            unsafe {
                aravis_sys::arv_fake_camera_set_fill_pattern(raw, None, std::ptr::null_mut());
                drop(Box::from_raw(fill));
            }
            return Err(DriverError::new(
                ErrorKind::Failed,
                &device,
                format!("the GigE Vision fake could not serve on {interface}"),
            ));
        }
        tracing::info!(%interface, "loopback GigE Vision camera serving");
        Ok(LoopbackCamera {
            _gv: gv,
            fake,
            fill,
        })
    }

    /// Give up the current client's control, as a GigE Vision camera does when that client's
    /// heartbeats stop for the camera's heartbeat timeout: streaming stops (its registers still
    /// read) until a client takes control again.
    pub fn drop_control(&self) {
        self.fake.set_control_channel_privilege(0);
    }
}

impl Drop for LoopbackCamera {
    fn drop(&mut self) {
        let raw: *mut aravis_sys::ArvFakeCamera = self.fake.to_glib_none().0;
        // SAFETY: restoring the default pattern takes the fill mutex, so no callback is using
        // `fill` afterwards; then it is freed exactly once.
        unsafe {
            aravis_sys::arv_fake_camera_set_fill_pattern(raw, None, std::ptr::null_mut());
            drop(Box::from_raw(self.fill));
        }
    }
}

/// Aravis's fill-pattern callback: the caller's closure writes the frame.
unsafe extern "C" fn fill_frame(
    buffer: *mut aravis_sys::ArvBuffer,
    data: *mut c_void,
    exposure_us: u32,
    _gain: u32,
    pixel_format: aravis_sys::ArvPixelFormat,
) {
    if buffer.is_null() || data.is_null() || pixel_format != aravis_sys::ARV_PIXEL_FORMAT_MONO_8 {
        return;
    }
    // SAFETY: `data` is the `Box<Fill>` registered in `start`, alive while registered.
    let fill = unsafe { &*(data as *const Box<Fill>) };
    // SAFETY: `buffer` is the live buffer Aravis is filling; its part 0 was sized by the fake
    // (width × height) just before this call.
    let (width, height) = unsafe {
        (
            aravis_sys::arv_buffer_get_image_width(buffer),
            aravis_sys::arv_buffer_get_image_height(buffer),
        )
    };
    let mut received = 0usize;
    // SAFETY: as above; the pointer is the buffer's own allocation, which the fake writes in
    // place (its default pattern does the same). `received` is the size received so far (0
    // here), not the allocation.
    let ptr: *mut u8 = unsafe { aravis_sys::arv_buffer_get_data(buffer, &mut received) };
    let (w, h) = (width.max(0) as u32, height.max(0) as u32);
    let need = w as usize * h as usize;
    if ptr.is_null() || need == 0 {
        return;
    }
    // SAFETY: the fake calls the pattern only after checking that the allocation holds its
    // payload, which for Mono8 is width × height bytes; nothing else accesses the buffer
    // while the fake fills it.
    let pixels = unsafe { std::slice::from_raw_parts_mut(ptr, need) };
    fill(pixels, w, h, f64::from(exposure_us));
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use ris_drivers::{Camera, ErrorKind, TriggerMode};

    use super::*;
    use crate::{AravisCamera, DeviceSpec, OpenOptions};

    /// A camera that gave this client's control up (a heartbeat timeout) streams nothing while
    /// its registers still read: the silent stream is reported as a disconnect, not a late
    /// frame, so the acquisition reconnects (taking control again) instead of retrying the
    /// trigger until it gives up; after the reconnect, frames come again.
    #[test]
    fn a_camera_that_dropped_control_is_disconnected_and_a_reconnect_brings_frames() {
        let _one = crate::FAKE_CAMERAS
            .lock()
            .unwrap_or_else(|e| e.into_inner());
        let (w, h) = (64u32, 48u32);
        let gige = LoopbackCamera::start(
            "127.0.0.1",
            200.0,
            Box::new(move |buf: &mut [u8], fw: u32, fh: u32, _| {
                if (fw, fh) == (w, h) {
                    buf.fill(77);
                }
            }),
        )
        .expect("loopback GigE Vision camera");
        let mut cam = AravisCamera::open(
            DeviceSpec::parse("127.0.0.1"),
            OpenOptions {
                roi: Some((0, 0, w as i32, h as i32)),
                ..OpenOptions::default()
            },
        )
        .expect("camera on 127.0.0.1");
        cam.set_trigger(TriggerMode::Software)
            .expect("trigger mode");
        cam.start().expect("start");
        let frame = |cam: &mut AravisCamera| {
            cam.trigger().expect("trigger");
            cam.next_frame(Duration::from_secs(2))
        };
        frame(&mut cam).expect("a frame while in control");
        gige.drop_control();
        let e = frame(&mut cam).expect_err("no frame without control");
        assert_eq!(e.kind, ErrorKind::Disconnected, "{e}");
        assert!(e.to_string().contains("heartbeat"), "{e}");
        cam.reconnect().expect("reconnect");
        let f = frame(&mut cam).expect("a frame after the reconnect");
        assert_eq!((f.width(), f.height()), (w, h));
        // Reopened while this client still holds control (the sequencer's answer to a stream
        // that stays silent under a camera that still answers): control passes to the new
        // channel, and frames come on the new stream.
        cam.reconnect().expect("reconnect while in control");
        let f = frame(&mut cam).expect("a frame after reopening");
        assert_eq!((f.width(), f.height()), (w, h));
    }
}
