//! The scan store under the data directory: one directory per scan, written as
//! `<id>.partial` and renamed when complete; the lock that makes one daemon its owner;
//! housekeeping at start and retention after every scan; the stored results served to clients.

use std::fs::File;
use std::path::{Path, PathBuf};

use anyhow::{anyhow, Context, Result};

use crate::protocol::ScanItem;

/// Exclusive ownership of a data directory (an advisory lock on `<data_dir>/risd.lock`, held
/// until dropped): a second risd on the same directory refuses to start instead of sweeping
/// away the first one's running scan.
pub struct DataDirLock {
    _file: File,
    path: PathBuf,
}

impl DataDirLock {
    /// Create the directory if needed and take its lock, or say who holds it.
    pub fn acquire(data_dir: &Path) -> Result<DataDirLock> {
        std::fs::create_dir_all(data_dir)
            .with_context(|| format!("creating the data directory {}", data_dir.display()))?;
        let path = data_dir.join("risd.lock");
        let file = std::fs::OpenOptions::new()
            .create(true)
            .truncate(false)
            .read(true)
            .write(true)
            .open(&path)
            .with_context(|| format!("opening the lock file {}", path.display()))?;
        match file.try_lock() {
            Ok(()) => {}
            Err(std::fs::TryLockError::WouldBlock) => {
                let holder = std::fs::read_to_string(&path).unwrap_or_default();
                return Err(anyhow!(
                    "the data directory {} is in use by another risd ({}); give each daemon its own --data-dir",
                    data_dir.display(),
                    holder.trim()
                ));
            }
            Err(std::fs::TryLockError::Error(e)) => {
                return Err(e).with_context(|| format!("locking {}", path.display()))
            }
        }
        // Who holds it, for the message above (best effort: the lock is what counts).
        let _ = file.set_len(0);
        let _ =
            std::io::Write::write_all(&mut &file, format!("pid {}", std::process::id()).as_bytes());
        Ok(DataDirLock { _file: file, path })
    }

    /// The lock file.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

/// Remove unfinished scans left by a crash (`*.partial`), and old scans beyond `keep` (0:
/// all kept) or older than `max_age_days` (0: no limit). Returns the names removed. Only the
/// holder of the data directory's lock may call it (a running scan is a `.partial`).
pub fn housekeeping(data_dir: &Path, keep: u32, max_age_days: u32) -> Result<Vec<String>> {
    sweep(data_dir, keep, max_age_days, true)
}

/// Retention after a scan: old scans beyond `keep` or older than `max_age_days` are removed;
/// unfinished ones are left alone.
pub fn retention(data_dir: &Path, keep: u32, max_age_days: u32) -> Result<Vec<String>> {
    sweep(data_dir, keep, max_age_days, false)
}

fn sweep(data_dir: &Path, keep: u32, max_age_days: u32, partials: bool) -> Result<Vec<String>> {
    let scans = data_dir.join("scans");
    let mut removed = Vec::new();
    let Ok(entries) = std::fs::read_dir(&scans) else {
        return Ok(removed);
    };
    let mut finished = Vec::new();
    for e in entries.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let path = e.path();
        if name.ends_with(".partial") {
            if !partials {
                continue;
            }
            std::fs::remove_dir_all(&path)
                .with_context(|| format!("removing the unfinished scan {}", path.display()))?;
            removed.push(name);
        } else if path.join("scan.json").is_file() {
            let modified = e.metadata().and_then(|m| m.modified()).ok();
            finished.push((modified, name, path));
        }
    }
    finished.sort_by(|a, b| (b.0, &b.1).cmp(&(a.0, &a.1)));
    let now = std::time::SystemTime::now();
    for (k, (modified, name, path)) in finished.into_iter().enumerate() {
        let too_many = keep > 0 && k >= keep as usize;
        let too_old = max_age_days > 0
            && modified
                .and_then(|m| now.duration_since(m).ok())
                .is_some_and(|age| age.as_secs() > u64::from(max_age_days) * 86_400);
        if too_many || too_old {
            std::fs::remove_dir_all(&path)
                .with_context(|| format!("removing the old scan {}", path.display()))?;
            removed.push(name);
        }
    }
    Ok(removed)
}

/// The stored results of finished scans: (key, file) for `<id>/report` (the inspection report,
/// else the scan's summary), `<id>/summary` (`scan.json`), `<id>/cloud/<sensor>`, `<id>/deviation` (the deviation cloud),
/// `<id>/map` (the labelled deviation map, PNG) and `<id>/page` (`report.html`), and the ids. Blocking directory walk: run off the async runtime.
pub fn stored_items(cell: &str, data_dir: &Path) -> (Vec<String>, Vec<(String, PathBuf)>) {
    let mut ids = Vec::new();
    let mut items = Vec::new();
    let Ok(entries) = std::fs::read_dir(data_dir.join("scans")) else {
        return (ids, items);
    };
    // Only what lies in the store itself: a symlink (to a directory or a file elsewhere) is
    // never served.
    let plain_file = |p: &Path| std::fs::symlink_metadata(p).is_ok_and(|m| m.is_file());
    for e in entries.flatten() {
        let id = e.file_name().to_string_lossy().into_owned();
        let dir: PathBuf = e.path();
        if id.ends_with(".partial")
            || !e.file_type().is_ok_and(|t| t.is_dir())
            || !plain_file(&dir.join("scan.json"))
        {
            continue;
        }
        let report = Some(dir.join("report.json"))
            .filter(|p| plain_file(p))
            .unwrap_or_else(|| dir.join("scan.json"));
        items.push((ScanItem::Report.key(cell, &id), report));
        items.push((ScanItem::Summary.key(cell, &id), dir.join("scan.json")));
        if let Ok(files) = std::fs::read_dir(&dir) {
            for f in files.flatten() {
                if !f.file_type().is_ok_and(|t| t.is_file()) {
                    continue;
                }
                let name = f.file_name().to_string_lossy().into_owned();
                match name.as_str() {
                    "report.html" => {
                        items.push((ScanItem::Page.key(cell, &id), f.path()));
                        continue;
                    }
                    "deviation.png" => {
                        items.push((ScanItem::Map.key(cell, &id), f.path()));
                        continue;
                    }
                    _ => {}
                }
                match name.strip_suffix(".ply") {
                    Some("deviation") => items.push((ScanItem::Deviation.key(cell, &id), f.path())),
                    Some(sensor) => {
                        items.push((ScanItem::Cloud(sensor.to_string()).key(cell, &id), f.path()))
                    }
                    None => {}
                }
            }
        }
        ids.push(id);
    }
    (ids, items)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_lock_on_the_data_directory_is_refused() {
        let dir = tempfile::tempdir().expect("tmp");
        let first = DataDirLock::acquire(dir.path()).expect("first");
        let err = DataDirLock::acquire(dir.path())
            .err()
            .expect("second refused");
        assert!(
            format!("{err:#}").contains("in use by another risd"),
            "{err:#}"
        );
        drop(first);
        DataDirLock::acquire(dir.path()).expect("free again");
    }

    #[test]
    fn the_store_serves_no_symlink_out_of_itself() {
        let dir = tempfile::tempdir().expect("tmp");
        let outside = tempfile::tempdir().expect("tmp");
        let secret = outside.path().join("secret.json");
        std::fs::write(&secret, "{\"secret\": 1}").expect("write");
        let scans = dir.path().join("scans");
        let a = scans.join("a");
        std::fs::create_dir_all(&a).expect("mkdir");
        std::fs::write(a.join("scan.json"), "{}").expect("write");
        std::fs::write(a.join("merged.ply"), "ply").expect("write");
        std::os::unix::fs::symlink(&secret, a.join("report.json")).expect("link");
        std::os::unix::fs::symlink(&secret, a.join("s1.ply")).expect("link");
        // A scan directory that is a link to a directory elsewhere.
        std::fs::create_dir_all(outside.path().join("b")).expect("mkdir");
        std::fs::write(outside.path().join("b/scan.json"), "{}").expect("write");
        std::os::unix::fs::symlink(outside.path().join("b"), scans.join("b")).expect("link");
        let (ids, items) = stored_items("c", dir.path());
        assert_eq!(ids, vec!["a".to_string()]);
        for (key, path) in &items {
            assert!(
                path.starts_with(dir.path()) && !path.is_symlink(),
                "{key} -> {}",
                path.display()
            );
        }
        let report = items
            .iter()
            .find(|(k, _)| k.ends_with("/report"))
            .expect("a report");
        assert_eq!(
            report.1,
            a.join("scan.json"),
            "the linked report.json is not served"
        );
        assert!(!items.iter().any(|(k, _)| k.ends_with("/cloud/s1")));
        assert!(items.iter().any(|(k, _)| k.ends_with("/cloud/merged")));
    }

    #[test]
    fn retention_keeps_the_newest_and_leaves_partials() {
        let dir = tempfile::tempdir().expect("tmp");
        let scans = dir.path().join("scans");
        for id in ["a", "b", "c"] {
            std::fs::create_dir_all(scans.join(id)).expect("mkdir");
            std::fs::write(scans.join(id).join("scan.json"), "{}").expect("write");
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        std::fs::create_dir_all(scans.join("d.partial")).expect("mkdir");
        let removed = retention(dir.path(), 2, 0).expect("retention");
        assert_eq!(removed, vec!["a".to_string()]);
        assert!(scans.join("d.partial").is_dir());
        let removed = housekeeping(dir.path(), 2, 0).expect("housekeeping");
        assert_eq!(removed, vec!["d.partial".to_string()]);
    }
}
