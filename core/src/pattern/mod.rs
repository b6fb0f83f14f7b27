//! Projector patterns (SPEC §3): names, the multi-shot order and rendering for any projector size.

mod gray;
mod mask;

pub use gray::{binary_to_gray, flipped_bit, gray_to_binary};
pub use mask::{ProjectionMask, MASK_SCALE};

use crate::{Error, Result};

/// Geometry of a Gray-coded projector: size and how many projector pixels one code cell spans.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CodeLayout {
    /// Projector width, pixels.
    pub width: u32,
    /// Projector height, pixels.
    pub height: u32,
    /// Projector pixels per column code cell (2 when the code was made for W/2 columns).
    pub column_step: u32,
    /// Projector pixels per row code cell.
    pub row_step: u32,
}

impl CodeLayout {
    /// A layout with one code cell per projector pixel.
    pub fn new(width: u32, height: u32) -> Self {
        CodeLayout {
            width,
            height,
            column_step: 1,
            row_step: 1,
        }
    }

    /// Number of column code cells, ceil(W / column_step).
    pub fn column_cells(&self) -> u32 {
        self.width.div_ceil(self.column_step.max(1))
    }

    /// Number of row code cells, ceil(H / row_step).
    pub fn row_cells(&self) -> u32 {
        self.height.div_ceil(self.row_step.max(1))
    }

    /// n_c = ceil(log2(column cells)): number of column bits.
    pub fn column_bits(&self) -> u32 {
        bits_for(self.column_cells())
    }

    /// n_r = ceil(log2(row cells)): number of row bits.
    pub fn row_bits(&self) -> u32 {
        bits_for(self.row_cells())
    }

    /// Number of bits of the code along `axis`.
    pub fn bits(&self, axis: CodeAxis) -> u32 {
        match axis {
            CodeAxis::Column => self.column_bits(),
            CodeAxis::Row => self.row_bits(),
        }
    }

    /// Number of cells of the code along `axis`.
    pub fn cells(&self, axis: CodeAxis) -> u32 {
        match axis {
            CodeAxis::Column => self.column_cells(),
            CodeAxis::Row => self.row_cells(),
        }
    }

    /// Projector pixels per cell along `axis`.
    pub fn step(&self, axis: CodeAxis) -> u32 {
        match axis {
            CodeAxis::Column => self.column_step.max(1),
            CodeAxis::Row => self.row_step.max(1),
        }
    }

    /// The full multi-shot sequence of SPEC §3: white, black, columns (each with inverse), rows
    /// (each with inverse).
    pub fn sequence(&self, with_rows: bool) -> Vec<Pattern> {
        let mut seq = vec![Pattern::White, Pattern::Black];
        for axis in [CodeAxis::Column, CodeAxis::Row] {
            if axis == CodeAxis::Row && !with_rows {
                continue;
            }
            for bit in 0..self.bits(axis) {
                seq.push(Pattern::Gray {
                    axis,
                    bit,
                    inverse: false,
                });
                seq.push(Pattern::Gray {
                    axis,
                    bit,
                    inverse: true,
                });
            }
        }
        seq
    }

    /// Render `pattern` as a row-major 8-bit image of the projector's size.
    pub fn render(&self, pattern: Pattern) -> Vec<u8> {
        let (w, h) = (self.width as usize, self.height as usize);
        let mut img = vec![0u8; w * h];
        match pattern {
            Pattern::White => img.fill(255),
            Pattern::Black => {}
            Pattern::Flat(level) => img.fill(level),
            Pattern::Gray { axis, bit, inverse } => {
                let n = self.bits(axis);
                let step = self.step(axis);
                let shift = n.saturating_sub(1).saturating_sub(bit);
                let on = |i: u32| -> u8 {
                    let lit = (binary_to_gray(i / step) >> shift) & 1 == 1;
                    if lit != inverse {
                        255
                    } else {
                        0
                    }
                };
                match axis {
                    CodeAxis::Column => {
                        let line: Vec<u8> = (0..w as u32).map(on).collect();
                        for row in img.chunks_exact_mut(w) {
                            row.copy_from_slice(&line);
                        }
                    }
                    CodeAxis::Row => {
                        for (y, row) in img.chunks_exact_mut(w).enumerate() {
                            row.fill(on(y as u32));
                        }
                    }
                }
            }
        }
        img
    }
}

fn bits_for(cells: u32) -> u32 {
    if cells <= 1 {
        0
    } else {
        32 - (cells - 1).leading_zeros()
    }
}

/// Which projector coordinate a Gray code encodes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum CodeAxis {
    /// Vertical stripes, encoding the projector column.
    Column,
    /// Horizontal stripes, encoding the projector row.
    Row,
}

/// One projector pattern (SPEC §3).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Pattern {
    /// All 255.
    White,
    /// All 0.
    Black,
    /// Bit `bit` (0 = most significant) of the Gray code along `axis`, or its inverse.
    Gray {
        /// Column or row code.
        axis: CodeAxis,
        /// Bit index, 0 = most significant.
        bit: u32,
        /// Whether this is the inverse pattern.
        inverse: bool,
    },
    /// A uniform level, for the photo response of the adaptive mask.
    Flat(u8),
}

impl Pattern {
    /// The canonical name: `white`, `gray_col_03_inv`, `flat_150`, ...
    pub fn name(&self) -> String {
        match self {
            Pattern::White => "white".into(),
            Pattern::Black => "black".into(),
            Pattern::Flat(l) => format!("flat_{l:03}"),
            Pattern::Gray { axis, bit, inverse } => format!(
                "gray_{}_{bit:02}{}",
                match axis {
                    CodeAxis::Column => "col",
                    CodeAxis::Row => "row",
                },
                if *inverse { "_inv" } else { "" }
            ),
        }
    }

    /// Parse a canonical pattern name.
    pub fn parse(name: &str) -> Result<Pattern> {
        let bad = || {
            Error::invalid(
                "pattern name",
                name,
                "unknown pattern (expected white, black, gray_col_KK[_inv], gray_row_KK[_inv] or flat_LLL)",
            )
        };
        match name {
            "white" => return Ok(Pattern::White),
            "black" => return Ok(Pattern::Black),
            _ => {}
        }
        if let Some(level) = name.strip_prefix("flat_") {
            return level.parse::<u8>().map(Pattern::Flat).map_err(|_| bad());
        }
        let (axis, rest) = if let Some(rest) = name.strip_prefix("gray_col_") {
            (CodeAxis::Column, rest)
        } else if let Some(rest) = name.strip_prefix("gray_row_") {
            (CodeAxis::Row, rest)
        } else {
            return Err(bad());
        };
        let (digits, inverse) = match rest.strip_suffix("_inv") {
            Some(d) => (d, true),
            None => (rest, false),
        };
        if digits.len() != 2 {
            return Err(bad());
        }
        let bit = digits.parse::<u32>().map_err(|_| bad())?;
        Ok(Pattern::Gray { axis, bit, inverse })
    }
}

impl std::fmt::Display for Pattern {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bit_counts_follow_spec() {
        let l = CodeLayout::new(1024, 768);
        assert_eq!((l.column_bits(), l.row_bits()), (10, 10));
        let l = CodeLayout {
            width: 1920,
            height: 1080,
            column_step: 2,
            row_step: 2,
        };
        assert_eq!((l.column_bits(), l.row_bits()), (10, 10));
        let l = CodeLayout::new(1280, 800);
        assert_eq!((l.column_bits(), l.row_bits()), (11, 10));
        assert_eq!(l.sequence(true).len(), 2 + 2 * 21);
    }

    #[test]
    fn names_round_trip() {
        for p in CodeLayout::new(1024, 768).sequence(true) {
            assert_eq!(Pattern::parse(&p.name()).expect("parse"), p);
        }
        assert_eq!(Pattern::parse("flat_050").expect("flat"), Pattern::Flat(50));
        assert!(Pattern::parse("gray_col_3").is_err());
        assert!(Pattern::parse("stripes").is_err());
    }

    #[test]
    fn rendered_columns_decode_to_their_index() {
        let l = CodeLayout {
            width: 37,
            height: 5,
            column_step: 2,
            row_step: 1,
        };
        let n = l.column_bits();
        let imgs: Vec<Vec<u8>> = (0..n)
            .map(|bit| {
                l.render(Pattern::Gray {
                    axis: CodeAxis::Column,
                    bit,
                    inverse: false,
                })
            })
            .collect();
        for x in 0..37u32 {
            let g = imgs
                .iter()
                .fold(0u32, |g, img| (g << 1) | u32::from(img[x as usize] == 255));
            assert_eq!(gray_to_binary(g), x / 2, "column {x}");
        }
        let inv = l.render(Pattern::Gray {
            axis: CodeAxis::Column,
            bit: 0,
            inverse: true,
        });
        assert!(inv.iter().zip(&imgs[0]).all(|(a, b)| a ^ b == 255));
    }
}
