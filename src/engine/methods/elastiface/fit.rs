//! The fit (Zell & Botsch 2013, "ElastiFace", §3.2-3.3): the joint fairing of the aligned
//! meshes into base meshes (§3.2, eqs. 2-5, [`super::fairing`]), the non-rigid registration of
//! the base meshes (§3.3, eqs. 6-8, [`super::register`]), then that of the originals from the
//! base meshes' closest points ([`super::originals`], with its closest-point rounds with
//! backward pairs). The registration's pattern, analysis and the target's solve-frame BVH are
//! built while the fairing runs.

use super::boundary_fit::BoundaryFit;
use super::prepare::Prepared;
use super::register::{self, StageReport};
use super::system::LapRows;
use super::{fairing, free, originals, refs, Call, ElastifaceParams, FairingReport, MethodError};
use crate::engine::control::Control;
use crate::engine::mesh::Surface;
use crate::engine::spatial::Bvh;

/// The fitted source and what the stages report.
pub struct Fit {
    /// The fitted welded source positions, in the solve frame.
    pub fitted: Vec<[f64; 3]>,
    /// The joint fairing's figures.
    pub fairing: FairingReport,
    /// Registration of the base meshes (`rms_fit` relative to the target diagonal).
    pub registration: StageReport,
    /// Registration of the originals (`rms_fit` relative to the target diagonal).
    pub registration_originals: StageReport,
    /// BVH of the target in the solve frame.
    pub target_bvh: Bvh,
    /// Per welded source vertex: free in the registration of the originals ([`free`]; empty
    /// when `free_visibility` is 0).
    pub free: Vec<bool>,
}

/// Fairs the prepared meshes (Laplacians `lap_s` / `lap_t`) and registers the source onto the
/// target.
///
/// # Errors
/// [`MethodError::Internal`], [`MethodError::Cancelled`].
pub fn fit(
    call: &Call<'_>,
    p: &Prepared,
    lap_s: &LapRows,
    lap_t: &LapRows,
) -> Result<Fit, MethodError> {
    let (params, control) = (call.params, call.control);
    let ref_diag = params.reference_diagonal;
    let (faired, reg, xt_bvh, paper_start, free) = fair_and_prepare(
        (&p.xs, &p.src, lap_s),
        (&p.xt, &p.tgt, lap_t),
        &p.pairs,
        params,
        control,
    )?;

    let bt32: Vec<[f32; 3]> = faired.target.iter().map(|q| q.map(|c| c as f32)).collect();
    let bt_bvh = Bvh::build(&bt32, &p.tgt.faces);
    let base_target = register::FitTarget {
        x: &faired.target,
        faces: &p.tgt.faces,
        bvh: &bt_bvh,
    };
    let (_, carried, mut base_report) = reg.base(
        &faired.source,
        &base_target,
        params.registration_iterations,
        control,
    )?;
    let orig_target = register::FitTarget {
        x: &p.xt,
        faces: &p.tgt.faces,
        bvh: &xt_bvh,
    };
    let boundary = if params.boundary_to_boundary {
        BoundaryFit::new(&p.loop_pairs, &p.xt)
    } else {
        None
    };
    let (fitted, mut orig_report) = reg.originals_from(
        paper_start,
        &p.xs,
        &orig_target,
        &carried,
        originals::Rounds {
            levels: params.original_stiffness_levels,
            per_level: params.original_iterations,
            backward_weight: params.backward_weight,
            max_distance: params.backward_max_distance * ref_diag,
            min_cos: params.backward_min_cos,
            free: &free,
            boundary: boundary.as_ref(),
        },
        control,
    )?;
    base_report.rms_fit /= ref_diag;
    orig_report.rms_fit /= ref_diag;
    Ok(Fit {
        fitted,
        fairing: FairingReport {
            iterations: faired.iterations,
            area_ratio: faired.area_ratio,
            collapse_guard: faired.collapse_guard,
            fold_guard: faired.fold_guard,
            unanchored_components: faired.unanchored_components,
        },
        registration: base_report,
        registration_originals: orig_report,
        target_bvh: xt_bvh,
        free,
    })
}

/// The warning of a fairing stopped by its collapse guard.
pub fn collapse_warning(fairing: &FairingReport) -> Option<String> {
    fairing.collapse_guard.then(|| {
        format!(
            "the joint fairing shrank the meshes to {:.0}% of their area; the area updates were stopped",
            100.0 * fairing.area_ratio
        )
    })
}

/// What the stages after the fairing start from.
type Overlapped<'a> = (
    fairing::Faired,
    register::Registration<'a>,
    Bvh,
    originals::PaperStart,
    Vec<bool>,
);

/// The joint fairing (§3.2) of the aligned source and target (positions, surface, Laplacian),
/// overlapped with what does not depend on it: the registration's pattern and analysis, the
/// original target's hierarchy, the paper's solve of the originals (factor and fixed
/// right-hand side) and the free vertices ([`free`]) are prepared on the other core meanwhile.
fn fair_and_prepare<'a>(
    src: (&[[f64; 3]], &'a Surface, &'a LapRows),
    tgt: (&[[f64; 3]], &Surface, &LapRows),
    pairs: &'a [refs::RefPair],
    params: &ElastifaceParams,
    control: &Control,
) -> Result<Overlapped<'a>, MethodError> {
    let (faired, prepared) = rayon::join(
        || {
            fairing::joint_fairing(
                &fairing::FairMesh {
                    x: src.0,
                    faces: &src.1.faces,
                    lap: src.2,
                },
                &fairing::FairMesh {
                    x: tgt.0,
                    faces: &tgt.1.faces,
                    lap: tgt.2,
                },
                pairs,
                fairing::FairingWeights {
                    lambda: [
                        params.lambda_smooth,
                        params.lambda_coincide,
                        params.lambda_position,
                    ],
                    iterations: params.fairing_iterations,
                },
                control,
            )
        },
        || {
            let x32: Vec<[f32; 3]> = tgt.0.iter().map(|p| p.map(|c| c as f32)).collect();
            let bvh = Bvh::build(&x32, &tgt.1.faces);
            let reg = register::Registration::new(src.2, &src.1.faces, pairs)?;
            let start = reg.paper_start(src.0, tgt.0)?;
            let free = free::free_vertices(src.1, params.free_visibility, control)?;
            Ok::<_, MethodError>((reg, bvh, start, free))
        },
    );
    let faired = faired?;
    let (reg, bvh, start, free) = prepared?;
    Ok((faired, reg, bvh, start, free))
}
