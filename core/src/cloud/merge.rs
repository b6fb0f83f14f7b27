//! Merging sensor clouds into the cell frame, de-duplicating where sensors overlap.

use rayon::prelude::*;

use super::PointCloud;
use crate::geometry::Matrix4;
use crate::spatial::{KdTree, Occupancy};

/// How many points each input contributed and how many overlap duplicates were dropped.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct MergeStats {
    /// Points kept per input cloud.
    pub kept: Vec<usize>,
    /// Points dropped per input cloud as duplicates of a more confident point.
    pub dropped: Vec<usize>,
}

/// Transform each cloud by its sensor → cell matrix and merge them. A point closer than
/// `radius` (mm) to a point of another sensor is a duplicate: of the two, the more confident
/// one stays. Points of one sensor never de-duplicate each other (one per camera pixel).
pub fn merge(clouds: &[(PointCloud, Matrix4<f64>)], radius: f64) -> (PointCloud, MergeStats) {
    let mut merger = Merger::new(radius);
    for (cloud, m) in clouds {
        merger.add(cloud, m);
    }
    merger.finish()
}

/// An incremental [`merge`]: sensor clouds are added as they arrive (a scan merges one group
/// while the next acquires), in the order of `add`.
#[derive(Debug)]
pub struct Merger {
    merged: PointCloud,
    owner: Vec<usize>,
    stats: MergeStats,
    radius: f64,
    /// Whether any input carried calibrated-volume flags.
    flagged: bool,
}

impl Merger {
    /// An empty merge with duplicate radius `radius` (mm).
    pub fn new(radius: f64) -> Merger {
        Merger {
            merged: PointCloud::default(),
            owner: Vec::new(),
            stats: MergeStats::default(),
            radius,
            flagged: false,
        }
    }

    /// Add the next sensor's cloud with its sensor → cell matrix.
    pub fn add(&mut self, cloud: &PointCloud, m: &Matrix4<f64>) {
        let s = self.stats.kept.len();
        self.stats.kept.push(0);
        self.stats.dropped.push(0);
        let radius = self.radius;
        let r2 = radius * radius;
        let merged = &mut self.merged;
        let owner = &mut self.owner;
        let stats = &mut self.stats;
        let pts: Vec<[f64; 3]> = cloud
            .points
            .par_iter()
            .map(|p| {
                let v = m * nalgebra::Vector4::new(
                    f64::from(p[0]),
                    f64::from(p[1]),
                    f64::from(p[2]),
                    1.0,
                );
                [v.x, v.y, v.z]
            })
            .collect();
        // Existing points from earlier sensors near each new point. Only merged points in the
        // coarse cells around this sensor's points can be within `radius`: the tree holds those.
        let around = Occupancy::around(&pts, (radius * 16.0).max(4.0), 1 << 24);
        let (candidates, existing): (Vec<usize>, Vec<[f64; 3]>) = merged
            .points
            .par_iter()
            .enumerate()
            .map(|(j, p)| (j, p.map(f64::from)))
            .filter(|(_, p)| around.contains(p))
            .unzip();
        let tree = KdTree::new(&existing);
        // Most new points are nowhere near an existing one: a finer occupancy of the
        // candidates spares them the tree search.
        let near_existing = Occupancy::around(&existing, (radius * 4.0).max(1.0), 1 << 24);
        let near: Vec<Option<usize>> = pts
            .par_iter()
            .map(|p| {
                if near_existing.contains(p) {
                    tree.nearest_within(p, r2).map(|(j, _)| candidates[j])
                } else {
                    None
                }
            })
            .collect();
        let outside = |i: usize| cloud.outside.get(i).copied().unwrap_or(false);
        self.flagged |= !cloud.outside.is_empty();
        let mut replaced = vec![false; merged.len()];
        for (i, p) in pts.iter().enumerate() {
            let conf = cloud.confidence.get(i).copied().unwrap_or(1.0);
            let point = [p[0] as f32, p[1] as f32, p[2] as f32];
            match near[i] {
                Some(j) if !replaced[j] => {
                    if conf > merged.confidence[j] {
                        stats.dropped[owner[j]] += 1;
                        stats.kept[owner[j]] -= 1;
                        merged.points[j] = point;
                        merged.confidence[j] = conf;
                        merged.outside[j] = outside(i);
                        owner[j] = s;
                        replaced[j] = true;
                        stats.kept[s] += 1;
                    } else {
                        stats.dropped[s] += 1;
                    }
                }
                Some(_) => stats.dropped[s] += 1,
                None => {
                    merged.points.push(point);
                    merged.confidence.push(conf);
                    merged.outside.push(outside(i));
                    owner.push(s);
                    stats.kept[s] += 1;
                }
            }
        }
    }

    /// The merged cloud and the per-input figures.
    pub fn finish(mut self) -> (PointCloud, MergeStats) {
        if !self.flagged {
            self.merged.outside.clear();
        }
        (self.merged, self.stats)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn overlap_is_deduplicated_by_confidence_in_the_cell_frame() {
        // Two sensors see x ∈ [0, 60) and [40, 100) of a plane z = 5 (cell frame), 1 mm grid.
        let grid = |x0: i32, x1: i32, conf: f32| {
            let mut c = PointCloud::default();
            for x in x0..x1 {
                for y in 0..20 {
                    c.points.push([x as f32, y as f32, 5.0]);
                    c.confidence.push(conf);
                }
            }
            c
        };
        // Sensor 2's frame is shifted by −10 mm in x relative to the cell.
        let mut shift = Matrix4::identity();
        shift[(0, 3)] = 10.0;
        let a = grid(0, 60, 0.5);
        let b = grid(30, 90, 0.8); // cell x = 40..100
        let (m, stats) = merge(&[(a, Matrix4::identity()), (b, shift)], 0.3);
        assert_eq!(m.len(), 100 * 20, "every cell position once");
        assert_eq!(
            stats.dropped,
            vec![20 * 20, 0],
            "sensor 2 is more confident in the overlap"
        );
        assert!(m
            .points
            .iter()
            .all(|p| p[2] == 5.0 && p[0] >= 0.0 && p[0] < 100.0));
        let overlap_conf: Vec<f32> = m
            .points
            .iter()
            .zip(&m.confidence)
            .filter(|(p, _)| p[0] >= 40.0 && p[0] < 60.0)
            .map(|(_, c)| *c)
            .collect();
        assert!(overlap_conf.iter().all(|c| *c == 0.8));
    }
}
