//! Sparse assembly shared by the joint fairing (§3.2) and the registrations (§3.3): the cotan
//! Laplacian as rows, the pattern of `Lᵀ A⁻¹ L` (each vertex's one-ring as a clique, i.e. the
//! two-ring) plus the cliques of the reference points, and value accumulation into that pattern.
//!
//! Both energies are quadratic with a fixed pattern, so the pattern and its symbolic Cholesky
//! analysis are built once per stage and only the values change between iterations (the paper
//! updates the Voronoi areas and the stiffness, never the connectivity).
//!
//! For speed (techniques of ours; the values are the same bit for bit): the two-ring pattern is
//! collected with a stamp per vertex instead of pushing every clique pair and sorting the
//! duplicates away, and [`BilaplacianSlots`] / [`face_slots`] record once where each term lands
//! in the value vector, so every re-assembly is a scatter without searches.

use std::sync::Arc;

use rayon::prelude::*;

use crate::engine::geometry::laplacian::{cotan_laplacian, mass_matrix, LaplacianParams, MassKind};
use crate::engine::linalg::{SparsityPattern, SymmetricMatrix};
use crate::engine::mesh::Surface;

use super::refs::RefRow;
use super::MethodError;

/// Bytes per `T log₂ T` of the method's working set for `T` instanced input triangles (source and
/// target together): the two-ring patterns, the sparse Cholesky factors (fill grows a little
/// faster than the pattern), the BVHs and per-vertex arrays of both meshes. Measured with
/// `retex transfer --method elastiface` on icospheres fitted to a stretched copy (peak resident
/// set less 400 bytes per triangle for the loaded inputs and surfaces): 41k triangles 85 MB, 164k
/// 361 MB, 655k 1.72 GB, i.e. 115-136 bytes per `T log₂ T`; 160 leaves a margin.
pub const SOLVER_BYTES_PER_T_LOG_T: u64 = 160;

/// The estimated working set of the fairing and registration solves for `triangles` instanced
/// input triangles ([`SOLVER_BYTES_PER_T_LOG_T`]).
pub fn solver_working_set_bytes(triangles: u64) -> u64 {
    let log = u64::from(64 - triangles.max(2).leading_zeros());
    triangles
        .saturating_mul(log)
        .saturating_mul(SOLVER_BYTES_PER_T_LOG_T)
}

/// Rows of the cotan Laplacian `L` (symmetric, negative semi-definite; see
/// [`crate::engine::geometry::laplacian`]), diagonal included, CSR.
#[derive(Clone, Debug)]
pub struct LapRows {
    offsets: Vec<usize>,
    cols: Vec<u32>,
    vals: Vec<f64>,
}

impl LapRows {
    /// The cotan Laplacian of `surface`. Cotangents are invariant under similarity transforms, so
    /// the Laplacian of the world-space surface is that of the aligned, normalised one.
    pub fn of(surface: &Surface) -> Result<Self, MethodError> {
        let lap = cotan_laplacian(surface, &LaplacianParams::default())
            .map_err(|e| MethodError::Internal(format!("cotan laplacian: {e}")))?;
        let pattern = lap.stiffness.pattern();
        let values = lap.stiffness.values();
        let n = pattern.dim();
        let mut offsets = Vec::with_capacity(n + 1);
        offsets.push(0);
        let mut cols = Vec::with_capacity(values.len());
        for j in 0..n {
            cols.extend(pattern.column(j).iter().map(|&i| i as u32));
            offsets.push(cols.len());
        }
        Ok(Self {
            offsets,
            cols,
            vals: values.to_vec(),
        })
    }

    /// Number of rows.
    pub fn len(&self) -> usize {
        self.offsets.len() - 1
    }

    /// Whether there are no rows.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Row `k`: column indices and values.
    pub fn row(&self, k: usize) -> (&[u32], &[f64]) {
        let r = self.offsets[k]..self.offsets[k + 1];
        (&self.cols[r.clone()], &self.vals[r])
    }

    /// `L x` for one coordinate.
    pub fn mul(&self, x: &[f64]) -> Vec<f64> {
        (0..self.len())
            .map(|k| {
                let (c, v) = self.row(k);
                c.iter().zip(v).map(|(&j, w)| w * x[j as usize]).sum()
            })
            .collect()
    }

    /// `Lᵀ diag(d) L x = L (d ∘ L x)` for one coordinate (`L` is symmetric).
    pub fn bilaplacian_mul(&self, d: &[f64], x: &[f64]) -> Vec<f64> {
        let y: Vec<f64> = self.mul(x).iter().zip(d).map(|(a, b)| a * b).collect();
        self.mul(&y)
    }
}

/// Mixed Voronoi areas (Meyer et al. 2003) of `positions` with `faces`, each at least
/// `1e-9 ×` the mean (a vertex of zero area would make `A⁻¹` infinite).
pub fn voronoi_areas(positions: &[[f64; 3]], faces: &[[u32; 3]]) -> Result<Vec<f64>, MethodError> {
    let surface = Surface::from_triangles(
        positions.iter().map(|p| p.map(|c| c as f32)).collect(),
        faces.to_vec(),
    );
    let mut a = mass_matrix(&surface, MassKind::MixedVoronoi)
        .map_err(|e| MethodError::Internal(format!("voronoi areas: {e}")))?;
    let mean = a.iter().sum::<f64>() / a.len().max(1) as f64;
    let floor = (mean * 1e-9).max(f64::MIN_POSITIVE);
    for x in &mut a {
        *x = x.max(floor);
    }
    Ok(a)
}

/// Collects the nonzero structure of a symmetric system.
pub struct PatternBuilder {
    cols: Vec<Vec<usize>>,
    /// Whether [`Self::clique_row`] added entries on one side only, so that the build must
    /// symmetrise them (cliques are symmetric by construction).
    one_sided: bool,
}

impl PatternBuilder {
    /// An `n × n` pattern with only the diagonal.
    pub fn new(n: usize) -> Self {
        Self {
            cols: vec![Vec::new(); n],
            one_sided: false,
        }
    }

    /// Every pair of `vertices` (a dense block).
    pub fn clique(&mut self, vertices: &[usize]) {
        for &a in vertices {
            for &b in vertices {
                if a != b {
                    self.cols[a].push(b);
                }
            }
        }
    }

    /// Entries `(i, j)` for every `j` in `cols` (the build symmetrises them).
    pub fn clique_row(&mut self, i: usize, cols: &[usize]) {
        self.one_sided = true;
        self.cols[i].extend(cols.iter().filter(|&&j| j != i));
    }

    /// The pattern of `Lᵀ A⁻¹ L` for a Laplacian whose unknowns start at `offset`: the union of
    /// the cliques of `L`'s rows. As `L`'s pattern is symmetric with its diagonal, vertex `v`'s
    /// column is the union of the rows `k` in row `v` (its two-ring), collected once per entry
    /// with a stamp instead of pushing every clique pair.
    pub fn bilaplacian(&mut self, lap: &LapRows, offset: usize) {
        let mut stamp = vec![usize::MAX; lap.len()];
        for v in 0..lap.len() {
            let col = &mut self.cols[v + offset];
            for &k in lap.row(v).0 {
                for &j in lap.row(k as usize).0 {
                    let j = j as usize;
                    if j != v && stamp[j] != v {
                        stamp[j] = v;
                        col.push(j + offset);
                    }
                }
            }
        }
    }

    /// The pattern of `rowᵀ row` for reference rows (each with its own offset).
    pub fn reference(&mut self, rows: &[(RefRow, usize)]) {
        let mut buf = Vec::new();
        for (r, offset) in rows {
            buf.extend(r.idx.iter().map(|&i| i as usize + offset));
        }
        buf.sort_unstable();
        buf.dedup();
        self.clique(&buf);
    }

    /// The finished pattern: columns sorted and deduplicated in parallel, symmetrised only when
    /// [`Self::clique_row`] was used.
    pub fn build(self) -> Result<Arc<SparsityPattern>, MethodError> {
        let pattern = if self.one_sided {
            SparsityPattern::from_columns(&self.cols)
        } else {
            SparsityPattern::from_symmetric_columns(self.cols)
        };
        pattern
            .map(Arc::new)
            .map_err(|e| MethodError::Internal(format!("pattern: {e}")))
    }
}

/// Where each term of `Lᵀ diag(d) L` lands in a pattern's value vector, for a Laplacian whose
/// unknowns start at `offset`: one slot per (row `k`, entry `a`, entry `b`) of `L`, in the
/// order [`Values::add_bilaplacian`] adds them. Built once per stage, so that every
/// re-assembly (new areas or stiffness) is a plain scatter instead of a search per term.
pub struct BilaplacianSlots {
    slots: Vec<u32>,
    rows: usize,
}

impl BilaplacianSlots {
    /// The slots of `lap` (offset `offset`) in `pattern`.
    ///
    /// # Errors
    /// [`MethodError::Internal`] if a term is outside the pattern or the pattern has `≥ 2³²`
    /// entries.
    pub fn new(
        pattern: &SparsityPattern,
        lap: &LapRows,
        offset: usize,
    ) -> Result<Self, MethodError> {
        if pattern.nnz() >= u32::MAX as usize - 1 {
            return Err(MethodError::Internal("pattern too large".into()));
        }
        let slots: Vec<u32> = (0..lap.len())
            .into_par_iter()
            .flat_map_iter(|k| {
                let c = lap.row(k).0;
                c.iter().flat_map(move |&a| {
                    c.iter().map(move |&b| {
                        pattern
                            .find(a as usize + offset, b as usize + offset)
                            .map_or(u32::MAX, |at| at as u32)
                    })
                })
            })
            .collect();
        if slots.contains(&u32::MAX) {
            return Err(MethodError::Internal(
                "a Laplacian term is not in the pattern".into(),
            ));
        }
        Ok(Self {
            slots,
            rows: lap.len(),
        })
    }
}

/// The 3 × 3 value positions of every face's corners in `pattern` (row-major over the corner
/// pairs), for [`Values::add_face_outer`].
///
/// # Errors
/// [`MethodError::Internal`] if a corner pair is outside the pattern.
pub fn face_slots(
    pattern: &SparsityPattern,
    faces: &[[u32; 3]],
) -> Result<Vec<[u32; 9]>, MethodError> {
    faces
        .iter()
        .map(|f| {
            let mut s = [0u32; 9];
            for a in 0..3 {
                for b in 0..3 {
                    let at = pattern
                        .find(f[a] as usize, f[b] as usize)
                        .ok_or_else(|| MethodError::Internal("face outside the pattern".into()))?;
                    s[3 * a + b] = at as u32;
                }
            }
            Ok(s)
        })
        .collect()
}

/// Values of a symmetric matrix with a fixed pattern, both triangles filled.
pub struct Values {
    pattern: Arc<SparsityPattern>,
    vals: Vec<f64>,
}

impl Values {
    /// All zero.
    pub fn zeros(pattern: &Arc<SparsityPattern>) -> Self {
        Self {
            pattern: pattern.clone(),
            vals: vec![0.0; pattern.nnz()],
        }
    }

    /// Adds `v` at `(i, j)` (only that entry; callers add symmetric pairs themselves).
    ///
    /// # Panics
    /// If `(i, j)` is not in the pattern (an assembly bug).
    pub fn add(&mut self, i: usize, j: usize, v: f64) {
        let at = self
            .pattern
            .find(i, j)
            .unwrap_or_else(|| panic!("({i}, {j}) is not in the pattern"));
        self.vals[at] += v;
    }

    /// Adds `w · rowᵀ row` for a sparse row given as (index, coefficient) pairs.
    pub fn add_outer(&mut self, row: &[(usize, f64)], w: f64) {
        for &(i, a) in row {
            for &(j, b) in row {
                self.add(i, j, w * a * b);
            }
        }
    }

    /// Adds `w · Lᵀ diag(1/A) L` for a Laplacian whose unknowns start at `offset`.
    pub fn add_bilaplacian(&mut self, lap: &LapRows, areas: &[f64], offset: usize, w: f64) {
        let mut row = Vec::new();
        for (k, area) in areas.iter().enumerate().take(lap.len()) {
            let (c, v) = lap.row(k);
            row.clear();
            row.extend(c.iter().zip(v).map(|(&j, &x)| (j as usize + offset, x)));
            self.add_outer(&row, w / area);
        }
    }

    /// [`Self::add_bilaplacian`] through precomputed slots (`slots` built for `lap` on this
    /// pattern): the same terms added in the same order, so the same values bit for bit.
    ///
    /// # Panics
    /// If `slots` were built for another Laplacian (a programming error).
    pub fn add_bilaplacian_at(
        &mut self,
        slots: &BilaplacianSlots,
        lap: &LapRows,
        areas: &[f64],
        w: f64,
    ) {
        assert_eq!(slots.rows, lap.len(), "slots of another Laplacian");
        let mut at = slots.slots.iter();
        for (k, area) in areas.iter().enumerate().take(lap.len()) {
            let v = lap.row(k).1;
            let s = w / area;
            for &a in v {
                let sa = s * a;
                for &b in v {
                    let i = *at.next().expect("one slot per term");
                    self.vals[i as usize] += sa * b;
                }
            }
        }
    }

    /// Adds `w` at every position of `diagonal` (the pattern's diagonal positions, from
    /// [`SparsityPattern::diagonal_positions`]), as [`Self::add`]`(i, i, w)` for every `i` would.
    pub fn add_diagonal(&mut self, diagonal: &[usize], w: f64) {
        for &at in diagonal {
            self.vals[at] += w;
        }
    }

    /// Adds `w · scale[i]` at the `i`-th position of `diagonal` ([`Self::add_diagonal`] with a
    /// factor per row).
    pub fn add_diagonal_scaled(&mut self, diagonal: &[usize], w: f64, scale: &[f64]) {
        for (&at, s) in diagonal.iter().zip(scale) {
            self.vals[at] += w * s;
        }
    }

    /// Adds `w · rowᵀ row` for the point `row` of face `f` through `slots` (the face's 3 × 3
    /// positions, [`face_slots`]): the terms of [`Self::add_outer`]`(&row.entries(0), w)` in
    /// its order, zero weights skipped as there. Rows whose corners repeat a vertex take
    /// [`Self::add_outer`] itself (their entries are merged).
    pub fn add_face_outer(&mut self, slots: &[u32; 9], row: &RefRow, w: f64) {
        let [i, j, k] = row.idx;
        if i == j || j == k || i == k {
            self.add_outer(&row.entries(0), w);
            return;
        }
        for a in 0..3 {
            if row.w[a] == 0.0 {
                continue;
            }
            let wa = w * row.w[a];
            for b in 0..3 {
                if row.w[b] == 0.0 {
                    continue;
                }
                self.vals[slots[3 * a + b] as usize] += wa * row.w[b];
            }
        }
    }

    /// The matrix.
    pub fn into_matrix(self) -> Result<SymmetricMatrix, MethodError> {
        SymmetricMatrix::new(self.pattern, self.vals)
            .map_err(|e| MethodError::Internal(format!("matrix: {e}")))
    }
}

/// Connected components of a face list over `n` vertices (union-find): the component id of
/// every vertex, ids in order of first appearance, and the component count.
pub fn components(n: usize, faces: &[[u32; 3]]) -> (Vec<u32>, usize) {
    let mut parent: Vec<u32> = (0..n as u32).collect();
    fn root(parent: &mut [u32], mut v: u32) -> u32 {
        while parent[v as usize] != v {
            let p = parent[parent[v as usize] as usize];
            parent[v as usize] = p;
            v = p;
        }
        v
    }
    for f in faces {
        let a = root(&mut parent, f[0]);
        for &v in &f[1..] {
            let b = root(&mut parent, v);
            if a != b {
                parent[b as usize] = a;
            }
        }
    }
    let mut id = vec![u32::MAX; n];
    let mut comp = vec![0u32; n];
    let mut count = 0u32;
    for v in 0..n {
        let r = root(&mut parent, v as u32) as usize;
        if id[r] == u32::MAX {
            id[r] = count;
            count += 1;
        }
        comp[v] = id[r];
    }
    (comp, count as usize)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A gently curved, jittered 7 × 7 grid.
    fn grid() -> Surface {
        let n = 7u32;
        let mut p = Vec::new();
        for j in 0..n {
            for i in 0..n {
                let (x, y) = (i as f32 + 0.13 * (j as f32).sin(), j as f32);
                p.push([x, y, 0.1 * (x * x + 0.5 * y * y)]);
            }
        }
        let mut f = Vec::new();
        for j in 0..n - 1 {
            for i in 0..n - 1 {
                let a = j * n + i;
                f.push([a, a + 1, a + n + 1]);
                f.push([a, a + n + 1, a + n]);
            }
        }
        Surface::from_triangles(p, f)
    }

    #[test]
    fn stamped_pattern_and_slots_match_the_clique_and_search_assembly() {
        let s = grid();
        let lap = LapRows::of(&s).unwrap();
        let n = lap.len();
        let mut pb = PatternBuilder::new(2 * n);
        pb.bilaplacian(&lap, 0);
        pb.bilaplacian(&lap, n);
        let pattern = pb.build().unwrap();
        let mut cliques = PatternBuilder::new(2 * n);
        for offset in [0, n] {
            for k in 0..n {
                let c: Vec<usize> = lap.row(k).0.iter().map(|&j| j as usize + offset).collect();
                cliques.clique(&c);
            }
        }
        assert_eq!(
            *pattern,
            SparsityPattern::from_columns(&cliques.cols).unwrap()
        );

        let areas: Vec<f64> = (0..n)
            .map(|i| 0.5 + (i as f64 * 0.37).sin().abs())
            .collect();
        let slots = BilaplacianSlots::new(&pattern, &lap, n).unwrap();
        let mut searched = Values::zeros(&pattern);
        searched.add_bilaplacian(&lap, &areas, n, 0.7);
        let mut slotted = Values::zeros(&pattern);
        slotted.add_bilaplacian_at(&slots, &lap, &areas, 0.7);
        assert_eq!(searched.vals, slotted.vals);

        let faces = face_slots(&pattern, &s.faces).unwrap();
        for (f, bary) in [(3, [0.2, 0.0, 0.8]), (40, [0.3, 0.3, 0.4])] {
            let row = RefRow::face(s.faces[f], bary);
            searched.add_outer(&row.entries(0), 1.3);
            slotted.add_face_outer(&faces[f], &row, 1.3);
        }
        assert_eq!(searched.vals, slotted.vals);
        let diagonal = pattern.diagonal_positions();
        for i in 0..2 * n {
            searched.add(i, i, 0.25);
        }
        slotted.add_diagonal(&diagonal, 0.25);
        assert_eq!(searched.vals, slotted.vals);
    }
}
