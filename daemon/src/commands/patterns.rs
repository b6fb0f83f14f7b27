//! `ris patterns`: write every pattern of a multi-shot sequence as 8-bit PNG.

use std::path::Path;

use anyhow::{Context, Result};
use rayon::prelude::*;
use ris_core::image::GrayImage;
use ris_core::pattern::{CodeLayout, Pattern};

/// Write the sequence (and optionally the flats of the photo response) to `out`; returns the
/// number of files written.
pub fn run(layout: CodeLayout, with_rows: bool, flats: bool, out: &Path) -> Result<usize> {
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let mut patterns = layout.sequence(with_rows);
    if flats {
        patterns.extend([0u8, 50, 100, 150, 200, 250].map(Pattern::Flat));
    }
    patterns.par_iter().try_for_each(|p| {
        let path = out.join(format!("{}.png", p.name()));
        GrayImage::from_u8(layout.width, layout.height, layout.render(*p))
            .save_png(&path)
            .with_context(|| format!("writing {}", path.display()))
    })?;
    tracing::info!(count = patterns.len(), dir = %out.display(), "patterns written");
    Ok(patterns.len())
}

/// Write the omnidirectional projector's ring pattern (SPEC §13): `rings.png` and `rings.toml`,
/// which states every ring so that the image can be rebuilt from it.
pub fn rings(width: u32, height: u32, center: Option<[f64; 2]>, out: &Path) -> Result<usize> {
    let center = center.unwrap_or([
        (f64::from(width) - 1.0) / 2.0,
        (f64::from(height) - 1.0) / 2.0,
    ]);
    let pattern = ris_core::omni::RingPattern::design(width, height, center)?;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let png = out.join("rings.png");
    GrayImage::from_u8(width, height, pattern.render())
        .save_png(&png)
        .with_context(|| format!("writing {}", png.display()))?;
    ris_core::io::write_toml(&out.join("rings.toml"), &pattern)
        .with_context(|| format!("writing {}", out.join("rings.toml").display()))?;
    tracing::info!(rings = pattern.ring.len(), dir = %out.display(), "ring pattern written");
    Ok(pattern.ring.len())
}

/// Write the single-shot X-point pattern (SPEC §10): `xpoint.png` and `xpoint.toml`, which
/// states every primitive so that the image can be redrawn from it.
pub fn xpoint(
    width: u32,
    height: u32,
    step: [u32; 2],
    min_distance: u32,
    seed: u64,
    out: &Path,
) -> Result<ris_core::single_shot::XPointPattern> {
    let pattern =
        ris_core::single_shot::XPointPattern::generate(width, height, step, min_distance, seed)?;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let png = out.join("xpoint.png");
    GrayImage::from_u8(width, height, pattern.render())
        .save_png(&png)
        .with_context(|| format!("writing {}", png.display()))?;
    ris_core::io::write_toml(&out.join("xpoint.toml"), &pattern)
        .with_context(|| format!("writing {}", out.join("xpoint.toml").display()))?;
    tracing::info!(primitives = pattern.primitives.u.len(), dir = %out.display(), "X-point pattern written");
    Ok(pattern)
}
