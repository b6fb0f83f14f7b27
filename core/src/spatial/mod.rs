//! Spatial indexing of point sets: nearest-neighbour queries for registration and inspection,
//! coarse occupancy for culling.

mod kdtree;
mod occupancy;

pub use kdtree::KdTree;
pub use occupancy::Occupancy;
