//! Spatial indexing of point sets: nearest-neighbour queries for registration and inspection.

mod kdtree;

pub use kdtree::KdTree;
