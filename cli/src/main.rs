//! `ris`: the offline command-line tool of RIS (patterns, decoding, reconstruction, simulation).

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand, ValueEnum};
use ris_cli::commands;
use ris_core::calibrate::GaugeParams;
use ris_core::decode::DecodeParams;
use ris_core::sensor::ModelChoice;

#[derive(Parser)]
#[command(
    name = "ris",
    version,
    about = "RIS structured-light tools: patterns, decode, reconstruct, simulate"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(clap::Args)]
struct DecodeArgs {
    /// Minimum white − black contrast (8-bit grey levels) for a valid pixel.
    #[arg(long, default_value_t = DecodeParams::default().contrast_threshold)]
    contrast_threshold: f32,
    /// Margin |pattern − inverse| below which a bit is undecidable (0 = decide by sign).
    #[arg(long, default_value_t = DecodeParams::default().bit_threshold)]
    bit_threshold: f32,
    /// Edges used on each side of a pixel for its sub-pixel line fit.
    #[arg(long, default_value_t = DecodeParams::default().edge_window)]
    edge_window: usize,
    /// Pixels removed next to invalid pixels across the scan direction (mixed footprints).
    #[arg(long, default_value_t = DecodeParams::default().edge_erosion)]
    edge_erosion: u32,
    /// Power of the contrast ratio weighting edges beside albedo changes (0 = off).
    #[arg(long, default_value_t = DecodeParams::default().albedo_weight_power)]
    albedo_weight_power: u32,
    /// Leave the line fit's curvature bias on curved surfaces (for comparisons only).
    #[arg(long)]
    no_bend_correction: bool,
    /// Leave the crossing's phase bias (the moiré of the camera's and the projector's pixel
    /// grids; for comparisons only).
    #[arg(long)]
    no_phase_correction: bool,
}

impl DecodeArgs {
    fn params(&self) -> DecodeParams {
        DecodeParams {
            contrast_threshold: self.contrast_threshold,
            bit_threshold: self.bit_threshold,
            edge_window: self.edge_window,
            edge_erosion: self.edge_erosion,
            albedo_weight_power: self.albedo_weight_power,
            bend_correction: !self.no_bend_correction,
            phase_correction: !self.no_phase_correction,
            ..DecodeParams::default()
        }
    }
}

#[derive(Subcommand)]
enum ExperimentCommand {
    /// Table 7.1: points per material of a sprayed reference, a naive scan and the adaptive
    /// projection-mask scan, and the adaptive scan's error against truth.
    Completeness {
        /// Scene file.
        #[arg(long)]
        scene: PathBuf,
        /// JSON on stdout instead of a table.
        #[arg(long)]
        json: bool,
        /// Also write the clouds, the adaptive capture and completeness.json here.
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Ch. 7.1.2: error and completeness of a Gray-code scan against one single-shot frame as
    /// the part (every object but the reference plane) moves faster.
    Motion {
        /// Scene file.
        #[arg(long)]
        scene: PathBuf,
        /// Part speeds, mm/s.
        #[arg(long, value_delimiter = ',', default_value = "0,5,20,50,100,200")]
        speeds: Vec<f64>,
        /// Direction of motion X,Y,Z (scene frame).
        #[arg(long, value_delimiter = ',', default_value = "1,0,0", num_args = 1)]
        direction: Vec<f64>,
        /// Frames per second of the projector-camera sequence.
        #[arg(long, default_value_t = 60.0)]
        fps: f64,
        /// Exposure of each frame, ms.
        #[arg(long, default_value_t = 5.0)]
        exposure_ms: f64,
        /// JSON on stdout instead of a table.
        #[arg(long)]
        json: bool,
    },
}

#[derive(Clone, Copy, ValueEnum)]
enum CameraBackend {
    Aravis,
    V4l2,
    Mock,
}

#[derive(Subcommand)]
enum CameraCommand {
    /// Cameras this build can open (the Aravis fake, the mock); `--discover` also asks Aravis,
    /// which broadcasts a GigE Vision discovery on every network interface.
    List {
        /// Broadcast a discovery (never done unless asked).
        #[arg(long)]
        discover: bool,
    },
    /// Grab frames: one PNG each and `frames.toml` (ids, timestamps, exposure, gain).
    Grab {
        /// Backend.
        #[arg(long, value_enum)]
        backend: CameraBackend,
        /// Device: an IP address, an Aravis id or `fake` (aravis); a scene file or `demo` (mock).
        #[arg(long)]
        device: String,
        /// Trigger: `software` (one trigger per frame) or `free` (free run).
        #[arg(long, default_value = "software")]
        trigger: String,
        /// Frames to grab.
        #[arg(long, default_value_t = 1)]
        count: usize,
        /// Exposure time, µs.
        #[arg(long)]
        exposure_us: Option<f64>,
        /// Wait per frame, ms.
        #[arg(long, default_value_t = 3000)]
        timeout_ms: u64,
        /// Output directory.
        #[arg(long)]
        out: PathBuf,
    },
}

#[derive(Subcommand)]
enum CalibrateCommand {
    /// The omnidirectional sensor's per-pixel ray tables (Eq. 6.1–6.6) from a two-position
    /// session of a dotted cylinder target (`ris simulate --scene SESSION.toml` makes one):
    /// writes OUT (the nominal file naming the tables) with cam_rays.npy and proj_rays.npy
    /// beside it; pixels the target did not cover at both positions stay NaN.
    Omni {
        /// Session directory (with session.toml).
        session: PathBuf,
        /// Sensor file to write.
        #[arg(long)]
        out: PathBuf,
    },
    /// A sensor (camera, projector centre, reference, per-pixel residual) from a multi-layer
    /// session (SPEC §7); the sensor file is written only when every gate passes.
    Sensor {
        /// Session directory (with session.toml) or the session file.
        session: PathBuf,
        /// Camera file from `ris calibrate camera`: keep its K and distortion, fit only the pose.
        #[arg(long)]
        camera: Option<PathBuf>,
        /// Sensor file to write.
        #[arg(long)]
        out: PathBuf,
        /// Report (JSON); default `<out stem>.report.json` beside the sensor file.
        #[arg(long)]
        report: Option<PathBuf>,
    },
    /// Camera intrinsics and Brown distortion from chessboard images (Zhang + Levenberg–Marquardt);
    /// views failing the quality gate are named and dropped.
    Camera {
        /// Inner corners along x and y, e.g. 9x6.
        #[arg(long)]
        board: String,
        /// Square size, mm.
        #[arg(long)]
        square: f64,
        /// Keep fx = fy.
        #[arg(long)]
        fix_aspect: bool,
        /// Chessboard images.
        #[arg(required = true)]
        images: Vec<PathBuf>,
        /// Camera file to write (TOML).
        #[arg(long)]
        out: PathBuf,
    },
    /// Each sensor's to_common transform from its measurement of a marker gauge (white 5 mm markers
    /// with CMM-measured centres); sensor files are written only when every sensor passes.
    Cell {
        /// Gauge file: `radius` and `[[marker]] center` in the cell frame.
        #[arg(long)]
        gauge: PathBuf,
        /// Each sensor's gauge measurement as SENSOR.toml:CLOUD.ply.
        #[arg(required = true)]
        inputs: Vec<String>,
        /// Largest accepted RMS of the matched marker centres, mm.
        #[arg(long, default_value_t = GaugeParams::default().max_rms)]
        max_rms: f64,
        /// Write a JSON report (transforms, markers, rejected clusters, overlaps).
        #[arg(long)]
        report: Option<PathBuf>,
    },
}

#[derive(Clone, Copy, ValueEnum)]
enum Model {
    Auto,
    Parallax,
    Classical,
}

#[derive(Subcommand)]
enum Command {
    /// Write the multi-shot Gray-code patterns for a projector as PNG files.
    Patterns(commands::patterns::PatternsArgs),
    /// Decode a capture set to sub-pixel projector coordinates (col.npy, row.npy, confidence.npy).
    Decode {
        /// Capture directory (with capture.toml).
        capture: PathBuf,
        /// Output directory.
        #[arg(long)]
        out: PathBuf,
        #[command(flatten)]
        decode: DecodeArgs,
    },
    /// Reconstruct a capture set into a binary PLY point cloud in the sensor world frame.
    Reconstruct {
        /// Sensor file (TOML).
        #[arg(long)]
        sensor: PathBuf,
        /// Capture directory.
        capture: PathBuf,
        /// Output PLY file.
        #[arg(long)]
        out: PathBuf,
        /// Sensor model (auto: parallax when the sensor has a reference).
        #[arg(long, value_enum, default_value_t = Model::Auto)]
        model: Model,
        /// Leave out the points outside the sensor's calibrated volume (default: keep them,
        /// flagged `outside_volume` in the PLY).
        #[arg(long)]
        drop_outside: bool,
        #[command(flatten)]
        decode: DecodeArgs,
    },
    /// Reconstruct one camera image of the X-point pattern (single shot) into a binary PLY in
    /// the sensor world frame.
    SingleShot {
        /// Sensor file (TOML); its [reference] recording predicts where X-points lie.
        #[arg(long)]
        sensor: PathBuf,
        /// The pattern file written with the projected image (xpoint.toml).
        #[arg(long)]
        pattern: PathBuf,
        /// The camera image (8- or 16-bit grey PNG).
        image: PathBuf,
        /// Output PLY file.
        #[arg(long)]
        out: PathBuf,
        /// Also write the fusion picture: distance colours over the camera image.
        #[arg(long)]
        fused: Option<PathBuf>,
        /// With --fused: distances NEAR,FAR in mm drawn red and blue (default: the points' 2nd
        /// to 98th percentile, rounded).
        #[arg(long)]
        range: Option<String>,
    },
    /// Cameras: list what can be opened, grab frames.
    #[command(subcommand)]
    Camera(CameraCommand),
    /// Serve a virtual GigE Vision camera on a loopback address: every frame is SCENE rendered
    /// under the light a projector monitor of DISPLAY shows at that moment.
    #[cfg(all(feature = "aravis", feature = "projector"))]
    VirtualCamera {
        /// The scene it sees (its projector's size must be the monitor's).
        #[arg(long)]
        scene: PathBuf,
        /// X display of the projector windows, e.g. :42.
        #[arg(long)]
        display: String,
        /// Monitor whose light it sees.
        #[arg(long, default_value_t = 0)]
        monitor: usize,
        /// Loopback address to serve on (GigE Vision's port 3956 is fixed).
        #[arg(long, default_value = "127.0.0.1")]
        address: String,
        /// Stop when the process that started it ends.
        #[arg(long)]
        exit_with_parent: bool,
    },
    /// Start a virtual cell's rig (Xvfb cut into one monitor per projector, one virtual camera
    /// per pair) and keep it running until Ctrl-C; then run risd on the virtual cell's config.
    #[cfg(all(feature = "aravis", feature = "projector"))]
    VirtualCell {
        /// Rig file.
        #[arg(long, default_value = "config/virtual-cell/rig.toml")]
        rig: PathBuf,
        /// X display to start (default: a free one).
        #[arg(long)]
        display: Option<String>,
    },
    /// Show a pattern full-screen on a projector (exact 1:1 pixels), or measure the present
    /// latency over a scan's sequence
    Project {
        /// Pattern name (white, black, flat_LLL, gray_col_KK, gray_col_KK_inv, gray_row_KK, gray_row_KK_inv).
        #[arg(long, default_value = "white")]
        pattern: String,
        /// Projector size (its native resolution), e.g. 1280x800.
        #[arg(long)]
        projector: String,
        /// Monitor index.
        #[arg(long, default_value_t = 0)]
        monitor: usize,
        /// Seconds to keep the pattern on screen.
        #[arg(long, default_value_t = 5.0)]
        hold: f64,
        /// Instead: show the scan's whole sequence N times and print the present latency.
        #[arg(long, value_name = "N", conflicts_with = "conformance")]
        latency: Option<usize>,
        /// Instead: check the projector against the driver conformance suite (a new cell's
        /// installation check).
        #[arg(long)]
        conformance: bool,
    },
    /// Precision (Eq. 3.4-3.6): repeated captures of one scene, per-pixel height standard
    /// deviation, the sensor figure and a heat map PNG.
    Precision {
        /// Sensor file (TOML).
        #[arg(long)]
        sensor: PathBuf,
        /// Capture directories of the same scene (two or more).
        #[arg(required = true)]
        captures: Vec<PathBuf>,
        /// Heat map to write (PNG).
        #[arg(long)]
        out: PathBuf,
        /// Top of the colour scale, mm (default three times the sensor figure).
        #[arg(long)]
        scale: Option<f64>,
        #[command(flatten)]
        decode: DecodeArgs,
    },
    /// Render a simulated scene: capture set, reference capture, sensor file and ground truth.
    Simulate {
        /// Scene file (TOML, SPEC §11).
        #[arg(long)]
        scene: PathBuf,
        /// Output directory (must not exist or be empty).
        #[arg(long)]
        out: PathBuf,
        /// Also render the camera's view of this projector picture (8-bit grey PNG of the
        /// projector's size, such as xpoint.png) to OUT/shown.png.
        #[arg(long)]
        show: Option<PathBuf>,
    },
    /// Ask a running risd for a scan, follow its progress and write the clouds and report
    /// into OUT/SCAN_ID/ (exit status 3 when the inspected part fails, 4 when it was not
    /// measured)
    Scan(commands::scan::ScanCommand),
    /// The station: a web console over the Zenoh fabric of one cell or many (live states,
    /// results with a 3D deviation view, the history in SQLite, trends with control limits and
    /// run rules, alarms, CSV and AQDEF export)
    Console(commands::console::ConsoleCommand),
    /// A running cell's stored scans: list them, get one's summary and report, fetch every
    /// stored item of one into OUT/ID/
    Scans(commands::scans::ScansCommand),
    /// The omnidirectional sensor (SPEC §13). With IMAGE: decode the ring pattern in the
    /// camera's image into the 360° cloud (sensor frame, mm, with `ring` and `azimuth` per
    /// point) and optionally the panorama with distance colours (azimuth 0…360° left to right,
    /// counter-clockwise from the sensor's +x seen from above; up at the top). `--analyse`: the
    /// resolution and depth error (Sec. 6.3) for wall points at each range and height.
    Omni {
        /// Omnidirectional sensor file (TOML, `kind = "omni"`).
        #[arg(long)]
        sensor: PathBuf,
        /// The camera's image of the ring pattern.
        #[arg(required_unless_present = "analyse")]
        image: Option<PathBuf>,
        /// The ring pattern shown (rings.toml; default: the design for the sensor's projector).
        #[arg(long)]
        pattern: Option<PathBuf>,
        /// Where to write the cloud (PLY).
        #[arg(long, required_unless_present = "analyse")]
        out: Option<PathBuf>,
        /// Also write the panorama (PNG) with distance colours.
        #[arg(long)]
        panorama: Option<PathBuf>,
        /// Distances coloured red and blue, mm (NEAR,FAR; default 2000,4000 as the seed).
        #[arg(long, default_value = "2000,4000")]
        range: String,
        /// Nearest and farthest point distance from the camera kept, mm (NEAR,FAR).
        #[arg(long, default_value = "300,20000")]
        depth: String,
        /// Print the error analysis instead of decoding.
        #[arg(long)]
        analyse: bool,
        /// Ranges of the walls from the sensor's axis, mm.
        #[arg(long, value_delimiter = ',', default_value = "2000,2500,3000,4000")]
        ranges: Vec<f64>,
        /// Heights FROM,TO,STEP in the sensor frame, mm.
        #[arg(long, default_value = "-1500,300,300")]
        heights: String,
        /// JSON on stdout instead of a table.
        #[arg(long)]
        json: bool,
    },
    /// Stream single-shot clouds from a running risd: start the stream, show frames per
    /// second, points and latency per sensor live, stop it, and keep each sensor's last cloud
    /// (SENSOR.ply, cell frame) and fusion picture (SENSOR.png) in OUT.
    Stream {
        #[command(flatten)]
        daemon: commands::client::DaemonArgs,
        /// Sensors to stream (repeat; default all).
        #[arg(long = "sensor")]
        sensors: Vec<String>,
        /// Frames per second asked of each pair (default: the rate_hz of the cell's single_shot section).
        #[arg(long)]
        rate: Option<f64>,
        /// Stop once every sensor delivered this many clouds.
        #[arg(long)]
        frames: Option<u64>,
        /// Stop after this many seconds.
        #[arg(long)]
        seconds: Option<f64>,
        /// Leave the stream running in risd when done.
        #[arg(long)]
        keep_running: bool,
        /// Write each sensor's last cloud and fusion picture here.
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// Inspect a cloud against its CAD model: deviation map, report and verdict (exit status 3
    /// when the part fails, 4 when too little of it or of a datum was measured for a verdict).
    Inspect(commands::inspect::InspectCommand),
    /// Acceptance test or re-verification by VDI/VDE 2634-2 (ISO 10360-13): PF, PS, SD and F
    /// from clouds of calibrated artefacts against the MPE, or a running cell's verification
    /// session (exit status 3 when a figure fails, 4 when an artefact was not measured).
    Verify(commands::verify::VerifyCommand),
    /// Experiments on simulated scenes.
    #[command(subcommand)]
    Experiment(ExperimentCommand),
    /// Calibration: the sensors' transforms into the cell frame.
    #[command(subcommand)]
    Calibrate(CalibrateCommand),
    /// Merge sensor clouds into the cell frame (each sensor's to_common transform), de-duplicating overlaps.
    Merge {
        /// Inputs as SENSOR.toml:CLOUD.ply.
        #[arg(required = true)]
        inputs: Vec<String>,
        /// Points of different sensors closer than this (mm) are duplicates; the more confident stays.
        #[arg(long, default_value_t = 0.5)]
        radius: f64,
        /// Output PLY.
        #[arg(long)]
        out: PathBuf,
    },
    /// Convert a point cloud between PLY and E57 (by the files' extensions; E57 in metres).
    Convert {
        /// Input cloud (.ply or .e57).
        input: PathBuf,
        /// Output cloud (.ply or .e57).
        output: PathBuf,
    },
    /// Rigidly register one point cloud onto another (ICP) and write the transform (TOML).
    Register {
        /// The reference cloud (PLY).
        #[arg(long)]
        fixed: PathBuf,
        /// The cloud to move (PLY).
        #[arg(long)]
        moving: PathBuf,
        /// Initial fixed_from_moving transform (TOML with a 4x4 `matrix`).
        #[arg(long)]
        init: Option<PathBuf>,
        /// point-to-plane or point-to-point.
        #[arg(long, default_value = "point-to-plane")]
        metric: String,
        /// Fraction of the closest pairs kept each iteration.
        #[arg(long, default_value_t = 0.9)]
        trim: f64,
        /// Pairs farther apart than this (mm) are never used.
        #[arg(long)]
        max_distance: Option<f64>,
        /// Iterations allowed; a registration that has not converged by then fails.
        #[arg(long, default_value_t = 50)]
        max_iterations: usize,
        /// Output transform file.
        #[arg(long)]
        out: PathBuf,
    },
    /// End-to-end demo: simulate the built-in scene, reconstruct it, write the cloud and accuracy.
    Demo {
        /// Output directory.
        #[arg(long, default_value = "out/demo")]
        out: PathBuf,
        /// Use this scene instead of the built-in one.
        #[arg(long)]
        scene: Option<PathBuf>,
    },
}

fn main() -> Result<()> {
    ris_daemon::logging::init("info", "error");
    let cli = Cli::parse();
    match cli.command {
        Command::Patterns(args) => commands::patterns::command(&args)?,
        Command::Decode {
            capture,
            out,
            decode,
        } => {
            commands::decode::run(&capture, &decode.params(), &out)?;
        }
        Command::Reconstruct {
            sensor,
            capture,
            out,
            model,
            drop_outside,
            decode,
        } => {
            let model = match model {
                Model::Auto => ModelChoice::Auto,
                Model::Parallax => ModelChoice::Parallax,
                Model::Classical => ModelChoice::Classical,
            };
            commands::reconstruct::run(
                &sensor,
                &capture,
                model,
                &decode.params(),
                drop_outside,
                &out,
            )?;
        }
        Command::SingleShot {
            sensor,
            pattern,
            image,
            out,
            fused,
            range,
        } => {
            anyhow::ensure!(
                range.is_none() || fused.is_some(),
                "--range colours the fusion picture: give --fused FUSED.png too"
            );
            let range = range
                .map(|r| commands::parse_range(&r, "--range"))
                .transpose()?;
            commands::single_shot::run(
                &sensor,
                &pattern,
                &image,
                &out,
                fused.as_deref().map(|f| (f, range)),
            )?;
        }
        #[cfg(all(feature = "aravis", feature = "projector"))]
        Command::VirtualCamera {
            scene,
            display,
            monitor,
            address,
            exit_with_parent,
        } => {
            let parent = std::os::unix::process::parent_id();
            let cam = commands::virtual_cell::virtual_camera(&scene, &display, monitor, &address)?;
            println!("virtual camera at {address}, lit by monitor {monitor} of {display}");
            let mut reported = 0;
            let mut since = std::time::Instant::now();
            loop {
                std::thread::sleep(std::time::Duration::from_millis(200));
                let (frames, grab_ms, render_ms) = cam.stats();
                if frames != reported && since.elapsed().as_secs() >= 5 {
                    // Where a frame's time goes, for the operator and the benchmark.
                    tracing::info!(frames, grab_ms, render_ms, "virtual camera");
                    (reported, since) = (frames, std::time::Instant::now());
                }
                if exit_with_parent && std::os::unix::process::parent_id() != parent {
                    let (frames, grab_ms, render_ms) = cam.stats();
                    tracing::info!(frames, grab_ms, render_ms, "the parent ended; stopping");
                    return Ok(());
                }
            }
        }
        #[cfg(all(feature = "aravis", feature = "projector"))]
        Command::VirtualCell { rig, display } => {
            let exe = anyhow::Context::context(std::env::current_exe(), "locating ris")?;
            let running = commands::virtual_cell::start_rig(&rig, &exe, display.as_deref())?;
            println!("virtual cell running on DISPLAY={}", running.display);
            for (a, m) in running.addresses.iter().zip(&running.monitors) {
                println!("  camera {a} lit by monitor {m}");
            }
            println!(
                "now: DISPLAY={} risd --config config/virtual-cell.toml   (Ctrl-C here stops the rig)",
                running.display
            );
            let runtime = anyhow::Context::context(
                tokio::runtime::Builder::new_current_thread()
                    .enable_all()
                    .build(),
                "runtime",
            )?;
            runtime.block_on(async {
                use tokio::signal::unix::{signal, SignalKind};
                let mut term = signal(SignalKind::terminate())?;
                tokio::select! {
                    _ = tokio::signal::ctrl_c() => {}
                    _ = term.recv() => {}
                }
                anyhow::Ok(())
            })?;
            drop(running);
        }
        Command::Project {
            pattern,
            projector,
            monitor,
            hold,
            latency,
            conformance,
        } => {
            let (width, height) = commands::parse_size(&projector)?;
            let what = match (latency, conformance) {
                (Some(n), _) => commands::project::Run::Latency(n),
                (None, true) => commands::project::Run::Conformance,
                (None, false) => commands::project::Run::Hold(hold),
            };
            commands::project::run(&pattern, width, height, monitor, what)?;
        }
        Command::Camera(CameraCommand::List { discover }) => {
            commands::camera::list(discover)?;
        }
        Command::Camera(CameraCommand::Grab {
            backend,
            device,
            trigger,
            count,
            exposure_us,
            timeout_ms,
            out,
        }) => {
            let software = match trigger.as_str() {
                "software" => true,
                "free" => false,
                other => anyhow::bail!("--trigger {other:?}: expected `software` or `free`"),
            };
            let backend = match backend {
                CameraBackend::Aravis => commands::camera::Backend::Aravis,
                CameraBackend::V4l2 => commands::camera::Backend::V4l2,
                CameraBackend::Mock => commands::camera::Backend::Mock,
            };
            commands::camera::grab(
                backend,
                &device,
                software,
                count,
                exposure_us,
                std::time::Duration::from_millis(timeout_ms),
                &out,
            )?;
        }
        Command::Precision {
            sensor,
            captures,
            out,
            scale,
            decode,
        } => {
            commands::precision::run(&sensor, &captures, &decode.params(), &out, scale)?;
        }
        Command::Simulate { scene, out, show } => {
            if ris_core::omni::calibrate::is_session(&scene) {
                ris_core::omni::calibrate::simulate_session_file(
                    &scene,
                    &ris_core::omni::Exposure::default(),
                    &out,
                )
                .with_context(|| {
                    format!(
                        "simulating the omni calibration session {}",
                        scene.display()
                    )
                })?;
                println!(
                    "simulated omni calibration session {} -> {}",
                    scene.display(),
                    out.display()
                );
                return Ok(());
            }
            if ris_core::omni::scene::OmniScene::is_room_scene(&scene) {
                commands::simulate::omni(&scene, &out, show.as_deref())?;
                return Ok(());
            }
            commands::simulate::run(&scene, &out, show.as_deref())?;
        }
        Command::Omni {
            sensor,
            image,
            pattern,
            out,
            panorama,
            range,
            depth,
            analyse: false,
            json,
            ..
        } => {
            let range = commands::parse_range(&range, "--range")?;
            let depth = commands::parse_range(&depth, "--depth")?;
            let (Some(image), Some(out)) = (image, out) else {
                anyhow::bail!("ris omni: IMAGE and --out are needed to decode (or --analyse)");
            };
            let summary = commands::omni::decode_file(
                &sensor,
                pattern.as_deref(),
                &image,
                &out,
                panorama.as_deref(),
                range,
                [depth.near, depth.far],
            )?;
            if json {
                println!("{}", serde_json::to_string_pretty(&summary)?);
            } else {
                println!("{}", summary.line());
            }
        }
        Command::Omni {
            sensor,
            ranges,
            heights,
            json,
            ..
        } => {
            let heights = commands::omni::heights(&heights)?;
            let points = commands::omni::analyse_file(&sensor, &ranges, &heights)?;
            if json {
                println!("{}", serde_json::to_string_pretty(&points)?);
            } else {
                commands::omni::print(&points);
            }
        }
        Command::Stream {
            daemon:
                commands::client::DaemonArgs {
                    connect,
                    cell,
                    user,
                    password_file,
                },
            sensors,
            rate,
            frames,
            seconds,
            keep_running,
            out,
        } => {
            commands::stream::run(&commands::stream::StreamArgs {
                connect,
                cell,
                sensors,
                rate,
                frames,
                seconds,
                keep_running,
                out,
                credentials: user.zip(password_file),
            })?;
        }
        Command::Scan(args) => {
            if let Some(code) = commands::scan::command(&args)? {
                std::process::exit(code);
            }
        }
        Command::Inspect(c) => {
            let report = commands::inspect::command(&c)?;
            if let Some(code) = commands::verdict_exit_code(&report.verdict) {
                std::process::exit(code);
            }
        }
        Command::Console(c) => commands::console::command(&c)?,
        Command::Scans(c) => commands::scans::command(&c)?,
        Command::Verify(c) => {
            if let Some(code) = commands::verify::command(&c)? {
                std::process::exit(code);
            }
        }
        Command::Experiment(ExperimentCommand::Motion {
            scene,
            speeds,
            direction,
            fps,
            exposure_ms,
            json,
        }) => {
            let [x, y, z] = direction[..] else {
                anyhow::bail!("--direction: three numbers X,Y,Z");
            };
            let m = commands::experiment::motion(&scene, &speeds, [x, y, z], fps, exposure_ms)?;
            if json {
                println!("{}", serde_json::to_string_pretty(&m)?);
            } else {
                commands::experiment::print_motion(&m);
            }
        }
        Command::Experiment(ExperimentCommand::Completeness { scene, json, out }) => {
            let c = commands::experiment::completeness(&scene, out.as_deref())?;
            if json {
                println!("{}", serde_json::to_string_pretty(&c)?);
            } else {
                commands::experiment::print_table(&c);
            }
        }
        Command::Calibrate(CalibrateCommand::Sensor {
            session,
            camera,
            out,
            report,
        }) => {
            let cal =
                commands::calibrate::sensor(&session, camera.as_deref(), &out, report.as_deref())?;
            if !cal.passed() {
                std::process::exit(3);
            }
        }
        Command::Calibrate(CalibrateCommand::Omni { session, out }) => {
            commands::calibrate::omni(&session, &out)?;
        }
        Command::Calibrate(CalibrateCommand::Camera {
            board,
            square,
            fix_aspect,
            images,
            out,
        }) => {
            commands::calibrate::camera(&board, square, fix_aspect, &images, &out)?;
        }
        Command::Calibrate(CalibrateCommand::Cell {
            gauge,
            inputs,
            max_rms,
            report,
        }) => {
            anyhow::ensure!(
                max_rms.is_finite() && max_rms > 0.0,
                "--max-rms must be positive, got {max_rms}"
            );
            let params = GaugeParams {
                max_rms,
                ..GaugeParams::default()
            };
            commands::calibrate::cell(&gauge, &inputs, &params, report.as_deref())?;
        }
        Command::Merge {
            inputs,
            radius,
            out,
        } => {
            commands::merge::run(&inputs, radius, &out)?;
        }
        Command::Convert { input, output } => {
            commands::convert::run(&input, &output)?;
        }
        Command::Register {
            fixed,
            moving,
            init,
            metric,
            trim,
            max_distance,
            max_iterations,
            out,
        } => {
            anyhow::ensure!(
                trim > 0.0 && trim <= 1.0,
                "--trim must be in (0, 1], got {trim}"
            );
            anyhow::ensure!(
                (1..=10_000).contains(&max_iterations),
                "--max-iterations must be 1 … 10000, got {max_iterations}"
            );
            let params = ris_core::register::IcpParams {
                metric: commands::register::metric(&metric)?,
                trim,
                max_distance: max_distance.unwrap_or(f64::INFINITY),
                max_iterations,
                ..Default::default()
            };
            commands::register::run(&fixed, &moving, init.as_deref(), &params, &out)?;
        }
        Command::Demo { out, scene } => {
            commands::demo::run(scene.as_deref(), &out)?;
        }
    }
    Ok(())
}
