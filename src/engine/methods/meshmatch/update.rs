//! Texture update (Chen et al. 2012, §5.3 "Texture update", Figure 10): the target is an edited
//! copy of the textured source (a creature lengthened after painting). The parts of the target
//! that were not edited keep the source's texture, copied by projection; MeshMatch synthesizes
//! only the rest, constrained by the copied parts (the copied vertices keep their colour in every
//! vote, exactly as painted vertices do in texture-by-example mode, [`super::example`]).
//!
//! The paper copies the unedited parts "verbatim" and notes that an editor which knows which
//! geometry changed allows finer-grained updates; it gives no rule for finding them. Here the
//! copied part is either given (`copy`: the forms of [`ExampleMask`], on the target) or found
//! automatically: the target synthesis vertices that lie within `tolerance` × the target's
//! bounding-box diagonal of the source surface, with their normal within 60° of the source
//! face's there (so a fold of the target that passes close to another part of the source is not
//! mistaken for it). The 60° bound and the default tolerance (0.2% of the diagonal: well above
//! the resampling error of the synthesis mesh, about 0.01% on a 64K resampling, and below the
//! smallest edit a user would call an edit) are ours; the paper has none.
//!
//! Copying reads the source at the closest point, so it is right for parts that stayed in place.
//! A part that moved (a head carried along by a lengthened neck) must be left out of the copied
//! region, and is then synthesized; a given `copy` mask whose vertices lie far from the source is
//! reported in a warning with the share that does.

use rayon::prelude::*;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::engine::asset::constraints::ConstraintsError;
use crate::engine::asset::Asset;
use crate::engine::mesh::Surface;
use crate::engine::spatial::{Bvh, ClosestHit};
use crate::engine::texture::sample::MaterialSampler;

use super::example::{painted_vertices, ExampleMask};
use super::sampling::{input_color, SynthesisMesh};

/// Smallest cosine between a target vertex normal and the source face normal at its closest
/// point for the vertex to be copied automatically (60°).
const MIN_NORMAL_COSINE: f32 = 0.5;

/// Texture-update mode (the `params.update` object).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct UpdateParams {
    /// The target region copied from the source (faces, a COLOR_0 channel or an image of the
    /// target, as in `example`). Default: found automatically, see `tolerance`.
    pub copy: Option<ExampleMask>,
    /// Automatic copy region: target points within this fraction of the target's bounding-box
    /// diagonal of the source surface (normals within 60°). A given `copy` mask whose points lie
    /// farther is warned about. Default 0.002.
    #[schemars(range(max = 0.1), extend("exclusiveMinimum" = 0))]
    pub tolerance: f32,
}

impl Default for UpdateParams {
    fn default() -> Self {
        Self {
            copy: None,
            tolerance: 0.002,
        }
    }
}

/// The source as the copy reads it.
pub struct CopySource<'a> {
    /// The source asset.
    pub asset: &'a Asset,
    /// Its welded surface.
    pub surface: &'a Surface,
    /// The surface's BVH.
    pub bvh: &'a Bvh,
}

/// The copied target synthesis vertices, their colours, and a warning if any.
pub struct CopiedRegion {
    /// Copied vertices of the target synthesis mesh.
    pub mask: Vec<bool>,
    /// Linear RGB per target synthesis vertex: the source's colour at its closest point (only
    /// read where `mask` is set).
    pub colors: Vec<[f32; 3]>,
    /// Things the user should know.
    pub warnings: Vec<String>,
}

fn err(path: &str, message: String) -> ConstraintsError {
    ConstraintsError::new(format!("params.update{path}"), message)
}

/// The copied region of the target synthesis mesh `mesh` (see the module docs).
///
/// # Errors
/// A [`ConstraintsError`] naming the field: a bad `copy` mask (as for `example`), or an automatic
/// region that is empty (nothing of the target lies on the source) or the whole target (nothing
/// was edited).
pub fn copied_region(
    update: &UpdateParams,
    source: &CopySource<'_>,
    target: (&Asset, &Surface),
    mesh: &SynthesisMesh,
) -> Result<CopiedRegion, ConstraintsError> {
    let s = &mesh.surface;
    let tolerance = update.tolerance * target.1.diagonal();
    let normals = s.vertex_normals();
    // Closest source point of every synthesis vertex, and whether it is within the tolerance
    // with agreeing normals.
    let hits: Vec<Option<(ClosestHit, bool)>> = s
        .positions
        .par_iter()
        .zip(normals.par_iter())
        .map(|(&p, &n)| {
            let hit = source.bvh.closest_point(p, f32::INFINITY)?;
            // Both normals are unit (zero for a degenerate face, which is then never copied).
            let m = source.surface.face_normal(hit.face as usize);
            let cosine = n[0] * m[0] + n[1] * m[1] + n[2] * m[2];
            let near = hit.distance_squared.sqrt() <= tolerance && cosine >= MIN_NORMAL_COSINE;
            Some((hit, near))
        })
        .collect();
    let mut warnings = Vec::new();
    let mask = match &update.copy {
        Some(copy) => {
            let mask = painted_vertices(copy, target.0, target.1, mesh).map_err(|e| {
                ConstraintsError::new(
                    e.path.replacen("params.example", "params.update.copy", 1),
                    e.message,
                )
            })?;
            let copied = mask.iter().filter(|&&m| m).count();
            let far = mask
                .iter()
                .zip(&hits)
                .filter(|(&m, h)| m && !h.as_ref().is_some_and(|h| h.1))
                .count();
            if far > 0 {
                warnings.push(format!(
                    "update: {:.1}% of the copied region lies farther than {tolerance:.4} from the source (or faces another way): it was copied from the closest source point; parts that moved should be left out of `copy` and synthesized",
                    100.0 * far as f64 / copied.max(1) as f64
                ));
            }
            mask
        }
        None => {
            let mask: Vec<bool> = hits
                .iter()
                .map(|h| h.as_ref().is_some_and(|h| h.1))
                .collect();
            let copied = mask.iter().filter(|&&m| m).count();
            if copied == 0 {
                return Err(err(
                    ".tolerance",
                    format!("no part of the target lies within {tolerance:.4} of the source: nothing to copy (raise the tolerance, give `copy`, or transfer without `update`)"),
                ));
            }
            if copied == mask.len() {
                return Err(err(
                    ".tolerance",
                    format!("the whole target lies within {tolerance:.4} of the source: nothing was edited, nothing to synthesize (lower the tolerance or give `copy`)"),
                ));
            }
            mask
        }
    };
    let sampler = MaterialSampler::new(source.asset);
    let colors = hits
        .iter()
        .zip(&mask)
        .map(|(h, &m)| match h {
            Some((hit, _)) if m => {
                let c = input_color(
                    source.asset,
                    source.surface,
                    &sampler,
                    hit.face as usize,
                    hit.bary,
                );
                [c[0], c[1], c[2]]
            }
            _ => [0.0; 3],
        })
        .collect();
    Ok(CopiedRegion {
        mask,
        colors,
        warnings,
    })
}
