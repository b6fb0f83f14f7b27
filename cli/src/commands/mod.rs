//! One module per `ris` sub-command.

pub mod calibrate;
pub mod camera;
pub mod client;
pub mod console;
pub mod convert;
pub mod decode;
pub mod demo;
pub mod experiment;
pub mod inspect;
pub mod merge;
pub mod omni;
pub mod patterns;
pub mod precision;
pub mod project;
pub mod reconstruct;
pub mod register;
pub mod scan;
pub mod scans;
pub mod simulate;
pub mod single_shot;
pub mod stream;
pub mod verify;
pub mod verify_session;
#[cfg(all(feature = "aravis", feature = "projector"))]
pub mod virtual_cell;

use std::path::PathBuf;

use anyhow::{bail, Context, Result};

/// Split a `SENSOR.toml:CLOUD.ply` argument.
pub fn parse_sensor_cloud(arg: &str) -> Result<(PathBuf, PathBuf)> {
    match arg.rsplit_once(':') {
        Some((s, c)) if !s.is_empty() && !c.is_empty() => Ok((s.into(), c.into())),
        _ => bail!("`{arg}` is not SENSOR.toml:CLOUD.ply"),
    }
}

/// Parse `WIDTHxHEIGHT` (e.g. `1024x768`).
pub fn parse_size(s: &str) -> Result<(u32, u32)> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .with_context(|| format!("`{s}` is not a size like 1024x768"))?;
    let w: u32 = w
        .trim()
        .parse()
        .with_context(|| format!("width in `{s}` is not a number"))?;
    let h: u32 = h
        .trim()
        .parse()
        .with_context(|| format!("height in `{s}` is not a number"))?;
    if w == 0 || h == 0 || w > 65536 || h > 65536 {
        bail!("size `{s}` is out of range (1..=65536 per side)");
    }
    Ok((w, h))
}

/// Parse a distance range `NEAR,FAR` in mm (`what` names the argument in errors).
pub fn parse_range(s: &str, what: &str) -> Result<ris_core::single_shot::FusionRange> {
    let (near, far) = s
        .split_once(',')
        .with_context(|| format!("{what} `{s}`: expected NEAR,FAR in mm"))?;
    let num = |t: &str| {
        t.trim()
            .parse::<f64>()
            .with_context(|| format!("{what} `{s}`: `{t}` is not a number"))
    };
    Ok(ris_core::single_shot::FusionRange::new(
        num(near)?,
        num(far)?,
        what,
    )?)
}

/// Distinct exit statuses so scripts can branch on the verdict: 3 for a failed part, 4 for
/// one that was not measured (neither pass nor fail).
pub fn verdict_exit_code(verdict: &str) -> Option<i32> {
    match verdict {
        "pass" => None,
        ris_core::inspect::NOT_MEASURED => Some(4),
        _ => Some(3),
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn sizes() {
        assert_eq!(super::parse_size("1024x768").expect("ok"), (1024, 768));
        assert!(super::parse_size("1024").is_err());
        assert!(super::parse_size("0x5").is_err());
        assert!(super::parse_size("ax5").is_err());
    }
}
