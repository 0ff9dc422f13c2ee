//! Sparse assembly shared by the joint fairing (§3.2) and the registrations (§3.3): the cotan
//! Laplacian as rows, the pattern of `Lᵀ A⁻¹ L` (each vertex's one-ring as a clique, i.e. the
//! two-ring) plus the cliques of the reference points, and value accumulation into that pattern.
//!
//! Both energies are quadratic with a fixed pattern, so the pattern and its symbolic Cholesky
//! analysis are built once per stage and only the values change between iterations (the paper
//! updates the Voronoi areas and the stiffness, never the connectivity).

use std::sync::Arc;

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
}

impl PatternBuilder {
    /// An `n × n` pattern with only the diagonal.
    pub fn new(n: usize) -> Self {
        Self {
            cols: vec![Vec::new(); n],
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
        self.cols[i].extend(cols.iter().filter(|&&j| j != i));
    }

    /// The pattern of `Lᵀ A⁻¹ L` for a Laplacian whose unknowns start at `offset`.
    pub fn bilaplacian(&mut self, lap: &LapRows, offset: usize) {
        let mut buf = Vec::new();
        for k in 0..lap.len() {
            buf.clear();
            buf.extend(lap.row(k).0.iter().map(|&c| c as usize + offset));
            self.clique(&buf);
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

    /// The finished pattern.
    pub fn build(self) -> Result<Arc<SparsityPattern>, MethodError> {
        SparsityPattern::from_columns(&self.cols)
            .map(Arc::new)
            .map_err(|e| MethodError::Internal(format!("pattern: {e}")))
    }
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
