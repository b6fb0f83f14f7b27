//! The cell's verification sessions (VDI/VDE 2634-2): `verify` scans add positions of
//! calibrated artefacts, each evaluated per scope (every sensor's cloud and the merged cell's,
//! all in the cell frame); a finished session is a certificate per scope, stored under
//! `<data_dir>/verifications/<id>/` and kept as the cell's history. The ledger also says what
//! health and every inspection report must carry: never verified, the last verification failed
//! or is older than `[verify] max_age_days`, figures drifting towards their MPE.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

use anyhow::{anyhow, Context, Result};
use base64::engine::general_purpose::STANDARD;
use base64::Engine as _;
use ris_core::geometry::Vec3;
use ris_core::verify::{
    assemble, certificate_html, certificate_page, evaluate, verdict, write_residual_map, Artefacts,
    Certificate, Figure, MeasuredCloud, Status, VerifyParams,
};

use crate::config::VerifySection;
use crate::protocol::{
    Artefact, HistoryEntry, VerificationHealth, VerificationRecord, VerificationSummary,
    VerifyKind, VerifyPosition, Worst,
};
use crate::scan::{new_scan_id, utc_time};

/// The scope of the merged cell cloud.
pub const MERGED: &str = "merged";

/// Seconds since 1970.
pub fn unix_now() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_secs())
}

/// The verification sessions of a cell: the open one and the finished ones on disk.
pub struct Ledger {
    cell: String,
    dir: PathBuf,
    config: VerifySection,
    artefacts: Artefacts,
    open: Option<VerificationRecord>,
    /// Finished sessions, oldest first.
    history: Vec<VerificationRecord>,
}

impl Ledger {
    /// Load the artefacts file and every stored session under `<data_dir>/verifications`;
    /// an unfinished one is open again (a restart mid-session loses nothing measured).
    pub fn load(cell: &str, data_dir: &Path, config: &VerifySection) -> Result<Ledger> {
        let artefacts = Artefacts::load(&config.artefacts).context("verify.artefacts")?;
        let dir = data_dir.join("verifications");
        let mut history = Vec::new();
        let mut open = None;
        if let Ok(entries) = std::fs::read_dir(&dir) {
            for e in entries.flatten() {
                let path = e.path().join("session.json");
                let Ok(text) = std::fs::read(&path) else {
                    continue;
                };
                match serde_json::from_slice::<VerificationRecord>(&text) {
                    Ok(r) if r.finished.is_some() => history.push(r),
                    Ok(r) => {
                        // Of several unfinished sessions (a crash between two), the newest.
                        if open
                            .as_ref()
                            .is_none_or(|o: &VerificationRecord| o.id < r.id)
                        {
                            open = Some(r);
                        }
                    }
                    Err(err) => tracing::warn!(
                        path = %path.display(),
                        error = %err,
                        "a stored verification is unreadable; left out of the history"
                    ),
                }
            }
        }
        history.sort_by_key(|r| (r.finished_unix, r.id.clone()));
        Ok(Ledger {
            cell: cell.to_string(),
            dir,
            config: config.clone(),
            artefacts,
            open,
            history,
        })
    }

    /// The artefacts file as loaded.
    pub fn artefacts(&self) -> &Artefacts {
        &self.artefacts
    }

    /// Refuse an artefact the artefacts file does not describe.
    pub fn check(&self, artefact: Artefact) -> Result<(), String> {
        let described = match artefact {
            Artefact::BallBar => self.artefacts.ball_bar.is_some(),
            Artefact::Sphere => self.artefacts.sphere.is_some(),
            Artefact::Plane => self.artefacts.plane.is_some(),
        };
        if described {
            Ok(())
        } else {
            Err(format!(
                "the cell's artefacts file {} has no [{}] section",
                self.config.artefacts.display(),
                artefact.section()
            ))
        }
    }

    /// Open a session of `kind` (refused while one is open).
    pub fn start(&mut self, kind: VerifyKind) -> Result<VerificationSummary, String> {
        if let Some(o) = &self.open {
            return Err(format!(
                "verification {} is open ({} positions measured): finish or abort it first",
                o.id,
                o.positions.len()
            ));
        }
        let record = VerificationRecord {
            id: new_scan_id(self.history.len() as u64 + 1),
            cell: self.cell.clone(),
            kind,
            started: utc_time(),
            finished: None,
            finished_unix: None,
            positions: Vec::new(),
            certificates: BTreeMap::new(),
            verdict: None,
            warnings: Vec::new(),
        };
        self.persist(&record).map_err(|e| format!("{e:#}"))?;
        tracing::info!(id = %record.id, ?kind, "verification opened");
        let summary = summary(&record);
        self.open = Some(record);
        Ok(summary)
    }

    /// Drop the open session (its directory too).
    pub fn abort(&mut self) -> Result<VerificationSummary, String> {
        let record = self
            .open
            .take()
            .ok_or_else(|| "no verification is open".to_string())?;
        let dir = self.dir.join(&record.id);
        if let Err(e) = std::fs::remove_dir_all(&dir) {
            tracing::warn!(path = %dir.display(), error = %e, "cannot remove the aborted verification");
        }
        tracing::info!(id = %record.id, "verification aborted");
        Ok(summary(&record))
    }

    /// Add a measured position to the open session (opening an acceptance test when none is
    /// open), replacing an earlier measurement of the same position; its residual maps are
    /// written into the session's directory.
    pub fn add(&mut self, measured: Measured) -> Result<VerifyPosition> {
        if self.open.is_none() {
            self.start(VerifyKind::Acceptance).map_err(|e| anyhow!(e))?;
        }
        let record = self.open.as_mut().expect("opened above");
        let dir = self.dir.join(&record.id);
        for (scope, maps) in &measured.maps {
            let scope_dir = dir.join(scope);
            ris_core::io::create_dir(&scope_dir)?;
            for m in maps {
                write_residual_map(&scope_dir, m)?;
            }
        }
        let position = measured.position;
        record.positions.retain(|p| p.position != position.position);
        record.positions.push(position.clone());
        let record = record.clone();
        self.persist(&record)?;
        Ok(position)
    }

    /// Evaluate the open session into one certificate per scope, judge the verdict and the
    /// drift, and store it (`session.json`, and per scope `verify.json` and `verify.html`
    /// beside the residual maps; `verify.html` of the merged cell at the top).
    pub fn finish(&mut self) -> Result<VerificationRecord, String> {
        let mut record = self
            .open
            .clone()
            .ok_or_else(|| "no verification is open: measure a position first".to_string())?;
        if record.positions.is_empty() {
            return Err(format!(
                "verification {} has no position yet: scan an artefact with \"mode\": \"verify\"",
                record.id
            ));
        }
        let now = utc_time();
        let mut scopes: BTreeMap<String, [Vec<Figure>; 4]> = BTreeMap::new();
        for p in &record.positions {
            for (scope, figures) in &p.scopes {
                let slot = scopes.entry(scope.clone()).or_default();
                let k = match p.artefact {
                    Artefact::BallBar => 0,
                    Artefact::Plane => 1,
                    Artefact::Sphere => 2,
                };
                for (j, f) in figures.iter().enumerate() {
                    // A sphere gives PF then PS.
                    slot[k + j.min(1)].push(f.clone());
                }
            }
        }
        record.certificates = scopes
            .into_iter()
            .map(|(scope, figures)| {
                let mut artefacts = self.artefacts.clone();
                artefacts.system.name = if scope == MERGED {
                    format!("{} (cell {})", artefacts.system.name, self.cell)
                } else {
                    format!(
                        "{} (cell {}, sensor {scope})",
                        artefacts.system.name, self.cell
                    )
                };
                (scope, assemble(&artefacts, figures, now.clone()))
            })
            .collect();
        record.verdict = Some(session_verdict(&record.certificates));
        record.warnings = self.drift(&record);
        record.finished = Some(now);
        record.finished_unix = Some(unix_now());
        let dir = self.dir.join(&record.id);
        let written = (|| -> Result<()> {
            for (scope, cert) in &record.certificates {
                let scope_dir = dir.join(scope);
                ris_core::io::create_dir(&scope_dir)?;
                ris_core::io::write_atomic(
                    &scope_dir.join("verify.json"),
                    &serde_json::to_vec_pretty(cert)?,
                )?;
                ris_core::io::write_atomic(
                    &scope_dir.join("verify.html"),
                    certificate_html(cert).as_bytes(),
                )?;
            }
            if let Some((scope, cert)) = page_certificate(&record.certificates) {
                // The session's page travels alone (published, fetched): its maps inline.
                let scope_dir = dir.join(scope);
                let html = certificate_page(cert, &|file| {
                    std::fs::read(scope_dir.join(file)).map_or_else(
                        |_| format!("{scope}/{file}"),
                        |png| format!("data:image/png;base64,{}", STANDARD.encode(png)),
                    )
                });
                ris_core::io::write_atomic(&dir.join("verify.html"), html.as_bytes())?;
            }
            // Last: a session is finished only once everything it names is written.
            self.persist(&record)
        })();
        written.map_err(|e| format!("storing verification {}: {e:#}", record.id))?;
        tracing::info!(id = %record.id, verdict = ?record.verdict, "verification finished");
        self.open = None;
        self.history.push(record.clone());
        Ok(record)
    }

    /// Warnings for figures of `record` near their MPE, or moved from the last passed
    /// acceptance test's figure at the same position and scope.
    fn drift(&self, record: &VerificationRecord) -> Vec<String> {
        let share = self.config.drift_share;
        let baseline = self
            .history
            .iter()
            .rev()
            .find(|r| r.kind == VerifyKind::Acceptance && r.verdict == Some(Status::Pass));
        let mut out = Vec::new();
        for (scope, cert) in &record.certificates {
            for (symbol, figures) in [("SD", &cert.sphere_spacing), ("PF", &cert.probing_form)] {
                for f in figures {
                    let Some(e) = f.error else { continue };
                    let label = &f.position.label;
                    if e.abs() >= share * f.mpe {
                        out.push(format!(
                            "{scope}: {symbol} at {label} is {e:+.3} mm, {:.0} % of its MPE {:.3} mm (warned from {:.0} %)",
                            100.0 * e.abs() / f.mpe,
                            f.mpe,
                            100.0 * share
                        ));
                    }
                    let before = baseline.and_then(|b| {
                        let c = b.certificates.get(scope)?;
                        let list = if symbol == "SD" {
                            &c.sphere_spacing
                        } else {
                            &c.probing_form
                        };
                        list.iter()
                            .find(|g| g.position.label == *label)
                            .and_then(|g| g.error)
                            .map(|g| (b.id.clone(), g))
                    });
                    if let Some((id, b)) = before {
                        let moved = e - b;
                        if moved.abs() >= share * f.mpe {
                            out.push(format!(
                                "{scope}: {symbol} at {label} moved by {moved:+.3} mm since the acceptance test {id} ({:.0} % of its MPE {:.3} mm)",
                                100.0 * moved.abs() / f.mpe,
                                f.mpe
                            ));
                        }
                    }
                }
            }
        }
        out
    }

    /// What health says: the last verification, its age, the open session and the warnings.
    pub fn health(&self, now_unix: u64) -> VerificationHealth {
        let last = self.history.last();
        VerificationHealth {
            last: last.map(summary),
            age_days: last
                .and_then(|r| r.finished_unix)
                .map(|t| now_unix.saturating_sub(t) as f64 / 86_400.0),
            open: self.open.as_ref().map(summary),
            warnings: self.warnings(now_unix),
        }
    }

    /// What every inspection report and health must carry before its figures are trusted.
    pub fn warnings(&self, now_unix: u64) -> Vec<String> {
        let Some(last) = self.history.last() else {
            return vec![format!(
                "cell {} has no verification on record: its accuracy is not proven (run an acceptance test: ris verify --cell {} --start)",
                self.cell, self.cell
            )];
        };
        let when = last.finished.as_deref().unwrap_or("?");
        let mut out = Vec::new();
        match last.verdict {
            Some(Status::Fail) => {
                let failed: Vec<String> = last
                    .certificates
                    .iter()
                    .flat_map(|(scope, c)| {
                        c.figures()
                            .filter(|f| f.status == Status::Fail)
                            .map(move |f| format!("{scope} {}", f.position.label))
                    })
                    .take(6)
                    .collect();
                out.push(format!(
                    "the last verification of cell {} ({}, {when}) failed ({}): its measurements may be out of the stated accuracy",
                    self.cell,
                    last.id,
                    failed.join(", ")
                ));
            }
            Some(Status::NotMeasured) | None => out.push(format!(
                "the last verification of cell {} ({}, {when}) measured nothing conclusive: its accuracy is not proven",
                self.cell, last.id
            )),
            Some(Status::Pass) => {}
        }
        if self.config.max_age_days > 0.0 {
            if let Some(t) = last.finished_unix {
                let age = now_unix.saturating_sub(t) as f64 / 86_400.0;
                if age > self.config.max_age_days {
                    out.push(format!(
                        "the last verification of cell {} ({}) is {age:.1} days old; [verify] max_age_days is {}: verify the cell again",
                        self.cell, last.id, self.config.max_age_days
                    ));
                }
            }
        }
        out.extend(last.warnings.iter().cloned());
        out
    }

    /// Every finished verification's figures per scope (only `scope` when given), oldest
    /// first.
    pub fn history(&self, scope: Option<&str>) -> Vec<HistoryEntry> {
        let mut out = Vec::new();
        for r in &self.history {
            for (name, cert) in &r.certificates {
                if scope.is_some_and(|s| s != name) {
                    continue;
                }
                let mut worst = BTreeMap::new();
                for (symbol, figures) in [
                    ("SD", &cert.sphere_spacing),
                    ("F", &cert.flatness),
                    ("PF", &cert.probing_form),
                    ("PS", &cert.probing_size),
                ] {
                    let w = figures
                        .iter()
                        .filter_map(|f| {
                            f.error.map(|e| Worst {
                                position: f.position.label.clone(),
                                error: e,
                                mpe: f.mpe,
                                share: e.abs() / f.mpe,
                            })
                        })
                        .max_by(|a, b| a.share.total_cmp(&b.share));
                    if let Some(w) = w {
                        worst.insert(symbol.to_string(), w);
                    }
                }
                out.push(HistoryEntry {
                    id: r.id.clone(),
                    kind: r.kind,
                    finished: r.finished.clone().unwrap_or_default(),
                    scope: name.clone(),
                    verdict: cert.verdict,
                    worst,
                });
            }
        }
        out
    }

    /// The open session.
    pub fn open_session(&self) -> Option<&VerificationRecord> {
        self.open.as_ref()
    }

    /// A stored session's directory.
    pub fn session_dir(&self, id: &str) -> PathBuf {
        self.dir.join(id)
    }

    /// The finished sessions, oldest first.
    pub fn finished(&self) -> &[VerificationRecord] {
        &self.history
    }

    fn persist(&self, record: &VerificationRecord) -> Result<()> {
        let dir = self.dir.join(&record.id);
        std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
        ris_core::io::write_atomic(
            &dir.join("session.json"),
            &serde_json::to_vec_pretty(record)?,
        )
        .with_context(|| format!("writing verification {}", record.id))
    }
}

/// A session in short.
pub fn summary(r: &VerificationRecord) -> VerificationSummary {
    VerificationSummary {
        id: r.id.clone(),
        kind: r.kind,
        started: r.started.clone(),
        finished: r.finished.clone(),
        positions: r.positions.len(),
        verdict: r.verdict,
        scopes: r
            .certificates
            .iter()
            .map(|(s, c)| (s.clone(), c.verdict))
            .collect(),
        warnings: r.warnings.clone(),
    }
}

/// `fail` when any scope fails (a sensor alone, or the merged cell); else the merged cell's
/// verdict (a sensor that does not see a position leaves its own scope not measured), or the
/// verdict over every scope when there is no merged one.
fn session_verdict(certificates: &BTreeMap<String, Certificate>) -> Status {
    if certificates.values().any(|c| c.verdict == Status::Fail) {
        return Status::Fail;
    }
    match certificates.get(MERGED) {
        Some(c) => c.verdict,
        None => verdict(certificates.values().map(|c| c.verdict)),
    }
}

/// The certificate the session's page shows: the merged cell's, else the first scope's.
fn page_certificate(
    certificates: &BTreeMap<String, Certificate>,
) -> Option<(&String, &Certificate)> {
    certificates
        .get_key_value(MERGED)
        .or_else(|| certificates.iter().next())
}

/// A position measured and evaluated, ready to join the session.
pub struct Measured {
    /// The figures per scope.
    pub position: VerifyPosition,
    /// The residual maps per scope (file names carry the position).
    pub maps: Vec<(String, Vec<ris_core::verify::ResidualMap>)>,
}

/// Evaluate `artefact` at `position` in each scope's cloud (cell frame): the figures are
/// labelled with the position and name the scan's cloud files.
pub fn measure(
    artefacts: &Artefacts,
    scan_id: &str,
    artefact: Artefact,
    position: &str,
    clouds: Vec<(String, Vec<Vec3>)>,
) -> Result<Measured> {
    let params = VerifyParams::default();
    let mut scopes = BTreeMap::new();
    let mut all_maps = Vec::new();
    for (scope, points) in clouds {
        let cloud = [MeasuredCloud {
            name: format!("{scan_id}/{scope}.ply"),
            points,
        }];
        let none: &[MeasuredCloud] = &[];
        let (bars, planes, spheres) = match artefact {
            Artefact::BallBar => (&cloud[..], none, none),
            Artefact::Plane => (none, &cloud[..], none),
            Artefact::Sphere => (none, none, &cloud[..]),
        };
        let (cert, mut maps) = evaluate(artefacts, bars, planes, spheres, &params, utc_time())
            .with_context(|| format!("evaluating {scope}"))?;
        let mut figures: Vec<Figure> = cert.figures().cloned().collect();
        for m in &mut maps {
            let file = format!("{position}-{}", m.file);
            for f in figures.iter_mut() {
                if f.map.as_deref() == Some(m.file.as_str()) {
                    f.map = Some(file.clone());
                }
            }
            m.title = format!("{scope}, {position}: {}", m.title);
            m.file = file;
        }
        for f in &mut figures {
            f.position.label = position.to_string();
        }
        scopes.insert(scope.clone(), figures);
        all_maps.push((scope, maps));
    }
    Ok(Measured {
        position: VerifyPosition {
            scan_id: scan_id.to_string(),
            artefact,
            position: position.to_string(),
            time: utc_time(),
            scopes,
        },
        maps: all_maps,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use ris_core::verify::synthetic::{bar_cloud, Noise};

    fn config() -> VerifySection {
        VerifySection {
            artefacts: Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../config/verify/demo-artefacts.toml"),
            max_age_days: 30.0,
            drift_share: 0.5,
        }
    }

    /// The demo artefacts' 300 mm bar at `scale` (its spacing × scale), measured in scope
    /// `merged`.
    fn bar(l: &Ledger, seed: u64, scale: f64) -> Measured {
        let (a, b) = (Vec3::new(-150.0, 0.0, 80.0), Vec3::new(150.0, 0.0, 80.0));
        let points = bar_cloud(&mut Noise::new(seed), a, b, 15.0, 0.01, scale);
        measure(
            l.artefacts(),
            &format!("scan-{seed}"),
            Artefact::BallBar,
            "bar-1",
            vec![(MERGED.to_string(), points)],
        )
        .expect("measured")
    }

    #[test]
    fn stale_failed_and_drifting_verifications_warn_and_the_ledger_survives_a_restart() {
        let dir = tempfile::tempdir().expect("tmp");
        let mut l = Ledger::load("c", dir.path(), &config()).expect("ledger");
        let now = unix_now();
        assert!(l.warnings(now)[0].contains("no verification on record"));
        assert!(l
            .finish()
            .expect_err("nothing open")
            .contains("no verification"));

        // An accepted cell warns of nothing until it is older than max_age_days.
        let first = bar(&l, 1, 1.0);
        l.add(first).expect("added");
        let accepted = l.finish().expect("finished");
        assert_eq!(
            accepted.verdict,
            Some(Status::Pass),
            "{:?}",
            accepted.certificates
        );
        assert!(l.warnings(now).is_empty(), "{:?}", l.warnings(now));
        let later = l.warnings(now + 31 * 86_400);
        assert!(
            later.len() == 1 && later[0].contains("days old") && later[0].contains("30"),
            "{later:?}"
        );

        // A check 0.2 mm long (67 % of the 0.3 mm MPE) passes but warns: near the MPE and
        // moved from the acceptance test.
        l.start(VerifyKind::Check).expect("check");
        let long = bar(&l, 2, 300.2 / 300.0);
        l.add(long).expect("added");
        let check = l.finish().expect("finished");
        assert_eq!(check.verdict, Some(Status::Pass));
        let w = check.warnings.join("\n");
        assert!(
            w.contains("of its MPE 0.300 mm (warned from 50 %)") && w.contains("moved by +0."),
            "{w}"
        );
        assert!(l.warnings(now).iter().any(|x| x.contains("moved by")));

        // 0.5 mm long fails: health's warning names it.
        l.start(VerifyKind::Check).expect("check");
        let failing = bar(&l, 3, 300.5 / 300.0);
        l.add(failing).expect("added");
        assert_eq!(l.finish().expect("finished").verdict, Some(Status::Fail));
        assert!(
            l.warnings(now)[0].contains("failed"),
            "{:?}",
            l.warnings(now)
        );

        // An open session and the history come back after a restart; a second start is
        // refused while one is open; abort drops it.
        let again = bar(&l, 4, 1.0);
        l.add(again).expect("opens an acceptance test");
        let reloaded = Ledger::load("c", dir.path(), &config()).expect("reloaded");
        assert_eq!(reloaded.finished().len(), 3);
        assert_eq!(reloaded.open_session().map(|o| o.positions.len()), Some(1));
        assert_eq!(reloaded.history(Some(MERGED)).len(), 3);
        assert!(l
            .start(VerifyKind::Acceptance)
            .expect_err("open")
            .contains("is open"));
        l.abort().expect("aborted");
        let reloaded = Ledger::load("c", dir.path(), &config()).expect("reloaded");
        assert!(reloaded.open_session().is_none());
    }

    #[test]
    fn an_artefact_the_file_does_not_describe_is_refused_by_name() {
        let dir = tempfile::tempdir().expect("tmp");
        let file = dir.path().join("bar-only.toml");
        std::fs::write(
            &file,
            "[ball_bar]\ndiameter_a = 30.0\ndiameter_b = 30.0\nspacing = 300.0\n[mpe]\nprobing_form = 0.4\nprobing_size = 0.2\nsphere_spacing = 0.3\nflatness = 0.5\n",
        )
        .expect("write");
        let l = Ledger::load(
            "c",
            dir.path(),
            &VerifySection {
                artefacts: file,
                ..config()
            },
        )
        .expect("ledger");
        assert!(l.check(Artefact::BallBar).is_ok());
        let e = l.check(Artefact::Sphere).expect_err("no sphere");
        assert!(e.contains("bar-only.toml") && e.contains("[sphere]"), "{e}");
    }
}
