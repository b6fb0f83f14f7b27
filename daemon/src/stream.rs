//! Single-shot streams (SPEC §12, `ris/<cell>/stream`): each selected pair projects its X-point
//! pattern once and captures continuously; every frame becomes a cloud in the cell frame and a
//! fusion picture, published on `ris/<cell>/stream/<sensor>/cloud` and `.../fused` with the
//! frame's number and timestamp. Acquisition never waits for computation or for a slow
//! consumer: a frame that arrives while the previous one of its sensor is still waiting to be
//! computed replaces it (counted as dropped), and publications drop rather than block. The
//! latest cloud of each sensor answers `ris/<cell>/stream/<sensor>/point?u=..&v=..`.

use std::collections::BTreeMap;
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant, SystemTime};

use anyhow::{anyhow, Context, Result};
use ris_core::cloud::PointCloud;
use ris_core::image::GrayImage;
use ris_core::pattern::Pattern;
use ris_drivers::Slide;
use zenoh::qos::CongestionControl;
use zenoh::{Session, Wait};

use crate::cell::Cell;
use crate::protocol::{echo, stream_sensor_key, SensorCounts, StreamSpec, StreamStatus};

/// The latest computed frame of a sensor, for the pixel query.
pub struct Latest {
    /// Frame number within the stream (from 1).
    pub frame: u64,
    /// When the frame arrived, ns since the Unix epoch.
    pub timestamp_ns: u64,
    /// The cloud in the cell frame, organised on the camera's pixels.
    pub cloud: PointCloud,
}

/// What the service and the scan worker share about streams.
#[derive(Default)]
pub struct StreamControl {
    state: Mutex<ControlState>,
    latest: Mutex<BTreeMap<String, Arc<Latest>>>,
}

#[derive(Default)]
struct ControlState {
    wanted: Option<StreamSpec>,
    generation: u64,
    status: StreamStatus,
}

impl StreamControl {
    fn lock(&self) -> std::sync::MutexGuard<'_, ControlState> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Ask for `spec` to stream (replacing any running stream).
    pub fn start(&self, spec: StreamSpec) {
        let mut st = self.lock();
        st.generation += 1;
        st.status = StreamStatus {
            state: "streaming".into(),
            spec: Some(spec.clone()),
            sensors: spec
                .sensors
                .iter()
                .map(|s| (s.clone(), SensorCounts::default()))
                .collect(),
            error: None,
        };
        st.wanted = Some(spec);
    }

    /// Stop streaming; the status of the stream that ran.
    pub fn stop(&self) -> StreamStatus {
        let mut st = self.lock();
        st.generation += 1;
        st.wanted = None;
        if st.status.state != "failed" {
            st.status.state = "stopped".into();
        }
        st.status.clone()
    }

    /// The stream's status.
    pub fn status(&self) -> StreamStatus {
        self.lock().status.clone()
    }

    /// The stream wanted now and its generation.
    pub fn wanted(&self) -> Option<(StreamSpec, u64)> {
        let st = self.lock();
        st.wanted.clone().map(|w| (w, st.generation))
    }

    fn current(&self, generation: u64) -> bool {
        let st = self.lock();
        st.generation == generation && st.wanted.is_some()
    }

    /// The stream of `generation` ended on its own with `error`.
    fn failed(&self, generation: u64, error: String) {
        let mut st = self.lock();
        if st.generation == generation {
            st.wanted = None;
            st.status.state = "failed".into();
            st.status.error = Some(error);
        }
    }

    fn set_state(&self, generation: u64, state: &str) {
        let mut st = self.lock();
        if st.generation == generation && st.status.state != "failed" {
            st.status.state = state.into();
        }
    }

    fn count(&self, generation: u64, sensor: &str, f: impl FnOnce(&mut SensorCounts)) {
        let mut st = self.lock();
        if st.generation == generation {
            if let Some(c) = st.status.sensors.get_mut(sensor) {
                f(c);
            }
        }
    }

    /// The latest computed frame of `sensor`.
    pub fn latest(&self, sensor: &str) -> Option<Arc<Latest>> {
        self.latest
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .get(sensor)
            .cloned()
    }

    fn set_latest(&self, sensor: &str, latest: Latest) {
        self.latest
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .insert(sensor.to_string(), Arc::new(latest));
    }
}

/// The answer to a pixel query: the point of the latest cloud of `sensor` whose camera pixel
/// is nearest (u, v).
pub fn point_query(
    control: &StreamControl,
    sensor: &str,
    u: f64,
    v: f64,
) -> Result<String, String> {
    if !(u.is_finite() && v.is_finite()) {
        return Err("u and v must be numbers (camera pixels)".into());
    }
    let latest = control
        .latest(sensor)
        .ok_or_else(|| format!("no streamed frame of sensor {} yet", echo(sensor)))?;
    let [w, h] = latest.cloud.image.unwrap_or([0, 0]);
    if !(u >= -0.5 && v >= -0.5 && u < f64::from(w) - 0.5 && v < f64::from(h) - 0.5) {
        return Err(format!(
            "pixel ({u}, {v}) is outside the {w}x{h} camera image"
        ));
    }
    let best = latest
        .cloud
        .pixels
        .iter()
        .enumerate()
        .map(|(i, &p)| {
            let (x, y) = (f64::from(p % w.max(1)), f64::from(p / w.max(1)));
            (i, ((x - u).powi(2) + (y - v).powi(2)).sqrt(), x, y)
        })
        .min_by(|a, b| a.1.total_cmp(&b.1))
        .ok_or_else(|| format!("the latest frame of {} has no points", echo(sensor)))?;
    let (i, d, x, y) = best;
    let p = latest.cloud.points[i];
    Ok(serde_json::json!({
        "sensor": sensor,
        "frame": latest.frame,
        "timestamp_ns": latest.timestamp_ns,
        "asked": [u, v],
        "pixel": [x, y],
        "pixel_distance": d,
        "point_mm": [p[0], p[1], p[2]],
        "frame_of_point": "cell",
        "confidence": latest.cloud.confidence.get(i).copied().unwrap_or(1.0),
        // Outside the sensor's calibrated volume the point is an extrapolation: said, not hidden.
        "outside_volume": latest.cloud.outside.get(i).copied().unwrap_or(false),
    })
    .to_string())
}

/// Why a stream run returned.
pub enum StreamEnd<J> {
    /// Stopped or replaced by a request, or risd is stopping.
    Stopped,
    /// A scan job arrived: run it, then stream again.
    Job(J),
    /// The queue of jobs closed.
    Closed,
}

/// One slot per sensor holding its newest value: a put replaces a value not yet taken, and
/// takes go round the sensors so none starves. A slot taken is busy until [`Newest::done`]:
/// several workers may take from it, never two values of one sensor at once, so each sensor's
/// values are handled in the order they came.
struct Newest<T> {
    slots: Mutex<NewestState<T>>,
    ready: Condvar,
}

struct NewestState<T> {
    values: Vec<Option<T>>,
    busy: Vec<bool>,
    closed: bool,
    next: usize,
}

impl<T> Newest<T> {
    fn new(n: usize) -> Newest<T> {
        Newest {
            slots: Mutex::new(NewestState {
                values: (0..n).map(|_| None).collect(),
                busy: vec![false; n],
                closed: false,
                next: 0,
            }),
            ready: Condvar::new(),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, NewestState<T>> {
        self.slots.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Put `v` in slot `k`; true when it replaced one that was never taken.
    fn put(&self, k: usize, v: T) -> bool {
        let replaced = self.lock().values[k].replace(v).is_some();
        self.ready.notify_all();
        replaced
    }

    fn close(&self) {
        self.lock().closed = true;
        self.ready.notify_all();
    }

    /// The next value of a slot that is not busy, and the slot (busy until
    /// [`Newest::done`]); `None` once closed (what was not taken is dropped).
    fn take(&self) -> Option<(usize, T)> {
        let mut s = self.lock();
        loop {
            if s.closed {
                return None;
            }
            let n = s.values.len();
            for d in 0..n {
                let k = (s.next + d) % n;
                if s.busy[k] {
                    continue;
                }
                if let Some(v) = s.values[k].take() {
                    s.busy[k] = true;
                    s.next = (k + 1) % n;
                    return Some((k, v));
                }
            }
            s = self.ready.wait(s).unwrap_or_else(|e| e.into_inner());
        }
    }

    /// Slot `k`'s value taken is handled: its next may be taken.
    fn done(&self, k: usize) {
        self.lock().busy[k] = false;
        self.ready.notify_all();
    }
}

/// One captured frame on its way to computation.
struct Captured {
    frame: u64,
    timestamp_ns: u64,
    arrived: Instant,
    image: GrayImage,
}

/// What a stream publishes with.
pub struct Publish<'a> {
    /// The Zenoh session.
    pub session: &'a Session,
    /// Cell name.
    pub cell: &'a str,
    /// Whether risd is stopping.
    pub stopping: &'a (dyn Fn() -> bool + Sync),
    /// Called every round: the worker's sign of life.
    pub beat: &'a (dyn Fn() + Sync),
}

/// Run the stream `spec` (of `generation`) on `cell` until it is stopped or replaced, a job
/// arrives on `jobs`, or risd stops.
pub fn run<J>(
    cell: &mut Cell,
    spec: &StreamSpec,
    generation: u64,
    control: &StreamControl,
    out: &Publish,
    jobs: &std::sync::mpsc::Receiver<J>,
) -> StreamEnd<J> {
    let result = stream(cell, spec, generation, control, out, jobs);
    for p in cell.pairs.iter_mut() {
        if spec.sensors.contains(&p.name) {
            let _ = p.camera.stop();
        }
    }
    match result {
        Ok(end) => {
            if matches!(end, StreamEnd::Job(_)) {
                control.set_state(generation, "paused");
            }
            end
        }
        Err(e) => {
            let reason = format!("{e:#}");
            tracing::warn!(%reason, "stream failed");
            control.failed(generation, reason);
            StreamEnd::Stopped
        }
    }
}

fn stream<J>(
    cell: &mut Cell,
    spec: &StreamSpec,
    generation: u64,
    control: &StreamControl,
    out: &Publish,
    jobs: &std::sync::mpsc::Receiver<J>,
) -> Result<StreamEnd<J>> {
    cell.reconnect();
    let chosen: Vec<usize> = cell
        .pairs
        .iter()
        .enumerate()
        .filter(|(_, p)| spec.sensors.contains(&p.name))
        .map(|(i, _)| i)
        .collect();
    let mut groups: Vec<u32> = chosen.iter().map(|&i| cell.pairs[i].group).collect();
    groups.sort_unstable();
    groups.dedup();
    // Each pair shows its pattern (slot 0) while its exposure group captures, black (slot 1)
    // while another group does.
    for &i in &chosen {
        let p = &mut cell.pairs[i];
        let single = p.single_shot.clone().map_err(|why| anyhow!(why))?;
        let slides = [single.slide().clone(), Slide::plain(Pattern::Black)];
        p.projector
            .load(&slides)
            .with_context(|| format!("sensor {}: loading its single-shot pattern", p.name))?;
        p.projector
            .show(usize::from(groups.len() > 1))
            .with_context(|| format!("sensor {}: projecting", p.name))?;
        let _ = p.camera.stop();
        p.camera
            .set_trigger(p.sequence.trigger.clone())
            .with_context(|| format!("sensor {}: trigger", p.name))?;
        p.camera
            .start()
            .with_context(|| format!("sensor {}: starting the camera", p.name))?;
    }
    control.set_state(generation, "streaming");
    tracing::info!(sensors = ?spec.sensors, rate_hz = spec.rate_hz, "stream started");
    let slots: Newest<Captured> = Newest::new(chosen.len());
    let period = Duration::from_secs_f64(1.0 / spec.rate_hz);
    let computers: Vec<_> = chosen
        .iter()
        .map(|&i| {
            let p = &cell.pairs[i];
            (
                p.name.clone(),
                p.to_common,
                p.single_shot.clone().map_err(|why| anyhow!(why)),
                p.range_mm,
            )
        })
        .collect();
    // Workers measure the sensors' frames side by side (one frame of a sensor at a time, so its
    // clouds go out in order) and publish each cloud as soon as it is measured; its picture is
    // drawn and encoded by a worker of its own, off the path of the next frame (a picture
    // not yet drawn when the next is ready is replaced, like a frame).
    let pictures: Newest<Drawn> = Newest::new(chosen.len());
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let workers = chosen.len().min(cores).max(1);
    // Pictures are drawn by threads of their own at a lower priority: on a busy machine the
    // clouds keep their rate and the pictures take the time left (a picture not drawn before
    // its sensor's next is replaced).
    let painters = rayon::ThreadPoolBuilder::new()
        .num_threads(cores)
        .thread_name(|i| format!("risd-picture-{i}"))
        .start_handler(|_| lower_priority())
        .build()
        .context("starting the picture threads")?;
    std::thread::scope(|scope| -> Result<StreamEnd<J>> {
        let (slots, pictures, painters) = (&slots, &pictures, &painters);
        let computers = &computers;
        let compute: Vec<_> = (0..workers)
            .map(|_| {
                scope.spawn(move || {
                    while let Some((k, c)) = slots.take() {
                        match publish_cloud(&computers[k], c, generation, control, out) {
                            Ok(drawn) => {
                                pictures.put(k, drawn);
                            }
                            Err(e) => {
                                tracing::warn!(sensor = %computers[k].0, error = %format!("{e:#}"), "stream frame not published")
                            }
                        }
                        // Only now may the sensor's next frame be taken: its picture is put
                        // after this one's.
                        slots.done(k);
                    }
                })
            })
            .collect();
        let draw = scope.spawn(move || {
            while let Some((k, d)) = pictures.take() {
                if let Err(e) = painters.install(|| publish_picture(&computers[k], d, out)) {
                    tracing::warn!(sensor = %computers[k].0, error = %format!("{e:#}"), "stream picture not published");
                }
                pictures.done(k);
            }
        });
        let ended = (|| -> Result<StreamEnd<J>> {
            let mut numbers = vec![0u64; chosen.len()];
            let mut misses = vec![0u32; chosen.len()];
            let mut last_ns = vec![0u64; chosen.len()];
            // Rounds start on a fixed schedule (a late wake-up is made up by the next sleep, so
            // the rate asked is the rate kept); one more than a round behind starts it afresh.
            let mut due = Instant::now();
            loop {
                (out.beat)();
                if (out.stopping)() || !control.current(generation) {
                    return Ok(StreamEnd::Stopped);
                }
                match jobs.try_recv() {
                    Ok(job) => return Ok(StreamEnd::Job(job)),
                    Err(std::sync::mpsc::TryRecvError::Disconnected) => {
                        return Ok(StreamEnd::Closed)
                    }
                    Err(std::sync::mpsc::TryRecvError::Empty) => {}
                }
                for g in &groups {
                    if groups.len() > 1 {
                        for &i in &chosen {
                            let p = &mut cell.pairs[i];
                            p.projector
                                .show(usize::from(p.group != *g))
                                .with_context(|| format!("sensor {}: projecting", p.name))?;
                        }
                    }
                    for (k, &i) in chosen.iter().enumerate() {
                        let p = &mut cell.pairs[i];
                        if p.group != *g {
                            continue;
                        }
                        let frame = match grab(p) {
                            Ok(f) => {
                                misses[k] = 0;
                                f
                            }
                            Err(e) => {
                                let e = e.context(format!("sensor {}: streaming", p.name));
                                p.note_failure(&e);
                                let lost = p.state != crate::protocol::DriverState::Connected;
                                misses[k] += 1;
                                control.count(generation, &p.name, |c| c.missed += 1);
                                // A lost camera ends the stream at once (risd reopens it between
                                // jobs); a frame that did not come is skipped, three in a row end
                                // the stream.
                                if lost || misses[k] >= MAX_MISSES {
                                    return Err(e.context(format!(
                                        "{} frame(s) in a row not delivered",
                                        misses[k]
                                    )));
                                }
                                tracing::warn!(sensor = %p.name, error = %format!("{e:#}"), "stream frame missed");
                                continue;
                            }
                        };
                        let arrived = Instant::now();
                        let unix = SystemTime::now()
                            .duration_since(SystemTime::UNIX_EPOCH)
                            .map_or(0, |d| d.as_nanos() as u64);
                        // Timestamps of one sensor strictly increase, whatever the clock does.
                        let ts = unix.max(last_ns[k] + 1);
                        last_ns[k] = ts;
                        numbers[k] += 1;
                        let replaced = slots.put(
                            k,
                            Captured {
                                frame: numbers[k],
                                timestamp_ns: ts,
                                arrived,
                                image: frame,
                            },
                        );
                        control.count(generation, &p.name, |c| {
                            c.frames += 1;
                            c.dropped += u64::from(replaced);
                        });
                    }
                }
                due += period;
                let now = Instant::now();
                match due.checked_duration_since(now) {
                    Some(rest) => std::thread::sleep(rest),
                    None if now - due > period => due = now,
                    None => {}
                }
            }
        })();
        slots.close();
        let mut panicked = false;
        for c in compute {
            panicked |= c.join().is_err();
        }
        pictures.close();
        panicked |= draw.join().is_err();
        if panicked {
            return Err(anyhow!("a thread of the stream panicked"));
        }
        ended
    })
}

/// Frames in a row a pair may fail to deliver before its stream ends.
const MAX_MISSES: u32 = 3;

/// Nice value of the threads that draw the stream's pictures (the clouds' threads keep 0).
const PICTURE_NICE: i32 = 10;

/// Lower the calling thread's scheduling priority to [`PICTURE_NICE`] (Linux keeps a nice
/// value per thread); where that is refused the thread keeps its priority.
#[cfg(target_os = "linux")]
#[allow(unsafe_code)] // two libc calls on the calling thread, no pointers
fn lower_priority() {
    // SAFETY: gettid and setpriority take plain integers and touch no memory of ours.
    let done = unsafe {
        let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
        libc::setpriority(libc::PRIO_PROCESS, tid, PICTURE_NICE)
    };
    if done != 0 {
        tracing::debug!(
            error = %std::io::Error::last_os_error(),
            "the picture thread keeps its priority"
        );
    }
}

#[cfg(not(target_os = "linux"))]
fn lower_priority() {}

/// Trigger `p`'s camera once and wait for the frame.
fn grab(p: &mut crate::pair::Pair) -> Result<GrayImage> {
    if p.sequence.trigger == ris_drivers::TriggerMode::Software {
        p.camera.trigger().context("trigger")?;
    }
    let frame = p
        .camera
        .next_frame(p.sequence.timeout)
        .context("waiting for the frame")?;
    Ok(frame.image)
}

type Computer = (
    String,
    nalgebra::Matrix4<f64>,
    Result<Arc<crate::single_shot::OneShot>>,
    Option<[f64; 2]>,
);

/// A measured frame whose picture is still to be drawn.
struct Drawn {
    captured: Captured,
    measured: crate::single_shot::FrameCloud,
    range: ris_core::single_shot::FusionRange,
}

/// The attachment of a frame's publications: `{"frame", "timestamp_ns", "points",
/// "latency_ms", "range_mm"}`.
fn attachment(
    c: &Captured,
    points: usize,
    latency_ms: f64,
    range: &ris_core::single_shot::FusionRange,
) -> String {
    serde_json::json!({
        "frame": c.frame,
        "timestamp_ns": c.timestamp_ns,
        "points": points,
        "latency_ms": latency_ms,
        "range_mm": [range.near, range.far],
    })
    .to_string()
}

/// Measure one frame and publish its cloud (cell frame, binary PLY) with its
/// [`attachment`]; what its picture needs is returned.
fn publish_cloud(
    (name, to_common, single, range_mm): &Computer,
    c: Captured,
    generation: u64,
    control: &StreamControl,
    out: &Publish,
) -> Result<Drawn> {
    let single = single.as_ref().map_err(|e| anyhow!("{e:#}"))?;
    let f = single.measure(&c.image)?;
    let range = single.fusion_range(&f, *range_mm)?;
    let mut cloud = f.cloud.clone();
    for p in cloud.points.iter_mut() {
        let v = to_common
            * nalgebra::Vector4::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]), 1.0);
        *p = [v.x as f32, v.y as f32, v.z as f32];
    }
    let ply = cloud.to_ply();
    let points = cloud.len();
    let latency_ms = c.arrived.elapsed().as_secs_f64() * 1e3;
    let attachment = attachment(&c, points, latency_ms, &range);
    control.set_latest(
        name,
        Latest {
            frame: c.frame,
            timestamp_ns: c.timestamp_ns,
            cloud,
        },
    );
    put(out, name, "cloud", ply, attachment)?;
    control.count(generation, name, |s| {
        s.published += 1;
        s.points = points;
        s.latency_ms = latency_ms;
    });
    tracing::debug!(sensor = %name, frame = c.frame, points, latency_ms, "stream frame");
    Ok(Drawn {
        captured: c,
        measured: f,
        range,
    })
}

/// Draw a measured frame's picture (PNG: the fusion image, or an omni sensor's panorama) and
/// publish it with the frame's [`attachment`] (its latency: to the picture's publication).
fn publish_picture((name, _, single, _): &Computer, d: Drawn, out: &Publish) -> Result<()> {
    let single = single.as_ref().map_err(|e| anyhow!("{e:#}"))?;
    let png = single.picture_in(&d.captured.image, &d.measured, d.range)?;
    let latency_ms = d.captured.arrived.elapsed().as_secs_f64() * 1e3;
    let attachment = attachment(&d.captured, d.measured.cloud.len(), latency_ms, &d.range);
    put(out, name, "fused", png, attachment)
}

/// Publish `bytes` on the stream key `what` of sensor `name`, dropped rather than blocking a
/// slow link.
fn put(out: &Publish, name: &str, what: &str, bytes: Vec<u8>, attachment: String) -> Result<()> {
    let key = stream_sensor_key(out.cell, name, what);
    out.session
        .put(&key, bytes)
        .attachment(attachment)
        .congestion_control(CongestionControl::Drop)
        .wait()
        .map_err(|e| anyhow!("publishing {key}: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::StreamRequest;

    #[test]
    fn start_requests_are_checked() {
        let cell = ["s1".to_string(), "s2".to_string()];
        let r = |b: &str| StreamRequest::parse(b.as_bytes());
        let spec = r(r#"{"action": "start", "sensors": ["s2"], "rate": 5}"#)
            .expect("parse")
            .spec(&cell, 10.0)
            .expect("spec");
        assert_eq!(spec.sensors, ["s2"]);
        assert_eq!(spec.rate_hz, 5.0);
        let all = r(r#"{"action": "start"}"#)
            .expect("parse")
            .spec(&cell, 10.0);
        assert_eq!(all.expect("spec").sensors.len(), 2);
        for bad in [
            r#"{"rate": 0}"#,
            r#"{"rate": 1e9}"#,
            r#"{"sensors": []}"#,
            r#"{"sensors": ["s9"]}"#,
        ] {
            assert!(r(bad).expect("parse").spec(&cell, 10.0).is_err(), "{bad}");
        }
        for bad in ["[1]", "{\"x\": 1}", "nope"] {
            assert!(r(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn the_newest_frame_replaces_one_not_taken() {
        let slot = Newest::new(2);
        assert!(!slot.put(0, 1));
        assert!(slot.put(0, 2));
        assert!(!slot.put(1, 7));
        assert_eq!(slot.take(), Some((0, 2)));
        assert!(!slot.put(0, 3));
        // Round the sensors: slot 1 before slot 0 again.
        assert_eq!(slot.take(), Some((1, 7)));
        // Slot 0 is busy until its value is handled.
        slot.done(1);
        assert!(!slot.put(1, 8));
        assert_eq!(slot.take(), Some((1, 8)));
        slot.done(0);
        assert_eq!(slot.take(), Some((0, 3)));
        slot.close();
        assert_eq!(slot.take(), None);
    }

    #[test]
    fn workers_never_hold_two_values_of_one_slot() {
        let slot = Arc::new(Newest::new(2));
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::scope(|scope| {
            for _ in 0..3 {
                let (slot, tx) = (slot.clone(), tx.clone());
                scope.spawn(move || {
                    while let Some((k, v)) = slot.take() {
                        tx.send((k, v, true)).expect("send");
                        std::thread::sleep(Duration::from_micros(200));
                        tx.send((k, v, false)).expect("send");
                        slot.done(k);
                    }
                });
            }
            for v in 0..400u32 {
                slot.put((v % 2) as usize, v);
                if v % 7 == 0 {
                    std::thread::sleep(Duration::from_micros(300));
                }
            }
            std::thread::sleep(Duration::from_millis(20));
            slot.close();
        });
        drop(tx);
        let mut holding = [None::<u32>; 2];
        let mut last = [None::<u32>; 2];
        for (k, v, start) in rx {
            if start {
                assert_eq!(
                    holding[k], None,
                    "slot {k}: {v} taken while another is held"
                );
                assert!(
                    last[k].is_none_or(|l| v > l),
                    "slot {k}: {v} after {last:?}"
                );
                holding[k] = Some(v);
                last[k] = Some(v);
            } else {
                holding[k] = None;
            }
        }
        assert!(last.iter().all(Option::is_some), "both slots served");
    }
}
