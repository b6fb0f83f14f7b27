//! The console's side of the Zenoh fabric: it finds every cell by its health liveliness token,
//! follows each scan's states, records every finished scan (its summary, and its report's
//! characteristics) in the history, backfills what a cell stored while the console was away,
//! runs the run rules on each new value and raises alarms on the page and on
//! `ris/<cell>/alarms`.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use anyhow::{anyhow, Context, Result};
use ris_daemon::protocol::{
    alarms_key, health_key, scan_key, scan_states_key, stream_sensor_key, Health, ScanItem,
    ScanReply, ScanRequest, ScanState,
};
use serde::Serialize;
use serde_json::Value;
use tokio::sync::broadcast;
use tokio_util::sync::CancellationToken;
use zenoh::sample::SampleKind;
use zenoh::Session;

use crate::characteristic::{self, Characteristic};
use crate::history::{time_of, Alarm, History, ScanRecord};
use crate::spc;

/// How often each live cell's health is asked.
const HEALTH_EVERY: Duration = Duration::from_secs(2);

/// What the console knows of one cell now.
#[derive(Clone, Debug, Default, Serialize)]
pub struct CellView {
    /// Whether its health token is alive.
    pub alive: bool,
    /// Its last health.
    pub health: Option<Health>,
    /// Scans in progress and their last state.
    pub active: BTreeMap<String, ScanState>,
}

/// Something the page shows as it happens (sent to browsers as server-sent events).
#[derive(Clone, Debug, Serialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum Event {
    /// A cell appeared or went away, or its health changed.
    Cell {
        /// Cell.
        cell: String,
        /// What the console knows of it.
        view: Box<CellView>,
    },
    /// A scan's state.
    State {
        /// Cell.
        cell: String,
        /// Scan id.
        scan_id: String,
        /// The state.
        state: ScanState,
    },
    /// A finished scan was recorded in the history.
    Recorded {
        /// The scan.
        scan: ScanRecord,
    },
    /// A run rule fired.
    Alarm {
        /// The alarm.
        alarm: Alarm,
    },
    /// A streaming sensor's fusion picture changed (fetch it from
    /// `/cells/<cell>/stream/<sensor>.png`).
    Fused {
        /// Cell.
        cell: String,
        /// Sensor.
        sensor: String,
        /// How many pictures of it the console has seen.
        count: u64,
    },
}

/// The latest fusion picture of each streaming sensor: (cell, sensor) → (pictures seen, PNG).
type Pictures = BTreeMap<(String, String), (u64, Arc<Vec<u8>>)>;

/// The console's link to every cell.
pub struct Fabric {
    /// The Zenoh session.
    pub session: Session,
    /// The history.
    pub history: Arc<History>,
    cells: Mutex<BTreeMap<String, CellView>>,
    pictures: Mutex<Pictures>,
    events: broadcast::Sender<Event>,
    /// Scans whose limits the run rules take as the baseline (the first of each part's series).
    baseline: usize,
}

impl Fabric {
    /// A fabric over `session` recording into `history`; run rules with limits from the first
    /// `baseline` scans of each part.
    pub fn new(session: Session, history: Arc<History>, baseline: usize) -> Arc<Fabric> {
        let (events, _) = broadcast::channel(1024);
        Arc::new(Fabric {
            session,
            history,
            cells: Mutex::new(BTreeMap::new()),
            pictures: Mutex::new(BTreeMap::new()),
            events,
            baseline,
        })
    }

    fn cells_lock(&self) -> std::sync::MutexGuard<'_, BTreeMap<String, CellView>> {
        self.cells.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The cells found so far and what is known of each.
    pub fn cells(&self) -> BTreeMap<String, CellView> {
        self.cells_lock().clone()
    }

    /// The latest fusion picture of `cell`'s `sensor` (PNG), if it streamed since the console
    /// started.
    pub fn picture(&self, cell: &str, sensor: &str) -> Option<Arc<Vec<u8>>> {
        let p = self.pictures.lock().unwrap_or_else(|e| e.into_inner());
        p.get(&(cell.to_string(), sensor.to_string()))
            .map(|(_, png)| png.clone())
    }

    /// The sensors of `cell` with a fusion picture.
    pub fn streaming(&self, cell: &str) -> Vec<String> {
        let p = self.pictures.lock().unwrap_or_else(|e| e.into_inner());
        p.keys()
            .filter(|(c, _)| c == cell)
            .map(|(_, s)| s.clone())
            .collect()
    }

    /// Events from now on.
    pub fn subscribe(&self) -> broadcast::Receiver<Event> {
        self.events.subscribe()
    }

    fn emit(&self, e: Event) {
        let _ = self.events.send(e);
    }

    /// Change what is known of `cell`; the page hears of it only when something changed.
    fn update_cell(&self, cell: &str, f: impl FnOnce(&mut CellView)) {
        let changed = {
            let mut cells = self.cells_lock();
            let v = cells.entry(cell.to_string()).or_default();
            let before = serde_json::to_string(&*v).ok();
            f(v);
            (before != serde_json::to_string(&*v).ok()).then(|| v.clone())
        };
        if let Some(view) = changed {
            self.emit(Event::Cell {
                cell: cell.to_string(),
                view: Box::new(view),
            });
        }
    }

    /// Follow the fabric until `shutdown`: cells' tokens, scans' states, health.
    pub async fn run(self: Arc<Self>, shutdown: CancellationToken) -> Result<()> {
        let tokens = self
            .session
            .liveliness()
            .declare_subscriber(health_key("*"))
            .history(true)
            .await
            .map_err(|e| anyhow!("following the cells' health tokens: {e}"))?;
        let states = self
            .session
            .declare_subscriber(scan_states_key("*"))
            .await
            .map_err(|e| anyhow!("following the scans' states: {e}"))?;
        let fused = self
            .session
            .declare_subscriber(stream_sensor_key("*", "*", "fused"))
            .await
            .map_err(|e| anyhow!("following the streams' fusion pictures: {e}"))?;
        let mut tick = tokio::time::interval(HEALTH_EVERY);
        loop {
            tokio::select! {
                _ = shutdown.cancelled() => return Ok(()),
                s = tokens.recv_async() => {
                    let Ok(s) = s else { return Ok(()) };
                    let Some(cell) = cell_of(s.key_expr().as_str()) else { continue };
                    match s.kind() {
                        SampleKind::Put => {
                            tracing::info!(%cell, "cell found");
                            self.update_cell(&cell, |v| v.alive = true);
                            let me = self.clone();
                            tokio::spawn(async move {
                                if let Err(e) = me.backfill(&cell).await {
                                    tracing::warn!(%cell, error = %format!("{e:#}"), "backfill failed");
                                }
                            });
                        }
                        SampleKind::Delete => {
                            tracing::info!(%cell, "cell gone");
                            self.update_cell(&cell, |v| { v.alive = false; v.health = None; });
                        }
                    }
                }
                s = states.recv_async() => {
                    let Ok(s) = s else { return Ok(()) };
                    let Some((cell, scan_id, ScanItem::State)) = ScanItem::parse(s.key_expr().as_str()) else { continue };
                    let Ok(state) = serde_json::from_slice::<ScanState>(&s.payload().to_bytes()) else { continue };
                    self.on_state(cell, scan_id, state);
                }
                s = fused.recv_async() => {
                    let Ok(s) = s else { return Ok(()) };
                    let parts: Vec<&str> = s.key_expr().as_str().split('/').collect();
                    let ["ris", cell, "stream", sensor, "fused"] = parts.as_slice() else { continue };
                    let key = (cell.to_string(), sensor.to_string());
                    let png = Arc::new(s.payload().to_bytes().into_owned());
                    let count = {
                        let mut p = self.pictures.lock().unwrap_or_else(|e| e.into_inner());
                        let e = p.entry(key.clone()).or_insert((0, png.clone()));
                        *e = (e.0 + 1, png);
                        e.0
                    };
                    self.emit(Event::Fused { cell: key.0, sensor: key.1, count });
                }
                _ = tick.tick() => {
                    let alive: Vec<String> = self.cells_lock().iter().filter(|(_, v)| v.alive).map(|(c, _)| c.clone()).collect();
                    for cell in alive {
                        let me = self.clone();
                        tokio::spawn(async move { me.refresh_health(&cell).await });
                    }
                }
            }
        }
    }

    fn on_state(self: &Arc<Self>, cell: String, scan_id: String, state: ScanState) {
        let finished = matches!(state, ScanState::Done | ScanState::Failed { .. });
        {
            let mut cells = self.cells_lock();
            let v = cells.entry(cell.clone()).or_default();
            if finished {
                v.active.remove(&scan_id);
            } else {
                v.active.insert(scan_id.clone(), state.clone());
            }
        }
        self.emit(Event::State {
            cell: cell.clone(),
            scan_id: scan_id.clone(),
            state: state.clone(),
        });
        if state == ScanState::Done {
            let me = self.clone();
            tokio::spawn(async move {
                if let Err(e) = me.ingest(&cell, &scan_id).await {
                    tracing::warn!(%cell, %scan_id, error = %format!("{e:#}"), "recording the scan failed");
                }
            });
        }
    }

    async fn refresh_health(&self, cell: &str) {
        let Ok(bytes) = self.fetch(&health_key(cell)).await else {
            return;
        };
        if let Ok(h) = serde_json::from_slice::<Health>(&bytes) {
            self.update_cell(cell, |v| v.health = Some(h));
        }
    }

    /// The first good reply to `key` (a stored item, health).
    pub async fn fetch(&self, key: &str) -> Result<Vec<u8>> {
        ris_daemon::client::fetch(&self.session, key).await
    }

    /// Start a scan on `cell`: the scan id, or the cell's reason.
    pub async fn start_scan(&self, cell: &str, request: &ScanRequest) -> Result<ScanReply> {
        ris_daemon::client::ask(&self.session, &scan_key(cell), request)
            .await
            .with_context(|| format!("starting a scan on cell {cell}"))
    }

    /// Record every scan `cell` stored that the history lacks, oldest first.
    pub async fn backfill(&self, cell: &str) -> Result<usize> {
        let mut ids = Vec::new();
        for (key, payload) in
            ris_daemon::client::replies(&self.session, &scan_states_key(cell)).await?
        {
            if let Some((c, id, ScanItem::State)) = ScanItem::parse(&key) {
                let done = serde_json::from_slice::<ScanState>(&payload)
                    .is_ok_and(|s| s == ScanState::Done);
                if c == cell && done {
                    ids.push(id);
                }
            }
        }
        ids.sort();
        ids.dedup();
        let mut added = 0;
        for id in ids {
            if self.history.has(cell, &id)? {
                continue;
            }
            if self.ingest(cell, &id).await? {
                added += 1;
            }
        }
        if added > 0 {
            tracing::info!(%cell, added, "backfilled stored scans");
        }
        Ok(added)
    }

    /// Record one finished scan (its summary and report) and run the rules on its values;
    /// `false` when it was recorded already.
    pub async fn ingest(&self, cell: &str, scan_id: &str) -> Result<bool> {
        if self.history.has(cell, scan_id)? {
            return Ok(false);
        }
        let summary = self
            .fetch(&ScanItem::Summary.key(cell, scan_id))
            .await
            .with_context(|| format!("scan {scan_id} of {cell}: its summary"))?;
        let summary: Value = serde_json::from_slice(&summary)
            .with_context(|| format!("scan {scan_id} of {cell}: the summary is not JSON"))?;
        let inspection = &summary["inspection"];
        let text = |v: &Value| v.as_str().map(str::to_string);
        let record = ScanRecord {
            cell: cell.to_string(),
            scan_id: scan_id.to_string(),
            part: text(&inspection["part"]),
            tag: text(&summary["tag"]),
            serial: text(&summary["serial"]),
            operator: text(&summary["operator"]),
            mode: text(&summary["mode"]).unwrap_or_else(|| "gray".into()),
            verdict: text(&inspection["verdict"]),
            reasons: inspection["reasons"]
                .as_array()
                .map(|a| a.iter().filter_map(text).collect())
                .unwrap_or_default(),
            time: time_of(scan_id),
        };
        let values = if record.part.is_some() {
            let report = self
                .fetch(&ScanItem::Report.key(cell, scan_id))
                .await
                .with_context(|| format!("scan {scan_id} of {cell}: its report"))?;
            let report: Value = serde_json::from_slice(&report)
                .with_context(|| format!("scan {scan_id} of {cell}: the report is not JSON"))?;
            characteristic::from_report(&report)
        } else {
            Vec::new()
        };
        if !self.history.record(&record, &values)? {
            return Ok(false);
        }
        self.emit(Event::Recorded {
            scan: record.clone(),
        });
        if let Some(part) = &record.part {
            self.run_rules(&record, part, &values).await?;
        }
        Ok(true)
    }

    /// Chart each of the scan's characteristics over its part's series and raise an alarm for
    /// every rule that fires at this scan.
    async fn run_rules(
        &self,
        scan: &ScanRecord,
        part: &str,
        values: &[Characteristic],
    ) -> Result<()> {
        for c in values {
            let series = self.history.series(part, &c.name, 100_000)?;
            let Some(at) = series
                .iter()
                .position(|p| p.cell == scan.cell && p.scan_id == scan.scan_id)
            else {
                continue;
            };
            let v: Vec<f64> = series.iter().map(|p| p.value).collect();
            let Some(chart) = spc::chart(&v, self.baseline) else {
                continue;
            };
            for s in chart.signals.iter().filter(|s| s.index == at) {
                let alarm = Alarm {
                    cell: scan.cell.clone(),
                    part: part.to_string(),
                    characteristic: c.name.clone(),
                    scan_id: scan.scan_id.clone(),
                    rule: serde_json::to_value(s.rule)
                        .ok()
                        .and_then(|r| r.as_str().map(str::to_string))
                        .unwrap_or_default(),
                    message: format!(
                        "{part}: {} {:.4} {} — {} (centre {:.4}, limits {:.4} … {:.4})",
                        c.name,
                        c.value,
                        c.unit,
                        s.rule.describe(),
                        chart.centre,
                        chart.lcl,
                        chart.ucl
                    ),
                    time: scan.time.clone(),
                };
                if self.history.raise(&alarm)? {
                    tracing::warn!(cell = %alarm.cell, part, characteristic = %alarm.characteristic, rule = %alarm.rule, "alarm");
                    if let Err(e) = self
                        .session
                        .put(alarms_key(&alarm.cell), serde_json::to_string(&alarm)?)
                        .congestion_control(zenoh::qos::CongestionControl::Block)
                        .await
                    {
                        tracing::warn!(error = %e, "publishing the alarm failed");
                    }
                    self.emit(Event::Alarm { alarm });
                }
            }
        }
        Ok(())
    }
}

/// The cell a `ris/<cell>/health` key names.
fn cell_of(key: &str) -> Option<String> {
    let rest = key.strip_prefix("ris/")?;
    let cell = rest.strip_suffix("/health")?;
    (!cell.is_empty() && !cell.contains('/')).then(|| cell.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn health_keys_name_their_cell() {
        assert_eq!(cell_of("ris/line-1/health").as_deref(), Some("line-1"));
        assert_eq!(cell_of("ris/a/b/health"), None);
        assert_eq!(cell_of("ris/a/scans/x/state"), None);
    }
}
