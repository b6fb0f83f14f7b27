//! The service's answers: scan and stream requests, streamed points and the stored scans.

use std::path::Path;
use std::sync::{mpsc, Mutex};

use anyhow::Result;
use zenoh::query::Query;
use zenoh::Session;

use crate::cell::ScanJob;
use crate::config::CellConfig;
use crate::protocol::{
    echo, scan_key, state_key, stream_key, stream_sensor_key, verify_key, ErrorReply, Health,
    ScanMode, ScanReply, ScanRequest, ScanState, StreamRequest, VerificationItem,
    VerificationRecord, VerifyAction, VerifyRequest,
};
use crate::scan;
use crate::store;
use crate::stream::{self, StreamControl};
use crate::verification::{self, Ledger};

use super::refusals::Refusals;
use super::worker::{publish_async, Job};

/// Validate a request against the cell and choose the part to inspect (an index into the
/// cell's parts); the error is the reply's reason.
pub fn validate(req: &ScanRequest, config: &CellConfig) -> Result<Option<usize>, String> {
    if let Some(list) = &req.sensors {
        if list.is_empty() {
            return Err("`sensors` is empty".into());
        }
        for s in list {
            if !config.sensors.iter().any(|c| c.name == *s) {
                return Err(format!("no sensor {} in cell {:?}", echo(s), config.name));
            }
        }
    }
    let named = match &req.part {
        Some(p) => Some(
            config
                .parts
                .iter()
                .position(|c| c.id == *p)
                .ok_or_else(|| format!("no part {} in cell {:?}", echo(p), config.name))?,
        ),
        None => None,
    };
    if req.mode == Some(ScanMode::Verify) {
        if config.verify.is_none() {
            return Err(format!(
                "cell {:?} has no [verify] section (its artefacts file): it cannot run verify scans",
                config.name
            ));
        }
        if req.inspect == Some(true) || req.part.is_some() {
            return Err(
                "a verify scan measures an artefact, not a part: leave out `part` and `inspect`"
                    .into(),
            );
        }
        return Ok(None);
    }
    // A single-shot cloud is sparse and noisier than a Gray-code one: it is inspected only
    // when the request asks for it, never by default.
    let single = req.mode == Some(ScanMode::SingleShot);
    match (req.inspect, named, config.parts.len()) {
        (Some(false), Some(_), _) => Err("`part` is named but `inspect` is false".into()),
        (Some(false), None, _) => Ok(None),
        (None, _, _) if single => Ok(None),
        (_, Some(i), _) => Ok(Some(i)),
        (_, None, 1) => Ok(Some(0)),
        (Some(true), None, 0) => Err(format!("cell {:?} defines no part to inspect", config.name)),
        (Some(true), None, n) => Err(format!(
            "cell {:?} defines {n} parts; name one in `part`",
            config.name
        )),
        (None, None, _) => Ok(None),
    }
}

pub(super) async fn reply_error(q: &Query, key: &str, reason: &str, refusals: &Refusals) {
    refusals.note(key, reason);
    let reply = ErrorReply {
        error: reason.to_string(),
    };
    if let Err(e) = q
        .reply_err(serde_json::to_string(&reply).unwrap_or_default())
        .await
    {
        tracing::warn!(%key, error = %e, "error reply failed");
    }
}

/// What a scan request is judged and queued with.
pub(super) struct ScanDesk<'a> {
    pub(super) config: &'a CellConfig,
    pub(super) status: &'a Mutex<Health>,
    pub(super) ledger: Option<&'a Mutex<Ledger>>,
    pub(super) session: &'a Session,
    pub(super) refusals: &'a Refusals,
}

pub(super) async fn handle_scan(
    q: &Query,
    desk: &ScanDesk<'_>,
    tx: &mpsc::SyncSender<Job>,
    counter: u64,
) {
    let ScanDesk {
        config,
        status,
        ledger,
        session,
        refusals,
    } = *desk;
    let key = scan_key(&config.name);
    // Only the exact key starts a scan: a wildcard query (`ris/*/scan`, `**`) is not a request.
    if q.key_expr().as_str() != key {
        tracing::debug!(asked = %q.key_expr(), "wildcard query on the scan key ignored");
        return;
    }
    let body = q
        .payload()
        .map(|p| p.to_bytes().into_owned())
        .unwrap_or_default();
    let outcome = ScanRequest::parse(&body)
        .and_then(|r| validate(&r, config).map(|part| (r, part)))
        .and_then(|(r, part)| {
            if let (Some(a), Some(ledger)) = (r.artefact, ledger) {
                ledger
                    .lock()
                    .map_err(|_| "the verification ledger is unavailable".to_string())?
                    .check(a)?;
            }
            Ok((r, part))
        })
        .and_then(|(r, part)| {
            let scan_id = scan::new_scan_id(counter);
            // Counted before the worker can take it, so the count never goes stale.
            if let Ok(mut s) = status.lock() {
                s.queue += 1;
            }
            let job = Job {
                scan_id: scan_id.clone(),
                scan: ScanJob {
                    sensors: r.sensors.clone(),
                    part,
                    tag: r.tag.clone(),
                    serial: r.serial.clone(),
                    operator: r.operator.clone(),
                    mode: r.mode.unwrap_or_default(),
                    verify: r.artefact.zip(r.position.clone()),
                    notes: Vec::new(),
                },
            };
            let sent = tx.try_send(job);
            if sent.is_err() {
                if let Ok(mut s) = status.lock() {
                    s.queue = s.queue.saturating_sub(1);
                }
            }
            match sent {
                Ok(()) => Ok((scan_id, r)),
                Err(mpsc::TrySendError::Full(_)) => Err(format!(
                    "the scan queue is full ({} waiting); try again later",
                    config.workers.queue
                )),
                Err(mpsc::TrySendError::Disconnected(_)) => Err("risd is stopping".into()),
            }
        });
    match outcome {
        Ok((scan_id, r)) => {
            tracing::info!(%scan_id, tag = ?r.tag.as_deref().map(echo), "scan accepted");
            publish_async(session, &config.name, &scan_id, &ScanState::Queued).await;
            let reply = ScanReply {
                scan_id,
                state: "accepted".into(),
                sensors: r
                    .sensors
                    .clone()
                    .unwrap_or_else(|| config.sensors.iter().map(|s| s.name.clone()).collect()),
            };
            if let Err(e) = q
                .reply(&key, serde_json::to_string(&reply).unwrap_or_default())
                .await
            {
                tracing::warn!(error = %e, "scan reply failed");
            }
        }
        Err(reason) => reply_error(q, &key, &reason, refusals).await,
    }
}

/// `ris/<cell>/stream`: start, stop or report the single-shot stream.
pub(super) async fn handle_stream(
    q: &Query,
    config: &CellConfig,
    ready: bool,
    status: &Mutex<Health>,
    streams: &StreamControl,
    refusals: &Refusals,
) {
    let key = stream_key(&config.name);
    if q.key_expr().as_str() != key {
        return;
    }
    let body = q
        .payload()
        .map(|p| p.to_bytes().into_owned())
        .unwrap_or_default();
    let names: Vec<String> = config.sensors.iter().map(|s| s.name.clone()).collect();
    let outcome = StreamRequest::parse(&body).and_then(|r| match r.action.as_deref() {
        None | Some("status") => Ok(serde_json::to_value(streams.status()).unwrap_or_default()),
        Some("stop") => {
            let st = streams.stop();
            tracing::info!("stream stopped by request");
            Ok(serde_json::to_value(st).unwrap_or_default())
        }
        Some("start") => {
            if !ready {
                return Err("the cell is starting: its pairs are being prepared; try again when ris/<cell>/health is alive".into());
            }
            let spec = r.spec(&names, config.single_shot.rate_hz)?;
            let pairs = status.lock().map(|s| s.pairs.clone()).unwrap_or_default();
            for p in pairs.iter().filter(|p| spec.sensors.contains(&p.sensor)) {
                if let Some(why) = &p.single_shot {
                    return Err(why.clone());
                }
            }
            tracing::info!(sensors = ?spec.sensors, rate_hz = spec.rate_hz, "stream requested");
            let keys: serde_json::Map<String, serde_json::Value> = spec
                .sensors
                .iter()
                .map(|s| {
                    (
                        s.clone(),
                        serde_json::json!({
                            "cloud": stream_sensor_key(&config.name, s, "cloud"),
                            "fused": stream_sensor_key(&config.name, s, "fused"),
                            "point": stream_sensor_key(&config.name, s, "point"),
                        }),
                    )
                })
                .collect();
            let reply = serde_json::json!({
                "state": "streaming",
                "sensors": spec.sensors,
                "rate_hz": spec.rate_hz,
                "keys": keys,
            });
            streams.start(spec);
            Ok(reply)
        }
        Some(other) => Err(format!(
            "unknown action {} (start, stop, status)",
            echo(other)
        )),
    });
    match outcome {
        Ok(v) => {
            if let Err(e) = q.reply(&key, v.to_string()).await {
                tracing::warn!(error = %e, "stream reply failed");
            }
        }
        Err(reason) => reply_error(q, &key, &reason, refusals).await,
    }
}

/// `ris/<cell>/stream/<sensor>/point?u=..&v=..`: the streamed point nearest a camera pixel.
pub(super) async fn handle_point(q: &Query, streams: &StreamControl) {
    let key = q.key_expr().clone();
    let sensor = key
        .as_str()
        .split('/')
        .nth(3)
        .unwrap_or_default()
        .to_string();
    if sensor.contains('*') {
        return;
    }
    // `u=..&v=..` as well as Zenoh's own `u=..;v=..`.
    let text = q.parameters().as_str().to_string();
    let params: Vec<(&str, &str)> = text
        .split(['&', ';'])
        .filter_map(|kv| kv.split_once('='))
        .collect();
    let num = |name: &str| {
        params
            .iter()
            .find(|(k, _)| *k == name)
            .map(|(_, v)| *v)
            .ok_or_else(|| format!("`{name}` is missing: ask ...point?u=<column>&v=<row>"))
            .and_then(|v| {
                v.parse::<f64>()
                    .map_err(|_| format!("`{name}` = {} is not a number", echo(v)))
            })
    };
    let answer = num("u")
        .and_then(|u| num("v").map(|v| (u, v)))
        .and_then(|(u, v)| stream::point_query(streams, &sensor, u, v));
    match answer {
        Ok(json) => {
            if let Err(e) = q.reply(key, json).await {
                tracing::warn!(error = %e, "point reply failed");
            }
        }
        Err(reason) => {
            let reply = serde_json::json!({ "error": reason }).to_string();
            if let Err(e) = q.reply_err(reply).await {
                tracing::warn!(error = %e, "point error reply failed");
            }
        }
    }
}

/// `ris/<cell>/verify`: open, finish, abort or report the cell's verification sessions; a
/// finished session's certificate and page are published under
/// `ris/<cell>/verifications/<id>/`.
pub(super) async fn handle_verify(
    q: &Query,
    cell: &str,
    ledger: Option<&Mutex<Ledger>>,
    session: &Session,
    refusals: &Refusals,
) {
    let key = verify_key(cell);
    if q.key_expr().as_str() != key {
        return;
    }
    let body = q
        .payload()
        .map(|p| p.to_bytes().into_owned())
        .unwrap_or_default();
    // Finishing writes the certificates: blocking work, kept off the runtime's other tasks.
    let outcome = tokio::task::block_in_place(
        || -> Result<(serde_json::Value, Option<VerificationRecord>), String> {
            let ledger = ledger.ok_or_else(|| {
                format!(
                "cell {cell:?} has no [verify] section (its artefacts file): it cannot be verified"
            )
            })?;
            let r = VerifyRequest::parse(&body)?;
            let mut l = ledger
                .lock()
                .map_err(|_| "the verification ledger is unavailable".to_string())?;
            fn json<T: serde::Serialize>(v: &T) -> serde_json::Value {
                serde_json::to_value(v).unwrap_or_default()
            }
            Ok(match r.action {
                VerifyAction::Status => (json(&l.health(verification::unix_now())), None),
                VerifyAction::Start => (json(&l.start(r.kind)?), None),
                VerifyAction::Abort => (json(&l.abort()?), None),
                VerifyAction::History => (json(&l.history(None)), None),
                VerifyAction::Finish => {
                    let record = l.finish()?;
                    (json(&verification::summary(&record)), Some(record))
                }
            })
        },
    );
    match outcome {
        Ok((reply, finished)) => {
            if let Some(record) = finished {
                let certificate = serde_json::to_vec(&record).unwrap_or_default();
                let ck = VerificationItem::Certificate.key(cell, &record.id);
                if let Err(e) = session
                    .put(&ck, certificate)
                    .congestion_control(zenoh::qos::CongestionControl::Block)
                    .await
                {
                    tracing::warn!(key = %ck, error = %e, "publication failed");
                }
                let dir = ledger
                    .and_then(|l| l.lock().ok().map(|l| l.session_dir(&record.id)))
                    .unwrap_or_default();
                if let Ok(page) = tokio::fs::read(dir.join("verify.html")).await {
                    let pk = VerificationItem::Page.key(cell, &record.id);
                    if let Err(e) = session
                        .put(&pk, page)
                        .congestion_control(zenoh::qos::CongestionControl::Block)
                        .await
                    {
                        tracing::warn!(key = %pk, error = %e, "publication failed");
                    }
                }
            }
            if let Err(e) = q.reply(&key, reply.to_string()).await {
                tracing::warn!(error = %e, "verify reply failed");
            }
        }
        Err(reason) => reply_error(q, &key, &reason, refusals).await,
    }
}

/// Answer `ris/<cell>/verifications/**` from the finished sessions on disk: `<id>/certificate`
/// (the session with its certificates) and `<id>/page` (the merged cell's certificate page).
pub(super) async fn handle_verifications(q: &Query, cell: &str, ledger: &Mutex<Ledger>) {
    let items: Vec<(String, std::path::PathBuf)> = match ledger.lock() {
        Ok(l) => l
            .finished()
            .iter()
            .flat_map(|r| {
                let dir = l.session_dir(&r.id);
                [
                    (
                        VerificationItem::Certificate.key(cell, &r.id),
                        dir.join("session.json"),
                    ),
                    (
                        VerificationItem::Page.key(cell, &r.id),
                        dir.join("verify.html"),
                    ),
                ]
            })
            .collect(),
        Err(_) => return,
    };
    reply_stored(q, items).await;
}

/// Answer `ris/<cell>/scans/**` from the finished scans on disk: `<id>/state`, `<id>/report`,
/// `<id>/cloud/<sensor>` and `<id>/deviation`, for every key the query matches.
pub(super) async fn handle_store(q: &Query, cell: &str, data_dir: &Path) {
    let (c, d) = (cell.to_string(), data_dir.to_path_buf());
    let Ok((ids, items)) = tokio::task::spawn_blocking(move || store::stored_items(&c, &d)).await
    else {
        return;
    };
    let asked = q.key_expr().clone();
    let matching = |key: &str| {
        zenoh::key_expr::KeyExpr::try_from(key.to_string())
            .ok()
            .filter(|k| asked.intersects(k))
    };
    for id in ids {
        if let Some(k) = matching(&state_key(cell, &id)) {
            let _ = q.reply(k, r#"{"state":"done"}"#).await;
        }
    }
    reply_stored(q, items).await;
}

/// Reply to `q` with each stored file whose key the query matches; only plain files of the
/// store itself, never a link out of it. Replies follow the query's congestion control.
async fn reply_stored(q: &Query, items: Vec<(String, std::path::PathBuf)>) {
    let asked = q.key_expr().clone();
    for (key, path) in items {
        let Some(k) = zenoh::key_expr::KeyExpr::try_from(key.clone())
            .ok()
            .filter(|k| asked.intersects(k))
        else {
            continue;
        };
        if !tokio::fs::symlink_metadata(&path)
            .await
            .is_ok_and(|m| m.is_file())
        {
            continue;
        }
        match tokio::fs::read(&path).await {
            Ok(bytes) => {
                if let Err(err) = q.reply(k, bytes).await {
                    tracing::warn!(%key, error = %err, "stored reply failed");
                }
            }
            Err(err) => {
                tracing::warn!(path = %path.display(), error = %err, "stored file unreadable")
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cell(parts: &[&str]) -> CellConfig {
        let mut text = String::from(
            "[cell]\nname = \"t\"\n[[sensor]]\nname = \"s1\"\nbackend = \"mock\"\nscene = \"s.toml\"\nto_common = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]\n",
        );
        for p in parts {
            text += &format!("[[part]]\nid = \"{p}\"\ncad = \"{p}.stl\"\ntolerance = 0.5\n");
        }
        CellConfig::parse(&text, Path::new("."), "test").expect("config")
    }

    fn req(json: &str) -> ScanRequest {
        ScanRequest::parse(json.as_bytes()).expect("request")
    }

    #[test]
    fn the_part_to_inspect_follows_the_request_and_the_cell() {
        let none = cell(&[]);
        let one = cell(&["door"]);
        let two = cell(&["door", "hood"]);
        assert_eq!(validate(&req("{}"), &none), Ok(None));
        assert_eq!(validate(&req("{}"), &one), Ok(Some(0)));
        assert_eq!(validate(&req("{}"), &two), Ok(None));
        assert_eq!(validate(&req(r#"{"inspect": false}"#), &one), Ok(None));
        assert_eq!(validate(&req(r#"{"part": "hood"}"#), &two), Ok(Some(1)));
        let err = |r: &str, c: &CellConfig| validate(&req(r), c).expect_err(r);
        assert!(err(r#"{"inspect": true}"#, &none).contains("no part"));
        assert!(err(r#"{"inspect": true}"#, &two).contains("name one"));
        assert!(err(r#"{"part": "roof"}"#, &two).contains("\"roof\""));
        assert!(err(r#"{"part": "door", "inspect": false}"#, &two).contains("inspect"));
        // An unknown mode is refused by the parser (the protocol's `ScanMode`).
        assert!(ScanRequest::parse(br#"{"mode": "fast"}"#).is_err());
        assert_eq!(validate(&req(r#"{"mode": "single-shot"}"#), &one), Ok(None));
        assert_eq!(
            validate(
                &req(r#"{"mode": "single-shot", "inspect": true, "part": "hood"}"#),
                &two
            ),
            Ok(Some(1))
        );
    }
}
