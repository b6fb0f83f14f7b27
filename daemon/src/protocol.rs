//! The Zenoh protocol of a cell (SPEC §12), the one definition risd, the `ris` clients and the
//! tests share: every key expression, and every request, reply, state and status as a type that
//! is serialised as the JSON on the wire. A request is a JSON object on the exact key; the
//! parsers bound what they echo, so a hostile payload cannot become a huge reply or log line.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::config::{SensorKind, MAX_RATE_HZ};

/// Longest tag a request may carry, characters.
pub const MAX_TAG: usize = 256;
/// Longest piece of a request echoed in a reply or a log line, characters.
pub const MAX_ECHO: usize = 64;
/// Largest request body, bytes.
pub const MAX_REQUEST: usize = 64 * 1024;

/// `ris/<cell>/scan`.
pub fn scan_key(cell: &str) -> String {
    format!("ris/{cell}/scan")
}

/// `ris/<cell>/health`.
pub fn health_key(cell: &str) -> String {
    format!("ris/{cell}/health")
}

/// `ris/<cell>/scans/<id>/state`.
pub fn state_key(cell: &str, scan_id: &str) -> String {
    ScanItem::State.key(cell, scan_id)
}

/// `ris/<cell>/claim/<claim>`: the liveliness token a daemon holds from its first instant;
/// of two daemons of one cell the one with the smaller claim (earlier start) serves.
pub fn claim_key(cell: &str, claim: &str) -> String {
    format!("ris/{cell}/claim/{claim}")
}

/// `ris/<cell>/alarms`: what a station (`ris console`) raises when a run rule fires on a
/// part's trend (JSON, one alarm per publication).
pub fn alarms_key(cell: &str) -> String {
    format!("ris/{cell}/alarms")
}

/// `ris/<cell>/**`: everything of a cell (access control).
pub fn cell_key(cell: &str) -> String {
    format!("ris/{cell}/**")
}

/// `ris/<cell>/scans/**`: every scan's publications and stored items.
pub fn scans_key(cell: &str) -> String {
    format!("ris/{cell}/scans/**")
}

/// `ris/<cell>/scans/*/state`: every scan's states.
pub fn scan_states_key(cell: &str) -> String {
    format!("ris/{cell}/scans/*/state")
}

/// One item of a scan, under `ris/<cell>/scans/<id>/`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum ScanItem {
    /// `state`: the scan's [`ScanState`], published as it changes.
    State,
    /// `report`: the inspection report (JSON; a scan without inspection: its summary).
    Report,
    /// `summary`: the scan's summary (`scan.json`: tag, serial, operator, mode, per-sensor
    /// timings, the inspection's verdict).
    Summary,
    /// `page`: the one-page HTML report.
    Page,
    /// `map`: the labelled deviation map (PNG).
    Map,
    /// `deviation`: the deviation cloud (PLY).
    Deviation,
    /// `cloud/<name>`: a sensor's cloud or the merged one (PLY).
    Cloud(String),
}

impl ScanItem {
    /// The key of this item of scan `scan_id` of `cell`.
    pub fn key(&self, cell: &str, scan_id: &str) -> String {
        let item = match self {
            ScanItem::State => "state",
            ScanItem::Report => "report",
            ScanItem::Summary => "summary",
            ScanItem::Page => "page",
            ScanItem::Map => "map",
            ScanItem::Deviation => "deviation",
            ScanItem::Cloud(name) => return format!("ris/{cell}/scans/{scan_id}/cloud/{name}"),
        };
        format!("ris/{cell}/scans/{scan_id}/{item}")
    }

    /// The cell, scan id and item a key names (`None`: not a scan item's key).
    pub fn parse(key: &str) -> Option<(String, String, ScanItem)> {
        let parts: Vec<&str> = key.split('/').collect();
        let (cell, id) = match parts.as_slice() {
            ["ris", cell, "scans", id, ..] => (*cell, *id),
            _ => return None,
        };
        let item = match &parts[4..] {
            ["state"] => ScanItem::State,
            ["report"] => ScanItem::Report,
            ["summary"] => ScanItem::Summary,
            ["page"] => ScanItem::Page,
            ["map"] => ScanItem::Map,
            ["deviation"] => ScanItem::Deviation,
            ["cloud", name] => ScanItem::Cloud((*name).to_string()),
            _ => return None,
        };
        Some((cell.to_string(), id.to_string(), item))
    }
}

/// The reply to an accepted scan request.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ScanReply {
    /// The scan's id (its keys are under `ris/<cell>/scans/<id>/`).
    pub scan_id: String,
    /// `accepted`.
    pub state: String,
    /// The sensors the scan will acquire, in order (a client's progress knows its total from
    /// the start).
    #[serde(default)]
    pub sensors: Vec<String>,
}

/// The body of every refusal (an error reply): what to change.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ErrorReply {
    /// Why, in words.
    pub error: String,
}

/// A scan request (`ris/<cell>/scan` payload: a JSON object, every field optional).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScanRequest {
    /// How the pairs acquire (default `gray`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mode: Option<ScanMode>,
    /// Sensors to scan (default all).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sensors: Option<Vec<String>>,
    /// Inspect the merged cloud (default: when the cell defines exactly one part, or `part`
    /// names one).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub inspect: Option<bool>,
    /// Part id (required to inspect when the cell defines several).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub part: Option<String>,
    /// Free text stored with the scan (`scan.json`), at most [`MAX_TAG`] characters.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tag: Option<String>,
    /// The scanned part's serial number, stored with the scan; at most [`MAX_TAG`]
    /// characters.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub serial: Option<String>,
    /// Who started the scan (a station's signed-in user), stored with the scan; at most
    /// [`MAX_TAG`] characters.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub operator: Option<String>,
    /// The artefact a `verify` scan measures.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub artefact: Option<Artefact>,
    /// The position a `verify` scan measures (letters, digits, `.`, `_`, `-`; at most
    /// [`MAX_POSITION`] characters); measuring a position again replaces it in the session.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub position: Option<String>,
}

/// Longest position name of a `verify` scan, characters.
pub const MAX_POSITION: usize = 64;

/// `text` cut to [`MAX_ECHO`] characters (with the full length said) for replies and logs.
pub fn echo(text: &str) -> String {
    let n = text.chars().count();
    if n <= MAX_ECHO {
        format!("{text:?}")
    } else {
        let head: String = text.chars().take(MAX_ECHO).collect();
        format!("{head:?}… ({n} characters)")
    }
}

impl ScanRequest {
    /// Parse a request body: a JSON object (`{}` for every default) of at most
    /// [`MAX_REQUEST`] bytes; arrays, scalars, an empty body and unknown fields are refused.
    pub fn parse(body: &[u8]) -> Result<ScanRequest, String> {
        if body.len() > MAX_REQUEST {
            return Err(format!(
                "the request has {} bytes; at most {MAX_REQUEST} are accepted",
                body.len()
            ));
        }
        let value: serde_json::Value = serde_json::from_slice(body).map_err(|e| {
            format!(
                "malformed request: not JSON ({}); send a JSON object such as {{}}",
                e.classify_name()
            )
        })?;
        if !value.is_object() {
            return Err("malformed request: the body must be a JSON object such as {} or {\"sensors\": [\"s1\"]}".into());
        }
        let req: ScanRequest = serde_json::from_value(value).map_err(|e| {
            let text = e.to_string();
            let cut: String = text.chars().take(200).collect();
            format!("malformed request: {cut}")
        })?;
        for (field, text) in [
            ("tag", &req.tag),
            ("serial", &req.serial),
            ("operator", &req.operator),
        ] {
            let n = text.as_deref().map_or(0, |t| t.chars().count());
            if n > MAX_TAG {
                return Err(format!("`{field}` has {n} characters; at most {MAX_TAG}"));
            }
        }
        let verify = req.mode == Some(ScanMode::Verify);
        match (&req.artefact, &req.position) {
            (Some(_), Some(p)) if verify => check_position(p)?,
            (None, _) if verify => {
                return Err(
                    "a verify scan names its `artefact`: \"ball_bar\", \"sphere\" or \"plane\""
                        .into(),
                )
            }
            (_, None) if verify => {
                return Err("a verify scan names its `position` (such as \"bar-1\")".into())
            }
            (None, None) => {}
            _ => {
                return Err(
                    "`artefact` and `position` belong to a scan with \"mode\": \"verify\"".into(),
                )
            }
        }
        Ok(req)
    }
}

/// Refuse a position name that could not name files and keys.
fn check_position(p: &str) -> Result<(), String> {
    let n = p.chars().count();
    if n == 0 || n > MAX_POSITION {
        return Err(format!(
            "`position` {} must have 1 … {MAX_POSITION} characters",
            echo(p)
        ));
    }
    if !p
        .chars()
        .all(|c| c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-'))
        || p.starts_with('.')
    {
        return Err(format!(
            "`position` {} must be letters, digits, `.`, `_` or `-` (such as \"bar-1\")",
            echo(p)
        ));
    }
    Ok(())
}

// Scans: how one acquires and the states it goes through.

/// Progress of a scan, as the daemon publishes it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "state", rename_all = "snake_case")]
pub enum ScanState {
    /// Waiting in the queue.
    Queued,
    /// A pair is acquiring.
    Acquiring {
        /// Sensor.
        sensor: String,
        /// Step of an adaptive scan (`flats`, `advanced projection`, `final projection`, ...).
        #[serde(skip_serializing_if = "Option::is_none")]
        phase: Option<String>,
        /// Frames recorded (of this step, in an adaptive scan).
        frame: usize,
        /// Frames of the sequence (of this step).
        frames: usize,
    },
    /// A sensor's capture is being decoded and reconstructed.
    Reconstructing {
        /// Sensor.
        sensor: String,
    },
    /// Sensor clouds are merged.
    Merging,
    /// The merged cloud is registered to the part's CAD model and its deviations measured.
    Inspecting {
        /// Part id.
        part: String,
    },
    /// Finished.
    Done,
    /// Failed.
    Failed {
        /// Why.
        reason: String,
    },
}

/// How a scan acquires.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ScanMode {
    /// The Gray-code sequence with inverses, unmasked.
    #[default]
    Gray,
    /// The adaptive projection-mask loop (dark, black and shiny surfaces), then the Gray
    /// sequence under the final mask.
    Adaptive,
    /// One frame of the X-point pattern per pair (moving parts; sparser points).
    SingleShot,
    /// The Gray-code sequence of a calibrated artefact in one position of a verification
    /// session (`artefact` and `position` name it); its figures join the session.
    Verify,
}

impl ScanMode {
    /// Parse a request's or command line's mode.
    pub fn parse(text: &str) -> Option<ScanMode> {
        match text {
            "gray" => Some(ScanMode::Gray),
            "adaptive" => Some(ScanMode::Adaptive),
            "single-shot" => Some(ScanMode::SingleShot),
            "verify" => Some(ScanMode::Verify),
            _ => None,
        }
    }
}

// Streams: the request, its keys and the status.

/// `ris/<cell>/stream`: start, stop or ask about the stream.
pub fn stream_key(cell: &str) -> String {
    format!("ris/{cell}/stream")
}

/// `ris/<cell>/stream/<sensor>/<what>` (`cloud`, `fused`, `point`; `*` for every one).
pub fn stream_sensor_key(cell: &str, sensor: &str, what: &str) -> String {
    format!("ris/{cell}/stream/{sensor}/{what}")
}

/// A stream request (a JSON object on the exact stream key).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StreamRequest {
    /// `start`, `stop` or `status` (default `status`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub action: Option<String>,
    /// Frames per second asked of each pair (default the cell's `[single_shot] rate_hz`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rate: Option<f64>,
    /// Sensors to stream (default all).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sensors: Option<Vec<String>>,
}

/// What a start asks for, validated.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StreamSpec {
    /// Sensors, in cell order.
    pub sensors: Vec<String>,
    /// Frames per second per pair at most.
    pub rate_hz: f64,
}

impl StreamRequest {
    /// Parse a request body: a JSON object of at most [`MAX_REQUEST`] bytes.
    pub fn parse(body: &[u8]) -> Result<StreamRequest, String> {
        if body.len() > MAX_REQUEST {
            return Err(format!(
                "the request has {} bytes; at most {MAX_REQUEST} are accepted",
                body.len()
            ));
        }
        if body.is_empty() {
            return Ok(StreamRequest::default());
        }
        let value: serde_json::Value = serde_json::from_slice(body)
            .map_err(|_| "malformed request: not JSON; send {\"action\": \"start\"}".to_string())?;
        if !value.is_object() {
            return Err(
                "malformed request: the body must be a JSON object such as {\"action\": \"start\"}"
                    .into(),
            );
        }
        serde_json::from_value(value).map_err(|e| {
            let text = e.to_string();
            format!(
                "malformed request: {}",
                text.chars().take(200).collect::<String>()
            )
        })
    }

    /// The stream a start asks of `sensors` (the cell's, in order), at `default_rate` unless
    /// the request names one.
    pub fn spec(&self, sensors: &[String], default_rate: f64) -> Result<StreamSpec, String> {
        let rate = self.rate.unwrap_or(default_rate);
        if !(rate.is_finite() && rate > 0.0 && rate <= MAX_RATE_HZ) {
            return Err(format!(
                "`rate` {rate} must be a positive number of frames per second up to {MAX_RATE_HZ}"
            ));
        }
        let chosen = match &self.sensors {
            None => sensors.to_vec(),
            Some(list) if list.is_empty() => return Err("`sensors` is empty".into()),
            Some(list) => {
                if let Some(s) = list.iter().find(|s| !sensors.contains(s)) {
                    return Err(format!("no sensor {} in the cell", echo(s)));
                }
                sensors
                    .iter()
                    .filter(|s| list.contains(s))
                    .cloned()
                    .collect()
            }
        };
        Ok(StreamSpec {
            sensors: chosen,
            rate_hz: rate,
        })
    }
}

/// Counters of one sensor's stream.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SensorCounts {
    /// Frames captured.
    pub frames: u64,
    /// Frames replaced before they were computed.
    pub dropped: u64,
    /// Frames the camera did not deliver in time (the stream goes on; three in a row end it).
    pub missed: u64,
    /// Clouds published.
    pub published: u64,
    /// Points of the last cloud.
    pub points: usize,
    /// Milliseconds from the last published frame's arrival to its publication.
    pub latency_ms: f64,
}

/// The stream as health and `status` report it.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct StreamStatus {
    /// `stopped`, `streaming`, `paused` (a scan runs) or `failed`.
    pub state: String,
    /// The running (or last) stream.
    pub spec: Option<StreamSpec>,
    /// Per sensor.
    pub sensors: BTreeMap<String, SensorCounts>,
    /// Why the last stream ended on its own.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
}

// Verification: the acceptance test and re-verification of the cell (VDI/VDE 2634-2).

/// `ris/<cell>/verify`: start, finish, abort or ask about verification sessions.
pub fn verify_key(cell: &str) -> String {
    format!("ris/{cell}/verify")
}

/// `ris/<cell>/verifications/**`: every stored verification.
pub fn verifications_key(cell: &str) -> String {
    format!("ris/{cell}/verifications/**")
}

/// One item of a stored verification, under `ris/<cell>/verifications/<id>/`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VerificationItem {
    /// `certificate`: the session with every position and each scope's certificate (JSON,
    /// a [`VerificationRecord`]).
    Certificate,
    /// `page`: the certificate of the merged cell as a one-page HTML document.
    Page,
}

impl VerificationItem {
    /// The key of this item of verification `id` of `cell`.
    pub fn key(self, cell: &str, id: &str) -> String {
        let item = match self {
            VerificationItem::Certificate => "certificate",
            VerificationItem::Page => "page",
        };
        format!("ris/{cell}/verifications/{id}/{item}")
    }
}

/// A calibrated artefact of the acceptance test (the sections of the artefacts file).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Artefact {
    /// Two spheres on a bar: the sphere-spacing error SD.
    BallBar,
    /// The probing sphere: the probing errors PF and PS.
    Sphere,
    /// The flat: the flatness measurement error F.
    Plane,
}

impl Artefact {
    /// Its section of the artefacts file.
    pub fn section(self) -> &'static str {
        match self {
            Artefact::BallBar => "ball_bar",
            Artefact::Sphere => "sphere",
            Artefact::Plane => "plane",
        }
    }
}

/// What a verification session is: the full acceptance test, or a quick check between tests.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VerifyKind {
    /// The acceptance test (or a full re-verification): every position of the guideline.
    #[default]
    Acceptance,
    /// A quick check: one artefact in one or a few positions, compared with the acceptance.
    Check,
}

/// What a verify request asks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VerifyAction {
    /// The open session, the last verification and what health says about them.
    #[default]
    Status,
    /// Open a session (refused while one is open).
    Start,
    /// Evaluate the open session's positions into its certificates, store and publish them.
    Finish,
    /// Drop the open session.
    Abort,
    /// Every stored verification's figures, oldest first.
    History,
}

/// A request on `ris/<cell>/verify` (a JSON object; an empty body asks the status).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VerifyRequest {
    /// What to do (default `status`).
    #[serde(default)]
    pub action: VerifyAction,
    /// The kind of session a `start` opens (default `acceptance`).
    #[serde(default)]
    pub kind: VerifyKind,
}

impl VerifyRequest {
    /// Parse a request body: a JSON object of at most [`MAX_REQUEST`] bytes, or nothing.
    pub fn parse(body: &[u8]) -> Result<VerifyRequest, String> {
        if body.len() > MAX_REQUEST {
            return Err(format!(
                "the request has {} bytes; at most {MAX_REQUEST} are accepted",
                body.len()
            ));
        }
        if body.is_empty() {
            return Ok(VerifyRequest::default());
        }
        let value: serde_json::Value = serde_json::from_slice(body)
            .map_err(|_| "malformed request: not JSON; send {\"action\": \"start\"}".to_string())?;
        if !value.is_object() {
            return Err("malformed request: the body must be a JSON object such as {\"action\": \"finish\"}".into());
        }
        serde_json::from_value(value).map_err(|e| {
            let text = e.to_string();
            format!(
                "malformed request: {}",
                text.chars().take(200).collect::<String>()
            )
        })
    }
}

/// One position of a verification session: the figures of each scope (each sensor's cloud
/// and the merged cell's, all in the cell frame).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct VerifyPosition {
    /// The scan that measured it.
    pub scan_id: String,
    /// The artefact.
    pub artefact: Artefact,
    /// The position's name.
    pub position: String,
    /// When it was measured (UTC).
    pub time: String,
    /// Figures per scope (`s1`, …, `merged`): SD for a bar, F for a flat, PF then PS for a
    /// sphere.
    pub scopes: BTreeMap<String, Vec<ris_core::verify::Figure>>,
}

/// A verification session as stored (`verifications/<id>/session.json`) and published
/// (`certificate`).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct VerificationRecord {
    /// The session id (a directory and key segment).
    pub id: String,
    /// Cell.
    pub cell: String,
    /// Acceptance test or quick check.
    pub kind: VerifyKind,
    /// When it was opened (UTC).
    pub started: String,
    /// When it was finished (UTC); `None` while open.
    pub finished: Option<String>,
    /// Seconds since 1970 when it was finished.
    pub finished_unix: Option<u64>,
    /// The measured positions in the order they were (last) measured.
    pub positions: Vec<VerifyPosition>,
    /// Each scope's certificate (when finished).
    #[serde(default)]
    pub certificates: BTreeMap<String, ris_core::verify::Certificate>,
    /// The session's verdict: `fail` when any scope fails, else the merged cell's.
    pub verdict: Option<ris_core::verify::Status>,
    /// Figures near their MPE or drifted from the last passed acceptance test.
    #[serde(default)]
    pub warnings: Vec<String>,
}

/// A verification in short, as health and `status` give it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct VerificationSummary {
    /// The session id.
    pub id: String,
    /// Acceptance test or quick check.
    pub kind: VerifyKind,
    /// When it was opened (UTC).
    pub started: String,
    /// When it was finished (UTC).
    pub finished: Option<String>,
    /// Positions measured.
    pub positions: usize,
    /// The verdict (when finished).
    pub verdict: Option<ris_core::verify::Status>,
    /// Each scope's verdict (when finished).
    #[serde(default)]
    pub scopes: BTreeMap<String, ris_core::verify::Status>,
    /// Its warnings.
    #[serde(default)]
    pub warnings: Vec<String>,
}

/// Health's account of the cell's verification.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct VerificationHealth {
    /// The last finished verification.
    pub last: Option<VerificationSummary>,
    /// Its age, days.
    pub age_days: Option<f64>,
    /// The session being measured.
    pub open: Option<VerificationSummary>,
    /// What a user must know before trusting the cell's figures (never verified, the last
    /// verification failed or is stale, figures drifting); also in every inspection report.
    pub warnings: Vec<String>,
}

/// One scope's figures of one stored verification, for its history.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct HistoryEntry {
    /// The session id.
    pub id: String,
    /// Acceptance test or quick check.
    pub kind: VerifyKind,
    /// When it was finished (UTC).
    pub finished: String,
    /// The scope (`s1`, …, `merged`).
    pub scope: String,
    /// The scope's verdict.
    pub verdict: ris_core::verify::Status,
    /// Per figure (`SD`, `PF`, `PS`, `F`) the measured error of largest share of its MPE.
    pub worst: BTreeMap<String, Worst>,
}

/// The figure of largest share of its MPE among one kind's positions.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Worst {
    /// The position.
    pub position: String,
    /// The error, mm.
    pub error: f64,
    /// The MPE, mm.
    pub mpe: f64,
    /// |error| / MPE.
    pub share: f64,
}

// Health.

/// What `ris/<cell>/health` answers.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct Health {
    /// `preparing`, `ready`, `scanning` or `stopping`.
    pub state: String,
    /// Sensors of the cell.
    pub sensors: Vec<String>,
    /// Scans waiting.
    pub queue: usize,
    /// Last finished scan id.
    pub last_scan: Option<String>,
    /// Last failure.
    pub last_error: Option<String>,
    /// Each pair's drivers (empty while preparing).
    pub pairs: Vec<PairStatus>,
    /// While preparing: the pairs whose sensor model is ready.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub prepared: Vec<String>,
    /// The single-shot stream.
    #[serde(default)]
    pub stream: StreamStatus,
    /// The cell's verification (when the cell has `[verify]`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub verification: Option<VerificationHealth>,
    /// Requests refused since risd started (logged at most one line per ten seconds).
    #[serde(default)]
    pub refused: u64,
}

/// One pair's line in health.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PairStatus {
    /// Sensor.
    pub sensor: String,
    /// Backend.
    pub backend: String,
    /// What it measures with (`structured-light` or `omni`).
    pub kind: SensorKind,
    /// Camera id.
    pub camera: String,
    /// Projector id.
    pub projector: String,
    /// Driver state.
    #[serde(flatten)]
    pub driver: DriverState,
    /// Why this pair cannot scan single-shot (absent when it can).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub single_shot: Option<String>,
}

/// The state of a pair's drivers, as health reports it.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "state", rename_all = "snake_case")]
pub enum DriverState {
    /// Both devices answer.
    Connected,
    /// The camera was lost; risd tries to reopen it between scans.
    Reconnecting {
        /// The last error.
        reason: String,
    },
}

/// serde_json's error category as a word.
trait Classify {
    fn classify_name(&self) -> &'static str;
}

impl Classify for serde_json::Error {
    fn classify_name(&self) -> &'static str {
        match self.classify() {
            serde_json::error::Category::Io => "unreadable",
            serde_json::error::Category::Syntax => "syntax error",
            serde_json::error::Category::Data => "wrong data",
            serde_json::error::Category::Eof => "ends early",
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_json_objects_are_requests() {
        assert!(ScanRequest::parse(b"{}").is_ok());
        assert!(ScanRequest::parse(br#"{"sensors": ["s1"], "tag": "x"}"#).is_ok());
        for bad in [
            &b""[..],
            b"[]",
            b"[\"gray\"]",
            b"null",
            b"3",
            b"\"gray\"",
            b"{",
            b"{\"x\": 1}",
        ] {
            assert!(
                ScanRequest::parse(bad).is_err(),
                "{:?}",
                String::from_utf8_lossy(bad)
            );
        }
        let long = format!(r#"{{"tag": "{}"}}"#, "t".repeat(MAX_TAG + 1));
        assert!(ScanRequest::parse(long.as_bytes())
            .expect_err("refused")
            .contains("at most"));
        let huge_field = format!(r#"{{"{}": 1}}"#, "f".repeat(100_000));
        assert!(
            ScanRequest::parse(huge_field.as_bytes())
                .expect_err("refused")
                .len()
                < 400
        );
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig { failure_persistence: None, ..Default::default() })]

        /// Any bytes: a request or a bounded error, never a panic.
        #[test]
        fn any_body_gives_a_request_or_a_bounded_error(body in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..512)) {
            if let Err(e) = ScanRequest::parse(&body) {
                proptest::prop_assert!(e.len() < 400, "{}", e);
            }
        }

        /// JSON-shaped bodies with arbitrary field names and values.
        #[test]
        fn json_bodies_are_objects_or_refused(key in "[a-z_]{0,12}", value in "[ -~]{0,40}", array in proptest::prelude::any::<bool>()) {
            let body = if array {
                format!("[{value:?}]")
            } else {
                format!("{{{key:?}: {value:?}}}")
            };
            match ScanRequest::parse(body.as_bytes()) {
                Ok(r) => proptest::prop_assert!(!array && r.tag.as_deref().is_none_or(|t| t.chars().count() <= MAX_TAG)),
                Err(e) => proptest::prop_assert!(e.len() < 400, "{}", e),
            }
        }
    }

    #[test]
    fn scan_item_keys_parse_back() {
        for item in [
            ScanItem::State,
            ScanItem::Report,
            ScanItem::Summary,
            ScanItem::Page,
            ScanItem::Map,
            ScanItem::Deviation,
            ScanItem::Cloud("merged".into()),
            ScanItem::Cloud("s2".into()),
        ] {
            let key = item.key("cell-a", "20261126T101500.000Z-3");
            assert_eq!(
                ScanItem::parse(&key),
                Some(("cell-a".into(), "20261126T101500.000Z-3".into(), item)),
                "{key}"
            );
        }
        assert_eq!(state_key("c", "i"), "ris/c/scans/i/state");
        for other in [
            "ris/c/health",
            "ris/c/scans/i",
            "ris/c/scans/i/other",
            "ris/c/scans/i/cloud",
            "x/c/scans/i/state",
        ] {
            assert!(ScanItem::parse(other).is_none(), "{other}");
        }
    }

    #[test]
    fn modes_are_named_on_the_wire_and_unknown_ones_refused() {
        let r = ScanRequest::parse(br#"{"mode": "adaptive"}"#).expect("adaptive");
        assert_eq!(r.mode, Some(ScanMode::Adaptive));
        let e = ScanRequest::parse(br#"{"mode": "fast"}"#).expect_err("unknown");
        assert!(e.contains("fast") && e.contains("single-shot"), "{e}");
        let health: Health = serde_json::from_str(
            &serde_json::to_string(&Health {
                state: "ready".into(),
                ..Health::default()
            })
            .expect("json"),
        )
        .expect("health parses back");
        assert_eq!(health.state, "ready");
    }

    #[test]
    fn echoes_are_bounded() {
        assert_eq!(echo("s1"), "\"s1\"");
        let e = echo(&"x".repeat(1_000_000));
        assert!(e.len() < 100 && e.contains("1000000 characters"), "{e}");
    }
}
