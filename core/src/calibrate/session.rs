//! The multi-layer calibration session on disk (SPEC §7): `session.toml` with the board and one
//! capture set per layer at a known height.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::chessboard::BoardSize;
use crate::io::{read_toml, write_toml};
use crate::{Error, Result};

/// `[board]` of a session.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoardSection {
    /// Inner corners along x and along y.
    pub inner_corners: [usize; 2],
    /// Square size, mm.
    pub square: f64,
}

/// `[[layer]]` of a session.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LayerSection {
    /// Capture set directory, relative to the session file.
    pub dir: String,
    /// Board surface height, mm (the lowest layer is 0).
    pub height: f64,
}

/// `session.toml` as written on disk.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SessionFile {
    /// The chessboard.
    pub board: BoardSection,
    /// The layers, the reference (height 0) first.
    pub layer: Vec<LayerSection>,
}

/// One validated layer.
#[derive(Clone, Debug)]
pub struct Layer {
    /// Capture set directory.
    pub dir: PathBuf,
    /// Board surface height, mm.
    pub height: f64,
}

/// A validated session.
#[derive(Clone, Debug)]
pub struct Session {
    /// The session file.
    pub path: PathBuf,
    /// Inner corners.
    pub board: BoardSize,
    /// Square, mm.
    pub square: f64,
    /// Layers; `layers[0]` is the reference at height 0.
    pub layers: Vec<Layer>,
}

impl SessionFile {
    /// Write atomically.
    pub fn save(&self, path: &Path) -> Result<()> {
        write_toml(path, self)
    }
}

impl Session {
    /// Read `DIR/session.toml` (or the file itself) and validate it; errors name the field.
    pub fn load(path: &Path) -> Result<Session> {
        let file_path = if path.is_dir() {
            path.join("session.toml")
        } else {
            path.to_path_buf()
        };
        let f: SessionFile = read_toml(&file_path)?;
        let ctx = file_path.display().to_string();
        let [cols, rows] = f.board.inner_corners;
        if cols < 3 || rows < 3 {
            return Err(Error::invalid(
                &ctx,
                "board.inner_corners",
                format!("[{cols}, {rows}]: at least 3 corners each way"),
            ));
        }
        if !(f.board.square.is_finite() && f.board.square > 0.0) {
            return Err(Error::invalid(
                &ctx,
                "board.square",
                format!("{} mm must be positive", f.board.square),
            ));
        }
        if f.layer.len() < 3 {
            return Err(Error::invalid(
                &ctx,
                "layer",
                format!(
                    "{} layers; the reference and at least two lifted layers are needed",
                    f.layer.len()
                ),
            ));
        }
        let base = file_path.parent().unwrap_or(Path::new("."));
        let mut layers = Vec::new();
        for (i, l) in f.layer.iter().enumerate() {
            if !l.height.is_finite() {
                return Err(Error::invalid(
                    &ctx,
                    format!("layer[{i}].height"),
                    "not a number",
                ));
            }
            if f.layer[..i].iter().any(|o| o.height == l.height) {
                return Err(Error::invalid(
                    &ctx,
                    format!("layer[{i}].height"),
                    format!("{} mm appears twice", l.height),
                ));
            }
            layers.push(Layer {
                dir: base.join(&l.dir),
                height: l.height,
            });
        }
        if layers[0].height != 0.0 || layers.iter().any(|l| l.height < 0.0) {
            return Err(Error::invalid(
                &ctx,
                "layer[0].height",
                "the first layer is the reference at height 0, and no layer lies below it",
            ));
        }
        Ok(Session {
            path: file_path,
            board: BoardSize { cols, rows },
            square: f.board.square,
            layers,
        })
    }

    /// World point (mm, SPEC §7 board frame) of inner corner (i, j) on a layer at `height`:
    /// origin at the grid centre, x with i (towards increasing u), y against j so that z points
    /// towards the camera.
    pub fn corner_point(&self, i: usize, j: usize, height: f64) -> [f64; 3] {
        [
            (i as f64 - (self.board.cols as f64 - 1.0) / 2.0) * self.square,
            -(j as f64 - (self.board.rows as f64 - 1.0) / 2.0) * self.square,
            height,
        ]
    }

    /// Half extents (x, y) of the squares' area, mm.
    pub fn board_half_extent(&self) -> [f64; 2] {
        [
            (self.board.cols as f64 + 1.0) / 2.0 * self.square,
            (self.board.rows as f64 + 1.0) / 2.0 * self.square,
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn load(text: &str) -> Result<Session> {
        let dir = tempfile::tempdir().expect("tempdir");
        std::fs::write(dir.path().join("session.toml"), text).expect("write");
        Session::load(dir.path())
    }

    const GOOD: &str = "[board]\ninner_corners = [13, 9]\nsquare = 40.0\n\
        [[layer]]\ndir = \"layer0\"\nheight = 0.0\n[[layer]]\ndir = \"layer1\"\nheight = 20.0\n\
        [[layer]]\ndir = \"layer2\"\nheight = 40.0\n";

    #[test]
    fn parses_and_numbers_the_board_frame() {
        let s = load(GOOD).expect("session");
        assert_eq!(s.layers.len(), 3);
        assert!(s.layers[1].dir.ends_with("layer1"));
        assert_eq!(s.corner_point(0, 0, 20.0), [-240.0, 160.0, 20.0]);
        assert_eq!(s.corner_point(6, 4, 0.0), [0.0, 0.0, 0.0]);
        assert_eq!(s.board_half_extent(), [280.0, 200.0]);
    }

    #[test]
    fn errors_name_the_field() {
        let bad = GOOD.replace("square = 40.0", "square = -4.0");
        assert!(load(&bad)
            .expect_err("square")
            .to_string()
            .contains("board.square"));
        let bad = GOOD.replace("height = 40.0", "height = 20.0");
        assert!(load(&bad)
            .expect_err("dup")
            .to_string()
            .contains("layer[2].height"));
        let bad = GOOD.replace("height = 0.0", "height = 5.0");
        assert!(load(&bad)
            .expect_err("ref")
            .to_string()
            .contains("layer[0].height"));
        let bad = GOOD.replace("square = 40.0", "square = 40.0\nsize = 3");
        assert!(load(&bad)
            .expect_err("unknown")
            .to_string()
            .contains("size"));
    }
}
