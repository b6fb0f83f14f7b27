//! The projector trait and what it shows.

use std::sync::Arc;

use ris_core::pattern::{CodeLayout, Pattern, ProjectionMask};

use crate::Result;

/// One image the projector shows: a pattern, optionally multiplied by a projection mask.
#[derive(Clone, Debug, PartialEq)]
pub struct Slide {
    /// The pattern.
    pub pattern: Pattern,
    /// The mask it is multiplied by (adaptive projection).
    pub mask: Option<Arc<ProjectionMask>>,
}

impl Slide {
    /// An unmasked pattern.
    pub fn plain(pattern: Pattern) -> Slide {
        Slide {
            pattern,
            mask: None,
        }
    }

    /// A picture (8-bit, the projector's size, row-major) shown as it is: white under the
    /// picture as its mask.
    pub fn picture(width: u32, height: u32, pixels: &[u8]) -> Slide {
        Slide {
            pattern: Pattern::White,
            mask: Some(Arc::new(ProjectionMask::picture(width, height, pixels))),
        }
    }

    /// The 8-bit image of this slide on a projector with `layout`.
    pub fn render(&self, layout: &CodeLayout) -> Vec<u8> {
        let mut px = layout.render(self.pattern);
        if let Some(m) = &self.mask {
            m.apply(&mut px);
        }
        px
    }

    /// Name for logs and capture sets (`gray_col_03`, `gray_col_03+mask`).
    pub fn name(&self) -> String {
        match self.mask {
            None => self.pattern.name(),
            Some(_) => format!("{}+mask", self.pattern.name()),
        }
    }
}

/// What a projector is.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ProjectorInfo {
    /// Stable id (monitor name, device).
    pub id: String,
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
}

/// Proof of presentation returned by [`Projector::show`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shown {
    /// The slide index that was requested.
    pub slot: usize,
    /// Presentation counter, incremented by every `show`.
    pub sequence: u64,
    /// When the image was on screen, [`crate::clock::now_ns`].
    pub presented_ns: u64,
}

/// A projector: slides are uploaded before a scan, then shown one by one.
pub trait Projector: Send {
    /// Identity and size.
    fn info(&self) -> &ProjectorInfo;
    /// Upload every slide of a scan (replacing earlier ones); slides are indexed in this order.
    fn load(&mut self, slides: &[Slide]) -> Result<()>;
    /// Show slide `slot` and return once it is on screen.
    fn show(&mut self, slot: usize) -> Result<Shown>;
}
