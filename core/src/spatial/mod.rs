//! Spatial indexing of point sets: nearest-neighbour queries for registration and inspection,
//! coarse occupancy for culling.

mod hash;
mod kdtree;
mod occupancy;

pub use hash::{IntHasher, IntMap, IntSet};
pub use kdtree::KdTree;
pub use occupancy::Occupancy;
