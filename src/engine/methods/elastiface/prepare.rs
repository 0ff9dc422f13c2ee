//! Input preparation (Zell & Botsch 2013, "ElastiFace", §3.1): the welded surfaces and their
//! BVHs, the hand-placed correspondences as reference points in triangles (eq. 1), the initial
//! similarity with the scale normalisation ([`super::frame`], §3.1 last paragraph), both meshes
//! in the solve frame, and the pairs derived along corresponding boundary loops
//! ([`super::boundary`], Fig. 5). The part-based morph's vertex weights (§5, [`super::region`])
//! are read here too, as they only need the source.

use super::boundary::{self, BoundaryReport, LoopPair};
use super::frame::Frame;
use super::metrics::{self, Residuals};
use super::refs::{self, RefPair};
use super::{region, writeback, Call, MethodError};
use crate::engine::mesh::{Surface, WeldParams};
use crate::engine::methods::align::best_similarity;
use crate::engine::methods::correspondence::resolve_on_surfaces;
use crate::engine::methods::surface_of;
use crate::engine::spatial::Bvh;

/// The prepared inputs every later stage reads.
pub struct Prepared {
    /// The welded source surface (world frame).
    pub src: Surface,
    /// BVH of `src`.
    pub src_bvh: Bvh,
    /// The welded target surface (world frame).
    pub tgt: Surface,
    /// BVH of `tgt`.
    pub tgt_bvh: Bvh,
    /// Per source primitive, per vertex: its welded vertex ([`writeback::welded_map`]).
    pub welded: Vec<Vec<u32>>,
    /// The part-based morph's per-vertex weights (`params.blend.region`), when given.
    pub region_weights: Option<Vec<f64>>,
    /// The welded source positions in its world frame.
    pub src_world: Vec<[f64; 3]>,
    /// The initial similarity and the normalisation.
    pub frame: Frame,
    /// The welded source positions in the solve frame.
    pub xs: Vec<[f64; 3]>,
    /// The welded target positions in the solve frame.
    pub xt: Vec<[f64; 3]>,
    /// The hand-placed pairs.
    pub hand: Vec<RefPair>,
    /// The hand-placed pairs followed by the boundary-loop pairs.
    pub pairs: Vec<RefPair>,
    /// The boundary-loop pairs' figures.
    pub boundary: BoundaryReport,
    /// The paired boundary loops (source loop, target loop).
    pub loop_pairs: Vec<LoopPair>,
    /// Correspondence residuals after the similarity alone (relative to the target diagonal).
    pub residuals_initial: Residuals,
}

/// Prepares the inputs (stages `surface` and `correspondences`).
///
/// # Errors
/// [`MethodError::Mesh`], [`MethodError::Constraints`] for unusable correspondences or region,
/// [`MethodError::Cancelled`].
pub fn prepare(call: &Call<'_>) -> Result<Prepared, MethodError> {
    let (source, target, params, control) = (call.source, call.target, call.params, call.control);
    let weld = WeldParams {
        relative_tolerance: params.weld_tolerance,
    };
    control.stage("surface", 0)?;
    let surface_and_bvh = |asset, side| {
        surface_of(asset, &weld, side).map(|s| {
            let bvh = Bvh::build(&s.positions, &s.faces);
            (s, bvh)
        })
    };
    let (src, tgt) = rayon::join(
        || surface_and_bvh(source, "source"),
        || surface_and_bvh(target, "target"),
    );
    let ((src, src_bvh), (tgt, tgt_bvh)) = (src?, tgt?);

    let welded = writeback::welded_map(source, &src);
    let region_weights = match params.region_blend() {
        Some((b, r)) => Some(region::vertex_weights(
            source,
            &welded,
            src.vertex_count(),
            r,
            b.feather_rings,
        )?),
        None => None,
    };

    control.stage("correspondences", 0)?;
    let resolved = resolve_on_surfaces(
        &call.constraints.correspondences,
        (source, &src_bvh, &src),
        (target, &tgt_bvh, &tgt),
        params.snap_tolerance,
    )?;
    let src_world = f64s(&src.positions);
    let tgt_world = f64s(&tgt.positions);
    let hand = refs::hand_pairs(&resolved, &src.faces, &tgt.faces);
    let from: Vec<[f64; 3]> = hand.iter().map(|p| p.source.eval(&src_world)).collect();
    let to: Vec<[f64; 3]> = hand.iter().map(|p| p.target.eval(&tgt_world)).collect();
    refs::check_not_collinear(&from, "source")?;
    refs::check_not_collinear(&to, "target")?;
    let similarity = best_similarity(&from, &to);
    let (lo, hi) = tgt.bounding_box();
    let frame = Frame::new(
        similarity,
        lo.map(f64::from),
        hi.map(f64::from),
        params.reference_diagonal,
    );
    let xs: Vec<[f64; 3]> = src_world
        .iter()
        .map(|p| frame.source_to_solve(*p))
        .collect();
    let xt: Vec<[f64; 3]> = tgt_world
        .iter()
        .map(|p| frame.target_to_solve(*p))
        .collect();
    let ref_diag = params.reference_diagonal;
    let src_diag = bbox_diagonal(&xs);
    let (derived, boundary, loop_pairs) = boundary::derive_boundary_pairs(
        &boundary::LoopSide {
            x: &xs,
            faces: &src.faces,
            diagonal: src_diag,
        },
        &boundary::LoopSide {
            x: &xt,
            faces: &tgt.faces,
            diagonal: ref_diag,
        },
        &hand,
    )?;
    let mut pairs = hand.clone();
    pairs.extend(derived);
    let residuals_initial = metrics::residuals(&hand, &xs, &xt, ref_diag);
    Ok(Prepared {
        src,
        src_bvh,
        tgt,
        tgt_bvh,
        welded,
        region_weights,
        src_world,
        frame,
        xs,
        xt,
        hand,
        pairs,
        boundary,
        loop_pairs,
        residuals_initial,
    })
}

fn f64s(p: &[[f32; 3]]) -> Vec<[f64; 3]> {
    p.iter().map(|q| q.map(f64::from)).collect()
}

fn bbox_diagonal(x: &[[f64; 3]]) -> f64 {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for p in x {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    (0..3).map(|k| (hi[k] - lo[k]).powi(2)).sum::<f64>().sqrt()
}
