//! `ris patterns`: write every pattern of a multi-shot sequence as 8-bit PNG.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use rayon::prelude::*;
use ris_core::image::GrayImage;
use ris_core::pattern::{CodeLayout, Pattern};
use ris_core::single_shot::{DenseRegion, XPointPattern};

/// `ris patterns`: what to write.
#[derive(Clone, Debug, clap::Args)]
pub struct PatternsArgs {
    /// Projector size, e.g. 1024x768.
    #[arg(long)]
    pub projector: String,
    /// Projector pixels per column code cell.
    #[arg(long, default_value_t = 1)]
    pub column_step: u32,
    /// Projector pixels per row code cell.
    #[arg(long, default_value_t = 1)]
    pub row_step: u32,
    /// Leave out the row codes.
    #[arg(long)]
    pub no_rows: bool,
    /// Add the flat levels of the photo response (flat_000 … flat_250).
    #[arg(long)]
    pub flats: bool,
    /// Write the omnidirectional projector's ring pattern instead (rings.png, rings.toml).
    #[arg(long)]
    pub rings: bool,
    /// Centre of the rings, e.g. 511.5,383.5 (default: the image centre).
    #[arg(long)]
    pub center: Option<String>,
    /// Write the single-shot X-point pattern instead (xpoint.png, xpoint.toml).
    #[arg(long)]
    pub xpoint: bool,
    /// With --xpoint: the seed of the code array.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// With --xpoint: grid steps DX,DY in projector pixels.
    #[arg(long, default_value = "14,14")]
    pub step: String,
    /// With --xpoint: Hamming distance every two distinct 3x3 windows keep (at most 3).
    #[arg(long, default_value_t = 3)]
    pub min_distance: u32,
    /// With --xpoint: a region with a finer step, X0,X1,Y0,Y1,DX,DY (projector columns
    /// X0…X1, rows Y0…Y1, steps DX,DY); repeat for more. The columns across X0…X1 and the
    /// rows across Y0…Y1 take the finer steps.
    #[arg(long)]
    pub dense: Vec<String>,
    /// Output directory.
    #[arg(long)]
    pub out: PathBuf,
}

/// Run `ris patterns`: the Gray-code sequence, the ring pattern (`--rings`) or the X-point
/// pattern (`--xpoint`) into `--out`, and say what was written.
pub fn command(args: &PatternsArgs) -> Result<()> {
    let PatternsArgs {
        projector,
        column_step,
        row_step,
        no_rows,
        flats,
        rings,
        center,
        xpoint,
        seed,
        step,
        min_distance,
        dense,
        out,
    } = args.clone();
    let (width, height) = super::parse_size(&projector)?;
    anyhow::ensure!(
        xpoint || dense.is_empty(),
        "--dense refines the X-point pattern: it needs --xpoint"
    );
    anyhow::ensure!(
        !(rings && xpoint),
        "--rings and --xpoint are different patterns: one at a time"
    );
    if xpoint {
        let step: Vec<u32> = step
            .split(',')
            .map(|x| x.trim().parse::<u32>())
            .collect::<std::result::Result<_, _>>()
            .map_err(|_| anyhow::anyhow!("--step {step:?}: expected DX,DY in pixels"))?;
        anyhow::ensure!(step.len() == 2, "--step: expected DX,DY in pixels");
        let dense = dense
            .iter()
            .map(|d| parse_dense(d))
            .collect::<Result<Vec<_>>>()?;
        let p = self::xpoint(
            width,
            height,
            [step[0], step[1]],
            &dense,
            min_distance,
            seed,
            &out,
        )?;
        let [c, r] = p.grid();
        println!(
            "wrote {} X-points ({c}x{r} grid, windows unique over {}x{}) for a {width}x{height} projector to {}",
            c * r,
            p.pattern.period[0],
            p.pattern.period[1],
            out.display()
        );
        return Ok(());
    }
    if rings {
        let center = match center {
            Some(c) => {
                let v: Vec<f64> = c
                    .split(',')
                    .map(|x| x.trim().parse::<f64>())
                    .collect::<std::result::Result<_, _>>()
                    .map_err(|_| anyhow::anyhow!("--center {c:?}: expected CX,CY"))?;
                anyhow::ensure!(v.len() == 2, "--center {c:?}: expected CX,CY");
                Some([v[0], v[1]])
            }
            None => None,
        };
        let n = self::rings(width, height, center, &out)?;
        println!(
            "wrote {n} rings for a {width}x{height} projector to {}",
            out.display()
        );
        return Ok(());
    }
    anyhow::ensure!(center.is_none(), "--center goes with --rings");
    anyhow::ensure!(
        column_step >= 1 && row_step >= 1,
        "--column-step and --row-step must be ≥ 1"
    );
    let n = run(
        CodeLayout {
            width,
            height,
            column_step,
            row_step,
        },
        !no_rows,
        flats,
        &out,
    )?;
    println!(
        "wrote {n} patterns for a {width}x{height} projector to {}",
        out.display()
    );
    Ok(())
}

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
