//! `ris decode`: capture set → col.npy, row.npy, confidence.npy and a false-colour PNG.

use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result};
use ris_core::capture::CaptureSet;
use ris_core::decode::{decode, DecodeParams, Decoded};

/// Decode the capture at `capture` and write the maps into `out`.
pub fn run(capture: &Path, params: &DecodeParams, out: &Path) -> Result<Decoded> {
    let set = CaptureSet::load(capture)
        .with_context(|| format!("reading capture set {}", capture.display()))?;
    let t = Instant::now();
    let decoded =
        decode(&set, params).with_context(|| format!("decoding {}", capture.display()))?;
    let elapsed = t.elapsed();
    decoded
        .save(out)
        .with_context(|| format!("writing decoded maps to {}", out.display()))?;
    let total = decoded.col.len();
    let valid = decoded.valid_count();
    println!(
        "decoded {}: {valid} of {total} pixels valid ({:.1} %), {:?} binarization, rows {}, {:.1} ms; maps in {}",
        capture.display(),
        100.0 * valid as f64 / total.max(1) as f64,
        decoded.binarization,
        if decoded.row.is_some() { "yes" } else { "no" },
        elapsed.as_secs_f64() * 1e3,
        out.display()
    );
    Ok(decoded)
}
