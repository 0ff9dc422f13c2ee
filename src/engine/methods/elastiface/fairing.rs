//! Joint fairing (§3.2, eqs. 2-5): both meshes are smoothed at once into similar, feature-less
//! base meshes `B^s`, `B^t`, minimising over all `n + m` vertices
//!
//! `λ1/ΣA [Σ A_i‖Δx_i^s‖² + Σ A_j‖Δx_j^t‖²] + λ2/K Σ w_k‖r_k^s − r_k^t‖²
//!  + λ3/K Σ w_k‖½(r_k^s + r_k^t) − ½(r̄_k^s + r̄_k^t)‖²`
//!
//! with `Δx_i = (L x)_i / A_i` (cotan Laplacian `L` of the input meshes, kept fixed; `A` the
//! mixed Voronoi areas, updated after every solve as the paper does after Kazhdan et al. 2012),
//! so the smoothness term is `λ1/ΣA · xᵀ Lᵀ A⁻¹ L x`. `K = Σ w_k` (hand-placed pairs weigh 1,
//! derived boundary pairs less). The normal equations are one sparse SPD system with three
//! right-hand sides per iteration, solved together in one pass over the factor; its pattern
//! (two-rings plus the reference cliques), symbolic Cholesky analysis and the value slots of
//! the smoothness terms are built once.
//!
//! Choices of ours, where the paper says nothing:
//! - **Unanchored components.** `Lᵀ A⁻¹ L` vanishes on per-component translations, so a
//!   connected component with no reference point would make the system singular. Each of its
//!   vertices is tied weakly to its start position with weight `0.01 λ3/K · A_i / A_component`
//!   (the whole component weighs 1 % of one reference point): it is smoothed but stays in place.
//! - **Collapse guard.** If the total area after a solve falls below half of the start (the
//!   fairing shrinking the meshes, which happens when the model is far smaller than the
//!   reference size), the iterations stop, the previous iterate is kept and the report says so.
//! - **Fold guard.** From the second solve on, if the area fraction of either mesh's triangles
//!   turned more than 90° from their input normals grows by more than [`FOLD_GROWTH`] over the
//!   previous iterate, the iterations stop and the previous iterate is kept (`fold_guard` in
//!   the report). On an open disc whose boundary is paired (README "elastiface") the rim starts
//!   to fold at the third solve (turned area 0 → 1.6 % → 3.2 % → 5.1 %), and the folds stayed in
//!   the fitted result (0.77 % of its area flipped); a closed head's first solve turns its
//!   collapsing cavities (0.9 % of the area), after which the fraction falls or stays within
//!   ±2e-5, so the guard leaves it alone. The first solve is always kept.

use crate::engine::control::Control;
use crate::engine::linalg::SymbolicCholesky;
use crate::engine::math::{cross, dot, length, sub};

use super::refs::RefPair;
use super::system::{components, voronoi_areas, BilaplacianSlots, LapRows, PatternBuilder, Values};
use super::MethodError;

/// The largest growth, from one solve to the next, of the turned-over area fraction that the
/// fold guard accepts (ours; see the module docs: the measured growths are 1.6 % where the rim
/// folds and at most 2e-5 elsewhere, so any value between about 1e-4 and 1e-2 gives the same
/// results on the tests' cases).
pub const FOLD_GROWTH: f64 = 1e-3;

/// One mesh of the fairing: start positions, faces and Laplacian.
pub struct FairMesh<'a> {
    /// Start positions (aligned, normalised).
    pub x: &'a [[f64; 3]],
    /// Faces.
    pub faces: &'a [[u32; 3]],
    /// Cotan Laplacian.
    pub lap: &'a LapRows,
}

/// The fairing weights and iteration count.
#[derive(Clone, Copy, Debug)]
pub struct FairingWeights {
    /// λ1, λ2, λ3.
    pub lambda: [f64; 3],
    /// Solves (area updates in between).
    pub iterations: usize,
}

/// The base meshes and how they were obtained.
#[derive(Clone, Debug)]
pub struct Faired {
    /// `B^s`.
    pub source: Vec<[f64; 3]>,
    /// `B^t`.
    pub target: Vec<[f64; 3]>,
    /// Iterations whose result was kept.
    pub iterations: usize,
    /// Total area of both base meshes over that of the inputs.
    pub area_ratio: f64,
    /// Whether the collapse guard stopped the iterations.
    pub collapse_guard: bool,
    /// Whether the fold guard stopped the iterations.
    pub fold_guard: bool,
    /// Components anchored weakly in place (source, target).
    pub unanchored_components: (usize, usize),
}

/// Per-vertex anchor weights for components without any reference point (see the module docs).
fn anchor_weights(
    n: usize,
    faces: &[[u32; 3]],
    areas: &[f64],
    referenced: impl Iterator<Item = usize>,
    unit: f64,
) -> (Vec<f64>, usize) {
    let (comp, count) = components(n, faces);
    let mut has_ref = vec![false; count];
    for v in referenced {
        has_ref[comp[v] as usize] = true;
    }
    let mut comp_area = vec![0.0; count];
    for v in 0..n {
        comp_area[comp[v] as usize] += areas[v];
    }
    let w = (0..n)
        .map(|v| {
            let c = comp[v] as usize;
            if has_ref[c] {
                0.0
            } else {
                unit * areas[v] / comp_area[c].max(f64::MIN_POSITIVE)
            }
        })
        .collect();
    (w, has_ref.iter().filter(|h| !**h).count())
}

/// Runs the joint fairing (see the module docs).
///
/// # Errors
/// [`MethodError::Internal`] when a factorisation fails, [`MethodError::Cancelled`].
pub fn joint_fairing(
    source: &FairMesh<'_>,
    target: &FairMesh<'_>,
    pairs: &[RefPair],
    weights: FairingWeights,
    control: &Control,
) -> Result<Faired, MethodError> {
    let (n, m) = (source.x.len(), target.x.len());
    let [l1, l2, l3] = weights.lambda;
    let k_total: f64 = pairs.iter().map(|p| p.weight).sum();
    let mut pb = PatternBuilder::new(n + m);
    pb.bilaplacian(source.lap, 0);
    pb.bilaplacian(target.lap, n);
    for p in pairs {
        pb.reference(&[(p.source, 0), (p.target, n)]);
    }
    let pattern = pb.build()?;
    let symbolic = SymbolicCholesky::new(pattern.clone())
        .map_err(|e| MethodError::Internal(format!("fairing analysis: {e}")))?;
    let slots_s = BilaplacianSlots::new(&pattern, source.lap, 0)?;
    let slots_t = BilaplacianSlots::new(&pattern, target.lap, n)?;

    let mut area_s = voronoi_areas(source.x, source.faces)?;
    let mut area_t = voronoi_areas(target.x, target.faces)?;
    let start_area: f64 = area_s.iter().sum::<f64>() + area_t.iter().sum::<f64>();
    let unit = 0.01 * l3 / k_total;
    let (anchor_s, free_s) = anchor_weights(
        n,
        source.faces,
        &area_s,
        pairs.iter().flat_map(|p| p.source.idx.map(|i| i as usize)),
        unit,
    );
    let (anchor_t, free_t) = anchor_weights(
        m,
        target.faces,
        &area_t,
        pairs.iter().flat_map(|p| p.target.idx.map(|i| i as usize)),
        unit,
    );

    // Right-hand side: λ3/K Σ w ½ Sᵀ c_k (+ anchors), constant over the iterations.
    let mut rhs = vec![vec![0.0; n + m]; 3];
    for p in pairs {
        let c = mid(p.source.eval(source.x), p.target.eval(target.x));
        let s = l3 / k_total * p.weight * 0.5;
        for (i, a) in p.source.entries(0).into_iter().chain(p.target.entries(n)) {
            for d in 0..3 {
                rhs[d][i] += s * a * c[d];
            }
        }
    }
    for (i, (&w, x)) in anchor_s.iter().zip(source.x).enumerate() {
        (0..3).for_each(|d| rhs[d][i] += w * x[d]);
    }
    for (j, (&w, x)) in anchor_t.iter().zip(target.x).enumerate() {
        (0..3).for_each(|d| rhs[d][n + j] += w * x[d]);
    }

    let mut cur_s = source.x.to_vec();
    let mut cur_t = target.x.to_vec();
    let mut done = 0;
    let mut guard = false;
    let mut fold_guard = false;
    let mut prev_turned = (0.0, 0.0);
    let mut area_now = start_area;
    let work = control.stage("fairing", weights.iterations as u64)?;
    for _ in 0..weights.iterations {
        control.check()?;
        let total_area: f64 = area_s.iter().sum::<f64>() + area_t.iter().sum::<f64>();
        let mut v = Values::zeros(&pattern);
        v.add_bilaplacian_at(&slots_s, source.lap, &area_s, l1 / total_area);
        v.add_bilaplacian_at(&slots_t, target.lap, &area_t, l1 / total_area);
        for p in pairs {
            let w = p.weight / k_total;
            let mut row = p.source.entries(0);
            row.extend(p.target.entries(n).into_iter().map(|(i, a)| (i, -a)));
            v.add_outer(&row, l2 * w);
            let mut row = p.source.entries(0);
            row.extend(p.target.entries(n));
            v.add_outer(&row, 0.25 * l3 * w);
        }
        for (i, &w) in anchor_s.iter().chain(&anchor_t).enumerate() {
            if w > 0.0 {
                v.add(i, i, w);
            }
        }
        let matrix = v.into_matrix()?;
        let factor = symbolic
            .factor_sequential(&matrix)
            .map_err(|e| MethodError::Internal(format!("fairing factorisation: {e}")))?;
        let mut x = rhs.clone();
        factor
            .solve_block(&mut x)
            .map_err(|e| MethodError::Internal(format!("fairing solve: {e}")))?;
        let next_s: Vec<[f64; 3]> = (0..n).map(|i| [x[0][i], x[1][i], x[2][i]]).collect();
        let next_t: Vec<[f64; 3]> = (0..m)
            .map(|j| [x[0][n + j], x[1][n + j], x[2][n + j]])
            .collect();
        let next_area_s = voronoi_areas(&next_s, source.faces)?;
        let next_area_t = voronoi_areas(&next_t, target.faces)?;
        let a: f64 = next_area_s.iter().sum::<f64>() + next_area_t.iter().sum::<f64>();
        work.tick(1)?;
        let turned = (
            turned_fraction(source.x, &next_s, source.faces),
            turned_fraction(target.x, &next_t, target.faces),
        );
        if done > 0
            && (turned.0 - prev_turned.0 > FOLD_GROWTH || turned.1 - prev_turned.1 > FOLD_GROWTH)
        {
            fold_guard = true;
            break;
        }
        prev_turned = turned;
        if a < 0.5 * start_area && done > 0 {
            guard = true;
            break;
        }
        guard |= a < 0.5 * start_area;
        cur_s = next_s;
        cur_t = next_t;
        area_s = next_area_s;
        area_t = next_area_t;
        area_now = a;
        done += 1;
        if guard {
            break;
        }
    }
    Ok(Faired {
        source: cur_s,
        target: cur_t,
        iterations: done,
        area_ratio: area_now / start_area,
        collapse_guard: guard,
        fold_guard,
        unanchored_components: (free_s, free_t),
    })
}

/// The area fraction of `faces` at `x1` whose normal points more than 90° away from its normal
/// at `x0`.
fn turned_fraction(x0: &[[f64; 3]], x1: &[[f64; 3]], faces: &[[u32; 3]]) -> f64 {
    let normal = |x: &[[f64; 3]], f: &[u32; 3]| {
        let [a, b, c] = f.map(|v| x[v as usize]);
        cross(sub(b, a), sub(c, a))
    };
    let (mut turned, mut total) = (0.0, 0.0);
    for f in faces {
        let n1 = normal(x1, f);
        let area = length(n1);
        total += area;
        if dot(normal(x0, f), n1) < 0.0 {
            turned += area;
        }
    }
    turned / total.max(f64::MIN_POSITIVE)
}

fn mid(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        0.5 * (a[0] + b[0]),
        0.5 * (a[1] + b[1]),
        0.5 * (a[2] + b[2]),
    ]
}
