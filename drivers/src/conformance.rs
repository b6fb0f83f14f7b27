//! One conformance suite for every backend: what the sequencer and the daemon rely on from a
//! [`Camera`] or a [`Projector`], checked through the traits only. Each backend's tests run it
//! against the real thing (mock pair, Aravis's fake camera, the projector window under Xvfb).

use std::time::Duration;

use ris_core::pattern::Pattern;

use crate::{Camera, ErrorKind, Projector, Slide, TriggerMode};

/// The first broken promise, as a sentence naming the device.
pub type Verdict = std::result::Result<(), String>;

macro_rules! ensure {
    ($cond:expr, $($msg:tt)+) => {
        let holds: bool = $cond;
        if !holds {
            return Err(format!($($msg)+));
        }
    };
}

fn sized(id: &str, width: u32, height: u32) -> Verdict {
    ensure!(width > 0 && height > 0, "{id}: size {width}x{height}");
    Ok(())
}

/// A camera: sane info; exposure set and read back, invalid values refused as
/// `InvalidArgument`; in software-trigger mode no frame without a trigger (`Timeout`), one
/// frame per trigger of the advertised size with increasing ids, the exposure it was taken
/// with, and a host time on the sequencer's clock between its trigger and its arrival; stop
/// ends the stream. `timeout` bounds each wait for a frame.
pub fn camera(cam: &mut dyn Camera, timeout: Duration) -> Verdict {
    let info = cam.info().clone();
    let id = &info.id;
    sized(id, info.width, info.height)?;
    ensure!(
        (1..=16).contains(&info.bit_depth),
        "{id}: bit depth {}",
        info.bit_depth
    );
    for bad in [f64::NAN, -5.0, 0.0] {
        match cam.set_exposure_us(bad) {
            Err(e) if e.kind == ErrorKind::InvalidArgument => {}
            other => return Err(format!("{id}: exposure {bad} µs gave {other:?}")),
        }
    }
    let want = 5_000.0;
    cam.set_exposure_us(want)
        .map_err(|e| format!("{id}: exposure {want} µs refused: {e}"))?;
    let got = cam.exposure_us();
    ensure!(
        (got - want).abs() <= 0.05 * want,
        "{id}: exposure reads back {got} µs after setting {want} µs"
    );
    cam.set_trigger(TriggerMode::Software)
        .map_err(|e| format!("{id}: software trigger refused: {e}"))?;
    cam.start().map_err(|e| format!("{id}: start: {e}"))?;
    let result = (|| -> Verdict {
        match cam.next_frame(Duration::from_millis(300)) {
            Err(e) if e.kind == ErrorKind::Timeout => {}
            Ok(f) => return Err(format!("{id}: frame {} without a trigger", f.frame_id)),
            Err(e) => return Err(format!("{id}: waiting without a trigger gave {e}")),
        }
        let mut last: Option<(u64, u64)> = None;
        for k in 0..3 {
            let triggered = crate::clock::now_ns();
            cam.trigger()
                .map_err(|e| format!("{id}: trigger {k}: {e}"))?;
            let f = cam
                .next_frame(timeout)
                .map_err(|e| format!("{id}: frame of trigger {k}: {e}"))?;
            let received = crate::clock::now_ns();
            // One clock for the sequencer and every backend: a frame arrives after its
            // trigger and before now (a wall-clock or device time fails this).
            ensure!(
                (triggered..=received).contains(&f.host_ns),
                "{id}: frame {} stamped {} ns, outside its trigger {triggered} … arrival {received} (host_ns must be ris_drivers::clock::now_ns)",
                f.frame_id,
                f.host_ns
            );
            ensure!(
                (f.width(), f.height()) == (info.width, info.height),
                "{id}: frame {}x{} from a {}x{} camera",
                f.width(),
                f.height(),
                info.width,
                info.height
            );
            ensure!(
                f.bit_depth == info.bit_depth,
                "{id}: frame bit depth {} from a {}-bit camera",
                f.bit_depth,
                info.bit_depth
            );
            ensure!(
                (f.exposure_us - got).abs() <= 1e-6 * got.max(1.0),
                "{id}: frame says exposure {} µs, camera {got} µs",
                f.exposure_us
            );
            if let Some((fid, ns)) = last {
                ensure!(
                    f.frame_id > fid,
                    "{id}: frame id {} after {fid}",
                    f.frame_id
                );
                ensure!(
                    f.host_ns >= ns,
                    "{id}: host time went back ({} < {ns})",
                    f.host_ns
                );
            }
            last = Some((f.frame_id, f.host_ns));
        }
        // One frame per trigger: nothing else is queued.
        match cam.next_frame(Duration::from_millis(300)) {
            Err(e) if e.kind == ErrorKind::Timeout => Ok(()),
            Ok(f) => Err(format!(
                "{id}: extra frame {} after three triggers",
                f.frame_id
            )),
            Err(e) => Err(format!("{id}: waiting after the triggers gave {e}")),
        }
    })();
    let stopped = cam.stop().map_err(|e| format!("{id}: stop: {e}"));
    result?;
    stopped?;
    match cam.next_frame(Duration::from_millis(100)) {
        Ok(f) => Err(format!("{id}: frame {} after stop", f.frame_id)),
        Err(_) => Ok(()),
    }
}

/// A projector: sane info; nothing to show before a load (`InvalidArgument`); every loaded
/// slide shown on request with its slot, a sequence number growing by one per show and a
/// presentation time taken after the call began; slots past the loaded ones refused; a new
/// load replaces the old slides.
pub fn projector(p: &mut dyn Projector) -> Verdict {
    let info = p.info().clone();
    let id = &info.id;
    sized(id, info.width, info.height)?;
    match p.show(0) {
        Err(e) if e.kind == ErrorKind::InvalidArgument => {}
        other => return Err(format!("{id}: show before any load gave {other:?}")),
    }
    let slides = [
        Slide::plain(Pattern::White),
        Slide::plain(Pattern::Black),
        Slide::plain(Pattern::Flat(77)),
    ];
    p.load(&slides).map_err(|e| format!("{id}: load: {e}"))?;
    let mut last: Option<(u64, u64)> = None;
    for slot in [0, 2, 1, 2] {
        let before = crate::clock::now_ns();
        let shown = p
            .show(slot)
            .map_err(|e| format!("{id}: show {slot}: {e}"))?;
        ensure!(
            shown.slot == slot,
            "{id}: show {slot} says slot {}",
            shown.slot
        );
        ensure!(
            shown.presented_ns >= before,
            "{id}: slot {slot} presented at {} before the call at {before}",
            shown.presented_ns
        );
        if let Some((seq, ns)) = last {
            ensure!(
                shown.sequence == seq + 1,
                "{id}: sequence {} after {seq}",
                shown.sequence
            );
            ensure!(
                shown.presented_ns >= ns,
                "{id}: presentation time went back"
            );
        }
        last = Some((shown.sequence, shown.presented_ns));
    }
    match p.show(3) {
        Err(e) if e.kind == ErrorKind::InvalidArgument => {}
        other => return Err(format!("{id}: show 3 of 3 slides gave {other:?}")),
    }
    p.load(&slides[..1])
        .map_err(|e| format!("{id}: second load: {e}"))?;
    match p.show(1) {
        Err(e) if e.kind == ErrorKind::InvalidArgument => {}
        other => {
            return Err(format!(
                "{id}: show 1 after loading one slide gave {other:?}"
            ))
        }
    }
    p.show(0)
        .map(|_| ())
        .map_err(|e| format!("{id}: show 0 after the second load: {e}"))
}
