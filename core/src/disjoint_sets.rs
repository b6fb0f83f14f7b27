//! Disjoint sets (union-find): the connected groups of a graph given as links, for the
//! omnidirectional decoder's ring arcs, the inspection's deviation regions and the single-shot
//! decoder's islands of agreeing placements.

/// A partition of `0..n` into sets, merged link by link; each set's root is its least member.
pub(crate) struct DisjointSets {
    parent: Vec<usize>,
}

impl DisjointSets {
    /// `n` sets of one member each.
    pub(crate) fn new(n: usize) -> DisjointSets {
        DisjointSets {
            parent: (0..n).collect(),
        }
    }

    /// The root of `x`'s set (path halving).
    pub(crate) fn find(&mut self, mut x: usize) -> usize {
        while self.parent[x] != x {
            self.parent[x] = self.parent[self.parent[x]];
            x = self.parent[x];
        }
        x
    }

    /// Merge the sets of `a` and `b`.
    pub(crate) fn union(&mut self, a: usize, b: usize) {
        let (ra, rb) = (self.find(a), self.find(b));
        if ra != rb {
            self.parent[ra.max(rb)] = ra.min(rb);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Links 0–2, 2–4 and 3–1 leave {0, 2, 4}, {1, 3} and {5}, each rooted at its least member.
    #[test]
    fn links_merge_sets_rooted_at_their_least_member() {
        let mut s = DisjointSets::new(6);
        for (a, b) in [(2, 4), (0, 2), (3, 1)] {
            s.union(a, b);
        }
        let roots: Vec<usize> = (0..6).map(|x| s.find(x)).collect();
        assert_eq!(roots, vec![0, 1, 0, 1, 0, 5]);
    }
}
