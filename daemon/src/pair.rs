//! A sensor pair as risd runs it: its camera and projector opened through their backend as
//! trait objects, the sensor model that turns its captures into clouds, the reference decode
//! the adaptive loop starts from, and the state of its drivers for health.

use std::sync::Arc;
use std::time::Instant;

use anyhow::{anyhow, Context, Result};
use ris_core::capture::CaptureSet;
use ris_core::decode::{decode, DecodeParams, Decoded};
use ris_core::omni::scene::OmniScene;
use ris_core::omni::OmniSensor;
use ris_core::pattern::CodeLayout;
use ris_core::sensor::{ModelChoice, Reconstructor, Sensor};
use ris_core::sim::{RenderCache, Scene, Simulator};
use ris_drivers::mock::{omni_pair, replay_pair, simulated_pair, FaultInjector};
use ris_drivers::sequence::SequenceParams;
use ris_drivers::{Camera, CameraSettings, ErrorKind, Projector, ProjectorSettings};

use crate::config::{Backend, CellConfig, SensorConfig, SensorKind, SingleShotSection};
use crate::prepared::{Cache, Key, REFERENCE, RENDER};
use crate::protocol::DriverState;
use crate::single_shot::{OneShot, PairRings, PairSingleShot};

/// A sensor pair ready to scan.
pub struct Pair {
    /// Sensor name.
    pub name: String,
    /// Exposure group.
    pub group: u32,
    /// Backend name (`mock`, `aravis`, `v4l2`, `replay`).
    pub backend: &'static str,
    /// What it measures with.
    pub kind: SensorKind,
    pub(crate) camera: Box<dyn Camera>,
    pub(crate) projector: Box<dyn Projector>,
    /// Fault injection of a simulated pair (tests); `None` for every other backend.
    pub faults: Option<FaultInjector>,
    pub(crate) layout: CodeLayout,
    /// The Gray-code sensor model (`None`: an omni sensor, which measures one frame only).
    pub(crate) reconstructor: Option<Arc<Reconstructor>>,
    pub(crate) to_common: nalgebra::Matrix4<f64>,
    /// The decoded reference recording (with row codes) the adaptive loop starts from.
    pub(crate) reference: Option<Arc<Decoded>>,
    /// Sequencing of this pair (trigger, settle time).
    pub(crate) sequence: SequenceParams,
    /// The configured exposure, restored after an adaptive scan chose another.
    pub(crate) exposure_us: f64,
    /// The drivers' state.
    pub state: DriverState,
    /// Single-shot scans and streams (every scan of an omni sensor): the pattern and its
    /// decoding, or why this pair cannot.
    pub(crate) single_shot: std::result::Result<Arc<OneShot>, String>,
    /// Distances drawn red and blue in its pictures, mm: the sensor's `range_mm`, else the
    /// cell's (`None`: each frame's own spread).
    pub(crate) range_mm: Option<[f64; 2]>,
}

impl Pair {
    /// Where this pair looks from in the cell frame (its camera's and projector's centres), so
    /// that a part's inspected surface can be what the scan could see; `None` for an omni
    /// sensor.
    pub fn viewpoint(&self) -> Option<ris_core::inspect::Viewpoint> {
        let reconstructor = self.reconstructor.as_ref()?;
        let (camera, projector) = reconstructor.centres();
        // the camera with the cell frame as its world: X_cam = R (to_common⁻¹ X_cell) + t
        let inverse = self.to_common.try_inverse()?;
        let rotation = inverse.fixed_view::<3, 3>(0, 0).into_owned();
        let shift = inverse.fixed_view::<3, 1>(0, 3).into_owned();
        let cam = reconstructor.camera();
        let image = ris_core::geometry::Pinhole {
            r: cam.r * rotation,
            t: cam.r * shift + cam.t,
            ..cam.clone()
        };
        let cell = |v: ris_core::geometry::Vec3| -> [f64; 3] {
            let h = self.to_common * nalgebra::Vector4::new(v.x, v.y, v.z, 1.0);
            [h.x, h.y, h.z]
        };
        Some(ris_core::inspect::Viewpoint {
            camera: cell(camera),
            projector: Some(cell(projector)),
            image: Some(image),
        })
    }
    /// The camera's and the projector's ids.
    pub fn devices(&self) -> (String, String) {
        (
            self.camera.info().id.clone(),
            self.projector.info().id.clone(),
        )
    }

    /// After a scan: whether its error says this pair's camera is gone.
    pub(crate) fn note_failure(&mut self, error: &anyhow::Error) {
        let lost = error.chain().any(|e| {
            e.downcast_ref::<ris_drivers::DriverError>()
                .is_some_and(|d| d.kind == ErrorKind::Disconnected)
                || e.downcast_ref::<ris_drivers::sequence::SequenceError>()
                    .is_some_and(|s| {
                        matches!(s, ris_drivers::sequence::SequenceError::Driver { source, .. }
                            if source.kind == ErrorKind::Disconnected)
                    })
        });
        if lost {
            tracing::warn!(sensor = %self.name, "camera lost; reconnecting between scans");
            self.state = DriverState::Reconnecting {
                reason: format!("{error:#}"),
            };
        }
    }

    /// Try once to reopen a lost camera (restoring its settings); true when connected.
    pub fn try_reconnect(&mut self) -> bool {
        if self.state == DriverState::Connected {
            return true;
        }
        match self.camera.reconnect() {
            Ok(()) => {
                tracing::info!(sensor = %self.name, "camera back");
                self.state = DriverState::Connected;
                true
            }
            Err(e) => {
                tracing::debug!(sensor = %self.name, error = %e, "camera still away");
                self.state = DriverState::Reconnecting {
                    reason: e.to_string(),
                };
                false
            }
        }
    }
}

/// The sensor model of a pair: from its scene (simulated and replayed-from-simulation pairs:
/// the reference is a white board rendered at the sensor's z = 0) or from its sensor file.
struct Model {
    layout: CodeLayout,
    camera_size: (u32, u32),
    reconstructor: Option<Reconstructor>,
    reference: Option<Decoded>,
    to_common: nalgebra::Matrix4<f64>,
    scene: Option<Scene>,
    /// An omni sensor: its ring decoding, and the room a mock one renders.
    omni: Option<(PairRings, Option<OmniScene>)>,
}

/// The model of an omni sensor: from its room scene (mock) or its sensor file.
fn omni_model(s: &SensorConfig) -> Result<Model> {
    let to_common = s
        .to_common
        .ok_or_else(|| anyhow!("sensor {}: no to_common", s.name))?;
    let (sensor, scene) = match (&s.scene, &s.sensor_file) {
        (Some(path), _) => {
            if !OmniScene::is_room_scene(path) {
                return Err(anyhow!(
                    "sensor {}: {} is not a room scene (an omni sensor's scene has a [room] table)",
                    s.name,
                    path.display()
                ));
            }
            let sc =
                OmniScene::load(path).with_context(|| format!("sensor {}: room scene", s.name))?;
            (sc.sensor.clone(), Some(sc))
        }
        (None, Some(path)) => (
            OmniSensor::load(path)
                .with_context(|| format!("sensor {}: omni sensor file", s.name))?,
            None,
        ),
        (None, None) => return Err(anyhow!("sensor {}: no sensor file", s.name)),
    };
    let (c, p) = (&sensor.camera.lens, &sensor.projector.lens);
    let (camera_size, layout) = ((c.width, c.height), CodeLayout::new(p.width, p.height));
    Ok(Model {
        layout,
        camera_size,
        reconstructor: None,
        reference: None,
        to_common,
        scene: None,
        omni: Some((PairRings::new(&s.name, sensor)?, scene)),
    })
}

fn model(s: &SensorConfig, cache: &Cache) -> Result<Model> {
    if s.kind == SensorKind::Omni {
        return omni_model(s);
    }
    let params = DecodeParams::default();
    if let Some(scene) = &s.scene {
        let sc = Scene::load(scene).with_context(|| format!("sensor {}: scene", s.name))?;
        // The reference: a white board rendered at the sensor's z = 0, decoded.
        let board_scene = sc.sprayed().reference();
        let layout = CodeLayout::new(board_scene.projector.width, board_scene.projector.height);
        let mut key = Key::new("simulated reference");
        key.add("scene", &board_scene);
        key.add("decode", params);
        let (reference, cached) = cache.get(&s.name, &REFERENCE, &key, || {
            let board = Simulator::new(board_scene);
            decode(&board.capture(&layout, 7, &|_, _| {}), &params)
                .with_context(|| format!("sensor {}: decoding the reference", s.name))
        })?;
        tracing::debug!(sensor = %s.name, cached, "reference decoded");
        let reconstructor = Reconstructor::parallax(&sc.camera, sc.projector.center(), &reference)
            .with_context(|| format!("sensor {}: parallax model", s.name))?;
        let to_common = s
            .to_common
            .ok_or_else(|| anyhow!("sensor {}: no to_common", s.name))?;
        return Ok(Model {
            layout,
            camera_size: (sc.camera.width, sc.camera.height),
            reconstructor: Some(reconstructor),
            reference: Some(reference),
            to_common,
            scene: Some(sc),
            omni: None,
        });
    }
    let path = s
        .sensor_file
        .as_ref()
        .ok_or_else(|| anyhow!("sensor {}: no sensor file", s.name))?;
    let sensor = Sensor::load(path)
        .with_context(|| format!("sensor {}: sensor file {}", s.name, path.display()))?;
    let reference = match &sensor.reference {
        Some(dir) => {
            let mut key = Key::new("recorded reference");
            key.dir("recording", dir);
            key.add("camera", (sensor.camera.width, sensor.camera.height));
            key.add("decode", params);
            let (reference, cached) = cache
                .get(&s.name, &REFERENCE, &key, || {
                    Ok(Reconstructor::decode_reference(&sensor, dir, &params)?)
                })
                .with_context(|| format!("sensor {}: reference {}", s.name, dir.display()))?;
            tracing::debug!(sensor = %s.name, cached, "reference decoded");
            Some(reference)
        }
        None => None,
    };
    let reconstructor =
        Reconstructor::with_reference(&sensor, ModelChoice::Auto, reference.as_ref())
            .with_context(|| format!("sensor {}: preparing {}", s.name, path.display()))?;
    let to_common = sensor.to_common.ok_or_else(|| {
        anyhow!(
            "sensor {}: {} has no [to_common]; calibrate the cell (ris calibrate cell)",
            s.name,
            path.display()
        )
    })?;
    let (pw, ph) = sensor.projector_size;
    Ok(Model {
        layout: CodeLayout::new(pw, ph),
        camera_size: (sensor.camera.width, sensor.camera.height),
        reconstructor: Some(reconstructor),
        reference,
        to_common,
        scene: None,
        omni: None,
    })
}

/// What preparing a pair computes before any device is touched: its sensor model and, for a
/// mock pair, the simulated cell its camera renders.
pub struct Prepared {
    model: Model,
    simulator: Option<Arc<Simulator>>,
    seconds: f64,
}

/// Prepare pair `s`: the sensor model (a bad sensor file fails here, before any device is
/// touched; the reference from `cache` when unchanged) and a mock pair's simulator.
pub fn prepare(s: &SensorConfig, cache: &Cache) -> Result<Prepared> {
    let t = Instant::now();
    let mut model = model(s, cache)?;
    let simulator = match (&s.backend, &model.omni) {
        (Backend::Mock, None) => {
            let sc = model
                .scene
                .take()
                .ok_or_else(|| anyhow!("sensor {}: a mock pair needs its scene", s.name))?;
            // The camera's ray-cast scene: keyed by the scene as parsed and by every mesh file
            // it loads (wherever it lies), not by the directory it happens to sit in.
            let mut key = Key::new("render cache");
            key.add("scene", &sc.file);
            let base = s.scene.as_deref().and_then(|p| p.parent());
            for mesh in sc.file.object.iter().filter_map(|o| o.file.as_ref()) {
                key.file("mesh", &base.map_or_else(|| mesh.into(), |b| b.join(mesh)));
            }
            let (render, cached) =
                cache.get(&s.name, &RENDER, &key, || Ok(RenderCache::build(&sc)))?;
            tracing::debug!(sensor = %s.name, cached, "render cache");
            Some(Arc::new(Simulator::with_cache(sc, render)))
        }
        _ => None,
    };
    Ok(Prepared {
        model,
        simulator,
        seconds: t.elapsed().as_secs_f64(),
    })
}

/// Open pair `s` through its backend: [`prepare`], then the projector, then the camera. `seed`
/// varies simulated noise.
pub fn open(s: &SensorConfig, single: &SingleShotSection, seed: u64) -> Result<Pair> {
    attach(s, prepare(s, &Cache::default())?, single, seed)
}

/// Open the devices of prepared pair `s`: the projector, then the camera.
pub fn attach(
    s: &SensorConfig,
    prepared: Prepared,
    single: &SingleShotSection,
    seed: u64,
) -> Result<Pair> {
    let t = Instant::now();
    let Prepared {
        model: mut m,
        simulator,
        seconds,
    } = prepared;
    let omni = m.omni.take();
    let room = omni.as_ref().and_then(|o| o.1.clone());
    let (camera, projector, faults, backend): (
        Box<dyn Camera>,
        Box<dyn Projector>,
        Option<FaultInjector>,
        &'static str,
    ) = match (&s.backend, room) {
        (Backend::Mock, Some(room)) => {
            let (mut cam, proj, faults) = omni_pair(Arc::new(room), &s.name, seed);
            cam.set_exposure_us(s.exposure_us)
                .with_context(|| format!("sensor {}: exposure", s.name))?;
            (Box::new(cam), Box::new(proj), Some(faults), "mock")
        }
        (Backend::Mock, None) => {
            let sim = simulator
                .ok_or_else(|| anyhow!("sensor {}: a mock pair needs its scene", s.name))?;
            let (mut cam, proj, faults) = simulated_pair(sim, &s.name, seed);
            cam.set_exposure_us(s.exposure_us)
                .with_context(|| format!("sensor {}: exposure", s.name))?;
            (Box::new(cam), Box::new(proj), Some(faults), "mock")
        }
        (Backend::Replay { recording }, _) => {
            let set = CaptureSet::load(recording)
                .with_context(|| format!("sensor {}: recording", s.name))?;
            if (set.width, set.height) != m.camera_size || set.layout != m.layout {
                return Err(anyhow!(
                    "sensor {}: the recording {} is {}x{} for a {}x{} projector; the sensor model is {}x{} for {}x{}",
                    s.name,
                    recording.display(),
                    set.width,
                    set.height,
                    set.layout.width,
                    set.layout.height,
                    m.camera_size.0,
                    m.camera_size.1,
                    m.layout.width,
                    m.layout.height
                ));
            }
            let (cam, proj, _) = replay_pair(Arc::new(set), &s.name);
            (Box::new(cam), Box::new(proj), None, "replay")
        }
        (Backend::Aravis | Backend::V4l2, _) => {
            let monitor = s.projector_monitor.unwrap_or(0);
            let projector = ris_projector::open_projector(&ProjectorSettings {
                monitor,
                width: m.layout.width,
                height: m.layout.height,
            })
            .with_context(|| format!("sensor {}: projector on monitor {monitor}", s.name))?;
            let settings = CameraSettings {
                device: s.device.clone().unwrap_or_default(),
                size: m.camera_size,
                exposure_us: s.exposure_us,
                gain_db: s.gain_db,
                trigger: s.trigger.clone(),
            };
            let (camera, name) = if s.backend == Backend::Aravis {
                (ris_aravis::open_camera(&settings), "aravis")
            } else {
                (ris_v4l2::open_camera(&settings), "v4l2")
            };
            let camera =
                camera.with_context(|| format!("sensor {}: camera {}", s.name, settings.device))?;
            (camera, projector, None, name)
        }
    };
    tracing::info!(
        sensor = %s.name,
        backend,
        camera = %camera.info().id,
        projector = %projector.info().id,
        prepared_s = seconds,
        opened_s = t.elapsed().as_secs_f64(),
        "pair ready"
    );
    let reference = m.reference.map(Arc::new);
    let reconstructor = m.reconstructor.map(Arc::new);
    let single_shot = match (omni, &reference, &reconstructor) {
        (Some((rings, _)), _, _) => Ok(Arc::new(OneShot::Rings(Box::new(rings)))),
        (None, Some(r), Some(rec)) => PairSingleShot::new(
            &s.name,
            (m.layout.width, m.layout.height),
            single,
            r.clone(),
            rec.clone(),
        )
        .map(|x| Arc::new(OneShot::XPoint(Box::new(x))))
        .map_err(|e| format!("{e:#}")),
        _ => Err(format!(
            "sensor {}: single-shot decoding needs the pair's Gray-code reference recording; its sensor file has no [reference]",
            s.name
        )),
    };
    if let Err(why) = &single_shot {
        tracing::info!(sensor = %s.name, %why, "no single-shot scans for this pair");
    }
    Ok(Pair {
        name: s.name.clone(),
        group: s.exposure_group,
        backend,
        kind: s.kind,
        camera,
        projector,
        faults,
        layout: m.layout,
        reconstructor,
        to_common: m.to_common,
        reference,
        sequence: SequenceParams {
            trigger: s.trigger.clone(),
            settle: s.settle,
            timeout: s.frame_timeout,
            ..SequenceParams::default()
        },
        exposure_us: s.exposure_us,
        state: DriverState::Connected,
        single_shot,
        range_mm: s.range_mm.or(single.range_mm),
    })
}

/// Open every pair of `config`: all prepared at once (each on its own thread; the models are
/// pure computation), then their devices opened one after another in file order (drivers and
/// displays are not opened concurrently). `prepared(name, done, total)` is called as each pair's
/// model is ready.
pub fn open_all(
    config: &CellConfig,
    seed: u64,
    cache: &Cache,
    prepared: &(dyn Fn(&str, usize, usize) + Sync),
) -> Result<Vec<Pair>> {
    let total = config.sensors.len();
    let done = std::sync::atomic::AtomicUsize::new(0);
    let models: Vec<Result<Prepared>> = std::thread::scope(|scope| {
        let handles: Vec<_> = config
            .sensors
            .iter()
            .map(|s| {
                let done = &done;
                scope.spawn(move || {
                    let p = prepare(s, cache);
                    if p.is_ok() {
                        let n = done.fetch_add(1, std::sync::atomic::Ordering::SeqCst) + 1;
                        prepared(&s.name, n, total);
                    }
                    p
                })
            })
            .collect();
        handles
            .into_iter()
            .zip(&config.sensors)
            .map(|(h, s)| {
                h.join().unwrap_or_else(|panic| {
                    Err(anyhow!(
                        "sensor {}: preparing panicked: {}",
                        s.name,
                        crate::scan::panic_message(panic.as_ref())
                    ))
                })
            })
            .collect()
    });
    config
        .sensors
        .iter()
        .zip(models)
        .map(|(s, m)| attach(s, m?, &config.single_shot, seed))
        .collect()
}
