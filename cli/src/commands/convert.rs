//! `ris convert`: a point cloud between PLY and E57, chosen by the files' extensions.

use std::path::Path;

use anyhow::{bail, Context, Result};
use ris_core::cloud::PointCloud;

/// The cloud format a path names.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Format {
    Ply,
    E57,
}

fn format_of(path: &Path) -> Result<Format> {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_lowercase())
        .unwrap_or_default();
    match ext.as_str() {
        "ply" => Ok(Format::Ply),
        "e57" => Ok(Format::E57),
        _ => bail!(
            "{}: unknown cloud format `.{ext}` (ris convert reads and writes .ply and .e57)",
            path.display()
        ),
    }
}

/// Read a cloud from PLY or E57, by the file's extension.
pub fn read(input: &Path) -> Result<PointCloud> {
    match format_of(input)? {
        Format::Ply => PointCloud::read_ply(input),
        Format::E57 => PointCloud::read_e57(input),
    }
    .with_context(|| format!("reading {}", input.display()))
}

/// Read `input` and write it as `output`; returns the cloud.
pub fn run(input: &Path, output: &Path) -> Result<PointCloud> {
    let to = format_of(output)?;
    let cloud = read(input)?;
    match to {
        Format::Ply => cloud.write_ply(output),
        Format::E57 => cloud.write_e57(output),
    }
    .with_context(|| format!("writing {}", output.display()))?;
    println!(
        "{} → {}: {} points{}",
        input.display(),
        output.display(),
        cloud.len(),
        if cloud.outside_count() > 0 {
            format!(
                ", {} flagged outside the calibrated volume",
                cloud.outside_count()
            )
        } else {
            String::new()
        }
    );
    Ok(cloud)
}
