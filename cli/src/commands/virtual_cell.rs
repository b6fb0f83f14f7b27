//! The virtual cell: the whole hardware stack without hardware. A virtual camera is a GigE
//! Vision camera on a loopback address (Aravis's own device side) whose every frame is the
//! simulator's rendering of a scene lit by what a projector monitor of an X display shows at
//! that moment, read back from the screen: the projector window is its only light source and
//! GigE Vision its only wire to risd. `ris virtual-cell` starts an Xvfb screen cut into one
//! monitor per projector and one virtual camera per pair, as a rig file describes.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{anyhow, bail, Context, Result};
use ris_aravis::LoopbackCamera;
use ris_core::pattern::{Pattern, ProjectionMask};
use ris_core::sim::{Scene, Simulator};
use ris_drivers::mock::NOMINAL_EXPOSURE_US;
use ris_projector::screen::{Monitor, Screen};
use ris_projector::xvfb::Xvfb;
use serde::Deserialize;

/// How often the device side polls its software trigger, Hz.
const TRIGGER_HZ: f64 = 500.0;

/// A virtual camera serving until dropped.
pub struct VirtualCamera {
    _gige: LoopbackCamera,
    /// Frames rendered so far.
    pub frames: Arc<AtomicU64>,
    /// Nanoseconds spent reading the monitor back, and rendering, over all frames.
    pub spent_ns: Arc<[AtomicU64; 2]>,
}

impl VirtualCamera {
    /// Frames so far, and mean ms per frame reading the screen and rendering.
    pub fn stats(&self) -> (u64, f64, f64) {
        let n = self.frames.load(Ordering::Relaxed);
        let ms =
            |i: usize| self.spent_ns[i].load(Ordering::Relaxed) as f64 * 1e-6 / n.max(1) as f64;
        (n, ms(0), ms(1))
    }
}

/// Serve the camera of `scene` on `address` (GigE Vision port 3956), lit by monitor `monitor`
/// of `display`, whose size must be the scene's projector's.
pub fn virtual_camera(
    scene: &Path,
    display: &str,
    monitor: usize,
    address: &str,
) -> Result<VirtualCamera> {
    let sc = Scene::load(scene).with_context(|| format!("scene {}", scene.display()))?;
    let screen = Screen::connect(Some(display)).context("the projector display")?;
    let m = screen.monitor(monitor)?;
    let sim = Simulator::new(sc);
    let layout = sim.layout();
    if (u32::from(m.width), u32::from(m.height)) != (layout.width, layout.height) {
        bail!(
            "monitor {monitor} ({}) of {display} is {}x{}; the scene's projector is {}x{}",
            m.name,
            m.width,
            m.height,
            layout.width,
            layout.height
        );
    }
    let (cw, ch) = (sim.scene.camera.width, sim.scene.camera.height);
    let screen = Mutex::new(screen);
    let frames = Arc::new(AtomicU64::new(0));
    let counter = frames.clone();
    let spent_ns = Arc::new([AtomicU64::new(0), AtomicU64::new(0)]);
    let spent = spent_ns.clone();
    let fill = move |buf: &mut [u8], w: u32, h: u32, exposure_us: f64| {
        let k = counter.fetch_add(1, Ordering::Relaxed);
        if (w, h) != (cw, ch) {
            // Not the calibrated size (the client has not set its region yet): black.
            buf.fill(0);
            return;
        }
        let t0 = Instant::now();
        let mut px = Vec::new();
        let grabbed = screen
            .lock()
            .map_err(|_| anyhow!("screen lock poisoned"))
            .and_then(|s| s.grab(&m, &mut px).map_err(anyhow::Error::from));
        if let Err(e) = grabbed {
            tracing::warn!(error = %e, "cannot read the projector monitor; black frame");
            buf.fill(0);
            return;
        }
        let light = ProjectionMask {
            width: layout.width,
            height: layout.height,
            values: px.iter().map(|&v| f32::from(v) / 255.0).collect(),
        };
        let exposure = if exposure_us > 0.0 {
            exposure_us / NOMINAL_EXPOSURE_US
        } else {
            1.0
        };
        let t1 = Instant::now();
        let image = sim.frame_with(&layout, Pattern::White, Some(&light), exposure, k);
        spent[0].fetch_add((t1 - t0).as_nanos() as u64, Ordering::Relaxed);
        spent[1].fetch_add(t1.elapsed().as_nanos() as u64, Ordering::Relaxed);
        if let ris_core::image::Pixels::U8(v) = image.pixels {
            if v.len() == buf.len() {
                buf.copy_from_slice(&v);
            }
        }
    };
    let gige = LoopbackCamera::start(address, TRIGGER_HZ, Box::new(fill))?;
    let x11 = display;
    tracing::info!(%address, x11, monitor, scene = %scene.display(), "virtual camera serving");
    Ok(VirtualCamera {
        _gige: gige,
        frames,
        spent_ns,
    })
}

/// A rig file: the virtual devices behind a virtual cell's configuration.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigFile {
    /// One per pair, in monitor order (left to right on the screen).
    pub camera: Vec<RigCamera>,
}

/// One virtual camera of a rig.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigCamera {
    /// Loopback address it serves on (127.0.0.N; GigE Vision's control port is fixed, so each
    /// camera has its own address).
    pub address: String,
    /// The scene it renders (its projector's size is its monitor's).
    pub scene: PathBuf,
}

/// A running virtual rig: Xvfb and the camera processes, stopped on drop.
pub struct VirtualRig {
    xvfb: Xvfb,
    cameras: Vec<Child>,
    /// The X display (`:N`).
    pub display: String,
    /// Monitor index of each camera's projector, as the cell config's `projector_monitor`.
    pub monitors: Vec<usize>,
    /// The cameras' addresses.
    pub addresses: Vec<String>,
}

impl VirtualRig {
    /// Process ids of Xvfb and the cameras.
    pub fn pids(&self) -> Vec<u32> {
        std::iter::once(self.xvfb.pid())
            .chain(self.cameras.iter().map(Child::id))
            .collect()
    }

    /// Stop camera `i` (a camera that disappears).
    pub fn kill_camera(&mut self, i: usize) {
        if let Some(c) = self.cameras.get_mut(i) {
            let _ = c.kill();
            let _ = c.wait();
        }
    }

    /// Start camera `i` again after [`VirtualRig::kill_camera`]. Not waited for: opening it
    /// here would take the control channel from a risd reconnecting to it.
    pub fn restart_camera(&mut self, ris: &Path, rig: &Path, i: usize) -> Result<()> {
        let file = load_rig(rig)?;
        let cam = file
            .camera
            .get(i)
            .ok_or_else(|| anyhow!("the rig has no camera {i}"))?;
        let base = rig.parent().unwrap_or(Path::new("."));
        let child = spawn_camera(
            ris,
            &base.join(&cam.scene),
            &self.display,
            self.monitors[i],
            &cam.address,
        )?;
        self.cameras[i] = child;
        Ok(())
    }
}

impl Drop for VirtualRig {
    fn drop(&mut self) {
        for c in &mut self.cameras {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

fn load_rig(path: &Path) -> Result<RigFile> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let rig: RigFile = toml::from_str(&text).map_err(|e| anyhow!("{}: {e}", path.display()))?;
    if rig.camera.is_empty() {
        bail!("{}: `camera`: the rig has no camera", path.display());
    }
    for (i, c) in rig.camera.iter().enumerate() {
        let ip: std::net::Ipv4Addr = c.address.parse().map_err(|_| {
            anyhow!(
                "{}: `camera[{i}].address`: {:?} is not an IPv4 address",
                path.display(),
                c.address
            )
        })?;
        if !ip.is_loopback() {
            bail!(
                "{}: `camera[{i}].address`: {ip} is not a loopback address (127.0.0.0/8)",
                path.display()
            );
        }
        if rig.camera[..i].iter().any(|o| o.address == c.address) {
            bail!(
                "{}: `camera[{i}].address`: {} is used twice",
                path.display(),
                c.address
            );
        }
    }
    Ok(rig)
}

/// Make sure `address` is an address of the loopback interface (Aravis's device side binds an
/// interface address; 127.0.0.1 always is one, others are added, which needs CAP_NET_ADMIN).
fn ensure_loopback_address(address: &str) -> Result<()> {
    let shown = Command::new("ip")
        .args(["-4", "-o", "addr", "show", "dev", "lo"])
        .output()
        .context("running `ip` (apt-get install iproute2)")?;
    let listed = String::from_utf8_lossy(&shown.stdout);
    if listed
        .split_whitespace()
        .any(|w| w.split('/').next() == Some(address))
    {
        return Ok(());
    }
    let added = Command::new("ip")
        .args(["addr", "add", &format!("{address}/8"), "dev", "lo"])
        .output()
        .context("running `ip`")?;
    if !added.status.success() {
        bail!(
            "{address} is not an address of the loopback interface and cannot be added here ({}); run as root: ip addr add {address}/8 dev lo",
            String::from_utf8_lossy(&added.stderr).trim()
        );
    }
    tracing::info!(%address, "loopback address added");
    Ok(())
}

fn spawn_camera(
    ris: &Path,
    scene: &Path,
    display: &str,
    monitor: usize,
    address: &str,
) -> Result<Child> {
    Command::new(ris)
        .arg("virtual-camera")
        .arg("--scene")
        .arg(scene)
        .args([
            "--display",
            display,
            "--monitor",
            &monitor.to_string(),
            "--address",
            address,
            "--exit-with-parent",
        ])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .spawn()
        .with_context(|| format!("starting {} virtual-camera", ris.display()))
}

/// Wait until a GigE Vision camera answers at `address`.
fn wait_for_camera(address: &str) -> Result<()> {
    let ip: std::net::IpAddr = address.parse().context("camera address")?;
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        match ris_aravis::AravisCamera::open(ris_aravis::DeviceSpec::Ip(ip), Default::default()) {
            Ok(_) => return Ok(()),
            Err(e) if Instant::now() < deadline => {
                tracing::debug!(%address, error = %e, "waiting for the virtual camera");
                std::thread::sleep(Duration::from_millis(250));
            }
            Err(e) => bail!("the virtual camera at {address} did not come up: {e}"),
        }
    }
}

/// Start the rig of `rig`: Xvfb on `display` (or a free one) with one monitor per camera laid
/// left to right, and one `ris virtual-camera` process (the executable `ris`) per camera.
pub fn start_rig(rig: &Path, ris: &Path, display: Option<&str>) -> Result<VirtualRig> {
    let file = load_rig(rig)?;
    let base = rig.parent().unwrap_or(Path::new("."));
    let mut sizes = Vec::new();
    for (i, c) in file.camera.iter().enumerate() {
        let sc = Scene::load(&base.join(&c.scene))
            .with_context(|| format!("{}: camera[{i}].scene", rig.display()))?;
        sizes.push((sc.file.projector.width, sc.file.projector.height));
    }
    for c in &file.camera {
        ensure_loopback_address(&c.address)?;
    }
    let width: u32 = sizes.iter().map(|s| s.0).sum();
    let height: u32 = sizes.iter().map(|s| s.1).max().unwrap_or(1);
    // X11 coordinates are 16-bit: the monitors side by side must fit.
    if width > i16::MAX as u32 || height > i16::MAX as u32 {
        bail!(
            "{}: the projectors side by side are {width}x{height}; an X screen holds at most 32767x32767",
            rig.display()
        );
    }
    // Ends with this thread: a rig killed with SIGKILL leaves no X server (its cameras watch
    // their parent themselves).
    let xvfb = Xvfb::start_tied(display, width, height)?;
    let display = xvfb.display();
    let mut rig_run = VirtualRig {
        xvfb,
        cameras: Vec::new(),
        display: display.clone(),
        monitors: Vec::new(),
        addresses: file.camera.iter().map(|c| c.address.clone()).collect(),
    };
    let screen = Screen::connect(Some(&display))
        .with_context(|| format!("the screen of Xvfb on {display}"))?;
    let mut x = 0i16;
    let wanted: Vec<Monitor> = sizes
        .iter()
        .enumerate()
        .map(|(i, &(w, h))| {
            let m = Monitor {
                name: format!("RIS-P{i}"),
                x,
                y: 0,
                width: w as u16,
                height: h as u16,
            };
            x += w as i16;
            m
        })
        .collect();
    screen.set_virtual_monitors(&wanted)?;
    let listed = screen.monitors()?;
    for m in &wanted {
        let i = listed
            .iter()
            .position(|l| l.name == m.name)
            .ok_or_else(|| anyhow!("monitor {} was not created on {display}", m.name))?;
        rig_run.monitors.push(i);
    }
    for (i, c) in file.camera.iter().enumerate() {
        let child = spawn_camera(
            ris,
            &base.join(&c.scene),
            &display,
            rig_run.monitors[i],
            &c.address,
        )?;
        rig_run.cameras.push(child);
    }
    for c in &file.camera {
        wait_for_camera(&c.address)?;
    }
    let x11 = display.as_str();
    tracing::info!(x11, monitors = ?rig_run.monitors, "virtual rig running");
    Ok(rig_run)
}
