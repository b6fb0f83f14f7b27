//! The console's history (SQLite): every scan it has seen on any cell, the characteristic
//! values of its report and the alarms the run rules raised. It outlives the cells' retention
//! of clouds; each scan is written in one transaction with `synchronous = FULL` in WAL mode, so
//! a killed console loses nothing it had recorded, and recording a scan again changes nothing.

use std::path::Path;
use std::sync::Mutex;

use rusqlite::{params, Connection, OptionalExtension};
use serde::Serialize;

use crate::characteristic::Characteristic;

/// What the history can fail with.
#[derive(Debug, thiserror::Error)]
pub enum HistoryError {
    /// The database file cannot be opened or is not a history.
    #[error("history database {path}: {source}")]
    Open {
        /// The file.
        path: String,
        /// SQLite's reason.
        source: rusqlite::Error,
    },
    /// A statement failed.
    #[error("history database: {0}")]
    Sql(#[from] rusqlite::Error),
}

/// One scan as the history keeps it.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct ScanRecord {
    /// Cell.
    pub cell: String,
    /// Scan id.
    pub scan_id: String,
    /// Inspected part (absent: a scan without inspection).
    pub part: Option<String>,
    /// The request's tag.
    pub tag: Option<String>,
    /// The part's serial number.
    pub serial: Option<String>,
    /// Who started it.
    pub operator: Option<String>,
    /// Acquisition mode.
    pub mode: String,
    /// `pass`, `fail`, `not_measured`, or absent (not inspected).
    pub verdict: Option<String>,
    /// Why it failed or was not measured.
    pub reasons: Vec<String>,
    /// UTC time of the scan, ISO 8601 (from its id).
    pub time: String,
}

/// One point of a characteristic's series.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SeriesPoint {
    /// Cell.
    pub cell: String,
    /// Scan id.
    pub scan_id: String,
    /// UTC time.
    pub time: String,
    /// Serial number.
    pub serial: Option<String>,
    /// Value.
    pub value: f64,
    /// Lower specification limit.
    pub lower: Option<f64>,
    /// Upper specification limit.
    pub upper: Option<f64>,
}

/// A raised alarm.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Alarm {
    /// Cell of the scan that fired it.
    pub cell: String,
    /// Part.
    pub part: String,
    /// Characteristic.
    pub characteristic: String,
    /// The scan whose value fired it.
    pub scan_id: String,
    /// The run rule, as [`crate::spc::Rule`] names it on the wire.
    pub rule: String,
    /// In words.
    pub message: String,
    /// UTC time of the scan.
    pub time: String,
}

/// What a search of the scans asks for (every field optional; text fields match a substring).
#[derive(Clone, Debug, Default, serde::Deserialize)]
pub struct Filter {
    /// Cell.
    #[serde(default)]
    pub cell: Option<String>,
    /// Part.
    #[serde(default)]
    pub part: Option<String>,
    /// Tag or serial number.
    #[serde(default)]
    pub text: Option<String>,
    /// Verdict (`pass`, `fail`, `not_measured`).
    #[serde(default)]
    pub verdict: Option<String>,
    /// From this date (ISO 8601, inclusive).
    #[serde(default)]
    pub from: Option<String>,
    /// Until this date (ISO 8601, inclusive of the whole day).
    #[serde(default)]
    pub to: Option<String>,
    /// At most this many (newest first; default 200).
    #[serde(default)]
    pub limit: Option<usize>,
}

/// The history database.
pub struct History {
    db: Mutex<Connection>,
}

const SCHEMA: &str = "
CREATE TABLE IF NOT EXISTS scans (
    cell TEXT NOT NULL, scan_id TEXT NOT NULL, part TEXT, tag TEXT, serial TEXT, operator TEXT,
    mode TEXT NOT NULL, verdict TEXT, reasons TEXT NOT NULL, time TEXT NOT NULL,
    PRIMARY KEY (cell, scan_id));
CREATE INDEX IF NOT EXISTS scans_by_part ON scans (part, time);
CREATE INDEX IF NOT EXISTS scans_by_time ON scans (time);
CREATE TABLE IF NOT EXISTS characteristics (
    cell TEXT NOT NULL, scan_id TEXT NOT NULL, name TEXT NOT NULL, value REAL NOT NULL,
    lower REAL, upper REAL, unit TEXT NOT NULL,
    PRIMARY KEY (cell, scan_id, name));
CREATE TABLE IF NOT EXISTS alarms (
    cell TEXT NOT NULL, part TEXT NOT NULL, characteristic TEXT NOT NULL, scan_id TEXT NOT NULL,
    rule TEXT NOT NULL, message TEXT NOT NULL, time TEXT NOT NULL,
    PRIMARY KEY (cell, scan_id, characteristic, rule));
";

fn record_from_row(r: &rusqlite::Row) -> rusqlite::Result<ScanRecord> {
    let reasons: String = r.get(8)?;
    Ok(ScanRecord {
        cell: r.get(0)?,
        scan_id: r.get(1)?,
        part: r.get(2)?,
        tag: r.get(3)?,
        serial: r.get(4)?,
        operator: r.get(5)?,
        mode: r.get(6)?,
        verdict: r.get(7)?,
        reasons: serde_json::from_str(&reasons).unwrap_or_default(),
        time: r.get(9)?,
    })
}

const RECORD_COLUMNS: &str =
    "cell, scan_id, part, tag, serial, operator, mode, verdict, reasons, time";

impl History {
    /// Open (creating it when missing) the history at `path`.
    pub fn open(path: &Path) -> Result<History, HistoryError> {
        let open = |e| HistoryError::Open {
            path: path.display().to_string(),
            source: e,
        };
        let db = Connection::open(path).map_err(open)?;
        db.busy_timeout(std::time::Duration::from_secs(5))
            .map_err(open)?;
        db.pragma_update(None, "journal_mode", "WAL")
            .map_err(open)?;
        db.pragma_update(None, "synchronous", "FULL")
            .map_err(open)?;
        db.execute_batch(SCHEMA).map_err(open)?;
        Ok(History { db: Mutex::new(db) })
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Connection> {
        self.db.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Whether the scan is recorded.
    pub fn has(&self, cell: &str, scan_id: &str) -> Result<bool, HistoryError> {
        Ok(self
            .lock()
            .query_row(
                "SELECT 1 FROM scans WHERE cell = ?1 AND scan_id = ?2",
                params![cell, scan_id],
                |_| Ok(()),
            )
            .optional()?
            .is_some())
    }

    /// Record a scan and its characteristics in one transaction; `false` when it was recorded
    /// already (nothing changes).
    pub fn record(
        &self,
        scan: &ScanRecord,
        values: &[Characteristic],
    ) -> Result<bool, HistoryError> {
        let mut db = self.lock();
        let tx = db.transaction()?;
        let new = tx.execute(
            &format!("INSERT OR IGNORE INTO scans ({RECORD_COLUMNS}) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10)"),
            params![
                scan.cell,
                scan.scan_id,
                scan.part,
                scan.tag,
                scan.serial,
                scan.operator,
                scan.mode,
                scan.verdict,
                serde_json::to_string(&scan.reasons).unwrap_or_else(|_| "[]".into()),
                scan.time
            ],
        )? == 1;
        if new {
            let mut insert = tx.prepare(
                "INSERT OR IGNORE INTO characteristics (cell, scan_id, name, value, lower, upper, unit) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7)",
            )?;
            for c in values {
                insert.execute(params![
                    scan.cell,
                    scan.scan_id,
                    c.name,
                    c.value,
                    c.lower,
                    c.upper,
                    c.unit
                ])?;
            }
        }
        tx.commit()?;
        Ok(new)
    }

    /// One scan.
    pub fn scan(&self, cell: &str, scan_id: &str) -> Result<Option<ScanRecord>, HistoryError> {
        Ok(self
            .lock()
            .query_row(
                &format!("SELECT {RECORD_COLUMNS} FROM scans WHERE cell = ?1 AND scan_id = ?2"),
                params![cell, scan_id],
                record_from_row,
            )
            .optional()?)
    }

    /// The characteristics recorded for one scan, in the order they were recorded.
    pub fn values(&self, cell: &str, scan_id: &str) -> Result<Vec<Characteristic>, HistoryError> {
        let db = self.lock();
        let mut q = db.prepare(
            "SELECT name, value, lower, upper, unit FROM characteristics WHERE cell = ?1 AND scan_id = ?2 ORDER BY rowid",
        )?;
        let rows = q.query_map(params![cell, scan_id], |r| {
            let unit: String = r.get(4)?;
            Ok(Characteristic {
                name: r.get(0)?,
                value: r.get(1)?,
                lower: r.get(2)?,
                upper: r.get(3)?,
                unit: match unit.as_str() {
                    "mm" => "mm",
                    "%" => "%",
                    _ => "",
                },
            })
        })?;
        Ok(rows.collect::<Result<_, _>>()?)
    }

    /// Scans matching `filter`, newest first.
    pub fn search(&self, filter: &Filter) -> Result<Vec<ScanRecord>, HistoryError> {
        let mut sql = format!("SELECT {RECORD_COLUMNS} FROM scans WHERE 1 = 1");
        let mut args: Vec<String> = Vec::new();
        let mut arg = |sql: &mut String, clause: &str, value: String| {
            args.push(value);
            sql.push_str(&clause.replace('?', &format!("?{}", args.len())));
        };
        let nonempty = |o: &Option<String>| o.clone().filter(|s| !s.trim().is_empty());
        if let Some(c) = nonempty(&filter.cell) {
            arg(&mut sql, " AND cell = ?", c);
        }
        if let Some(p) = nonempty(&filter.part) {
            arg(&mut sql, " AND part = ?", p);
        }
        if let Some(v) = nonempty(&filter.verdict) {
            arg(&mut sql, " AND verdict = ?", v);
        }
        if let Some(t) = nonempty(&filter.text) {
            let like = format!("%{}%", t.replace(['%', '_'], ""));
            arg(&mut sql, " AND (tag LIKE ? ", like.clone());
            arg(&mut sql, "OR serial LIKE ?)", like);
        }
        if let Some(f) = nonempty(&filter.from) {
            arg(&mut sql, " AND time >= ?", f);
        }
        if let Some(t) = nonempty(&filter.to) {
            arg(&mut sql, " AND substr(time, 1, 10) <= ?", t);
        }
        sql.push_str(&format!(
            " ORDER BY time DESC, scan_id DESC LIMIT {}",
            filter.limit.unwrap_or(200).min(10_000)
        ));
        let db = self.lock();
        let mut q = db.prepare(&sql)?;
        let rows = q.query_map(rusqlite::params_from_iter(args.iter()), record_from_row)?;
        Ok(rows.collect::<Result<_, _>>()?)
    }

    /// The newest scan of each cell in `cells`.
    pub fn latest(&self, cell: &str) -> Result<Option<ScanRecord>, HistoryError> {
        Ok(self
            .search(&Filter {
                cell: Some(cell.to_string()),
                limit: Some(1),
                ..Filter::default()
            })?
            .into_iter()
            .next())
    }

    /// Every cell the history has a scan of.
    pub fn cells(&self) -> Result<Vec<String>, HistoryError> {
        self.strings("SELECT DISTINCT cell FROM scans ORDER BY cell", [])
    }

    /// Every inspected part.
    pub fn parts(&self) -> Result<Vec<String>, HistoryError> {
        self.strings(
            "SELECT DISTINCT part FROM scans WHERE part IS NOT NULL ORDER BY part",
            [],
        )
    }

    /// The characteristics recorded for `part`, in the order of its first scan's report.
    pub fn characteristics(&self, part: &str) -> Result<Vec<String>, HistoryError> {
        self.strings(
            "SELECT c.name FROM characteristics c JOIN scans s ON s.cell = c.cell AND s.scan_id = c.scan_id
             WHERE s.part = ?1 GROUP BY c.name ORDER BY MIN(c.rowid)",
            [part],
        )
    }

    fn strings<P: rusqlite::Params>(&self, sql: &str, p: P) -> Result<Vec<String>, HistoryError> {
        let db = self.lock();
        let mut q = db.prepare(sql)?;
        let rows = q.query_map(p, |r| r.get::<_, String>(0))?;
        Ok(rows.collect::<Result<_, _>>()?)
    }

    /// The values of `characteristic` over `part`'s scans, oldest first (every cell; at most
    /// the newest `limit`).
    pub fn series(
        &self,
        part: &str,
        characteristic: &str,
        limit: usize,
    ) -> Result<Vec<SeriesPoint>, HistoryError> {
        let db = self.lock();
        let mut q = db.prepare(
            "SELECT * FROM (SELECT s.cell, s.scan_id, s.time, s.serial, c.value, c.lower, c.upper
               FROM characteristics c JOIN scans s ON s.cell = c.cell AND s.scan_id = c.scan_id
              WHERE s.part = ?1 AND c.name = ?2 ORDER BY s.time DESC, s.scan_id DESC LIMIT ?3)
             ORDER BY time, scan_id",
        )?;
        let rows = q.query_map(params![part, characteristic, limit as i64], |r| {
            Ok(SeriesPoint {
                cell: r.get(0)?,
                scan_id: r.get(1)?,
                time: r.get(2)?,
                serial: r.get(3)?,
                value: r.get(4)?,
                lower: r.get(5)?,
                upper: r.get(6)?,
            })
        })?;
        Ok(rows.collect::<Result<_, _>>()?)
    }

    /// Record an alarm; `false` when it was raised already.
    pub fn raise(&self, alarm: &Alarm) -> Result<bool, HistoryError> {
        Ok(self.lock().execute(
            "INSERT OR IGNORE INTO alarms (cell, part, characteristic, scan_id, rule, message, time) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7)",
            params![
                alarm.cell,
                alarm.part,
                alarm.characteristic,
                alarm.scan_id,
                alarm.rule,
                alarm.message,
                alarm.time
            ],
        )? == 1)
    }

    /// The newest alarms (of `part` when given).
    pub fn alarms(&self, part: Option<&str>, limit: usize) -> Result<Vec<Alarm>, HistoryError> {
        let db = self.lock();
        let mut q = db.prepare(
            "SELECT cell, part, characteristic, scan_id, rule, message, time FROM alarms
              WHERE ?1 IS NULL OR part = ?1 ORDER BY time DESC, rowid DESC LIMIT ?2",
        )?;
        let rows = q.query_map(params![part, limit as i64], |r| {
            Ok(Alarm {
                cell: r.get(0)?,
                part: r.get(1)?,
                characteristic: r.get(2)?,
                scan_id: r.get(3)?,
                rule: r.get(4)?,
                message: r.get(5)?,
                time: r.get(6)?,
            })
        })?;
        Ok(rows.collect::<Result<_, _>>()?)
    }
}

/// The UTC time a scan id (`20261122T084921.028Z-0`) encodes, as ISO 8601
/// (`2026-11-22T08:49:21.028Z`); the id itself when it is not one.
pub fn time_of(scan_id: &str) -> String {
    let b = scan_id.as_bytes();
    let digits = |r: std::ops::Range<usize>| {
        b.get(r.clone())
            .is_some_and(|s| s.iter().all(u8::is_ascii_digit))
    };
    if b.len() >= 19
        && digits(0..8)
        && b[8] == b'T'
        && digits(9..15)
        && b[15] == b'.'
        && digits(16..19)
    {
        let s = &scan_id;
        format!(
            "{}-{}-{}T{}:{}:{}.{}Z",
            &s[0..4],
            &s[4..6],
            &s[6..8],
            &s[9..11],
            &s[11..13],
            &s[13..15],
            &s[16..19]
        )
    } else {
        scan_id.to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scan(cell: &str, id: &str, part: &str, serial: &str, verdict: &str) -> ScanRecord {
        ScanRecord {
            cell: cell.into(),
            scan_id: id.into(),
            part: Some(part.into()),
            serial: Some(serial.into()),
            mode: "gray".into(),
            verdict: Some(verdict.into()),
            time: time_of(id),
            ..ScanRecord::default()
        }
    }

    fn value(name: &str, v: f64) -> Characteristic {
        Characteristic {
            name: name.into(),
            value: v,
            lower: Some(-0.5),
            upper: Some(0.5),
            unit: "mm",
        }
    }

    #[test]
    fn scans_are_recorded_once_and_found_again_after_reopening() {
        let dir = tempfile::tempdir().expect("tmp");
        let path = dir.path().join("h.sqlite");
        {
            let h = History::open(&path).expect("open");
            for i in 0..5 {
                let id = format!("20261122T08492{i}.000Z-{i}");
                let cell = if i % 2 == 0 { "a" } else { "b" };
                let s = scan(
                    cell,
                    &id,
                    "panel",
                    &format!("SN{i}"),
                    if i == 3 { "fail" } else { "pass" },
                );
                assert!(h
                    .record(&s, &[value("mean", i as f64 * 0.01), value("rms", 0.1)])
                    .expect("record"));
                assert!(
                    !h.record(&s, &[value("mean", 9.0)]).expect("again"),
                    "recorded twice"
                );
            }
        }
        let h = History::open(&path).expect("reopen");
        assert_eq!(h.cells().expect("cells"), ["a", "b"]);
        assert_eq!(h.parts().expect("parts"), ["panel"]);
        assert_eq!(h.characteristics("panel").expect("names"), ["mean", "rms"]);
        let series = h.series("panel", "mean", 1000).expect("series");
        let values: Vec<f64> = series.iter().map(|p| p.value).collect();
        assert_eq!(values, [0.0, 0.01, 0.02, 0.03, 0.04]);
        assert_eq!(h.series("panel", "mean", 2).expect("series").len(), 2);
        let fails = h
            .search(&Filter {
                verdict: Some("fail".into()),
                ..Filter::default()
            })
            .expect("search");
        assert_eq!(fails.len(), 1);
        assert_eq!(fails[0].serial.as_deref(), Some("SN3"));
        let by_serial = h
            .search(&Filter {
                text: Some("SN4".into()),
                ..Filter::default()
            })
            .expect("search");
        assert_eq!(by_serial.len(), 1);
        let latest = h.latest("b").expect("latest").expect("one");
        assert_eq!(latest.scan_id, "20261122T084923.000Z-3");
        let to = h
            .search(&Filter {
                to: Some("2026-11-21".into()),
                ..Filter::default()
            })
            .expect("search");
        assert!(to.is_empty());
    }

    #[test]
    fn scan_ids_give_their_time() {
        assert_eq!(
            time_of("20261122T084921.028Z-0"),
            "2026-11-22T08:49:21.028Z"
        );
        assert_eq!(time_of("odd"), "odd");
    }

    #[test]
    fn a_file_that_is_no_database_is_refused_by_name() {
        let dir = tempfile::tempdir().expect("tmp");
        let path = dir.path().join("not.sqlite");
        std::fs::write(&path, vec![b'x'; 4096]).expect("write");
        let e = History::open(&path).err().expect("refused").to_string();
        assert!(e.contains("not.sqlite"), "{e}");
    }
}
