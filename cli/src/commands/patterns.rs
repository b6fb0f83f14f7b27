//! `ris patterns`: write every pattern of a multi-shot sequence as 8-bit PNG.

use std::path::Path;

use anyhow::{Context, Result};
use rayon::prelude::*;
use ris_core::image::GrayImage;
use ris_core::pattern::{CodeLayout, Pattern};
use ris_core::single_shot::{DenseRegion, XPointPattern};

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
    dense: &[DenseRegion],
    min_distance: u32,
    seed: u64,
    out: &Path,
) -> Result<XPointPattern> {
    let pattern = XPointPattern::with_dense(width, height, step, dense, min_distance, seed)?;
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

/// A dense region from `--dense X0,X1,Y0,Y1,DX,DY` (projector pixels).
pub fn parse_dense(text: &str) -> Result<DenseRegion> {
    let bad =
        || anyhow::anyhow!("--dense {text:?}: expected X0,X1,Y0,Y1,DX,DY in projector pixels");
    let v: Vec<f64> = text
        .split(',')
        .map(|x| x.trim().parse::<f64>())
        .collect::<std::result::Result<_, _>>()
        .map_err(|_| bad())?;
    let whole = |x: f64| (x.fract() == 0.0 && (1.0..=512.0).contains(&x)).then_some(x as u32);
    match v[..] {
        [x0, x1, y0, y1, dx, dy] => Ok(DenseRegion {
            x: [x0, x1],
            y: [y0, y1],
            step: [whole(dx).ok_or_else(bad)?, whole(dy).ok_or_else(bad)?],
        }),
        _ => Err(bad()),
    }
}
