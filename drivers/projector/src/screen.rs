//! The X screen the projectors are monitors of: the monitor list as RandR 1.5 reports it
//! (virtual monitors included, the order of `xrandr --listmonitors`), virtual monitors for a
//! test display, and what a monitor shows right now, read back from the screen.

use ris_drivers::{DriverError, ErrorKind, Result};
use x11rb::connection::Connection;
use x11rb::protocol::randr::{self, ConnectionExt as _};
use x11rb::protocol::xproto::{self, ConnectionExt as _};
use x11rb::rust_connection::RustConnection;

/// One monitor: a named rectangle of the screen.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Monitor {
    /// RandR name (`DP-1`, or the name given to a virtual monitor).
    pub name: String,
    /// Left edge on the screen, pixels.
    pub x: i16,
    /// Top edge, pixels.
    pub y: i16,
    /// Width, pixels.
    pub width: u16,
    /// Height, pixels.
    pub height: u16,
}

fn x_error(display: &str, what: &str, e: impl std::fmt::Display) -> DriverError {
    DriverError::new(ErrorKind::Failed, display, format!("{what}: {e}"))
}

/// A connection to the display (`None`: `DISPLAY`).
pub struct Screen {
    conn: RustConnection,
    root: xproto::Window,
    display: String,
}

impl Screen {
    /// Connect to `display` (`:99`), or to `DISPLAY` when `None`.
    pub fn connect(display: Option<&str>) -> Result<Screen> {
        let name = display
            .map(str::to_string)
            .or_else(|| std::env::var("DISPLAY").ok())
            .unwrap_or_else(|| "(DISPLAY unset)".into());
        let (conn, n) = RustConnection::connect(display).map_err(|e| {
            DriverError::new(
                ErrorKind::Unsupported,
                &name,
                format!("no X display (is DISPLAY set and an X server running?): {e}"),
            )
        })?;
        let root = conn
            .setup()
            .roots
            .get(n)
            .map(|s| s.root)
            .ok_or_else(|| x_error(&name, "screen", format!("no screen {n}")))?;
        Ok(Screen {
            conn,
            root,
            display: name,
        })
    }

    /// The active monitors in RandR's order.
    pub fn monitors(&self) -> Result<Vec<Monitor>> {
        let err = |e: &dyn std::fmt::Display| x_error(&self.display, "listing the monitors", e);
        let reply = self
            .conn
            .randr_get_monitors(self.root, true)
            .map_err(|e| err(&e))?
            .reply()
            .map_err(|e| err(&e))?;
        reply
            .monitors
            .iter()
            .map(|m| {
                let name = self
                    .conn
                    .get_atom_name(m.name)
                    .map_err(|e| err(&e))?
                    .reply()
                    .map_err(|e| err(&e))?
                    .name;
                Ok(Monitor {
                    name: String::from_utf8_lossy(&name).into_owned(),
                    x: m.x,
                    y: m.y,
                    width: m.width,
                    height: m.height,
                })
            })
            .collect()
    }

    /// Monitor `index`, or an error that lists the monitors there are.
    pub fn monitor(&self, index: usize) -> Result<Monitor> {
        let all = self.monitors()?;
        all.get(index).cloned().ok_or_else(|| {
            let names: Vec<String> = all
                .iter()
                .enumerate()
                .map(|(i, m)| format!("{i}: {} {}x{}+{}+{}", m.name, m.width, m.height, m.x, m.y))
                .collect();
            DriverError::new(
                ErrorKind::InvalidArgument,
                format!("{} monitor {index}", self.display),
                format!(
                    "no such monitor; the display has {} ({})",
                    all.len(),
                    names.join(", ")
                ),
            )
        })
    }

    /// Replace the virtual monitors with `monitors` (RandR `SetMonitor` without outputs, as
    /// `xrandr --setmonitor NAME W/0xH/0+X+Y none` does): how one large Xvfb screen becomes
    /// one monitor per projector. Monitors of real outputs are kept.
    pub fn set_virtual_monitors(&self, monitors: &[Monitor]) -> Result<()> {
        let err = |e: &dyn std::fmt::Display| x_error(&self.display, "setting the monitors", e);
        for m in monitors {
            let atom = self
                .conn
                .intern_atom(false, m.name.as_bytes())
                .map_err(|e| err(&e))?
                .reply()
                .map_err(|e| err(&e))?
                .atom;
            self.conn
                .randr_set_monitor(
                    self.root,
                    randr::MonitorInfo {
                        name: atom,
                        primary: false,
                        automatic: false,
                        x: m.x,
                        y: m.y,
                        width: m.width,
                        height: m.height,
                        width_in_millimeters: 0,
                        height_in_millimeters: 0,
                        outputs: Vec::new(),
                    },
                )
                .map_err(|e| err(&e))?
                .check()
                .map_err(|e| err(&e))?;
        }
        Ok(())
    }

    /// What `monitor` shows now, as 8-bit gray (the green channel; projector slides are gray),
    /// row-major, written into `out`.
    pub fn grab(&self, monitor: &Monitor, out: &mut Vec<u8>) -> Result<()> {
        let err = |e: &dyn std::fmt::Display| x_error(&self.display, "reading the screen", e);
        let reply = self
            .conn
            .get_image(
                xproto::ImageFormat::Z_PIXMAP,
                self.root,
                monitor.x,
                monitor.y,
                monitor.width,
                monitor.height,
                !0,
            )
            .map_err(|e| err(&e))?
            .reply()
            .map_err(|e| err(&e))?;
        let (w, h) = (usize::from(monitor.width), usize::from(monitor.height));
        let bpp = self
            .conn
            .setup()
            .pixmap_formats
            .iter()
            .find(|f| f.depth == reply.depth)
            .map(|f| usize::from(f.bits_per_pixel))
            .unwrap_or(32);
        if bpp != 32 || reply.data.len() < 4 * w * h {
            return Err(err(&format!(
                "a depth-{} image of {} bytes ({bpp} bits per pixel) for {w}x{h}; a 24/32-bit TrueColor screen is needed",
                reply.depth,
                reply.data.len()
            )));
        }
        out.clear();
        out.extend(reply.data.chunks_exact(4).take(w * h).map(|p| p[1]));
        Ok(())
    }
}
