//! TANGENT computed with MikkTSpace, shared by the methods that write tangent frames: ElastiFace
//! recomputes the fitted source's (issue 10, "Interface": "TANGENT recomputed or dropped") and
//! `detail` writes the frames its normal map is baked in (issue 13, "Interface").
//!
//! Not a step of either paper (Zell & Botsch 2013 keep the template's UVs and say nothing about
//! tangent frames); it is what glTF 2.0 §3.7.2.1 asks of a client that lacks tangents: MikkTSpace
//! on the written positions, normals and the texture coordinates of the normal texture. The
//! algorithm is the `bevy_mikktspace` crate (a safe Rust port of Mikkelsen's reference code,
//! byte-identical to it), so a viewer that regenerates tangents itself gets the same frames.
//!
//! The texture coordinates are given to MikkTSpace as `(u, 1 − v)`: glTF's `v` grows downwards
//! in the image, while the normal texture's green channel points up (§3.9.3), and MikkTSpace's
//! bitangent follows `+v`. With glTF's `v` as is, `w` comes out negated: a normal map read with
//! those frames has its green channel flipped (KhronosGroup/glTF-Sample-Models#174; Blender's
//! exporter and the Khronos sample viewer use the flipped `v`). Invisible on one regular UV
//! layout with symmetric detail, it showed as shading steps across every seam of a generated
//! atlas, whose charts are turned differently.
//!
//! Inputs are the primitive's own (mesh-local) vertices: the fitted POSITION, the recomputed
//! NORMAL (unit), and the UV set `normalTexture.texCoord` of its material (0 without one). A
//! vertex MikkTSpace leaves without a frame (only on degenerate faces with no neighbour) gets
//! any unit vector orthogonal to its normal with w = +1, so the attribute stays valid. A
//! primitive without that UV set has no tangent space: its TANGENT is removed instead.

use bevy_mikktspace::{generate_tangents, Geometry, TangentSpace};

use crate::engine::asset::Asset;

/// One primitive's vertices as MikkTSpace sees them, and the frames it writes back.
struct Frames<'a> {
    triangles: &'a [[u32; 3]],
    positions: &'a [[f32; 3]],
    normals: &'a [[f32; 3]],
    uvs: &'a [[f32; 2]],
    out: Vec<Option<[f32; 4]>>,
}

impl Geometry for Frames<'_> {
    fn num_faces(&self) -> usize {
        self.triangles.len()
    }

    fn num_vertices_of_face(&self, _face: usize) -> usize {
        3
    }

    fn position(&self, face: usize, vert: usize) -> [f32; 3] {
        self.positions[self.triangles[face][vert] as usize]
    }

    fn normal(&self, face: usize, vert: usize) -> [f32; 3] {
        self.normals[self.triangles[face][vert] as usize]
    }

    fn tex_coord(&self, face: usize, vert: usize) -> [f32; 2] {
        // glTF's v grows downwards in the image while a normal map's green channel points up
        // (§3.9.3): MikkTSpace, whose bitangent follows +v, is given 1 − v.
        let [u, v] = self.uvs[self.triangles[face][vert] as usize];
        [u, 1.0 - v]
    }

    fn set_tangent(&mut self, tangent_space: Option<TangentSpace>, face: usize, vert: usize) {
        let v = self.triangles[face][vert] as usize;
        if let Some(t) = tangent_space {
            self.out[v] = Some(t.tangent_encoded());
        }
    }
}

/// The UV set a primitive's tangent space follows: its material's normal texture's, else 0.
fn normal_uv_set(asset: &Asset, p: usize) -> usize {
    asset.primitives[p]
        .material
        .and_then(|m| asset.json["materials"][m]["normalTexture"]["texCoord"].as_u64())
        .unwrap_or(0) as usize
}

fn is_unit(v: &[f32]) -> bool {
    let l2: f32 = v.iter().map(|c| c * c).sum();
    l2.is_finite() && (l2 - 1.0).abs() < 1e-3
}

/// A unit vector orthogonal to the unit `n` (+x if `n` is not a usable direction).
fn any_orthogonal(n: [f32; 3]) -> [f32; 3] {
    let a = if n[0].abs() < 0.9 {
        [1.0, 0.0, 0.0]
    } else {
        [0.0, 1.0, 0.0]
    };
    let d = a[0] * n[0] + a[1] * n[1] + a[2] * n[2];
    let t = [a[0] - d * n[0], a[1] - d * n[1], a[2] - d * n[2]];
    let l = (t[0] * t[0] + t[1] * t[1] + t[2] * t[2]).sqrt();
    if l.is_finite() && l > 1e-6 {
        t.map(|c| c / l)
    } else {
        // A zero or non-finite normal (kept from the input on a vertex without a face).
        [1.0, 0.0, 0.0]
    }
}

/// MikkTSpace tangents (xyz unit, w = ±1) of primitive `p` with the given mesh-local positions
/// and unit normals, or `None` if the primitive lacks the UV set its tangents follow.
pub fn mikktspace_tangents(
    asset: &Asset,
    p: usize,
    positions: &[[f32; 3]],
    normals: &[[f32; 3]],
) -> Option<Vec<[f32; 4]>> {
    mikktspace_tangents_in_set(asset, p, normal_uv_set(asset, p), positions, normals)
}

/// As [`mikktspace_tangents`], in UV set `set` (the set a normal texture about to be written will
/// be read through).
pub fn mikktspace_tangents_in_set(
    asset: &Asset,
    p: usize,
    set: usize,
    positions: &[[f32; 3]],
    normals: &[[f32; 3]],
) -> Option<Vec<[f32; 4]>> {
    let prim = &asset.primitives[p];
    let uvs = prim.tex_coords.get(set)?;
    Some(mikktspace_tangents_of(
        &prim.triangles,
        positions,
        normals,
        uvs,
    ))
}

/// MikkTSpace tangents (xyz unit, w = ±1) of the triangles `triangles` over per-vertex
/// `positions`, unit `normals` and `uvs` (a primitive being built, e.g. one whose vertices an
/// atlas split at its seams).
pub fn mikktspace_tangents_of(
    triangles: &[[u32; 3]],
    positions: &[[f32; 3]],
    normals: &[[f32; 3]],
    uvs: &[[f32; 2]],
) -> Vec<[f32; 4]> {
    let mut frames = Frames {
        triangles,
        positions,
        normals,
        uvs,
        out: vec![None; positions.len()],
    };
    // The crate's error type has no variants: generation cannot fail.
    let _ = generate_tangents(&mut frames);
    frames
        .out
        .iter()
        .zip(normals)
        .map(|(t, n)| match t {
            Some(t) if is_unit(&t[..3]) => *t,
            _ => {
                let o = any_orthogonal(*n);
                [o[0], o[1], o[2], 1.0]
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A flat grid in the xy plane facing +z, with u along +x and glTF's v along −y (the image
    /// drawn upright on it): the tangent is +x and the bitangent `cross(n, t) · w` points up the
    /// image, along +y, the direction the normal map's green channel stands for (glTF §3.9.3).
    /// With glTF's v given to MikkTSpace as is, it pointed down.
    #[test]
    fn bitangent_points_up_the_image_as_the_green_channel() {
        let n = 4;
        let mut positions = Vec::new();
        let mut uvs = Vec::new();
        for j in 0..=n {
            for i in 0..=n {
                let (x, y) = (i as f32 / n as f32, j as f32 / n as f32);
                positions.push([x, y, 0.0]);
                uvs.push([x, 1.0 - y]);
            }
        }
        let mut triangles = Vec::new();
        for j in 0..n {
            for i in 0..n {
                let a = (j * (n + 1) + i) as u32;
                let (b, c, d) = (a + 1, a + n as u32 + 1, a + n as u32 + 2);
                triangles.extend([[a, b, d], [a, d, c]]);
            }
        }
        let normals = vec![[0.0, 0.0, 1.0]; positions.len()];
        for t in mikktspace_tangents_of(&triangles, &positions, &normals, &uvs) {
            assert!((t[0] - 1.0).abs() < 1e-5, "tangent {t:?}");
            // cross((0, 0, 1), (1, 0, 0)) = (0, 1, 0): w = +1 gives +y.
            assert_eq!(t[3], 1.0, "bitangent points down the image: {t:?}");
        }
    }
}
