//! Losing the X server. Xlib's default I/O error handler prints "X connection broken" and calls
//! `exit(1)` from whichever thread noticed, which kills the daemon without a word (and, racing
//! the main thread's own exit, can crash it). The handler installed here instead records the
//! loss, logs it, and parks the display thread for good: every projector then fails with
//! [`ErrorKind::Disconnected`](ris_drivers::ErrorKind::Disconnected) naming the cause, and the
//! process goes on (reporting the pair failed) until it is restarted.
#![allow(unsafe_code)] // one FFI call (installing the handler) and the handler itself

use std::os::raw::c_int;
use std::sync::atomic::{AtomicBool, Ordering};

static LOST: AtomicBool = AtomicBool::new(false);

/// Whether the process's connection to the X server has broken.
pub(crate) fn lost() -> bool {
    LOST.load(Ordering::SeqCst)
}

/// Install the handler (process-wide, before the display thread opens its connection).
pub(crate) fn guard() -> Result<(), String> {
    let xlib = x11_dl::xlib::Xlib::open().map_err(|e| format!("loading Xlib: {e}"))?;
    // SAFETY: `on_io_error` has the signature Xlib expects and never returns.
    unsafe { (xlib.XSetIOErrorHandler)(Some(on_io_error)) };
    Ok(())
}

unsafe extern "C" fn on_io_error(_display: *mut x11_dl::xlib::Display) -> c_int {
    if !LOST.swap(true, Ordering::SeqCst) {
        tracing::error!(
            "the connection to the X server broke (server ended or restarted): projector windows are gone until risd restarts"
        );
    }
    // Xlib exits the process if this returns; the thread that noticed (the display thread)
    // sleeps instead, and the rest of the process sees `lost()`.
    loop {
        std::thread::park();
    }
}
