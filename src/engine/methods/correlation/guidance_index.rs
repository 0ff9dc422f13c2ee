//! Exact nearest neighbour in guidance space (Mertens et al. 2006, §5.1: the paper's
//! non-parametric synthesis searches the source for the best match with an ANN library). Here a
//! small k-d tree over the source samples' guidance values (up to 3-D) gives, per target sample,
//! the source sample whose guidance *value* is closest: the non-parametric synthesis uses it to
//! initialise the coarsest level "by the guidance alone" and as one extra candidate of every
//! search pass (the full neighbourhood distance then decides). Written by hand: the crate has no
//! k-d tree and the query is twenty lines.
//!
//! Build: median split on the axis of largest spread, leaves of at most [`LEAF`] points;
//! `O(n log n)`. Query: depth-first, nearer child first, pruned by the splitting plane. Ties go
//! to the lower sample index, so the result does not depend on the build order.

/// Points per leaf.
const LEAF: usize = 8;

enum Node {
    Leaf { start: u32, end: u32 },
    Split { axis: u8, at: f32, lo: u32, hi: u32 },
}

/// A k-d tree over 3-D points (unused guidance axes are 0).
pub struct GuidanceIndex {
    points: Vec<[f32; 3]>,
    /// Sample index of each point, in leaf order.
    order: Vec<u32>,
    nodes: Vec<Node>,
}

impl GuidanceIndex {
    /// Indexes `points[i]` for the `i` where `keep(i)`; `None` when no point is kept.
    pub fn build(points: &[[f32; 3]], keep: impl Fn(usize) -> bool) -> Option<Self> {
        let mut order: Vec<u32> = (0..points.len() as u32)
            .filter(|&i| keep(i as usize))
            .collect();
        if order.is_empty() {
            return None;
        }
        let mut nodes = Vec::new();
        let n = order.len();
        split(points, &mut order, 0, n, &mut nodes);
        Some(Self {
            points: points.to_vec(),
            order,
            nodes,
        })
    }

    /// The indexed sample nearest to `q` (squared Euclidean distance; lowest index on ties).
    pub fn nearest(&self, q: [f32; 3]) -> u32 {
        let mut best = (f32::INFINITY, u32::MAX);
        self.visit(0, q, &mut best);
        best.1
    }

    fn visit(&self, node: usize, q: [f32; 3], best: &mut (f32, u32)) {
        match self.nodes[node] {
            Node::Leaf { start, end } => {
                for &i in &self.order[start as usize..end as usize] {
                    let p = self.points[i as usize];
                    let d = (0..3).map(|k| (p[k] - q[k]).powi(2)).sum::<f32>();
                    if d < best.0 || (d == best.0 && i < best.1) {
                        *best = (d, i);
                    }
                }
            }
            Node::Split { axis, at, lo, hi } => {
                let delta = q[axis as usize] - at;
                let (near, far) = if delta < 0.0 { (lo, hi) } else { (hi, lo) };
                self.visit(near as usize, q, best);
                if delta * delta <= best.0 {
                    self.visit(far as usize, q, best);
                }
            }
        }
    }
}

/// Builds the subtree of `order[start..end]`; returns its node index.
fn split(
    points: &[[f32; 3]],
    order: &mut [u32],
    start: usize,
    end: usize,
    nodes: &mut Vec<Node>,
) -> u32 {
    let id = nodes.len() as u32;
    if end - start <= LEAF {
        nodes.push(Node::Leaf {
            start: start as u32,
            end: end as u32,
        });
        return id;
    }
    let slice = &mut order[start..end];
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for &i in slice.iter() {
        for k in 0..3 {
            lo[k] = lo[k].min(points[i as usize][k]);
            hi[k] = hi[k].max(points[i as usize][k]);
        }
    }
    let axis = (0..3)
        .max_by(|&a, &b| (hi[a] - lo[a]).total_cmp(&(hi[b] - lo[b])))
        .unwrap_or(0);
    let mid = slice.len() / 2;
    slice.select_nth_unstable_by(mid, |&a, &b| {
        points[a as usize][axis]
            .total_cmp(&points[b as usize][axis])
            .then(a.cmp(&b))
    });
    let at = points[slice[mid] as usize][axis];
    nodes.push(Node::Leaf { start: 0, end: 0 });
    let lo_id = split(points, order, start, start + mid, nodes);
    let hi_id = split(points, order, start + mid, end, nodes);
    nodes[id as usize] = Node::Split {
        axis: axis as u8,
        at,
        lo: lo_id,
        hi: hi_id,
    };
    id
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::rng::SplitMix64;

    #[test]
    fn nearest_equals_brute_force() {
        let mut rng = SplitMix64::new(7);
        let pts: Vec<[f32; 3]> = (0..2000)
            .map(|_| [rng.unit_f32(), rng.unit_f32(), rng.unit_f32() * 0.1])
            .collect();
        let index = GuidanceIndex::build(&pts, |i| i % 3 != 0).unwrap();
        for _ in 0..300 {
            let q = [rng.unit_f32(), rng.unit_f32(), rng.unit_f32()];
            let d = |i: usize| (0..3).map(|k| (pts[i][k] - q[k]).powi(2)).sum::<f32>();
            let brute = (0..pts.len())
                .filter(|i| i % 3 != 0)
                .min_by(|&a, &b| d(a).total_cmp(&d(b)).then(a.cmp(&b)))
                .unwrap();
            assert_eq!(index.nearest(q) as usize, brute);
        }
        assert!(GuidanceIndex::build(&pts, |_| false).is_none());
    }
}
