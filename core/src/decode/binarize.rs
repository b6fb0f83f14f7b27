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
            // Zipped iterators (no bounds checks) and the threshold test hoisted out of the
            // pixel loop keep these loops vectorisable.
            for (j, p) in pat.iter().enumerate() {
                let p = &p[base..base + w];
                match inv {
                    Some(inv) => {
                        let q = &inv[j][base..base + w];
                        for (r, (&a, &b)) in row.iter_mut().zip(p.iter().zip(q)) {
                            *r = (*r << 1) | i32::from(a.to_i32() > b.to_i32());
                        }
                        if th.bit > 0 {
                            for (u, (&a, &b)) in undecided.iter_mut().zip(p.iter().zip(q)) {
                                *u |= (a.to_i32() - b.to_i32()).abs() <= th.bit;
                            }
                        }
                    }
                    None => {
                        // 2P − (W + K): the pattern against the mid level, at the scale of P − I.
                        for (r, ((&a, &wv), &kv)) in row.iter_mut().zip(p.iter().zip(wh).zip(bl)) {
                            *r = (*r << 1) | i32::from(2 * a.to_i32() > wv.to_i32() + kv.to_i32());
                        }
                        if th.bit > 0 {
                            for (u, ((&a, &wv), &kv)) in
                                undecided.iter_mut().zip(p.iter().zip(wh).zip(bl))
                            {
                                *u |= (2 * a.to_i32() - wv.to_i32() - kv.to_i32()).abs()
                                    <= 2 * th.bit;
                            }
                        }
                    }
                }
            }
            for (r, ((&wv, &kv), &u)) in row.iter_mut().zip(wh.iter().zip(bl).zip(undecided.iter()))
            {
                let code = gray_to_binary(*r as u32);
                *r = if wv.to_i32() - kv.to_i32() > th.contrast && !u && code < cells {
                    code as i32
                } else {
                    -1
                };
            }
        },
    );
    codes
}
