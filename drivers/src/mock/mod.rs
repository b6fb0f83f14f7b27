//! The mock backend: a projector and camera pair driven by the simulator (the camera renders
//! what the projector currently shows, with the scene's materials), by the room renderer of an
//! omnidirectional sensor (camera and projector behind their mirrors), or by a recorded capture
//! set (replay), with injectable faults so tests can prove the sequencer copes with them.

mod faults;

pub use faults::{Fault, FaultInjector};

use std::collections::VecDeque;
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use ris_core::capture::CaptureSet;
use ris_core::omni::scene::OmniScene;
use ris_core::pattern::CodeLayout;
use ris_core::sim::Simulator;

use crate::clock::now_ns;
use crate::{
    Camera, CameraInfo, DriverError, ErrorKind, Frame, Projector, ProjectorInfo, Result, Shown,
    Slide, TriggerMode,
};

/// Exposure (µs) at which the simulated camera renders with the scene's own `exposure`.
pub const NOMINAL_EXPOSURE_US: f64 = 10_000.0;

/// What the mock camera sees.
enum Source {
    Sim(Arc<Simulator>),
    Omni(Arc<OmniScene>),
    Replay(Arc<CaptureSet>),
}

struct State {
    slides: Vec<Slide>,
    showing: Option<usize>,
    /// The slide shown before `showing`, and when `showing` was asked for (for a slow projector).
    previous: Option<usize>,
    shown_at: Option<std::time::Instant>,
    latency: std::time::Duration,
    show_seq: u64,
    streaming: bool,
    trigger: TriggerMode,
    exposure_us: f64,
    gain_db: f64,
    queue: VecDeque<Frame>,
    late: Option<Frame>,
    next_id: u64,
    triggers: u64,
    connected: bool,
    /// The stream stopped ([`Fault::StreamStall`]) until a reconnect.
    stalled: bool,
    faults: Vec<(u64, Fault)>,
    reconnectable: bool,
    /// Scans of the cell begun (a wearing scene's dent deepens with each).
    scans: u64,
}

struct Shared {
    state: Mutex<State>,
    arrived: Condvar,
    source: Source,
    layout: CodeLayout,
    seed: u64,
    /// When the pair was opened: the clock of a moving scene.
    opened: std::time::Instant,
    /// A wearing scene as it is in the current scan (built once per scan).
    worn: Mutex<Option<(u64, Arc<Simulator>)>>,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, State> {
        // A panic while holding the lock leaves plain data behind; keep serving it.
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// `sim`'s scene worn as in scan `scans`.
    fn worn(&self, sim: &Simulator, scans: u64) -> Arc<Simulator> {
        let mut w = self.worn.lock().unwrap_or_else(|e| e.into_inner());
        match &*w {
            Some((n, s)) if *n == scans => s.clone(),
            _ => {
                let s = Arc::new(Simulator::new(sim.scene.worn(scans)));
                *w = Some((scans, s.clone()));
                s
            }
        }
    }
}

/// The simulated (or replayed) camera of a mock pair.
pub struct MockCamera {
    shared: Arc<Shared>,
    info: CameraInfo,
}

/// The mock projector of a pair: it only records what it shows.
pub struct MockProjector {
    shared: Arc<Shared>,
    info: ProjectorInfo,
    camera_id: String,
}

/// A pair whose camera renders `sim`'s scene lit by whatever the projector shows; a scene
/// with moving objects is rendered where they are at each trigger (seconds since the pair
/// opened). `seed` varies the noise between pairs and scans.
pub fn simulated_pair(
    sim: Arc<Simulator>,
    id: &str,
    seed: u64,
) -> (MockCamera, MockProjector, FaultInjector) {
    let layout = sim.layout();
    let (w, h) = (sim.scene.camera.width, sim.scene.camera.height);
    pair(Source::Sim(sim), layout, (w, h), id, seed)
}

/// An omnidirectional pair: its camera renders `scene`'s room, seen through the camera's
/// mirror and lit through the projector's mirror by whatever the projector shows. `seed`
/// varies the noise between pairs and frames.
pub fn omni_pair(
    scene: Arc<OmniScene>,
    id: &str,
    seed: u64,
) -> (MockCamera, MockProjector, FaultInjector) {
    let (c, p) = (&scene.sensor.camera.lens, &scene.sensor.projector.lens);
    let layout = CodeLayout::new(p.width, p.height);
    let size = (c.width, c.height);
    pair(Source::Omni(scene), layout, size, id, seed)
}

/// A pair whose camera serves the recorded frame of whatever pattern the projector shows
/// (masks and exposure are ignored: the recording is what it is).
pub fn replay_pair(
    capture: Arc<CaptureSet>,
    id: &str,
) -> (MockCamera, MockProjector, FaultInjector) {
    let layout = capture.layout;
    let size = (capture.width, capture.height);
    pair(Source::Replay(capture), layout, size, id, 0)
}

fn pair(
    source: Source,
    layout: CodeLayout,
    (width, height): (u32, u32),
    id: &str,
    seed: u64,
) -> (MockCamera, MockProjector, FaultInjector) {
    let shared = Arc::new(Shared {
        state: Mutex::new(State {
            slides: Vec::new(),
            showing: None,
            previous: None,
            shown_at: None,
            latency: std::time::Duration::ZERO,
            show_seq: 0,
            streaming: false,
            trigger: TriggerMode::Software,
            exposure_us: NOMINAL_EXPOSURE_US,
            gain_db: 0.0,
            queue: VecDeque::new(),
            late: None,
            next_id: 1,
            triggers: 0,
            connected: true,
            stalled: false,
            faults: Vec::new(),
            reconnectable: true,
            scans: 0,
        }),
        arrived: Condvar::new(),
        source,
        layout,
        seed,
        opened: std::time::Instant::now(),
        worn: Mutex::new(None),
    });
    let camera = MockCamera {
        shared: shared.clone(),
        info: CameraInfo {
            id: format!("{id}/camera"),
            model: match shared.source {
                Source::Sim(_) => "RIS simulated camera".into(),
                Source::Omni(_) => "RIS simulated omnidirectional camera".into(),
                Source::Replay(_) => "RIS replay camera".into(),
            },
            width,
            height,
            bit_depth: 8,
        },
    };
    let projector = MockProjector {
        shared: shared.clone(),
        info: ProjectorInfo {
            id: format!("{id}/projector"),
            width: layout.width,
            height: layout.height,
        },
        camera_id: camera.info.id.clone(),
    };
    (camera, projector, FaultInjector { shared })
}

impl MockCamera {
    fn err(&self, kind: ErrorKind, message: impl Into<String>) -> DriverError {
        DriverError::new(kind, &self.info.id, message)
    }

    fn check_connected(&self, st: &State) -> Result<()> {
        if st.connected {
            Ok(())
        } else {
            Err(self.err(ErrorKind::Disconnected, "device not responding"))
        }
    }

    fn expose(&self, st: &mut State) -> Result<()> {
        expose(&self.shared, st, &self.info.id)
    }
}

/// Expose one frame of what the projector shows now, applying any fault planned for this
/// exposure, and queue it.
fn expose(shared: &Shared, st: &mut State, camera: &str) -> Result<()> {
    let err = |kind, message: String| DriverError::new(kind, camera, message);
    let index = st.triggers;
    st.triggers += 1;
    if let Some(late) = st.late.take() {
        st.queue.push_back(late);
    }
    let fault = st
        .faults
        .iter()
        .position(|(at, _)| *at == index)
        .map(|i| st.faults.remove(i).1);
    if fault == Some(Fault::Disconnect) {
        st.connected = false;
        return Err(err(
            ErrorKind::Disconnected,
            "link lost during trigger".into(),
        ));
    }
    if fault == Some(Fault::StreamStall) {
        st.stalled = true;
    }
    if st.stalled {
        tracing::debug!(camera, index, "mock: the stream is stalled");
        return Ok(());
    }
    if fault == Some(Fault::MissedTrigger) {
        tracing::debug!(camera, index, "mock: trigger ignored");
        return Ok(());
    }
    let id = st.next_id;
    st.next_id += 1;
    if fault == Some(Fault::DropFrame) {
        tracing::debug!(camera, index, id, "mock: frame dropped");
        return Ok(());
    }
    let mut slot = st.showing.ok_or_else(|| {
        err(
            ErrorKind::Failed,
            "triggered before the projector showed anything".into(),
        )
    })?;
    let late = st.shown_at.is_some_and(|t| t.elapsed() < st.latency);
    if let (true, Some(before)) = (late, st.previous) {
        tracing::debug!(
            camera,
            index,
            slot,
            before,
            "mock: the slide is not on screen yet"
        );
        slot = before;
    }
    if fault == Some(Fault::WrongPattern) {
        slot = (slot + 1) % st.slides.len();
        tracing::debug!(
            camera,
            index,
            slot,
            "mock: projector showed the wrong slide"
        );
    }
    let slide = &st.slides[slot];
    let image = match &shared.source {
        Source::Sim(sim) => {
            let worn;
            let sim: &Simulator = if sim.scene.wears() && st.scans > 0 {
                worn = shared.worn(sim, st.scans);
                &worn
            } else {
                sim
            };
            let gain = 10f64.powf(st.gain_db / 20.0);
            let exposure = st.exposure_us / NOMINAL_EXPOSURE_US * gain;
            let seed = shared.seed.wrapping_mul(1_000_003).wrapping_add(id);
            if sim.scene.moving() {
                // A moving part is rendered where it is now (seconds since the pair opened).
                let t = shared.opened.elapsed().as_secs_f64();
                Simulator::new(sim.scene.at(t)).frame_with(
                    &shared.layout,
                    slide.pattern,
                    slide.mask.as_deref(),
                    exposure,
                    seed,
                )
            } else {
                sim.frame_with(
                    &shared.layout,
                    slide.pattern,
                    slide.mask.as_deref(),
                    exposure,
                    seed,
                )
            }
        }
        Source::Omni(scene) => {
            let gain = 10f64.powf(st.gain_db / 20.0);
            let exposure = ris_core::omni::Exposure {
                gain: scene.exposure.gain * st.exposure_us / NOMINAL_EXPOSURE_US * gain,
                seed: shared
                    .seed
                    .wrapping_mul(1_000_003)
                    .wrapping_add(id)
                    .wrapping_add(scene.exposure.seed),
                ..scene.exposure
            };
            let picture = slide.render(&shared.layout);
            ris_core::omni::render(&scene.sensor, &scene.room, &picture, &exposure)
                .map_err(|e| err(ErrorKind::Failed, format!("rendering the room: {e}")))?
                .0
        }
        Source::Replay(set) => set.frame(slide.pattern).cloned().ok_or_else(|| {
            err(
                ErrorKind::Failed,
                format!("the recording has no `{}` frame", slide.pattern.name()),
            )
        })?,
    };
    let now = now_ns();
    let frame = Frame {
        image,
        bit_depth: 8,
        frame_id: id,
        host_ns: now,
        device_ns: now,
        exposure_us: st.exposure_us,
        gain_db: st.gain_db,
    };
    match fault {
        Some(Fault::DuplicateFrame) => {
            st.queue.push_back(frame.clone());
            st.queue.push_back(frame);
        }
        Some(Fault::LateFrame) => st.late = Some(frame),
        _ => st.queue.push_back(frame),
    }
    shared.arrived.notify_all();
    Ok(())
}

impl Camera for MockCamera {
    fn info(&self) -> &CameraInfo {
        &self.info
    }

    fn set_exposure_us(&mut self, us: f64) -> Result<()> {
        let mut st = self.shared.lock();
        self.check_connected(&st)?;
        if !(us.is_finite() && (1.0..=10_000_000.0).contains(&us)) {
            return Err(self.err(
                ErrorKind::InvalidArgument,
                format!("exposure {us} µs is outside 1..=10000000"),
            ));
        }
        st.exposure_us = us;
        Ok(())
    }

    fn exposure_us(&self) -> f64 {
        self.shared.lock().exposure_us
    }

    fn set_gain_db(&mut self, db: f64) -> Result<()> {
        let mut st = self.shared.lock();
        self.check_connected(&st)?;
        if !(db.is_finite() && (0.0..=24.0).contains(&db)) {
            return Err(self.err(
                ErrorKind::InvalidArgument,
                format!("gain {db} dB is outside 0..=24"),
            ));
        }
        st.gain_db = db;
        Ok(())
    }

    fn set_trigger(&mut self, mode: TriggerMode) -> Result<()> {
        let mut st = self.shared.lock();
        self.check_connected(&st)?;
        if st.streaming {
            return Err(self.err(ErrorKind::Busy, "cannot change the trigger while streaming"));
        }
        st.trigger = mode;
        Ok(())
    }

    fn start(&mut self) -> Result<()> {
        let mut st = self.shared.lock();
        self.check_connected(&st)?;
        st.streaming = true;
        Ok(())
    }

    fn stop(&mut self) -> Result<()> {
        let mut st = self.shared.lock();
        st.streaming = false;
        st.queue.clear();
        st.late = None;
        Ok(())
    }

    fn trigger(&mut self) -> Result<()> {
        let mut st = self.shared.lock();
        self.check_connected(&st)?;
        if !st.streaming {
            return Err(self.err(ErrorKind::Busy, "trigger while not streaming"));
        }
        if st.trigger != TriggerMode::Software {
            return Err(self.err(
                ErrorKind::Unsupported,
                format!("software trigger in {:?} mode", st.trigger),
            ));
        }
        self.expose(&mut st)
    }

    fn next_frame(&mut self, timeout: Duration) -> Result<Frame> {
        let deadline = Instant::now() + timeout;
        let mut st = self.shared.lock();
        loop {
            self.check_connected(&st)?;
            if !st.streaming {
                return Err(self.err(ErrorKind::Busy, "not streaming"));
            }
            if st.trigger == TriggerMode::FreeRun && st.queue.is_empty() && st.showing.is_some() {
                self.expose(&mut st)?;
            }
            if let Some(f) = st.queue.pop_front() {
                return Ok(f);
            }
            let now = Instant::now();
            if now >= deadline {
                return Err(self.err(
                    ErrorKind::Timeout,
                    format!("no frame within {} ms", timeout.as_millis()),
                ));
            }
            st = self
                .shared
                .arrived
                .wait_timeout(st, deadline - now)
                .unwrap_or_else(|e| e.into_inner())
                .0;
        }
    }

    fn reconnect(&mut self) -> Result<()> {
        let mut st = self.shared.lock();
        if st.connected && !st.stalled {
            return Ok(());
        }
        if !st.connected && !st.reconnectable {
            return Err(self.err(ErrorKind::Disconnected, "device did not come back"));
        }
        st.connected = true;
        st.stalled = false;
        st.queue.clear();
        st.late = None;
        tracing::info!(camera = %self.info.id, "mock: reconnected");
        Ok(())
    }
}

impl Projector for MockProjector {
    fn info(&self) -> &ProjectorInfo {
        &self.info
    }

    fn load(&mut self, slides: &[Slide]) -> Result<()> {
        for s in slides {
            if let Some(m) = &s.mask {
                if (m.width, m.height) != (self.info.width, self.info.height) {
                    return Err(DriverError::new(
                        ErrorKind::InvalidArgument,
                        &self.info.id,
                        format!(
                            "mask of `{}` is {}x{}, the projector is {}x{}",
                            s.name(),
                            m.width,
                            m.height,
                            self.info.width,
                            self.info.height
                        ),
                    ));
                }
            }
        }
        let mut st = self.shared.lock();
        st.slides = slides.to_vec();
        st.showing = None;
        st.previous = None;
        Ok(())
    }

    fn show(&mut self, slot: usize) -> Result<Shown> {
        let mut st = self.shared.lock();
        if slot >= st.slides.len() {
            return Err(DriverError::new(
                ErrorKind::InvalidArgument,
                &self.info.id,
                format!("slide {slot} of {} loaded", st.slides.len()),
            ));
        }
        st.previous = st.showing;
        st.showing = Some(slot);
        st.shown_at = Some(std::time::Instant::now());
        st.show_seq += 1;
        let shown = Shown {
            slot,
            sequence: st.show_seq,
            presented_ns: now_ns(),
        };
        if let TriggerMode::Hardware { .. } = st.trigger {
            if st.streaming && st.connected {
                // The projector's sync output is wired to the camera's trigger line.
                expose(&self.shared, &mut st, &self.camera_id)?;
            }
        }
        Ok(shown)
    }
}
