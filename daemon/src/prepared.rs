//! Prepared pairs kept on disk. The slowest part of preparing a pair is its decoded reference
//! recording (a full Gray-code sequence rendered or loaded, then decoded): it is stored under the
//! cache directory, keyed by everything it depends on, and reused while none of that changed.
//!
//! A key is text naming every input (the scene or the recording's files with their sizes and
//! times, the decoder's parameters, the executable that decodes); the file is named by the key's
//! digest and holds the key itself, compared in full on load, so neither a digest collision nor a
//! rebuilt binary can return a stale reference. A cache that cannot be read or written costs
//! time, never a start: the reference is computed as without one.

use std::fmt::Debug;
use std::hash::{Hash, Hasher};
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use ris_core::decode::{Binarization, Decoded};
use ris_core::io::bytes::{ByteReader, ByteWriter};
use ris_core::pattern::CodeLayout;
use ris_core::sim::RenderCache;

const MAGIC: &[u8; 8] = b"RISREF01";

/// What a cached reference depends on.
#[derive(Clone, Debug)]
pub struct Key {
    text: String,
}

impl Key {
    /// A key for `what`, starting with the format and the running executable (its path, size and
    /// modification time: any rebuild or upgrade of the decoder misses the cache).
    pub fn new(what: &str) -> Key {
        let mut key = Key {
            text: format!("{}\n{what}\n", String::from_utf8_lossy(MAGIC)),
        };
        match std::env::current_exe() {
            Ok(exe) => key.file("executable", &exe),
            Err(_) => key.add("executable", "unknown"),
        }
        key
    }

    /// Add an input by its `Debug` text (floats print exactly).
    pub fn add(&mut self, name: &str, value: impl Debug) {
        self.text.push_str(&format!("{name} = {value:?}\n"));
    }

    /// Add a file by its path, size and modification time.
    pub fn file(&mut self, name: &str, path: &Path) {
        let stamp = std::fs::metadata(path).ok().map(|m| {
            let modified = m
                .modified()
                .ok()
                .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
                .map(|d| d.as_nanos());
            (m.len(), modified)
        });
        self.add(name, (path, stamp));
    }

    /// Add every file of directory `dir` (sorted by name) by size and modification time.
    pub fn dir(&mut self, name: &str, dir: &Path) {
        let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
            .map(|rd| rd.filter_map(|e| e.ok().map(|e| e.path())).collect())
            .unwrap_or_default();
        files.sort();
        self.add(name, dir);
        for f in files {
            self.file("  file", &f);
        }
    }

    /// 32 hexadecimal digits naming the key's file.
    fn digest(&self) -> String {
        let half = |salt: u64| {
            let mut h = std::hash::DefaultHasher::new();
            salt.hash(&mut h);
            self.text.hash(&mut h);
            h.finish()
        };
        format!("{:016x}{:016x}", half(0x5249_5331), half(0x5249_5332))
    }
}

/// The cache directory of prepared pairs (`None`: no cache).
#[derive(Clone, Debug, Default)]
pub struct Cache {
    dir: Option<PathBuf>,
}

/// A kind of cached table: its file extension and how it is written and read back.
pub struct Kind<T> {
    /// File extension, naming the kind.
    pub extension: &'static str,
    /// The table as bytes.
    pub encode: fn(&T) -> Vec<u8>,
    /// The table from its bytes (`None`: damaged).
    pub decode: fn(&[u8]) -> Option<T>,
}

/// Decoded reference recordings.
pub const REFERENCE: Kind<Decoded> = Kind {
    extension: "reference",
    encode: encode_decoded,
    decode: decode_decoded,
};

/// A mock pair's render cache (its simulated camera's ray-cast scene).
pub const RENDER: Kind<RenderCache> = Kind {
    extension: "render",
    encode: RenderCache::to_bytes,
    decode: RenderCache::from_bytes,
};

impl Cache {
    /// A cache under `dir`, created when first written.
    pub fn new(dir: Option<PathBuf>) -> Cache {
        Cache { dir }
    }

    /// The directory, when there is one.
    pub fn dir(&self) -> Option<&Path> {
        self.dir.as_deref()
    }

    fn path<T>(&self, sensor: &str, kind: &Kind<T>, key: &Key) -> Option<PathBuf> {
        Some(self.dir.as_ref()?.join(format!(
            "{}-{}.{}",
            file_stem(sensor),
            key.digest(),
            kind.extension
        )))
    }

    /// Sensor `sensor`'s table of `kind` for `key`: from the cache when stored under the same
    /// key, else from `make` (then stored, replacing that sensor's older entries of the kind).
    /// The flag says whether it came from the cache.
    pub fn get<T>(
        &self,
        sensor: &str,
        kind: &Kind<T>,
        key: &Key,
        make: impl FnOnce() -> Result<T>,
    ) -> Result<(T, bool)> {
        let Some(path) = self.path(sensor, kind, key) else {
            return Ok((make()?, false));
        };
        match std::fs::read(&path) {
            Ok(bytes) => match read_entry(&bytes, &key.text).and_then(kind.decode) {
                Some(table) => return Ok((table, true)),
                None => {
                    tracing::warn!(file = %path.display(), "ignoring a damaged cache entry; computing it again")
                }
            },
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => {
                tracing::warn!(file = %path.display(), error = %e, "cannot read the cache entry; computing it again")
            }
        }
        let table = make()?;
        let mut entry = ByteWriter::default();
        entry.raw(MAGIC);
        entry.bytes(key.text.as_bytes());
        entry.raw(&(kind.encode)(&table));
        if let Err(e) = self.store(&path, sensor, kind, &entry.bytes) {
            tracing::warn!(file = %path.display(), error = %format!("{e:#}"), "cannot write the cache entry; the next start computes it again");
        }
        Ok((table, false))
    }

    fn store<T>(&self, path: &Path, sensor: &str, kind: &Kind<T>, bytes: &[u8]) -> Result<()> {
        let dir = path.parent().context("cache path without a directory")?;
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        ris_core::io::write_atomic(path, bytes)?;
        // One entry per sensor and kind: older keys go.
        let prefix = format!("{}-", file_stem(sensor));
        let suffix = format!(".{}", kind.extension);
        if let Ok(rd) = std::fs::read_dir(dir) {
            for e in rd.flatten() {
                let name = e.file_name().to_string_lossy().into_owned();
                let stale = name.len() == prefix.len() + 32 + suffix.len()
                    && name.starts_with(&prefix)
                    && name.ends_with(&suffix)
                    && e.path() != path;
                if stale {
                    let _ = std::fs::remove_file(e.path());
                }
            }
        }
        Ok(())
    }
}

/// `sensor` as a file name's start: anything but letters and digits becomes `_`, so no name is
/// another's prefix followed by `-`.
fn file_stem(sensor: &str) -> String {
    sensor
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .collect()
}

/// The payload of an entry stored under exactly `key`.
fn read_entry<'a>(bytes: &'a [u8], key: &str) -> Option<&'a [u8]> {
    let mut r = ByteReader::new(bytes);
    if r.raw(MAGIC.len())? != MAGIC || r.bytes()? != key.as_bytes() {
        return None;
    }
    r.raw(r.remaining())
}

fn encode_decoded(d: &Decoded) -> Vec<u8> {
    let mut w = ByteWriter::with_capacity(64 + 12 * d.col.len());
    for v in [
        d.width,
        d.height,
        d.layout.width,
        d.layout.height,
        d.layout.column_step,
        d.layout.row_step,
    ] {
        w.u32(v);
    }
    w.u8(match d.binarization {
        Binarization::Dual => 0,
        Binarization::Threshold => 1,
    });
    w.f32s(&d.col);
    w.u8(u8::from(d.row.is_some()));
    if let Some(row) = &d.row {
        w.f32s(row);
    }
    w.f32s(&d.confidence);
    w.bytes
}

fn decode_decoded(bytes: &[u8]) -> Option<Decoded> {
    let mut r = ByteReader::new(bytes);
    let [width, height, lw, lh, cs, rs] =
        [r.u32()?, r.u32()?, r.u32()?, r.u32()?, r.u32()?, r.u32()?];
    let binarization = match r.u8()? {
        0 => Binarization::Dual,
        1 => Binarization::Threshold,
        _ => return None,
    };
    let col = r.f32s()?;
    let row = match r.u8()? {
        0 => None,
        1 => Some(r.f32s()?),
        _ => return None,
    };
    let confidence = r.f32s()?;
    let n = (width as usize).checked_mul(height as usize)?;
    let consistent = r.remaining() == 0
        && col.len() == n
        && confidence.len() == n
        && row.as_ref().is_none_or(|r| r.len() == n);
    consistent.then_some(Decoded {
        width,
        height,
        layout: CodeLayout {
            width: lw,
            height: lh,
            column_step: cs,
            row_step: rs,
        },
        col,
        row,
        confidence,
        binarization,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decoded(seed: u32) -> Decoded {
        let (w, h) = (7u32, 5u32);
        let n = (w * h) as usize;
        let f = |i: usize| (i as f32 * 0.37 + seed as f32).sin() * 100.0;
        let mut col: Vec<f32> = (0..n).map(f).collect();
        col[3] = f32::NAN;
        Decoded {
            width: w,
            height: h,
            layout: CodeLayout {
                width: 64,
                height: 48,
                column_step: 2,
                row_step: 1,
            },
            col,
            row: seed
                .is_multiple_of(2)
                .then(|| (0..n).map(|i| f(i + 9)).collect()),
            confidence: (0..n).map(|i| (i % 3) as f32 / 2.0).collect(),
            binarization: if seed.is_multiple_of(3) {
                Binarization::Threshold
            } else {
                Binarization::Dual
            },
        }
    }

    fn same(a: &Decoded, b: &Decoded) -> bool {
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        a.width == b.width
            && a.height == b.height
            && a.layout == b.layout
            && a.binarization == b.binarization
            && bits(&a.col) == bits(&b.col)
            && a.row.as_deref().map(bits) == b.row.as_deref().map(bits)
            && bits(&a.confidence) == bits(&b.confidence)
    }

    #[test]
    fn entries_round_trip_bit_for_bit_and_refuse_other_keys_and_damage() {
        for seed in 0..6 {
            let d = decoded(seed);
            let mut w = ByteWriter::default();
            w.raw(MAGIC);
            w.bytes(b"key a");
            w.raw(&encode_decoded(&d));
            let bytes = w.bytes;
            let read = |b: &[u8], key| read_entry(b, key).and_then(decode_decoded);
            assert!(same(&read(&bytes, "key a").expect("read"), &d));
            assert!(read(&bytes, "key b").is_none());
            for cut in [0, 7, 20, bytes.len() - 1] {
                assert!(read(&bytes[..cut], "key a").is_none(), "cut {cut}");
            }
            let mut longer = bytes.clone();
            longer.push(0);
            assert!(read(&longer, "key a").is_none());
        }
    }

    #[test]
    fn the_cache_reuses_while_inputs_hold_and_recomputes_when_one_changes() {
        let dir = tempfile::tempdir().expect("tmp");
        let input = dir.path().join("input.txt");
        std::fs::write(&input, "one").expect("write");
        let cache = Cache::new(Some(dir.path().join("cache")));
        let key = |value: u32| {
            let mut k = Key::new("test");
            k.add("value", value);
            k.file("input", &input);
            k
        };
        let calls = std::cell::Cell::new(0);
        let make = |seed| {
            calls.set(calls.get() + 1);
            Ok(decoded(seed))
        };
        let get = |sensor, k: &Key, seed| cache.get(sensor, &REFERENCE, k, || make(seed));
        let (a, hit) = get("s 1", &key(1), 1).expect("first");
        assert!(!hit && calls.get() == 1);
        let (b, hit) = get("s 1", &key(1), 2).expect("second");
        assert!(hit && calls.get() == 1 && same(&a, &b));
        // A changed parameter, then a changed file: computed again, the old entry replaced.
        let (_, hit) = get("s 1", &key(2), 2).expect("third");
        assert!(!hit && calls.get() == 2);
        std::fs::write(&input, "two, longer").expect("write");
        let (_, hit) = get("s 1", &key(2), 4).expect("fourth");
        assert!(!hit && calls.get() == 3);
        let entries = std::fs::read_dir(dir.path().join("cache"))
            .expect("dir")
            .count();
        assert_eq!(entries, 1);
        // Another sensor keeps its own entry; a damaged entry is recomputed, not an error.
        get("s2", &key(2), 6).expect("other");
        let path = cache.path("s2", &REFERENCE, &key(2)).expect("path");
        std::fs::write(&path, b"RISREF01garbage").expect("damage");
        let (d, hit) = get("s2", &key(2), 6).expect("damaged");
        assert!(!hit && same(&d, &decoded(6)));
        assert_eq!(
            std::fs::read_dir(dir.path().join("cache"))
                .expect("dir")
                .count(),
            2
        );
        // No directory: always computed.
        let (_, hit) = Cache::default()
            .get("s1", &REFERENCE, &key(1), || make(1))
            .expect("none");
        assert!(!hit);
    }
}
