//! The projector window under Xvfb (software Vulkan): `ris project` shows a pattern so that a
//! screen capture (`xwd -root`) equals it pixel for pixel, and the window passes the driver
//! conformance suite. Needs `xvfb`, `x11-apps` and `mesa-vulkan-drivers` (`.ci/run` installs
//! them).
#![cfg(feature = "projector")]

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use ris_core::pattern::{CodeLayout, Pattern};

#[path = "../../daemon/tests/common/mod.rs"]
mod common;
use common::Xvfb;

/// The root window as 8-bit (r, g, b) rows, from `xwd -root` (XWD version 7, ZPixmap,
/// 24-bit depth in 32-bit pixels).
fn capture_root(display: &str) -> (u32, u32, Vec<[u8; 3]>) {
    let out = Command::new("xwd")
        .args(["-root", "-silent", "-display", display])
        .output()
        .expect("xwd (apt-get install x11-apps)");
    assert!(out.status.success(), "xwd failed");
    let b = out.stdout;
    let field = |i: usize| u32::from_be_bytes([b[4 * i], b[4 * i + 1], b[4 * i + 2], b[4 * i + 3]]);
    let (header, version, format) = (field(0) as usize, field(1), field(2));
    assert_eq!((version, format), (7, 2), "XWD version 7, ZPixmap");
    let (width, height) = (field(4), field(5));
    let (byte_order, bits_per_pixel, bytes_per_line) = (field(7), field(11), field(12) as usize);
    let masks = (field(14), field(15), field(16));
    let colours = field(19) as usize;
    assert_eq!(bits_per_pixel, 32, "32-bit pixels");
    assert_eq!(masks, (0xff0000, 0xff00, 0xff), "RGB masks");
    let data = &b[header + 12 * colours..];
    let mut px = Vec::with_capacity((width * height) as usize);
    for y in 0..height as usize {
        for x in 0..width as usize {
            let o = y * bytes_per_line + 4 * x;
            let q = [data[o], data[o + 1], data[o + 2], data[o + 3]];
            let v = if byte_order == 0 {
                u32::from_le_bytes(q)
            } else {
                u32::from_be_bytes(q)
            };
            px.push([(v >> 16) as u8, (v >> 8) as u8, v as u8]);
        }
    }
    (width, height, px)
}

/// Run `ris project` with `args` on `display` until it prints `until`; the child keeps running.
fn ris_project(display: &str, args: &[&str], until: &str) -> (Child, Vec<String>) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_ris"))
        .arg("project")
        .args(args)
        .env("DISPLAY", display)
        .env("RIS_LOG", "warn")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("ris project");
    let stdout = child.stdout.take().expect("stdout");
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    let mut lines = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(60);
    while let Ok(line) = rx.recv_timeout(deadline.saturating_duration_since(Instant::now())) {
        let done = line.contains(until);
        lines.push(line);
        if done {
            return (child, lines);
        }
    }
    let _ = child.kill();
    let _ = child.wait();
    panic!("`ris project {args:?}` never printed {until:?}: {lines:?}");
}

#[test]
fn patterns_reach_the_screen_pixel_for_pixel_and_the_window_conforms() {
    let (w, h) = (1280u32, 800u32);
    let x = Xvfb::start(None, w, h).expect("Xvfb (.ci/run installs it)");
    let display = x.display();
    let layout = CodeLayout::new(w, h);
    // A stripe pattern (the acceptance case) and a mid grey, which an sRGB surface would
    // re-encode (77 → 149).
    for name in ["gray_col_04", "flat_077"] {
        let (mut child, _) = ris_project(
            &display,
            &["--pattern", name, "--projector", "1280x800", "--hold", "6"],
            "on monitor",
        );
        let (cw, ch, px) = capture_root(&display);
        let _ = child.kill();
        let _ = child.wait();
        assert_eq!((cw, ch), (w, h));
        let want = layout.render(Pattern::parse(name).expect("pattern"));
        let wrong: Vec<(usize, [u8; 3], u8)> = px
            .iter()
            .zip(&want)
            .enumerate()
            .filter(|(_, (got, want))| **got != [**want; 3])
            .map(|(i, (got, want))| (i, *got, *want))
            .take(5)
            .collect();
        assert!(
            wrong.is_empty(),
            "{name}: pixels differ (index, screen rgb, pattern): {wrong:?}"
        );
    }
    let (mut child, lines) = ris_project(
        &display,
        &["--projector", "1280x800", "--conformance"],
        "conformance: ok",
    );
    // stderr to its end (the child's exit) before waiting, so a full pipe cannot stall it.
    let mut stderr = String::new();
    if let Some(mut e) = child.stderr.take() {
        let _ = std::io::Read::read_to_string(&mut e, &mut stderr);
    }
    let status = child.wait().expect("wait");
    assert!(
        status.success(),
        "`ris project --conformance` ended with {status}; stdout {lines:?}; stderr: {stderr}"
    );
}
