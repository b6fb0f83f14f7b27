//! The 6×6 normal equations of a linearised point-to-plane step (rotation ω, then
//! translation t), accumulated in parallel in a fixed order: the same input gives the same
//! pose bit for bit whatever the thread scheduling, so a replayed scan is inspected exactly as
//! it was the first time.

use nalgebra::{Matrix6, Vector6};
use rayon::prelude::*;

/// Σ w·a·aᵀ, Σ w·a·b and the rows that contributed.
#[derive(Clone, Copy, Debug)]
pub struct NormalEquations {
    /// Σ w·a·aᵀ.
    pub ata: Matrix6<f64>,
    /// Σ w·a·b.
    pub atb: Vector6<f64>,
    /// Rows accumulated.
    pub count: usize,
}

impl NormalEquations {
    fn zero() -> NormalEquations {
        NormalEquations {
            ata: Matrix6::zeros(),
            atb: Vector6::zeros(),
            count: 0,
        }
    }

    fn add(mut self, other: NormalEquations) -> NormalEquations {
        self.ata += other.ata;
        self.atb += other.atb;
        self.count += other.count;
        self
    }
}

/// Rows per chunk: the unit of parallel work, summed in chunk order.
const CHUNK: usize = 2048;

/// Accumulate `row(item)` = (a, b, w) over `items` (`None`: the item gives no row).
pub fn accumulate<T: Sync>(
    items: &[T],
    row: impl Fn(&T) -> Option<(Vector6<f64>, f64, f64)> + Sync,
) -> NormalEquations {
    let parts: Vec<NormalEquations> = items
        .par_chunks(CHUNK)
        .map(|chunk| {
            let mut e = NormalEquations::zero();
            for item in chunk {
                if let Some((a, b, w)) = row(item) {
                    e.ata += a * a.transpose() * w;
                    e.atb += a * (b * w);
                    e.count += 1;
                }
            }
            e
        })
        .collect();
    parts
        .into_iter()
        .fold(NormalEquations::zero(), NormalEquations::add)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_sum_does_not_depend_on_the_thread_count() {
        let items: Vec<f64> = (0..100_000).map(|i| (f64::from(i) * 0.37).sin()).collect();
        let row = |x: &f64| {
            Some((
                Vector6::new(*x, x * x, 1.0, x.cos(), 0.5, -x),
                x * 3.0,
                1.0 + x.abs(),
            ))
        };
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .expect("pool")
            .install(|| accumulate(&items, row));
        let many = rayon::ThreadPoolBuilder::new()
            .num_threads(7)
            .build()
            .expect("pool")
            .install(|| accumulate(&items, row));
        assert_eq!(one.ata, many.ata);
        assert_eq!(one.atb, many.atb);
        assert_eq!(one.count, 100_000);
    }
}
