//! Capture sets on disk (SPEC §4): a directory with `capture.toml` and one image per pattern.
//!
//! Other tools' captures (OpenCV GrayCodePattern order, SLStudio sequences) are read through the
//! `[frames]` table, which maps pattern names to file names.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::image::GrayImage;
use crate::io::{create_dir, read_toml, write_toml};
use crate::pattern::{CodeAxis, CodeLayout, Pattern};
use crate::{Error, Result};

/// Name of the manifest inside a capture directory.
pub const MANIFEST: &str = "capture.toml";

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ManifestFile {
    projector: ProjectorSection,
    camera: CameraSection,
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    frames: BTreeMap<String, String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    mask: Option<MaskSection>,
    #[serde(default, skip_serializing_if = "toml::Table::is_empty")]
    meta: toml::Table,
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ProjectorSection {
    width: u32,
    height: u32,
    #[serde(default = "one")]
    column_step: u32,
    #[serde(default = "one")]
    row_step: u32,
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraSection {
    width: u32,
    height: u32,
}

#[derive(Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct MaskSection {
    file: String,
}

fn one() -> u32 {
    1
}

/// A set of camera frames, one per projected pattern, with the projector's code layout.
#[derive(Clone, Debug)]
pub struct CaptureSet {
    /// Projector size and code steps.
    pub layout: CodeLayout,
    /// Camera width, pixels.
    pub width: u32,
    /// Camera height, pixels.
    pub height: u32,
    /// The frames, by pattern.
    pub frames: BTreeMap<Pattern, GrayImage>,
    /// The projection mask the patterns were multiplied by (16-bit, M × 4096), if any.
    pub mask: Option<GrayImage>,
    /// Free-form metadata (sensor, timestamp, exposure, frame ids, ...).
    pub meta: toml::Table,
}

impl CaptureSet {
    /// An empty capture set.
    pub fn new(layout: CodeLayout, width: u32, height: u32) -> Self {
        CaptureSet {
            layout,
            width,
            height,
            frames: BTreeMap::new(),
            mask: None,
            meta: toml::Table::new(),
        }
    }

    /// The frame of `pattern`, if recorded.
    pub fn frame(&self, pattern: Pattern) -> Option<&GrayImage> {
        self.frames.get(&pattern)
    }

    /// Whether the set carries every inverse pattern of `axis`.
    pub fn has_inverses(&self, axis: CodeAxis) -> bool {
        (0..self.layout.bits(axis)).all(|bit| {
            self.frames.contains_key(&Pattern::Gray {
                axis,
                bit,
                inverse: true,
            })
        })
    }

    /// Whether the set carries every pattern of the code along `axis`.
    pub fn has_code(&self, axis: CodeAxis) -> bool {
        self.layout.bits(axis) > 0
            && (0..self.layout.bits(axis)).all(|bit| {
                self.frames.contains_key(&Pattern::Gray {
                    axis,
                    bit,
                    inverse: false,
                })
            })
    }

    /// Read a capture directory. Every frame is checked against the camera size; a missing
    /// required frame (white, black, column codes; white alone for a single frame) is an error
    /// naming the file it looked for.
    pub fn load(dir: &Path) -> Result<CaptureSet> {
        let manifest_path = dir.join(MANIFEST);
        let m: ManifestFile = read_toml(&manifest_path)?;
        let ctx = manifest_path.display().to_string();
        if m.projector.width == 0 || m.projector.height == 0 {
            return Err(Error::invalid(
                &ctx,
                "projector.width/height",
                "must be positive",
            ));
        }
        if m.projector.column_step == 0 || m.projector.row_step == 0 {
            return Err(Error::invalid(
                &ctx,
                "projector.column_step/row_step",
                "must be ≥ 1",
            ));
        }
        if m.camera.width == 0 || m.camera.height == 0 {
            return Err(Error::invalid(
                &ctx,
                "camera.width/height",
                "must be positive",
            ));
        }
        let layout = CodeLayout {
            width: m.projector.width,
            height: m.projector.height,
            column_step: m.projector.column_step,
            row_step: m.projector.row_step,
        };
        let mut files: BTreeMap<Pattern, PathBuf> = BTreeMap::new();
        for (name, file) in &m.frames {
            let p = Pattern::parse(name).map_err(|_| {
                Error::invalid(&ctx, format!("frames.{name}"), "unknown pattern name")
            })?;
            files.insert(p, dir.join(file));
        }
        // Required: white, black, all column codes. Optional: inverses, rows, flats. A set of
        // the white frame alone is one frame of a projected picture (what a single-shot or
        // omnidirectional scan records): nothing else is required; the Gray-code decoder names
        // what such a set lacks.
        let single = m.frames.keys().all(|name| name == "white")
            && !dir.join(format!("{}.png", Pattern::Black.name())).exists()
            && !dir
                .join(format!(
                    "{}.png",
                    Pattern::Gray {
                        axis: CodeAxis::Column,
                        bit: 0,
                        inverse: false
                    }
                    .name()
                ))
                .exists();
        let mut wanted: Vec<(Pattern, bool)> =
            vec![(Pattern::White, true), (Pattern::Black, !single)];
        for axis in [CodeAxis::Column, CodeAxis::Row] {
            for bit in 0..layout.bits(axis) {
                wanted.push((
                    Pattern::Gray {
                        axis,
                        bit,
                        inverse: false,
                    },
                    axis == CodeAxis::Column && !single,
                ));
                wanted.push((
                    Pattern::Gray {
                        axis,
                        bit,
                        inverse: true,
                    },
                    false,
                ));
            }
        }
        let mut to_load: Vec<(Pattern, PathBuf)> = Vec::new();
        for (p, required) in wanted {
            let path = files
                .remove(&p)
                .unwrap_or_else(|| dir.join(format!("{}.png", p.name())));
            if path.exists() {
                to_load.push((p, path));
            } else if required || m.frames.contains_key(&p.name()) {
                return Err(Error::invalid(
                    &ctx,
                    format!("frames.{}", p.name()),
                    format!("frame file {} is missing", path.display()),
                ));
            }
        }
        // Anything else mapped explicitly (flats, bits beyond the layout) must exist too.
        for (p, path) in files {
            if let Pattern::Gray { axis, bit, .. } = p {
                if bit >= layout.bits(axis) {
                    return Err(Error::invalid(
                        &ctx,
                        format!("frames.{}", p.name()),
                        format!(
                            "bit {bit} does not exist for a {}-bit code",
                            layout.bits(axis)
                        ),
                    ));
                }
            }
            if !path.exists() {
                return Err(Error::invalid(
                    &ctx,
                    format!("frames.{}", p.name()),
                    format!("frame file {} is missing", path.display()),
                ));
            }
            to_load.push((p, path));
        }
        // Flats written by us under their default names.
        for level in [0u8, 50, 100, 150, 200, 250] {
            let p = Pattern::Flat(level);
            let path = dir.join(format!("{}.png", p.name()));
            if !to_load.iter().any(|(q, _)| *q == p) && path.exists() {
                to_load.push((p, path));
            }
        }
        let loaded: Vec<(Pattern, GrayImage)> = to_load
            .into_par_iter()
            .map(|(p, path)| {
                let img = GrayImage::load(&path)?;
                if (img.width, img.height) != (m.camera.width, m.camera.height) {
                    return Err(Error::invalid(
                        path.display(),
                        "size",
                        format!(
                            "frame is {}x{} but {} says the camera is {}x{}",
                            img.width, img.height, ctx, m.camera.width, m.camera.height
                        ),
                    ));
                }
                Ok((p, img))
            })
            .collect::<Result<_>>()?;
        let mut set = CaptureSet::new(layout, m.camera.width, m.camera.height);
        set.frames = loaded.into_iter().collect();
        set.meta = m.meta;
        for axis in [CodeAxis::Column, CodeAxis::Row] {
            let n_inv = (0..layout.bits(axis))
                .filter(|&bit| {
                    set.frames.contains_key(&Pattern::Gray {
                        axis,
                        bit,
                        inverse: true,
                    })
                })
                .count();
            if n_inv != 0 && n_inv != layout.bits(axis) as usize {
                return Err(Error::invalid(
                    &ctx,
                    "frames",
                    format!(
                        "{axis:?} code has {n_inv} of {} inverse frames: give all or none",
                        layout.bits(axis)
                    ),
                ));
            }
        }
        let any_row = (0..layout.row_bits()).any(|bit| {
            set.frames.contains_key(&Pattern::Gray {
                axis: CodeAxis::Row,
                bit,
                inverse: false,
            })
        });
        if any_row && !set.has_code(CodeAxis::Row) {
            return Err(Error::invalid(
                &ctx,
                "frames",
                "row code is incomplete: give every gray_row_KK or none",
            ));
        }
        if let Some(mask) = m.mask {
            let path = dir.join(&mask.file);
            let img = GrayImage::load(&path)?;
            if (img.width, img.height) != (layout.width, layout.height) {
                return Err(Error::invalid(
                    &ctx,
                    "mask.file",
                    format!(
                        "mask is {}x{}, projector is {}x{}",
                        img.width, img.height, layout.width, layout.height
                    ),
                ));
            }
            set.mask = Some(img);
        }
        tracing::debug!(dir = %dir.display(), frames = set.frames.len(), "capture set loaded");
        Ok(set)
    }

    /// Write the set to `dir`: one PNG per frame under its canonical name, then `capture.toml`
    /// last, so a directory without a manifest is recognisably incomplete.
    pub fn save(&self, dir: &Path) -> Result<()> {
        create_dir(dir)?;
        self.frames
            .par_iter()
            .try_for_each(|(p, img)| img.save_png(&dir.join(format!("{}.png", p.name()))))?;
        let mask = match &self.mask {
            Some(m) => {
                m.save_png(&dir.join("mask.png"))?;
                Some(MaskSection {
                    file: "mask.png".into(),
                })
            }
            None => None,
        };
        let manifest = ManifestFile {
            projector: ProjectorSection {
                width: self.layout.width,
                height: self.layout.height,
                column_step: self.layout.column_step,
                row_step: self.layout.row_step,
            },
            camera: CameraSection {
                width: self.width,
                height: self.height,
            },
            frames: BTreeMap::new(),
            mask,
            meta: self.meta.clone(),
        };
        write_toml(&dir.join(MANIFEST), &manifest)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tiny() -> CaptureSet {
        let layout = CodeLayout::new(8, 4);
        let mut set = CaptureSet::new(layout, 8, 4);
        for p in layout.sequence(true) {
            set.frames
                .insert(p, GrayImage::from_u8(8, 4, layout.render(p)));
        }
        set
    }

    #[test]
    fn save_load_round_trip() {
        let dir = tempfile::tempdir().expect("tempdir");
        let set = tiny();
        set.save(dir.path()).expect("save");
        let back = CaptureSet::load(dir.path()).expect("load");
        assert_eq!(back.frames, set.frames);
        assert!(back.has_inverses(CodeAxis::Column) && back.has_code(CodeAxis::Row));
    }

    #[test]
    fn frames_table_maps_foreign_names_and_errors_name_the_file() {
        let dir = tempfile::tempdir().expect("tempdir");
        let set = tiny();
        set.save(dir.path()).expect("save");
        std::fs::rename(
            dir.path().join("white.png"),
            dir.path().join("frame_00.png"),
        )
        .expect("rename");
        let manifest = dir.path().join(MANIFEST);
        let text = std::fs::read_to_string(&manifest).expect("read");
        std::fs::write(
            &manifest,
            format!("{text}\n[frames]\nwhite = \"frame_00.png\"\n"),
        )
        .expect("write");
        CaptureSet::load(dir.path()).expect("mapped white loads");
        std::fs::remove_file(dir.path().join("frame_00.png")).expect("rm");
        let msg = CaptureSet::load(dir.path())
            .expect_err("missing")
            .to_string();
        assert!(
            msg.contains("frame_00.png") && msg.contains("frames.white"),
            "{msg}"
        );
    }

    #[test]
    fn a_single_frame_loads_and_a_gray_set_missing_a_frame_does_not() {
        let dir = tempfile::tempdir().expect("tempdir");
        let layout = CodeLayout::new(8, 4);
        let mut set = CaptureSet::new(layout, 8, 4);
        set.frames
            .insert(Pattern::White, GrayImage::from_u8(8, 4, vec![200; 32]));
        set.save(dir.path()).expect("save");
        let back = CaptureSet::load(dir.path()).expect("a single frame loads");
        assert_eq!(back.frames, set.frames);
        let msg = crate::decode::decode(&back, &crate::decode::DecodeParams::default())
            .expect_err("no code to decode")
            .to_string();
        assert!(msg.contains("`black`"), "{msg}");
        // A Gray-code set is held to its required frames.
        let dir = tempfile::tempdir().expect("tempdir");
        tiny().save(dir.path()).expect("save");
        std::fs::remove_file(dir.path().join("black.png")).expect("rm");
        let msg = CaptureSet::load(dir.path())
            .expect_err("black missing")
            .to_string();
        assert!(msg.contains("black.png"), "{msg}");
    }

    #[test]
    fn size_mismatch_and_unknown_pattern_are_errors() {
        let dir = tempfile::tempdir().expect("tempdir");
        tiny().save(dir.path()).expect("save");
        GrayImage::from_u8(4, 4, vec![0; 16])
            .save_png(&dir.path().join("black.png"))
            .expect("save");
        let msg = CaptureSet::load(dir.path()).expect_err("size").to_string();
        assert!(msg.contains("black.png") && msg.contains("4x4"), "{msg}");
        let manifest = dir.path().join(MANIFEST);
        let text = std::fs::read_to_string(&manifest).expect("read");
        std::fs::write(
            &manifest,
            format!("{text}\n[frames]\nstripes = \"a.png\"\n"),
        )
        .expect("write");
        let msg = CaptureSet::load(dir.path())
            .expect_err("unknown")
            .to_string();
        assert!(msg.contains("frames.stripes"), "{msg}");
    }
}
