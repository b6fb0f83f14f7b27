//! Rendered calibration sessions (SPEC §7): the scene's camera and projector looking at a
//! chessboard on a table, lifted to each height of `[calibration]`; one capture set per layer,
//! `session.toml`, and the true sensor for tests.

use std::path::{Path, PathBuf};

use super::scene::{CalibrationSection, Scene};
use super::shapes::{Object, Shape};
use super::texture::Texture;
use super::{sensor_file, Simulator};
use crate::calibrate::{BoardSection, LayerSection, SessionFile};
use crate::geometry::Vec3;
use crate::sensor::ReferenceSection;
use crate::{Error, Result};

/// Paths written by [`simulate_session`].
#[derive(Clone, Debug)]
pub struct SessionOutput {
    /// `session.toml`.
    pub session: PathBuf,
    /// The true sensor (`truth.toml`: camera, projector centre and full model, reference
    /// `layer0`).
    pub truth: PathBuf,
}

/// Validate `[calibration]` against the scene; returns (board material, table material).
fn check(scene: &Scene, c: &CalibrationSection) -> Result<(usize, usize)> {
    let ctx = "scene [calibration]";
    let find = |name: &str, field: &str| {
        scene
            .materials
            .iter()
            .position(|m| m.name == name)
            .ok_or_else(|| Error::invalid(ctx, field, format!("no [material.{name}] in the scene")))
    };
    let board = find(&c.board_material, "board_material")?;
    let table = find(&c.table_material, "table_material")?;
    if c.inner_corners.iter().any(|&n| n < 3) {
        return Err(Error::invalid(ctx, "inner_corners", "at least 3 each way"));
    }
    for (field, v) in [
        ("square", c.square),
        ("thickness", c.thickness),
        ("margin", c.margin),
    ] {
        if !(v.is_finite() && v > 0.0) {
            return Err(Error::invalid(ctx, field, format!("{v} must be positive")));
        }
    }
    if !(0.0..=1.0).contains(&c.dark) {
        return Err(Error::invalid(
            ctx,
            "dark",
            format!("{} is outside 0..1", c.dark),
        ));
    }
    if c.heights.len() < 3
        || c.heights[0] != 0.0
        || c.heights.iter().any(|h| !h.is_finite() || *h < 0.0)
    {
        return Err(Error::invalid(
            ctx,
            "heights",
            "at least three finite heights ≥ 0, the first 0",
        ));
    }
    if !scene.file.object.is_empty() {
        return Err(Error::invalid(
            ctx,
            "object",
            "a calibration session renders its own board and table; remove the [[object]]s",
        ));
    }
    Ok((board, table))
}

/// The scene of one layer: the table below z = −thickness and the board with its surface at
/// `height`.
fn layer_scene(
    scene: &Scene,
    c: &CalibrationSection,
    height: f64,
    board: usize,
    table: usize,
) -> Scene {
    let mut s = scene.clone();
    s.materials[board].texture = Texture::Chessboard {
        cols: c.inner_corners[0],
        rows: c.inner_corners[1],
        square: c.square,
        dark: c.dark,
    };
    let half = Vec3::new(
        (c.inner_corners[0] as f64 + 1.0) / 2.0 * c.square + c.margin,
        (c.inner_corners[1] as f64 + 1.0) / 2.0 * c.square + c.margin,
        c.thickness / 2.0,
    );
    s.objects = vec![
        Object::still(
            Shape::Box {
                center: Vec3::new(0.0, 0.0, -c.thickness - 50.0),
                half: Vec3::new(5000.0, 5000.0, 50.0),
            },
            table,
            None,
        ),
        Object::still(
            Shape::Box {
                center: Vec3::new(0.0, 0.0, height - c.thickness / 2.0),
                half,
            },
            board,
            None,
        ),
    ];
    s
}

/// Render the calibration session of `scene` (which must have `[calibration]`) into `out`.
pub fn simulate_session(
    scene: &Scene,
    out: &Path,
    progress: &(dyn Fn(&str, usize, usize) + Sync),
) -> Result<SessionOutput> {
    let c = scene.file.calibration.as_ref().ok_or_else(|| {
        Error::invalid(
            "scene",
            "calibration",
            "the scene has no [calibration] section",
        )
    })?;
    let (board, table) = check(scene, c)?;
    crate::io::write_dir_atomically(out, |dir| {
        crate::io::create_dir(dir)?;
        let mut layers = Vec::new();
        for (i, &h) in c.heights.iter().enumerate() {
            let name = format!("layer{i}");
            let sim = Simulator::new(layer_scene(scene, c, h, board, table));
            let layout = sim.layout();
            let label = format!("layer {i}");
            sim.capture(&layout, 10_000 * i as u64, &|k, n| progress(&label, k, n))
                .save(&dir.join(&name))?;
            layers.push(LayerSection {
                dir: name,
                height: h,
            });
        }
        SessionFile {
            board: BoardSection {
                inner_corners: c.inner_corners,
                square: c.square,
            },
            layer: layers,
        }
        .save(&dir.join("session.toml"))?;
        let mut truth = sensor_file(scene);
        let [hx, hy] = [
            (c.inner_corners[0] as f64 + 1.0) / 2.0 * c.square,
            (c.inner_corners[1] as f64 + 1.0) / 2.0 * c.square,
        ];
        truth.reference = Some(ReferenceSection {
            capture: "layer0".into(),
            extent: Some([-hx, hx, -hy, hy]),
        });
        truth.save(&dir.join("truth.toml"))
    })?;
    Ok(SessionOutput {
        session: out.join("session.toml"),
        truth: out.join("truth.toml"),
    })
}
