//! Pass 1 of decoding: dual-projection binarization, Gray → binary, validity.

use rayon::prelude::*;

use crate::image::Sample;
use crate::pattern::gray_to_binary;

/// Integer thresholds in the capture's own grey levels.
#[derive(Clone, Copy, Debug)]
pub(super) struct Thresholds {
    pub contrast: i32,
    pub bit: i32,
}

/// Integer code cell per pixel (row-major), −1 where invalid: contrast below threshold, a bit
/// undecidable, or a code beyond the projector's cells.
#[allow(clippy::too_many_arguments)] // the planes of one axis, passed flat for the hot loop
pub(super) fn codes<T: Sample>(
    w: usize,
    h: usize,
    white: &[T],
    black: &[T],
    pat: &[&[T]],
    inv: Option<&[&[T]]>,
    cells: u32,
    th: Thresholds,
) -> Vec<i32> {
    let mut codes = vec![0i32; w * h];
    codes.par_chunks_mut(w).enumerate().for_each_init(
        || vec![false; w],
        |undecided, (y, row)| {
            let base = y * w;
            let wh = &white[base..base + w];
            let bl = &black[base..base + w];
            row.fill(0);
            undecided.fill(false);
            for (j, p) in pat.iter().enumerate() {
                let p = &p[base..base + w];
                match inv {
                    Some(inv) => {
                        let q = &inv[j][base..base + w];
                        for x in 0..w {
                            let s = p[x].to_i32() - q[x].to_i32();
                            row[x] = (row[x] << 1) | i32::from(s > 0);
                            undecided[x] |= th.bit > 0 && s.abs() <= th.bit;
                        }
                    }
                    None => {
                        for x in 0..w {
                            // 2P − (W + K): the pattern against the mid level, at the same scale
                            // as P − I.
                            let s = 2 * p[x].to_i32() - wh[x].to_i32() - bl[x].to_i32();
                            row[x] = (row[x] << 1) | i32::from(s > 0);
                            undecided[x] |= th.bit > 0 && s.abs() <= 2 * th.bit;
                        }
                    }
                }
            }
            for x in 0..w {
                let contrast = wh[x].to_i32() - bl[x].to_i32();
                let code = gray_to_binary(row[x] as u32);
                row[x] = if contrast > th.contrast && !undecided[x] && code < cells {
                    code as i32
                } else {
                    -1
                };
            }
        },
    );
    codes
}
