//! A source whose detail comes as a displacement texture (issue 13, "Interface": "a source whose
//! material carries a displacement texture in `materials[i].extras.retex_displacement =
//! {index, texCoord, scale, offset}`"), the form `detail` itself writes. The paper's source is
//! exactly this (§3: a base mesh with a detail map D); the source mesh is then the base.
//!
//! The texture is decoded at full precision (16-bit grey stays 16-bit; colour images use their
//! first channel), its header checked against the default ingest limits (the method does not see
//! the job's, which are never larger). A level vertex's displacement is the texture, bilinear
//! with REPEAT wrap (`d = offset + scale · value`), at the source point closest to it (BVH, then
//! the triangle's UVs in `texCoord`); points on primitives whose material has no such texture get
//! no value (counted as missing, 0).
//!
//! Written by hand: a bilinear lookup and a UV interpolation.

use crate::engine::asset::images::checked_dimensions;
use crate::engine::asset::{Asset, IngestLimits};
use crate::engine::mesh::Surface;
use crate::engine::methods::MethodError;
use crate::engine::spatial::Bvh;

/// The material extra read (and written by [`super::outputs`]).
pub use super::outputs::DISPLACEMENT_KEY;

/// One material's displacement texture.
#[derive(Clone, Debug)]
pub struct DisplacementMap {
    width: usize,
    height: usize,
    /// Values in [0, 1], row-major, top row first.
    texels: Vec<f32>,
    tex_coord: usize,
    scale: f64,
    offset: f64,
}

impl DisplacementMap {
    /// Bilinear value at `uv` (REPEAT), as displacement.
    fn sample(&self, uv: [f32; 2]) -> f64 {
        let (w, h) = (self.width as f64, self.height as f64);
        let x = uv[0] as f64 * w - 0.5;
        let y = uv[1] as f64 * h - 0.5;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let at = |i: f64, j: f64| {
            let i = (i as i64).rem_euclid(self.width as i64) as usize;
            let j = (j as i64).rem_euclid(self.height as i64) as usize;
            self.texels[j * self.width + i] as f64
        };
        let top = at(x0, y0) * (1.0 - fx) + at(x0 + 1.0, y0) * fx;
        let bottom = at(x0, y0 + 1.0) * (1.0 - fx) + at(x0 + 1.0, y0 + 1.0) * fx;
        self.offset + self.scale * (top * (1.0 - fy) + bottom * fy)
    }
}

fn unusable(message: String) -> MethodError {
    MethodError::UnusableInput {
        field: Some("source".into()),
        kind: "unusable-input",
        message,
    }
}

fn decode(
    asset: &Asset,
    m: usize,
    extra: &serde_json::Value,
) -> Result<DisplacementMap, MethodError> {
    let what = format!("source material {m}: extras.{DISPLACEMENT_KEY}");
    let texture = extra["index"]
        .as_u64()
        .ok_or_else(|| unusable(format!("{what}.index is missing or not an integer")))?;
    let number = |k: &str, default: f64| match &extra[k] {
        serde_json::Value::Null => Ok(default),
        v => v
            .as_f64()
            .filter(|x| x.is_finite())
            .ok_or_else(|| unusable(format!("{what}.{k} is not a finite number"))),
    };
    let (scale, offset) = (number("scale", 1.0)?, number("offset", 0.0)?);
    let tex_coord = extra["texCoord"].as_u64().unwrap_or(0) as usize;
    let image = asset
        .textures
        .get(texture as usize)
        .and_then(|t| t.image)
        .and_then(|i| asset.images.get(i).map(|img| (i, img)))
        .ok_or_else(|| {
            unusable(format!(
                "{what}.index {texture} names no texture with an image"
            ))
        })?;
    let (index, source) = image;
    checked_dimensions(index, &source.bytes, &IngestLimits::default())
        .map_err(|e| unusable(format!("{what}: {e}")))?;
    let decoded = image::load_from_memory(&source.bytes)
        .map_err(|e| unusable(format!("{what}: image {index} does not decode: {e}")))?
        .to_luma16();
    Ok(DisplacementMap {
        width: decoded.width() as usize,
        height: decoded.height() as usize,
        texels: decoded.pixels().map(|p| p[0] as f32 / 65535.0).collect(),
        tex_coord,
        scale,
        offset,
    })
}

/// The displacement maps of the source's materials (index = material), or `None` when no
/// material carries one.
///
/// # Errors
/// [`MethodError::UnusableInput`] naming the material for a malformed extra or image.
pub fn read_maps(asset: &Asset) -> Result<Option<Vec<Option<DisplacementMap>>>, MethodError> {
    let materials = asset.json["materials"]
        .as_array()
        .cloned()
        .unwrap_or_default();
    let mut any = false;
    let mut maps = Vec::with_capacity(materials.len());
    for (m, mat) in materials.iter().enumerate() {
        let extra = &mat["extras"][DISPLACEMENT_KEY];
        if extra.is_null() {
            maps.push(None);
        } else {
            maps.push(Some(decode(asset, m, extra)?));
            any = true;
        }
    }
    Ok(any.then_some(maps))
}

/// The source surface with its maps, answering "what displacement is closest to `p`".
pub struct TextureDetail<'a> {
    asset: &'a Asset,
    surface: &'a Surface,
    bvh: Bvh,
    maps: Vec<Option<DisplacementMap>>,
    /// Factor on the map's values (the source's scale, `params.match_scale`).
    value_scale: f64,
}

impl<'a> TextureDetail<'a> {
    /// `surface` is the source's (welded, possibly scaled by `value_scale`).
    pub fn new(
        asset: &'a Asset,
        surface: &'a Surface,
        maps: Vec<Option<DisplacementMap>>,
        value_scale: f64,
    ) -> Self {
        Self {
            asset,
            surface,
            bvh: Bvh::build(&surface.positions, &surface.faces),
            maps,
            value_scale,
        }
    }

    /// The mean world size of a map texel over the faces whose material has a map
    /// (`√(area / (uv area · width · height))`); infinite without one.
    pub fn texel_size(&self) -> f64 {
        let (mut area, mut texels) = (0.0, 0.0);
        for f in 0..self.surface.face_count() {
            let Some((prim, tri, _)) = self.surface.primitive_point(self.asset, f, [1.0 / 3.0; 3])
            else {
                continue;
            };
            let primitive = &self.asset.primitives[prim];
            let Some(map) = primitive
                .material
                .and_then(|m| self.maps.get(m))
                .and_then(|m| m.as_ref())
            else {
                continue;
            };
            let Some(uvs) = primitive.tex_coords.get(map.tex_coord) else {
                continue;
            };
            let [a, b, c] = primitive.triangles[tri].map(|v| uvs[v as usize].map(|x| x as f64));
            let uv = 0.5 * ((b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1])).abs();
            texels += uv * (map.width * map.height) as f64;
            area += self.surface.face_area(f) as f64;
        }
        match texels > 0.0 {
            true => (area / texels).sqrt(),
            false => f64::INFINITY,
        }
    }

    /// The displacement at the source point closest to `p`, if its material has a map.
    pub fn at(&self, p: [f32; 3]) -> Option<f64> {
        let hit = self.bvh.closest_point(p, f32::INFINITY)?;
        let (prim, tri, b) =
            self.surface
                .primitive_point(self.asset, hit.face as usize, hit.bary)?;
        let primitive = &self.asset.primitives[prim];
        let map = self.maps.get(primitive.material?)?.as_ref()?;
        let uvs = primitive.tex_coords.get(map.tex_coord)?;
        let t = primitive.triangles[tri];
        let uv = [0, 1].map(|c| (0..3).map(|k| b[k] * uvs[t[k] as usize][c]).sum::<f32>());
        Some(self.value_scale * map.sample(uv))
    }
}
