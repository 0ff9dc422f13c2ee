//! Surface samples at several resolutions and the Gaussian / Laplacian pyramids of per-sample
//! fields over them (Mertens et al. 2006, §3.1: "an even, dense sampling ... with a Gaussian
//! pyramid built by smoothing and down-sampling"; the Laplacian pyramid is Burt & Adelson's, as
//! Heeger & Bergen use it).
//!
//! **Samples (level 0).** The paper distributes 512,000 points by point repulsion. retex instead
//! resamples the welded input surface by longest-edge bisection ([`multires::resample`], the
//! sampling MeshMatch's synthesis meshes use) to about `samples` vertices, and the samples are
//! that mesh's vertices, so every sample has neighbours (its mesh edges) and a place on the input
//! (`location`). Uniformity: longest-edge bisection keeps edges within about a factor of 2 of each
//! other, and on an evenly tessellated input the mean incident edge length per sample has a 95th /
//! 5th percentile ratio of 1.53-1.77 (measured on a sphere, a bumpy sphere and a bumpy torus at
//! 4K, 16K and 64K samples; test
//! `correlation_synthesis::pyramid::pyramid_samples_are_even_and_levels_quarter` asserts < 2).
//! Point repulsion would be more even; the pyramid and the statistics weight every sample by its
//! area, so the spread biases no histogram. An input that already has more vertices than asked is
//! kept as it is (its own tessellation decides the spread); vertices used by no triangle are
//! dropped.
//!
//! **Coarser levels.** [`multires::build_hierarchy`] (shortest-edge-first midpoint collapse) with
//! a ratio of ¼ per level (an image pyramid halves each axis), so level `l` has about `n/4^l`
//! samples; the hierarchy may stop early on a mesh that cannot be decimated further
//! ([`SurfacePyramid::level_count`] says how many levels there are).
//!
//! **Gaussian pyramid.** `G₀ = f`; `G_{l+1} = down(smooth(G_l))`. `smooth` is two passes of
//! `x ← ½·x + ½·mean(neighbours)` over the level's mesh edges (retex's constant: on an even mesh
//! with spacing `h` each pass adds a variance of about `h²/4` per axis, so with the area-weighted
//! averaging over the ~4 vertices that collapse into one coarse vertex the kernel's σ is about `h`,
//! like the 5-tap binomial kernel of an image pyramid). `down` gives each coarse vertex the
//! area-weighted mean of its children (the fine vertices whose collapse group it is).
//!
//! **Laplacian pyramid.** Band `l` is `G_l − up(G_{l+1})` where `up` is the hierarchy's
//! barycentric prolongation at each fine vertex's closest point on the coarser level; the last
//! band is the coarsest Gaussian level. [`SurfacePyramid::collapse`] adds the bands back in the
//! same order and is the exact inverse up to float rounding.

use rayon::prelude::*;

use crate::engine::control::Control;
use crate::engine::mesh::csr::vertex_neighbours;
use crate::engine::mesh::Surface;
use crate::engine::methods::MethodError;
use crate::engine::multires::{
    build_hierarchy, resample, FacePoint, Hierarchy, HierarchyError, HierarchyParams,
    ResampleError, ResampleParams,
};

/// Vertex-count ratio between consecutive levels.
const LEVEL_RATIO: f32 = 0.25;
/// Smoothing passes before down-sampling (see the module docs).
const SMOOTH_PASSES: usize = 2;

/// Samples of a surface at several resolutions (§3.1); see the module docs.
#[derive(Clone, Debug)]
pub struct SurfacePyramid {
    hierarchy: Hierarchy,
    levels: usize,
    location: Vec<FacePoint>,
    input_face: Vec<u32>,
    area: Vec<Vec<f32>>,
    /// Per level (all but the coarsest): vertex neighbours as CSR (offsets, neighbours).
    neighbours: Vec<(Vec<u32>, Vec<u32>)>,
}

fn unusable(message: String) -> MethodError {
    MethodError::UnusableInput {
        field: None,
        kind: "unusable-mesh",
        message,
    }
}

fn from_resample(e: ResampleError) -> MethodError {
    match e {
        ResampleError::Cancelled => MethodError::Cancelled,
        e => unusable(format!("surface sampling: {e}")),
    }
}

fn from_hierarchy(e: HierarchyError) -> MethodError {
    match e {
        HierarchyError::Cancelled => MethodError::Cancelled,
        e => unusable(format!("surface pyramid: {e}")),
    }
}

/// Lumped (one third of the incident faces') area of every vertex.
fn lumped_area(s: &Surface) -> Vec<f32> {
    let mut a = vec![0.0f64; s.vertex_count()];
    for f in 0..s.face_count() {
        let third = s.face_area(f) as f64 / 3.0;
        for &v in &s.faces[f] {
            a[v as usize] += third;
        }
    }
    a.into_iter().map(|x| x as f32).collect()
}

/// Drops vertices used by no face (renumbering faces and `location`).
fn drop_unused(
    positions: Vec<[f32; 3]>,
    faces: Vec<[u32; 3]>,
    location: Vec<FacePoint>,
) -> (Surface, Vec<FacePoint>) {
    let mut used = vec![false; positions.len()];
    for f in &faces {
        for &v in f {
            used[v as usize] = true;
        }
    }
    if used.iter().all(|&u| u) {
        return (Surface::from_triangles(positions, faces), location);
    }
    let mut map = vec![u32::MAX; positions.len()];
    let (mut pos, mut loc) = (Vec::new(), Vec::new());
    for v in 0..positions.len() {
        if used[v] {
            map[v] = pos.len() as u32;
            pos.push(positions[v]);
            loc.push(location[v]);
        }
    }
    let faces = faces
        .into_iter()
        .map(|f| f.map(|v| map[v as usize]))
        .collect();
    (Surface::from_triangles(pos, faces), loc)
}

impl SurfacePyramid {
    /// Resamples `surface` to about `samples` vertices and builds up to `levels` levels.
    ///
    /// # Errors
    /// [`MethodError::UnusableInput`] for an empty or broken surface or `samples`/`levels` of 0,
    /// [`MethodError::Cancelled`] when cancelled.
    pub fn build(
        surface: &Surface,
        samples: usize,
        levels: usize,
        control: &Control,
    ) -> Result<Self, MethodError> {
        if samples == 0 || levels == 0 {
            return Err(unusable(format!(
                "surface pyramid needs samples ≥ 1 and levels ≥ 1 (got {samples}, {levels})"
            )));
        }
        if surface.faces.is_empty() {
            return Err(unusable("surface pyramid: the surface has no faces".into()));
        }
        let r = resample(
            &surface.positions,
            &surface.faces,
            &ResampleParams {
                max_vertices: samples.max(surface.vertex_count()),
                ..Default::default()
            },
            control,
        )
        .map_err(from_resample)?;
        let input_face = r.triangle_faces;
        let (mesh0, location) = drop_unused(r.positions, r.triangles, r.sources);
        let n0 = mesh0.vertex_count() as f64;
        let coarsest = n0 * (LEVEL_RATIO as f64).powi(levels as i32 - 1);
        let params = HierarchyParams {
            target_ratio: LEVEL_RATIO,
            min_vertices: (coarsest.ceil() as usize).clamp(4, 1_000_000),
            ..Default::default()
        };
        let hierarchy = build_hierarchy(&mesh0, &params, control).map_err(from_hierarchy)?;
        let levels = levels.min(hierarchy.level_count());
        let stage = control.stage("pyramid", levels as u64)?;
        let mut area = Vec::with_capacity(levels);
        let mut neighbours = Vec::with_capacity(levels);
        for l in 0..levels {
            let s = &hierarchy.level(l).surface;
            area.push(lumped_area(s));
            if l + 1 < levels {
                neighbours.push(vertex_neighbours(s));
            }
            stage.tick(1)?;
        }
        Ok(Self {
            hierarchy,
            levels,
            location,
            input_face,
            area,
            neighbours,
        })
    }

    /// Number of levels (1 ..= the `levels` asked for).
    pub fn level_count(&self) -> usize {
        self.levels
    }

    /// Samples on `level`.
    pub fn len(&self, level: usize) -> usize {
        self.area[level].len()
    }

    /// True when level 0 has no samples (never, for a built pyramid).
    pub fn is_empty(&self) -> bool {
        self.area[0].is_empty()
    }

    /// The mesh of `level` (its vertices are the samples).
    pub fn mesh(&self, level: usize) -> &Surface {
        &self.hierarchy.level(level).surface
    }

    /// Level-0 sample → its (face, barycentric) point on the input surface.
    pub fn location(&self) -> &[FacePoint] {
        &self.location
    }

    /// Level-0 triangle → the input face it lies in.
    pub fn input_face(&self) -> &[u32] {
        &self.input_face
    }

    /// Lumped area per sample of `level` (the weights for statistics).
    pub fn area(&self, level: usize) -> &[f32] {
        &self.area[level]
    }

    /// The multiresolution hierarchy of the levels (parents, descendants, prolongation).
    pub fn hierarchy(&self) -> &Hierarchy {
        &self.hierarchy
    }

    /// The parent on level `level + 1` of every sample of `level` (`level` < the coarsest).
    pub fn parent(&self, level: usize) -> &[u32] {
        &self.hierarchy.level(level).parent
    }

    /// Two passes of neighbour averaging on `level` (see the module docs).
    fn smooth<const D: usize>(&self, level: usize, f: &[[f32; D]]) -> Vec<[f32; D]> {
        let (off, nb) = &self.neighbours[level];
        let mut cur = f.to_vec();
        for _ in 0..SMOOTH_PASSES {
            cur = (0..cur.len())
                .into_par_iter()
                .map(|v| {
                    let ns = &nb[off[v] as usize..off[v + 1] as usize];
                    if ns.is_empty() {
                        return cur[v];
                    }
                    let mut m = [0.0f32; D];
                    for &n in ns {
                        for k in 0..D {
                            m[k] += cur[n as usize][k];
                        }
                    }
                    let inv = 0.5 / ns.len() as f32;
                    std::array::from_fn(|k| 0.5 * cur[v][k] + inv * m[k])
                })
                .collect();
        }
        cur
    }

    /// Area-weighted mean of the children of every vertex of `level + 1`.
    fn down<const D: usize>(&self, level: usize, f: &[[f32; D]]) -> Vec<[f32; D]> {
        let parent = self.parent(level);
        let area = &self.area[level];
        let n = self.len(level + 1);
        let mut sum = vec![[0.0f64; D]; n];
        let mut w = vec![0.0f64; n];
        for (v, &p) in parent.iter().enumerate() {
            let a = (area[v] as f64).max(1e-30);
            for k in 0..D {
                sum[p as usize][k] += a * f[v][k] as f64;
            }
            w[p as usize] += a;
        }
        sum.iter()
            .zip(&w)
            .map(|(s, &w)| std::array::from_fn(|k| (s[k] / w.max(1e-300)) as f32))
            .collect()
    }

    /// The Gaussian pyramid of a level-0 field: levels 0 (the field itself) to the coarsest.
    ///
    /// # Panics
    /// If `level0` does not have one value per level-0 sample.
    pub fn gaussian<const D: usize>(&self, level0: &[[f32; D]]) -> Vec<Vec<[f32; D]>> {
        self.gaussian_levels(level0, self.levels)
    }

    /// The first `n` levels (1 ..= [`SurfacePyramid::level_count`]) of the Gaussian pyramid.
    ///
    /// # Panics
    /// If `level0` does not have one value per level-0 sample or `n` is out of range.
    pub fn gaussian_levels<const D: usize>(
        &self,
        level0: &[[f32; D]],
        n: usize,
    ) -> Vec<Vec<[f32; D]>> {
        assert_eq!(level0.len(), self.len(0), "one value per level-0 sample");
        assert!(
            (1..=self.levels).contains(&n),
            "level count {n} out of range"
        );
        let mut out = vec![level0.to_vec()];
        for l in 0..n - 1 {
            let s = self.smooth(l, &out[l]);
            out.push(self.down(l, &s));
        }
        out
    }

    /// The Laplacian pyramid of a level-0 field: band `l` on level `l`; the last band is the
    /// coarsest Gaussian level.
    ///
    /// # Panics
    /// If `level0` does not have one value per level-0 sample.
    pub fn laplacian<const D: usize>(&self, level0: &[[f32; D]]) -> Vec<Vec<[f32; D]>> {
        self.laplacian_levels(level0, self.levels)
    }

    /// The Laplacian pyramid over the first `n` levels (the last band is Gaussian level `n − 1`).
    ///
    /// # Panics
    /// If `level0` does not have one value per level-0 sample or `n` is out of range.
    pub fn laplacian_levels<const D: usize>(
        &self,
        level0: &[[f32; D]],
        n: usize,
    ) -> Vec<Vec<[f32; D]>> {
        let mut g = self.gaussian_levels(level0, n);
        for l in 0..n - 1 {
            let up = self.hierarchy.prolongate(l + 1, &g[l + 1]);
            for (x, u) in g[l].iter_mut().zip(&up) {
                for k in 0..D {
                    x[k] -= u[k];
                }
            }
        }
        g
    }

    /// The level-0 field whose Laplacian pyramid is `bands` (the exact inverse of
    /// [`SurfacePyramid::laplacian`] and of [`SurfacePyramid::laplacian_levels`] for
    /// `bands.len()` levels, up to float rounding).
    ///
    /// # Panics
    /// If there are no bands or more than levels, or a band has not one value per sample.
    pub fn collapse<const D: usize>(&self, bands: &[Vec<[f32; D]>]) -> Vec<[f32; D]> {
        let n = bands.len();
        assert!((1..=self.levels).contains(&n), "one band per level");
        assert_eq!(bands[n - 1].len(), self.len(n - 1), "one value per sample");
        let mut cur = bands[n - 1].clone();
        for l in (0..n - 1).rev() {
            assert_eq!(bands[l].len(), self.len(l), "one value per sample");
            let up = self.hierarchy.prolongate(l + 1, &cur);
            cur = bands[l]
                .iter()
                .zip(&up)
                .map(|(b, u)| std::array::from_fn(|k| b[k] + u[k]))
                .collect();
        }
        cur
    }
}
