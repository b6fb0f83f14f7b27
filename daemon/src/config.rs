//! The cell configuration of `risd` (TOML): what the cell is, its sensor pairs, where scans go,
//! how it talks Zenoh. Parsed with unknown keys refused, then validated into [`CellConfig`] with
//! errors that name the file and the field.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use serde::Deserialize;

/// `[cell]`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CellSection {
    /// Cell name: the `<cell>` of every Zenoh key (letters, digits, `-`, `_`).
    pub name: String,
}

/// `[zenoh]`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ZenohSection {
    /// `peer` or `client`.
    #[serde(default = "peer")]
    pub mode: String,
    /// Endpoints to listen on (default `tcp/127.0.0.1:7447`: loopback only).
    #[serde(default = "loopback")]
    pub listen: Vec<String>,
    /// Endpoints to connect to.
    #[serde(default)]
    pub connect: Vec<String>,
    /// Authentication and access control; without it anyone who reaches the endpoints may
    /// scan and read.
    #[serde(default)]
    pub access: Option<AccessSection>,
}

impl Default for ZenohSection {
    fn default() -> Self {
        ZenohSection {
            mode: peer(),
            listen: loopback(),
            connect: Vec::new(),
            access: None,
        }
    }
}

/// `[zenoh.access]`: who may do what on the cell's keys (Zenoh user/password authentication
/// and access control). Everything not granted here is denied, publishing under
/// `ris/<cell>/**` included.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AccessSection {
    /// Zenoh's user/password dictionary: one `user:password` per line (keep it mode 0600).
    pub users: PathBuf,
    /// Users who may start scans and read states, clouds, reports and health.
    #[serde(default)]
    pub operators: Vec<String>,
    /// Users who may read states, clouds, reports and health, but not scan.
    #[serde(default)]
    pub readers: Vec<String>,
}

/// `[storage]`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StorageSection {
    /// Directory of the scans (one sub-directory per scan).
    #[serde(default = "data_dir")]
    pub data_dir: PathBuf,
    /// Scans kept (oldest removed first); 0 keeps all.
    #[serde(default = "fifty")]
    pub keep_scans: u32,
    /// Scans older than this many days are removed; 0 keeps them.
    #[serde(default = "thirty")]
    pub max_age_days: u32,
    /// Also store each sensor's capture set.
    #[serde(default)]
    pub keep_captures: bool,
    /// Also write every cloud as E57 (`<name>.e57`, metres) beside its PLY.
    #[serde(default)]
    pub e57: bool,
    /// Where prepared pairs (decoded reference recordings) are kept between starts; default
    /// `<data_dir>/cache`.
    #[serde(default)]
    pub cache_dir: Option<PathBuf>,
}

impl StorageSection {
    /// The prepared pairs' cache directory.
    pub fn cache_dir(&self) -> PathBuf {
        self.cache_dir
            .clone()
            .unwrap_or_else(|| self.data_dir.join("cache"))
    }
}

impl Default for StorageSection {
    fn default() -> Self {
        StorageSection {
            data_dir: data_dir(),
            keep_scans: fifty(),
            max_age_days: thirty(),
            keep_captures: false,
            e57: false,
            cache_dir: None,
        }
    }
}

/// `[workers]`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorkersSection {
    /// Compute threads (decoding, reconstruction, merge); 0 = one per core.
    #[serde(default)]
    pub threads: usize,
    /// Scans that may wait behind the running one; more are refused.
    #[serde(default = "four")]
    pub queue: usize,
    /// Longest a scan's computing stage (one sensor's reconstruction, the inspection) may run,
    /// s: past it the stage stops at its next iteration and the scan fails naming it. Within
    /// 1 … 86 400; the default 600 is far above a healthy stage (seconds).
    #[serde(default = "stage_deadline")]
    pub stage_deadline_s: f64,
}

fn stage_deadline() -> f64 {
    crate::scan::STAGE_DEADLINE.as_secs_f64()
}

impl WorkersSection {
    /// [`WorkersSection::stage_deadline_s`] as a duration.
    pub fn stage_deadline(&self) -> std::time::Duration {
        std::time::Duration::from_secs_f64(self.stage_deadline_s)
    }
}

impl Default for WorkersSection {
    fn default() -> Self {
        WorkersSection {
            threads: 0,
            queue: four(),
            stage_deadline_s: stage_deadline(),
        }
    }
}

/// `[[sensor]]`.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorSection {
    /// Sensor name (`s1`): the key of its cloud.
    pub name: String,
    /// `structured-light` (a projector+camera pair; the default) or `omni` (camera and
    /// projector behind hyperbolic mirrors, SPEC §13: one ring-pattern frame per scan).
    #[serde(default)]
    pub kind: Option<String>,
    /// `mock` (simulated pair), `aravis` (GigE Vision), `v4l2` (USB) or `replay` (a recorded
    /// capture set).
    pub backend: String,
    /// Camera device: id or IP (aravis), path (v4l2).
    #[serde(default)]
    pub device: Option<String>,
    /// Monitor of the projector window.
    #[serde(default)]
    pub projector_monitor: Option<u32>,
    /// Sensor file (camera, projector, reference, `[to_common]`); required except for `mock`.
    #[serde(default)]
    pub sensor_file: Option<PathBuf>,
    /// Simulator scene of a `mock` pair (its sensor world frame).
    #[serde(default)]
    pub scene: Option<PathBuf>,
    /// Sensor → cell transform of a `mock` pair (row-major 4×4); others take it from the
    /// sensor file.
    #[serde(default)]
    pub to_common: Option<[[f64; 4]; 4]>,
    /// Pairs in the same group project at the same time (their projections do not overlap);
    /// groups take turns.
    #[serde(default)]
    pub exposure_group: u32,
    /// Camera exposure, µs.
    #[serde(default = "exposure")]
    pub exposure_us: f64,
    /// Camera gain, dB (hardware pairs; default: the camera's own setting).
    #[serde(default)]
    pub gain_db: Option<f64>,
    /// `software` (a trigger command after each slide is on screen; the default) or
    /// `hardware` (the projector's sync output wired to a camera line).
    #[serde(default)]
    pub trigger: Option<String>,
    /// Camera line of a hardware trigger (default `Line0`).
    #[serde(default)]
    pub trigger_line: Option<String>,
    /// Wait between a slide's presentation and its exposure, ms (projector response time).
    #[serde(default)]
    pub settle_ms: f64,
    /// Longest wait for one frame after its trigger, ms (default 2000): long exposures, slow
    /// links or software-rendered cameras need more.
    #[serde(default = "frame_timeout")]
    pub frame_timeout_ms: f64,
    /// The capture set a `replay` pair serves (a kept scan's `captures/<sensor>`).
    #[serde(default)]
    pub recording: Option<PathBuf>,
    /// Distances drawn red and blue in this sensor's fusion pictures or panoramas, mm
    /// (default: the cell's `[single_shot] range_mm`): sensors at different standoffs.
    #[serde(default)]
    pub range_mm: Option<[f64; 2]>,
}

/// `[[part]]`: a part the cell inspects.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PartSection {
    /// Part id named by scan requests.
    pub id: String,
    /// CAD model (STEP in a build with the `step` feature; STL, binary or ASCII; PLY or OBJ
    /// mesh), cell frame.
    pub cad: PathBuf,
    /// Datums (`[[datum]] name, position, radius`, and for a 3-2-1 frame `order`, `feature`).
    #[serde(default)]
    pub datums: Option<PathBuf>,
    /// Tolerance on |deviation|, mm.
    pub tolerance: f64,
    /// Minimum fraction of the CAD surface measured for a verdict (default 0.5); below it
    /// the part is `not_measured`.
    #[serde(default = "half")]
    pub min_coverage: f64,
    /// `fit` (default): register the cloud to the CAD before measuring deviations; `known`:
    /// the part sits where the cell's calibration puts it (a fixture), nothing is fitted and
    /// every deviation is measured where it lies.
    #[serde(default)]
    pub pose: PartPose,
    /// The surface coverage and the verdict are about: `whole` (default, every face of the
    /// CAD) or `seen` (what the scanning sensors' cameras and projectors can see of the part
    /// where it lies).
    #[serde(default)]
    pub inspected: PartSurface,
    /// The inspected surface as STEP faces, by entity number (`faces = [17, 137]`, the `#n` of
    /// their ADVANCED_FACE); needs a STEP `cad`. Points closest to other faces are left out.
    #[serde(default)]
    pub faces: Vec<u32>,
    /// Characteristics file: ISO 1101 flatness, profile, diameter and position toleranced on
    /// the STEP `cad`'s faces (`[[characteristic]]` tables); each is part of the verdict.
    #[serde(default)]
    pub characteristics: Option<PathBuf>,
}

/// Which part of a part's CAD its inspection is about.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PartSurface {
    /// Every face of the CAD.
    #[default]
    Whole,
    /// What the scanning sensors can see (camera and projector both).
    Seen,
}

/// How a part's pose in the cell is found.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PartPose {
    /// Registered to the CAD model (from the nominal pose), each scan.
    #[default]
    Fit,
    /// Known: the cell frame is the part's (a fixtured part).
    Known,
}

/// `[ros2]`: also publish every cloud as a ROS 2 `sensor_msgs/msg/PointCloud2` the way
/// `rmw_zenoh` does (see `ros2`).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Ros2Section {
    /// Publish (default false).
    #[serde(default)]
    pub enable: bool,
    /// The ROS domain (`ROS_DOMAIN_ID`), 0 … 232.
    #[serde(default)]
    pub domain_id: u32,
    /// The node's namespace, which prefixes the topics (default `/ris`).
    #[serde(default = "ros_namespace")]
    pub namespace: String,
    /// The node's name (default `risd`).
    #[serde(default = "ros_node")]
    pub node: String,
    /// The tf frame of the merged cloud (default: the cell's name).
    #[serde(default)]
    pub frame_id: Option<String>,
    /// The tf frame of each sensor's cloud, by sensor (default `<cell>_<sensor>`).
    #[serde(default)]
    pub sensor_frames: std::collections::BTreeMap<String, String>,
}

impl Default for Ros2Section {
    fn default() -> Self {
        Ros2Section {
            enable: false,
            domain_id: 0,
            namespace: ros_namespace(),
            node: ros_node(),
            frame_id: None,
            sensor_frames: Default::default(),
        }
    }
}

impl Ros2Section {
    /// The tf frame of the merged cloud of `cell`.
    pub fn cell_frame(&self, cell: &str) -> String {
        self.frame_id.clone().unwrap_or_else(|| cell.to_string())
    }

    /// The tf frame of `sensor`'s cloud.
    pub fn sensor_frame(&self, cell: &str, sensor: &str) -> String {
        self.sensor_frames
            .get(sensor)
            .cloned()
            .unwrap_or_else(|| format!("{cell}_{sensor}"))
    }
}

/// Whether `s` is one token of a ROS 2 name: a letter or `_`, then letters, digits or `_`.
fn ros_token(s: &str) -> bool {
    s.chars()
        .next()
        .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
        && s.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
}

/// `[single_shot]`: the X-point pattern every pair projects for single-shot scans and
/// streams, and how streams are shown.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SingleShotSection {
    /// Grid steps of the pattern, projector pixels (default 14 × 14).
    #[serde(default = "xpoint_step")]
    pub step: [u32; 2],
    /// Seed of the pattern's code.
    #[serde(default)]
    pub seed: u64,
    /// Distances drawn red and blue in the fusion pictures, mm (default: each frame's own
    /// 2nd to 98th percentile).
    #[serde(default)]
    pub range_mm: Option<[f64; 2]>,
    /// Frames per second a stream asks of each pair unless its request says otherwise.
    #[serde(default = "stream_rate")]
    pub rate_hz: f64,
    /// Regions of each projector with a finer step (`[[single_shot.dense]]`).
    #[serde(default)]
    pub dense: Vec<ris_core::single_shot::DenseRegion>,
}

impl Default for SingleShotSection {
    fn default() -> Self {
        SingleShotSection {
            step: xpoint_step(),
            seed: 0,
            range_mm: None,
            rate_hz: stream_rate(),
            dense: Vec::new(),
        }
    }
}

/// Fastest stream rate a request or the config may ask, frames per second.
pub const MAX_RATE_HZ: f64 = 1000.0;

fn xpoint_step() -> [u32; 2] {
    [14, 14]
}
fn stream_rate() -> f64 {
    10.0
}

/// `[verify]`: the cell's acceptance test and re-verification (VDI/VDE 2634-2) through
/// `mode: "verify"` scans.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VerifySection {
    /// The artefacts file (`ARTEFACTS.toml`: calibrated artefacts, MPE, the calibrated volume
    /// in the cell frame).
    pub artefacts: PathBuf,
    /// A verification older than this many days is stale: health and every inspection report
    /// say so (0: never stale).
    #[serde(default = "thirty_f")]
    pub max_age_days: f64,
    /// Warn when a measured SD or PF reaches this share of its MPE, or moves by it from the
    /// last passed acceptance test's figure at the same position (0 … 1).
    #[serde(default = "half")]
    pub drift_share: f64,
}

/// A cell configuration file.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CellFile {
    /// The cell.
    pub cell: CellSection,
    /// Zenoh.
    #[serde(default)]
    pub zenoh: ZenohSection,
    /// Storage.
    #[serde(default)]
    pub storage: StorageSection,
    /// Compute workers.
    #[serde(default)]
    pub workers: WorkersSection,
    /// Sensor pairs.
    #[serde(default)]
    pub sensor: Vec<SensorSection>,
    /// Parts.
    #[serde(default)]
    pub part: Vec<PartSection>,
    /// ROS 2 publication.
    #[serde(default)]
    pub ros2: Ros2Section,
    /// Single-shot scans and streams.
    #[serde(default)]
    pub single_shot: SingleShotSection,
    /// The acceptance test and re-verification.
    #[serde(default)]
    pub verify: Option<VerifySection>,
}

fn peer() -> String {
    "peer".into()
}
fn data_dir() -> PathBuf {
    PathBuf::from("/var/lib/risd")
}
fn fifty() -> u32 {
    50
}
fn thirty() -> u32 {
    30
}
fn thirty_f() -> f64 {
    30.0
}
fn loopback() -> Vec<String> {
    vec!["tcp/127.0.0.1:7447".into()]
}
fn ros_namespace() -> String {
    "/ris".into()
}
fn ros_node() -> String {
    "risd".into()
}
fn half() -> f64 {
    0.5
}
fn four() -> usize {
    4
}
fn exposure() -> f64 {
    10_000.0
}
fn frame_timeout() -> f64 {
    2_000.0
}

/// Which kind of pair a sensor is.
#[derive(Clone, Debug, PartialEq)]
pub enum Backend {
    /// Simulated pair rendering its sensor's `scene`.
    Mock,
    /// GigE Vision camera.
    Aravis,
    /// V4L2 camera.
    V4l2,
    /// A recorded capture set served as the camera's frames.
    Replay {
        /// The capture set directory.
        recording: PathBuf,
    },
}

impl Backend {
    /// The name a configuration gives it.
    pub fn name(&self) -> &'static str {
        match self {
            Backend::Mock => "mock",
            Backend::Aravis => "aravis",
            Backend::V4l2 => "v4l2",
            Backend::Replay { .. } => "replay",
        }
    }
}

/// The hardware backends this build has, as the end of a sentence.
fn built_backends() -> String {
    let mut on = Vec::new();
    if cfg!(feature = "aravis") && cfg!(feature = "projector") {
        on.push("aravis");
    }
    if cfg!(feature = "v4l2") && cfg!(feature = "projector") {
        on.push("v4l2");
    }
    if on.is_empty() {
        String::new()
    } else {
        format!(" and {}", on.join(", "))
    }
}

/// What a sensor measures with.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SensorKind {
    /// A projector+camera pair: Gray codes, the adaptive loop, X-point single shots.
    #[default]
    StructuredLight,
    /// An omnidirectional sensor: every scan and stream frame is one ring-pattern frame.
    Omni,
}

/// A validated sensor pair.
#[derive(Clone, Debug)]
pub struct SensorConfig {
    /// Name.
    pub name: String,
    /// What it measures with.
    pub kind: SensorKind,
    /// Backend.
    pub backend: Backend,
    /// Camera device.
    pub device: Option<String>,
    /// Projector monitor.
    pub projector_monitor: Option<u32>,
    /// Sensor file, resolved.
    pub sensor_file: Option<PathBuf>,
    /// Simulator scene that gives the sensor model of a mock pair (and of a replay pair
    /// recorded from one).
    pub scene: Option<PathBuf>,
    /// Sensor → cell transform given in the cell file (pairs modelled by a scene).
    pub to_common: Option<nalgebra::Matrix4<f64>>,
    /// Exposure group.
    pub exposure_group: u32,
    /// Exposure, µs.
    pub exposure_us: f64,
    /// Gain, dB.
    pub gain_db: Option<f64>,
    /// How exposures start.
    pub trigger: ris_drivers::TriggerMode,
    /// Wait between presentation and exposure.
    pub settle: std::time::Duration,
    /// Longest wait for one frame.
    pub frame_timeout: std::time::Duration,
    /// Fusion picture range of this sensor, mm (`None`: the cell's).
    pub range_mm: Option<[f64; 2]>,
}

/// A validated part.
#[derive(Clone, Debug)]
pub struct PartConfig {
    /// Id.
    pub id: String,
    /// CAD, resolved.
    pub cad: PathBuf,
    /// Datums, resolved.
    pub datums: Option<PathBuf>,
    /// Tolerance, mm.
    pub tolerance: f64,
    /// Minimum measured fraction of the CAD surface.
    pub min_coverage: f64,
    /// Whether the pose is fitted or known.
    pub pose: PartPose,
    /// The inspected surface (with `faces` empty).
    pub inspected: PartSurface,
    /// The inspected STEP faces (entity numbers); empty: `inspected` says.
    pub faces: Vec<u32>,
    /// Characteristics file, resolved.
    pub characteristics: Option<PathBuf>,
}

/// A validated cell configuration, paths resolved against the file's directory.
#[derive(Clone, Debug)]
pub struct CellConfig {
    /// Cell name.
    pub name: String,
    /// Zenoh settings.
    pub zenoh: ZenohSection,
    /// Storage settings (data dir resolved).
    pub storage: StorageSection,
    /// Workers.
    pub workers: WorkersSection,
    /// Sensor pairs in file order.
    pub sensors: Vec<SensorConfig>,
    /// Parts.
    pub parts: Vec<PartConfig>,
    /// ROS 2 publication (validated: names are ROS 2 names when enabled).
    pub ros2: Ros2Section,
    /// Single-shot scans and streams (validated).
    pub single_shot: SingleShotSection,
    /// The acceptance test and re-verification (artefacts path resolved).
    pub verify: Option<VerifySection>,
}

/// Most scans that may wait in the queue.
pub const MAX_QUEUE: usize = 1000;
/// Most compute threads.
pub const MAX_THREADS: usize = 1024;
/// Longest exposure, µs.
pub const MAX_EXPOSURE_US: f64 = 10_000_000.0;

/// Why a picture's distance range `[near, far]` (mm) is unusable, if it is.
fn range_error([near, far]: [f64; 2]) -> Option<String> {
    (!(near.is_finite() && far.is_finite() && near >= 0.0 && near < far))
        .then(|| format!("[{near}, {far}]: need 0 <= near < far (mm)"))
}

/// Check Zenoh endpoints (`tcp/host:port`, a port within 1 … 65535), naming `key` (e.g.
/// `zenoh.listen`, or `--listen`) in the error. risd and `ris` are built with Zenoh's TCP
/// transport only: another protocol would fail when the session opens, so it is refused here.
pub fn check_endpoints(ctx: &str, key: &str, list: &[String]) -> Result<()> {
    for e in list {
        let bad = |why: &str| {
            anyhow::anyhow!(
                "{ctx}: `{key}`: {:?} {why}; an endpoint looks like tcp/127.0.0.1:7447",
                e.chars().take(100).collect::<String>()
            )
        };
        let (proto, rest) = e.split_once('/').ok_or_else(|| bad("has no protocol"))?;
        let address = rest.split(['?', '#']).next().unwrap_or_default();
        match proto {
            "tcp" => {
                let (host, port) = address.rsplit_once(':').ok_or_else(|| bad("has no port"))?;
                if host.is_empty() {
                    return Err(bad("has no host"));
                }
                match port.parse::<u16>() {
                    Ok(p) if p > 0 => {}
                    _ => return Err(bad("has a port outside 1 … 65535")),
                }
            }
            "udp" | "tls" | "quic" | "unixsock-stream" | "ws" | "serial" => {
                return Err(bad(&format!(
                    "uses {proto}, a Zenoh transport this build does not include (it speaks tcp only)"
                )))
            }
            _ => return Err(bad("names an unknown protocol (use tcp)")),
        }
    }
    Ok(())
}

/// The configuration of the built-in mock cell (`config/mock-cell.toml`).
pub const MOCK_CELL: &str = include_str!("../../config/mock-cell.toml");

impl CellConfig {
    /// Read and validate a cell file.
    pub fn load(path: &Path) -> Result<CellConfig> {
        let text =
            std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        let base = path.parent().unwrap_or(Path::new("."));
        CellConfig::parse(&text, base, &path.display().to_string())
    }

    /// Parse and validate `text`; relative paths resolve against `base`, `ctx` names the source.
    pub fn parse(text: &str, base: &Path, ctx: &str) -> Result<CellConfig> {
        let file: CellFile = toml::from_str(text).map_err(|e| anyhow::anyhow!("{ctx}: {e}"))?;
        let field = |f: &str, msg: String| anyhow::anyhow!("{ctx}: `{f}`: {msg}");
        let name_ok = |s: &str| {
            !s.is_empty()
                && s.chars()
                    .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
        };
        if !name_ok(&file.cell.name) {
            return Err(field(
                "cell.name",
                format!(
                    "{:?} must be letters, digits, - or _ (it is a Zenoh key)",
                    file.cell.name
                ),
            ));
        }
        if !matches!(file.zenoh.mode.as_str(), "peer" | "client") {
            return Err(field(
                "zenoh.mode",
                format!("{:?} must be \"peer\" or \"client\"", file.zenoh.mode),
            ));
        }
        check_endpoints(ctx, "zenoh.listen", &file.zenoh.listen)?;
        check_endpoints(ctx, "zenoh.connect", &file.zenoh.connect)?;
        if !(1..=MAX_QUEUE).contains(&file.workers.queue) {
            return Err(field(
                "workers.queue",
                format!("{} must be within 1 … {MAX_QUEUE}", file.workers.queue),
            ));
        }
        if file.workers.threads > MAX_THREADS {
            return Err(field(
                "workers.threads",
                format!("{} must be within 0 … {MAX_THREADS}", file.workers.threads),
            ));
        }
        if !(1.0..=86_400.0).contains(&file.workers.stage_deadline_s) {
            return Err(field(
                "workers.stage_deadline_s",
                format!(
                    "{} must be within 1 … 86400 s",
                    file.workers.stage_deadline_s
                ),
            ));
        }
        if file.sensor.is_empty() {
            return Err(field("sensor", "the cell has no [[sensor]]".into()));
        }
        let resolve = |p: &Path| {
            if p.is_absolute() {
                p.to_path_buf()
            } else {
                base.join(p)
            }
        };
        let mut sensors: Vec<SensorConfig> = Vec::new();
        for (i, s) in file.sensor.iter().enumerate() {
            let f = |k: &str| format!("sensor[{i}].{k}");
            if !name_ok(&s.name) {
                return Err(field(
                    &f("name"),
                    format!("{:?} must be letters, digits, - or _", s.name),
                ));
            }
            if sensors.iter().any(|o| o.name == s.name) {
                return Err(field(&f("name"), format!("{:?} is used twice", s.name)));
            }
            if s.name == "merged" {
                return Err(field(
                    &f("name"),
                    "\"merged\" names the merged cloud".into(),
                ));
            }
            if !(s.exposure_us.is_finite()
                && s.exposure_us > 0.0
                && s.exposure_us <= MAX_EXPOSURE_US)
            {
                return Err(field(
                    &f("exposure_us"),
                    format!(
                        "{} must be a positive number of µs up to {MAX_EXPOSURE_US} (10 s)",
                        s.exposure_us
                    ),
                ));
            }
            let scene = s.scene.as_deref().map(resolve);
            let kind = match s.kind.as_deref() {
                None | Some("structured-light") => SensorKind::StructuredLight,
                Some("omni") => SensorKind::Omni,
                Some(other) => {
                    return Err(field(
                        &f("kind"),
                        format!(
                            "{:?} is not \"structured-light\" or \"omni\"",
                            other.chars().take(64).collect::<String>()
                        ),
                    ))
                }
            };
            let omni = kind == SensorKind::Omni;
            if omni && s.backend == "replay" {
                return Err(field(
                    &f("backend"),
                    "an omni sensor is \"mock\", \"aravis\" or \"v4l2\"; replay serves Gray-code recordings".into(),
                ));
            }
            let backend = match s.backend.as_str() {
                "mock" if scene.is_none() => {
                    return Err(field(
                        &f("scene"),
                        "a mock pair needs the scene it simulates".into(),
                    ))
                }
                "mock" => Backend::Mock,
                "aravis" => Backend::Aravis,
                "v4l2" => Backend::V4l2,
                "replay" => Backend::Replay {
                    recording: resolve(s.recording.as_deref().ok_or_else(|| {
                        field(
                            &f("recording"),
                            "a replay pair needs the capture set it serves".into(),
                        )
                    })?),
                },
                other => {
                    return Err(field(
                        &f("backend"),
                        format!(
                            "{:?} is not one of \"mock\", \"aravis\", \"v4l2\", \"replay\"",
                            other.chars().take(64).collect::<String>()
                        ),
                    ))
                }
            };
            let hardware = matches!(backend, Backend::Aravis | Backend::V4l2);
            if hardware {
                if s.sensor_file.is_none() {
                    return Err(field(
                        &f("sensor_file"),
                        "a hardware pair needs its sensor file".into(),
                    ));
                }
                if s.device.is_none() {
                    return Err(field(
                        &f("device"),
                        "a hardware pair needs its camera device".into(),
                    ));
                }
                if s.projector_monitor.is_none() {
                    return Err(field(
                        &f("projector_monitor"),
                        "a hardware pair needs the monitor of its projector".into(),
                    ));
                }
            } else if s.device.is_some() || s.projector_monitor.is_some() {
                return Err(field(
                    &f(if s.device.is_some() {
                        "device"
                    } else {
                        "projector_monitor"
                    }),
                    format!("a {} pair has no devices", s.backend),
                ));
            }
            if matches!(backend, Backend::Replay { .. })
                && s.scene.is_some() == s.sensor_file.is_some()
            {
                return Err(field(
                    &f("scene"),
                    "a replay pair takes its sensor model from `scene` (recorded from a mock pair) or `sensor_file`, one of them".into(),
                ));
            }
            if scene.is_some() && hardware {
                return Err(field(
                    &f("scene"),
                    "a hardware pair's model is its sensor file, not a scene".into(),
                ));
            }
            if s.to_common.is_some() && scene.is_none() && !omni {
                return Err(field(
                    &f("to_common"),
                    "only pairs modelled by a scene take it here; others read [to_common] from the sensor file".into(),
                ));
            }
            if (scene.is_some() || omni) && s.to_common.is_none() {
                return Err(field(
                    &f("to_common"),
                    if omni {
                        "an omni sensor needs its sensor → cell transform here (its sensor file has none)".into()
                    } else {
                        "a pair modelled by a scene needs its sensor → cell transform".into()
                    },
                ));
            }
            if let Some(g) = s.gain_db {
                if !(g.is_finite() && (0.0..=48.0).contains(&g)) {
                    return Err(field(
                        &f("gain_db"),
                        format!("{g} must be within 0 … 48 dB"),
                    ));
                }
            }
            if let Some(why) = s.range_mm.and_then(range_error) {
                return Err(field(&f("range_mm"), why));
            }
            if !(s.settle_ms.is_finite() && (0.0..=10_000.0).contains(&s.settle_ms)) {
                return Err(field(
                    &f("settle_ms"),
                    format!("{} must be within 0 … 10000 ms", s.settle_ms),
                ));
            }
            if !(s.frame_timeout_ms.is_finite() && (10.0..=120_000.0).contains(&s.frame_timeout_ms))
            {
                return Err(field(
                    &f("frame_timeout_ms"),
                    format!("{} must be within 10 … 120000 ms", s.frame_timeout_ms),
                ));
            }
            let trigger = match (s.trigger.as_deref(), &s.trigger_line) {
                (None | Some("software"), None) => ris_drivers::TriggerMode::Software,
                (None | Some("software"), Some(_)) => {
                    return Err(field(
                        &f("trigger_line"),
                        "only a hardware trigger has a line".into(),
                    ))
                }
                (Some("hardware"), line) => {
                    if let Some(l) = line {
                        if l.is_empty()
                            || l.len() > 64
                            || !l.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
                        {
                            return Err(field(
                                &f("trigger_line"),
                                format!(
                                    "{:?} is not a camera line name such as Line0",
                                    l.chars().take(64).collect::<String>()
                                ),
                            ));
                        }
                    }
                    if !hardware {
                        return Err(field(
                            &f("trigger"),
                            format!("a {} pair has no trigger line", s.backend),
                        ));
                    }
                    ris_drivers::TriggerMode::Hardware {
                        source: line.clone().unwrap_or_else(|| "Line0".into()),
                    }
                }
                (Some(other), _) => {
                    return Err(field(
                        &f("trigger"),
                        format!(
                            "{:?} is not \"software\" or \"hardware\"",
                            other.chars().take(64).collect::<String>()
                        ),
                    ))
                }
            };
            let to_common = match s.to_common {
                None => None,
                Some(m) => {
                    let m = nalgebra::Matrix4::from_fn(|r, c| m[r][c]);
                    let rot = m.fixed_view::<3, 3>(0, 0).into_owned();
                    let ortho = (rot.transpose() * rot - nalgebra::Matrix3::identity()).norm();
                    if !m.iter().all(|v| v.is_finite())
                        || ortho > 1e-6
                        || rot.determinant() < 0.0
                        || (m.row(3) - nalgebra::RowVector4::new(0.0, 0.0, 0.0, 1.0)).norm() > 1e-9
                    {
                        return Err(field(
                            &f("to_common"),
                            "must be a rigid transform (proper rotation, last row 0 0 0 1)".into(),
                        ));
                    }
                    Some(m)
                }
            };
            sensors.push(SensorConfig {
                name: s.name.clone(),
                kind,
                backend,
                device: s.device.clone(),
                projector_monitor: s.projector_monitor,
                sensor_file: s.sensor_file.as_deref().map(resolve),
                scene,
                to_common,
                exposure_group: s.exposure_group,
                exposure_us: s.exposure_us,
                gain_db: s.gain_db,
                trigger,
                settle: std::time::Duration::from_secs_f64(s.settle_ms / 1000.0),
                frame_timeout: std::time::Duration::from_secs_f64(s.frame_timeout_ms / 1000.0),
                range_mm: s.range_mm,
            });
        }
        let mut parts: Vec<PartConfig> = Vec::new();
        for (i, p) in file.part.iter().enumerate() {
            let f = |k: &str| format!("part[{i}].{k}");
            if !name_ok(&p.id) {
                return Err(field(
                    &f("id"),
                    format!("{:?} must be letters, digits, - or _", p.id),
                ));
            }
            if parts.iter().any(|o| o.id == p.id) {
                return Err(field(&f("id"), format!("{:?} is used twice", p.id)));
            }
            if !(p.tolerance.is_finite() && p.tolerance > 0.0) {
                return Err(field(
                    &f("tolerance"),
                    format!("{} must be positive", p.tolerance),
                ));
            }
            if !(0.0..=1.0).contains(&p.min_coverage) {
                return Err(field(
                    &f("min_coverage"),
                    format!("{} must be within 0 … 1", p.min_coverage),
                ));
            }
            if !p.faces.is_empty() && p.inspected == PartSurface::Seen {
                return Err(field(
                    &f("faces"),
                    "give the inspected surface either as `faces` or as `inspected = \"seen\"`, not both".into(),
                ));
            }
            parts.push(PartConfig {
                id: p.id.clone(),
                cad: resolve(&p.cad),
                datums: p.datums.as_deref().map(resolve),
                tolerance: p.tolerance,
                min_coverage: p.min_coverage,
                pose: p.pose,
                inspected: p.inspected,
                faces: p.faces.clone(),
                characteristics: p.characteristics.as_deref().map(resolve),
            });
        }
        let mut zenoh = file.zenoh.clone();
        if let Some(a) = &mut zenoh.access {
            a.users = resolve(&a.users);
            if a.operators.is_empty() && a.readers.is_empty() {
                return Err(field(
                    "zenoh.access",
                    "names no operators and no readers: nobody could use the cell".into(),
                ));
            }
            for u in a.operators.iter().chain(&a.readers) {
                if u.is_empty() || u.contains([':', '\n']) {
                    return Err(field(
                        "zenoh.access.operators/readers",
                        format!("{u:?} is not a user name"),
                    ));
                }
            }
        }
        let mut storage = file.storage.clone();
        storage.data_dir = resolve(&storage.data_dir);
        storage.cache_dir = storage.cache_dir.as_deref().map(resolve);
        let single_shot = file.single_shot.clone();
        if single_shot
            .step
            .iter()
            .any(|&d| !(ris_core::single_shot::MIN_STEP..=512).contains(&d))
        {
            return Err(field(
                "single_shot.step",
                format!(
                    "{:?}: each step must be {} … 512 projector pixels",
                    single_shot.step,
                    ris_core::single_shot::MIN_STEP
                ),
            ));
        }
        for (k, r) in single_shot.dense.iter().enumerate() {
            r.check(None, single_shot.step)
                .map_err(|why| field(&format!("single_shot.dense[{k}]"), why))?;
        }
        if let Some(why) = single_shot.range_mm.and_then(range_error) {
            return Err(field("single_shot.range_mm", why));
        }
        if !(single_shot.rate_hz.is_finite()
            && single_shot.rate_hz > 0.0
            && single_shot.rate_hz <= MAX_RATE_HZ)
        {
            return Err(field(
                "single_shot.rate_hz",
                format!(
                    "{} must be a positive rate up to {MAX_RATE_HZ}",
                    single_shot.rate_hz
                ),
            ));
        }
        let ros2 = file.ros2.clone();
        if ros2.domain_id > 232 {
            return Err(field(
                "ros2.domain_id",
                format!("{} must be within 0 … 232", ros2.domain_id),
            ));
        }
        for (k, frame) in ros2
            .frame_id
            .iter()
            .map(|f| ("ros2.frame_id".to_string(), f))
            .chain(
                ros2.sensor_frames
                    .iter()
                    .map(|(s, f)| (format!("ros2.sensor_frames.{s}"), f)),
            )
        {
            if frame.is_empty()
                || frame.len() > 256
                || frame.chars().any(|c| c.is_whitespace() || c.is_control())
            {
                return Err(field(&k, format!("{frame:?} is not a tf frame id")));
            }
        }
        if let Some(s) = ros2
            .sensor_frames
            .keys()
            .find(|s| !sensors.iter().any(|c| &c.name == *s))
        {
            return Err(field(
                &format!("ros2.sensor_frames.{s}"),
                "names no sensor of the cell".into(),
            ));
        }
        if ros2.enable {
            let ns_ok = ros2.namespace == "/"
                || (ros2.namespace.starts_with('/')
                    && ros2.namespace[1..].split('/').all(ros_token));
            if !ns_ok {
                return Err(field(
                    "ros2.namespace",
                    format!("{:?} is not a ROS 2 namespace such as /ris", ros2.namespace),
                ));
            }
            if !ros_token(&ros2.node) {
                return Err(field(
                    "ros2.node",
                    format!(
                        "{:?} is not a ROS 2 node name (letters, digits, _)",
                        ros2.node
                    ),
                ));
            }
            if !ros_token(&file.cell.name) {
                return Err(field(
                    "cell.name",
                    format!("{:?} is part of the ROS 2 topics with [ros2] enabled: letters, digits and _, not starting with a digit", file.cell.name),
                ));
            }
            if let Some(s) = sensors.iter().find(|s| !ros_token(&s.name)) {
                return Err(field(
                    "sensor.name",
                    format!("{:?} is part of a ROS 2 topic with [ros2] enabled: letters, digits and _, not starting with a digit", s.name),
                ));
            }
        }
        let mut verify = file.verify.clone();
        if let Some(v) = &mut verify {
            v.artefacts = resolve(&v.artefacts);
            if !(v.max_age_days.is_finite() && v.max_age_days >= 0.0) {
                return Err(field(
                    "verify.max_age_days",
                    format!("{} must be a number of days, 0 or more", v.max_age_days),
                ));
            }
            if !(v.drift_share > 0.0 && v.drift_share <= 1.0) {
                return Err(field(
                    "verify.drift_share",
                    format!("{} must be a share of the MPE within (0, 1]", v.drift_share),
                ));
            }
        }
        Ok(CellConfig {
            name: file.cell.name,
            zenoh,
            storage,
            workers: file.workers,
            sensors,
            parts,
            ros2,
            single_shot,
            verify,
        })
    }

    /// The exposure groups in order, each with the indices of its sensors.
    pub fn exposure_groups(&self) -> Vec<(u32, Vec<usize>)> {
        let mut groups: std::collections::BTreeMap<u32, Vec<usize>> = Default::default();
        for (i, s) in self.sensors.iter().enumerate() {
            groups.entry(s.exposure_group).or_default().push(i);
        }
        groups.into_iter().collect()
    }

    /// Refuse backends this build of risd cannot run (hardware backends are cargo features),
    /// naming the feature to build with.
    pub fn check_build(&self) -> Result<()> {
        for s in &self.sensors {
            let needs: &[(&str, bool)] = match s.backend {
                Backend::Aravis => &[
                    ("aravis", cfg!(feature = "aravis")),
                    ("projector", cfg!(feature = "projector")),
                ],
                Backend::V4l2 => &[
                    ("v4l2", cfg!(feature = "v4l2")),
                    ("projector", cfg!(feature = "projector")),
                ],
                Backend::Mock | Backend::Replay { .. } => &[],
            };
            let missing: Vec<&str> = needs
                .iter()
                .filter(|(_, on)| !on)
                .map(|(f, _)| *f)
                .collect();
            if !missing.is_empty() {
                bail!(
                    "sensor {}: backend {:?} needs a risd built with the {} feature{} (cargo build --release --features {}); this build runs the mock and replay backends{}",
                    s.name,
                    s.backend.name(),
                    missing.join(" and "),
                    if missing.len() > 1 { "s" } else { "" },
                    missing.join(","),
                    built_backends()
                );
            }
        }
        Ok(())
    }

    /// Check that this build can run every backend ([`CellConfig::check_build`]) and that every
    /// referenced file exists and parses (scenes, sensor files, recordings, CAD, datums).
    pub fn check_files(&self) -> Result<()> {
        self.check_build()?;
        check_data_dir(&self.storage.data_dir)?;
        for s in &self.sensors {
            if s.kind == SensorKind::Omni {
                match (&s.scene, &s.sensor_file) {
                    (Some(scene), _) => {
                        ris_core::omni::scene::OmniScene::load(scene)
                            .map(|_| ())
                            .with_context(|| format!("sensor {}: room scene", s.name))?
                    }
                    (None, Some(f)) => ris_core::omni::OmniSensor::load(f)
                        .map(|_| ())
                        .with_context(|| format!("sensor {}: omni sensor file", s.name))?,
                    (None, None) => {}
                }
                continue;
            }
            if let Some(scene) = &s.scene {
                ris_core::sim::Scene::load(scene)
                    .with_context(|| format!("sensor {}: scene", s.name))?;
            }
            if let Backend::Replay { recording } = &s.backend {
                if !recording.join("capture.toml").is_file() {
                    bail!(
                        "sensor {}: no recording at {} (replay serves a capture set kept by a scan: `risd --once --keep-captures --data-dir DIR --scan-id ID` keeps it under DIR/scans/ID/captures/{})",
                        s.name,
                        recording.display(),
                        s.name
                    );
                }
                ris_core::capture::CaptureSet::load(recording)
                    .with_context(|| format!("sensor {}: recording", s.name))?;
            }
            if let Some(f) = &s.sensor_file {
                let sensor = ris_core::sensor::Sensor::load(f)
                    .with_context(|| format!("sensor {}: sensor file", s.name))?;
                if sensor.to_common.is_none() && s.to_common.is_none() {
                    bail!(
                        "sensor {}: {} has no [to_common]; calibrate the cell (ris calibrate cell)",
                        s.name,
                        f.display()
                    );
                }
            }
        }
        if let Some(a) = &self.zenoh.access {
            let text = std::fs::read_to_string(&a.users)
                .with_context(|| format!("zenoh.access.users: reading {}", a.users.display()))?;
            let known: Vec<&str> = text
                .lines()
                .filter_map(|l| l.split_once(':').map(|(u, _)| u))
                .collect();
            for u in a.operators.iter().chain(&a.readers) {
                if !known.contains(&u.as_str()) {
                    bail!(
                        "zenoh.access: user {u:?} has no password in {}",
                        a.users.display()
                    );
                }
            }
        }
        if let Some(v) = &self.verify {
            ris_core::verify::Artefacts::load(&v.artefacts).context("verify.artefacts")?;
        }
        for p in &self.parts {
            let mesh = crate::scan::Part::load_cad(p)?.0;
            if let Some(d) = &p.datums {
                let datums = ris_core::inspect::load_datums(d)
                    .with_context(|| format!("part {}: datums", p.id))?;
                if let Some(bounds) = mesh.bounds() {
                    ris_core::inspect::check_datums_against(
                        &d.display().to_string(),
                        &datums,
                        bounds,
                    )
                    .with_context(|| format!("part {}: datums", p.id))?;
                }
            }
        }
        Ok(())
    }
}

/// Whether risd could keep its scans in `dir`: an existing writable directory, or one it can
/// create (its nearest existing ancestor is a writable directory).
pub fn check_data_dir(dir: &Path) -> Result<()> {
    let named = |why: String| anyhow::anyhow!("storage.data_dir: {}: {why}", dir.display());
    let mut existing = dir;
    loop {
        match std::fs::metadata(existing) {
            Ok(m) if !m.is_dir() => {
                return Err(named(if existing == dir {
                    "is not a directory".into()
                } else {
                    format!("{} is not a directory", existing.display())
                }))
            }
            Ok(_) => break,
            Err(_) => match existing.parent() {
                Some(p) if !p.as_os_str().is_empty() => existing = p,
                _ => {
                    existing = Path::new(".");
                    break;
                }
            },
        }
    }
    // Writable as risd needs it: a file can be created and removed there.
    let probe = existing.join(format!(".risd-check-{}", std::process::id()));
    match std::fs::File::create(&probe) {
        Ok(_) => {
            let _ = std::fs::remove_file(&probe);
            Ok(())
        }
        Err(e) => Err(named(format!(
            "{} is not writable ({}): give risd a directory it may write (--data-dir or [storage] data_dir)",
            existing.display(),
            e.kind()
        ))),
    }
}
