//! The example mask of MeshMatch's texture-by-example mode (Chen et al. 2012, §5.3 "Texture by
//! example"): which part of a mesh is painted. The painted part keeps its colour and serves as the
//! source; the rest is synthesized from it.
//!
//! Three forms, in the `params.example` object of the constraints:
//! - `{"faces": [{"mesh": 0, "primitive": 0, "triangles": [0, 1, 2]}]}`: listed triangles;
//! - `{"vertex_color": {"channel": "r", "threshold": 0.5}}`: COLOR_0's channel above the threshold;
//! - `{"image": {"index": 1, "channel": "a", "threshold": 0.5}}`: a glTF image of the asset, read
//!   with the base-colour texture's UVs (so a mask painted in the same layout); colour channels
//!   are compared in linear space, alpha as stored.
//!
//! A synthesis vertex is painted when every synthesis triangle around it lies in a painted region
//! (faces), or when the mask value at the vertex's point on the input passes the threshold (vertex
//! colour, image). On a decimated synthesis mesh a triangle counts as in the input face closest to
//! its centroid.

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

use crate::engine::asset::constraints::ConstraintsError;
use crate::engine::asset::{Asset, Sampler};
use crate::engine::mesh::Surface;
use crate::engine::texture::sample::{sample_image, MaterialSampler};

use super::sampling::SynthesisMesh;

/// A colour channel.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum Channel {
    /// Red.
    R,
    /// Green.
    G,
    /// Blue.
    B,
    /// Alpha.
    A,
}

impl Channel {
    fn index(self) -> usize {
        match self {
            Channel::R => 0,
            Channel::G => 1,
            Channel::B => 2,
            Channel::A => 3,
        }
    }
}

/// Triangles of one primitive.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct FaceSet {
    /// glTF mesh index.
    pub mesh: usize,
    /// Primitive index within the mesh.
    pub primitive: usize,
    /// Triangle indices within the primitive.
    pub triangles: Vec<usize>,
}

/// Which part of the mesh is painted.
// The thresholds' range is checked with the other params (`MeshMatchParams::validate`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum ExampleMask {
    /// Listed triangles.
    Faces(Vec<FaceSet>),
    /// A COLOR_0 channel above a threshold.
    VertexColor {
        /// The channel.
        channel: Channel,
        /// Painted where the value is above this.
        #[schemars(range(min = 0, max = 1))]
        threshold: f32,
    },
    /// An image of the asset through the base-colour UVs.
    Image {
        /// Index into the glTF `images`.
        index: usize,
        /// The channel.
        channel: Channel,
        /// Painted where the value is above this.
        #[schemars(range(min = 0, max = 1))]
        threshold: f32,
    },
}

fn err(path: &str, message: String) -> ConstraintsError {
    ConstraintsError::new(format!("params.example{path}"), message)
}

/// The painted flag of every synthesis vertex.
///
/// # Errors
/// A [`ConstraintsError`] naming the field for an index out of range, an asset without COLOR_0,
/// an undecodable image, or a mask that selects nothing or everything. The thresholds are
/// range-checked beforehand, with the other params.
pub fn painted_vertices(
    mask: &ExampleMask,
    asset: &Asset,
    input: &Surface,
    mesh: &SynthesisMesh,
) -> Result<Vec<bool>, ConstraintsError> {
    let s = &mesh.surface;
    let nv = s.vertex_count();
    let painted: Vec<bool> = match mask {
        ExampleMask::Faces(sets) => {
            let mut chosen = std::collections::HashSet::new();
            for (i, set) in sets.iter().enumerate() {
                let prim = asset
                    .primitives
                    .iter()
                    .position(|p| p.mesh == set.mesh && p.primitive == set.primitive)
                    .ok_or_else(|| {
                        err(
                            &format!(".faces[{i}]"),
                            format!(
                                "mesh {} primitive {} does not exist",
                                set.mesh, set.primitive
                            ),
                        )
                    })?;
                let count = asset.primitives[prim].triangles.len();
                for (j, &t) in set.triangles.iter().enumerate() {
                    if t >= count {
                        return Err(err(
                            &format!(".faces[{i}].triangles[{j}]"),
                            format!("triangle {t} is out of range (the primitive has {count})"),
                        ));
                    }
                    chosen.insert((prim as u32, t as u32));
                }
            }
            let face_painted: Vec<bool> = mesh
                .input_face
                .iter()
                .map(|&f| {
                    let o = input.origins[f as usize];
                    chosen.contains(&(o.primitive, o.triangle))
                })
                .collect();
            let mut all = vec![true; nv];
            let mut any = vec![false; nv];
            for (f, face) in s.faces.iter().enumerate() {
                for &v in face {
                    all[v as usize] &= face_painted[f];
                    any[v as usize] = true;
                }
            }
            all.iter().zip(&any).map(|(a, b)| *a && *b).collect()
        }
        ExampleMask::VertexColor { channel, threshold } => {
            if !asset.primitives.iter().any(|p| p.colors.is_some()) {
                return Err(err(
                    ".vertex_color",
                    "the asset has no COLOR_0 attribute".into(),
                ));
            }
            let c = channel.index();
            values_at_vertices(asset, input, mesh, |prim, tri, bary| {
                let p = &asset.primitives[prim];
                let t = p.triangles[tri];
                match &p.colors {
                    Some(colors) => (0..3)
                        .map(|k| bary[k] * colors.get(t[k] as usize).map_or(0.0, |x| x[c]))
                        .sum(),
                    None => 0.0,
                }
            })
            .into_iter()
            .map(|v| v > *threshold)
            .collect()
        }
        ExampleMask::Image {
            index,
            channel,
            threshold,
        } => {
            let decoded = asset
                .decoded_image(*index)
                .map_err(|e| err(".image.index", e))?;
            let sampler = MaterialSampler::new(asset);
            let c = channel.index();
            values_at_vertices(asset, input, mesh, |prim, tri, bary| {
                match sampler.texture_uv(prim, tri, bary) {
                    Some(uv) => sample_image(decoded, &Sampler::default(), uv)[c],
                    None => 0.0,
                }
            })
            .into_iter()
            .map(|v| v > *threshold)
            .collect()
        }
    };
    let count = painted.iter().filter(|p| **p).count();
    if count == 0 {
        return Err(err("", "the mask selects no part of the mesh".into()));
    }
    if count == nv {
        return Err(err(
            "",
            "the mask selects the whole mesh: nothing is left to synthesize".into(),
        ));
    }
    Ok(painted)
}

/// Evaluates `value(primitive, triangle, bary in the triangle's vertex order)` at every synthesis
/// vertex, at its point on the input surface ([`SynthesisMesh::vertex_link`]).
fn values_at_vertices(
    asset: &Asset,
    input: &Surface,
    mesh: &SynthesisMesh,
    value: impl Fn(usize, usize, [f32; 3]) -> f32,
) -> Vec<f32> {
    mesh.vertex_link
        .iter()
        .map(|link| {
            if link.face == u32::MAX || input.origins.is_empty() {
                return 0.0;
            }
            let f = link.face as usize;
            let b = link.bary;
            let o = input.origins[f];
            let (prim, tri) = (o.primitive as usize, o.triangle as usize);
            let triangle = asset.primitives[prim].triangles[tri];
            // The face's corner order may be flipped (mirrored instances): map onto the
            // triangle's vertex order.
            let mut bary = [0.0f32; 3];
            for (k, corner) in input.corners[f].iter().enumerate() {
                if let Some(j) = triangle.iter().position(|x| *x == corner.vertex) {
                    bary[j] += b[k];
                }
            }
            value(prim, tri, bary)
        })
        .collect()
}
