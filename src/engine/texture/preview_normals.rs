//! Normal maps in the turntable preview ([`super::preview`]; issue 16: "base colour and, where a
//! method outputs one, the normal map lit").
//!
//! A primitive whose material has a `normalTexture` (glTF 2.0 §3.9.3) is lit with the normal the
//! texture encodes in tangent space: texel `c` (raw bytes, linear, not sRGB) gives
//! `t = (2c/255 − 1) · (scale, scale, 1)`, and the shading normal is
//! `normalize(t.x · T + t.y · B + t.z · N)` (§3.9.3: "X [-1 to 1] … Y … Z", scaled in X and Y).
//!
//! Deviations, and why:
//! - The tangent frame is generated per triangle from its world positions and UVs (the
//!   derivative of position along `u` for T; for B the derivative along `−v`, because glTF's
//!   `v` grows downwards in the image while the green channel points up), then made orthonormal
//!   with the flat face normal N, which is the normal the preview shades with. The file's
//!   `TANGENT` attribute is not read (the asset model does not load it); per-triangle frames
//!   match MikkTSpace's per-vertex frames on a flat or evenly mapped surface and differ by the
//!   interpolation of vertex frames on curved ones, which a 256 px preview does not show.
//! - A triangle whose UVs are degenerate (zero area in UV space) is lit with its face normal.
//! - Normal maps of more than [`MAX_NORMAL_MAP_PIXELS`] texels, or that do not decode, are left
//!   out with a note (the preview is a dashboard tile; decoding an 8K map for it is not worth
//!   256 MB of memory on a worker).
//! - `KHR_texture_transform` on the normal texture is applied (offset, rotation, scale and its
//!   texCoord override), as for the base colour.

use std::sync::Arc;

use crate::engine::asset::images::{decode_rgba8, sniff};
use crate::engine::asset::{Asset, DecodedImage, IngestLimits, Sampler, UvTransform, Wrap};
use crate::engine::math::{cross, dot, normalize, scale, sub};
use crate::engine::texture::sample::apply_uv_transform;

/// Largest normal map decoded for a preview (4096 × 4096 texels, 64 MiB of RGBA8).
pub const MAX_NORMAL_MAP_PIXELS: u64 = 1 << 24;

/// One primitive's normal texture.
struct Bound {
    image: Arc<DecodedImage>,
    sampler: Sampler,
    /// The UV set (after the texture transform's override).
    set: usize,
    scale: f32,
    transform: Option<UvTransform>,
}

/// A triangle's orthonormal tangent frame (world space).
#[derive(Clone, Copy, Debug)]
pub struct Frame {
    t: [f32; 3],
    b: [f32; 3],
    n: [f32; 3],
}

/// The normal textures of an asset's primitives, decoded once per image.
pub struct NormalMaps {
    by_primitive: Vec<Option<Bound>>,
}

fn parse_transform(info: &serde_json::Value) -> (Option<UvTransform>, Option<usize>) {
    let t = &info["extensions"]["KHR_texture_transform"];
    if !t.is_object() {
        return (None, None);
    }
    let pair = |v: &serde_json::Value, d: [f32; 2]| {
        [
            v[0].as_f64().map_or(d[0], |x| x as f32),
            v[1].as_f64().map_or(d[1], |x| x as f32),
        ]
    };
    let tr = UvTransform {
        offset: pair(&t["offset"], [0.0, 0.0]),
        rotation: t["rotation"].as_f64().map_or(0.0, |x| x as f32),
        scale: pair(&t["scale"], [1.0, 1.0]),
    };
    (Some(tr), t["texCoord"].as_u64().map(|x| x as usize))
}

impl NormalMaps {
    /// Resolves and decodes the normal texture of every primitive; returns the maps and one
    /// note per normal texture left out.
    pub fn new(asset: &Asset) -> (Self, Vec<String>) {
        let mut notes = Vec::new();
        let mut decoded: Vec<Option<Option<Arc<DecodedImage>>>> = vec![None; asset.images.len()];
        let limits = IngestLimits::default();
        let by_primitive = asset
            .primitives
            .iter()
            .map(|prim| {
                let m = prim.material?;
                let info = &asset.json["materials"][m]["normalTexture"];
                let texture = asset.textures.get(info["index"].as_u64()? as usize)?;
                let image = texture.image?;
                let source = asset.images.get(image)?;
                let slot = decoded.get_mut(image)?;
                let pixels = slot
                    .get_or_insert_with(|| {
                        let texels = source.width as u64 * source.height as u64;
                        if texels > MAX_NORMAL_MAP_PIXELS {
                            notes.push(format!(
                                "normal map image {image} ({} × {}) is larger than {MAX_NORMAL_MAP_PIXELS} texels; not lit",
                                source.width, source.height
                            ));
                            return None;
                        }
                        let decoded = sniff(&source.bytes)
                            .ok_or_else(|| "unrecognized image format".to_string())
                            .and_then(|f| {
                                decode_rgba8(image, &source.bytes, f, &limits)
                                    .map_err(|e| e.to_string())
                            });
                        match decoded {
                            Ok(d) => Some(Arc::new(d)),
                            Err(e) => {
                                notes.push(format!("normal map image {image}: {e}; not lit"));
                                None
                            }
                        }
                    })
                    .clone()?;
                let (transform, set_override) = parse_transform(info);
                let set = set_override.unwrap_or(info["texCoord"].as_u64().unwrap_or(0) as usize);
                prim.tex_coords.get(set)?;
                Some(Bound {
                    image: pixels,
                    sampler: texture.sampler,
                    set,
                    scale: info["scale"].as_f64().map_or(1.0, |s| s as f32),
                    transform,
                })
            })
            .collect();
        (Self { by_primitive }, notes)
    }

    /// No normal maps (every triangle lit with its face normal).
    pub fn empty() -> Self {
        Self {
            by_primitive: Vec::new(),
        }
    }

    /// Whether any primitive has a usable normal map.
    pub fn any(&self) -> bool {
        self.by_primitive.iter().any(Option::is_some)
    }

    fn uvs(&self, asset: &Asset, primitive: usize, triangle: usize) -> Option<[[f32; 2]; 3]> {
        let bound = self.by_primitive.get(primitive)?.as_ref()?;
        let prim = &asset.primitives[primitive];
        let uvs = prim.tex_coords.get(bound.set)?;
        let tri = prim.triangles.get(triangle)?;
        let mut out = [[0.0; 2]; 3];
        for k in 0..3 {
            let uv = *uvs.get(tri[k] as usize)?;
            out[k] = match &bound.transform {
                Some(t) => apply_uv_transform(t, uv),
                None => uv,
            };
        }
        Some(out)
    }

    /// The tangent frame of a triangle with world corners `p` and face normal `n`, or `None`
    /// when its primitive has no normal map or its UVs are degenerate.
    pub fn frame(
        &self,
        asset: &Asset,
        primitive: usize,
        triangle: usize,
        p: &[[f32; 3]; 3],
        n: [f32; 3],
    ) -> Option<Frame> {
        let uv = self.uvs(asset, primitive, triangle)?;
        let (e1, e2) = (sub(p[1], p[0]), sub(p[2], p[0]));
        let (du1, dv1) = (uv[1][0] - uv[0][0], uv[1][1] - uv[0][1]);
        let (du2, dv2) = (uv[2][0] - uv[0][0], uv[2][1] - uv[0][1]);
        let det = du1 * dv2 - du2 * dv1;
        if det.abs() < 1e-12 || !det.is_finite() || dot(n, n) < 0.5 {
            return None;
        }
        // dP/du and dP/dv by Cramer's rule.
        let dpdu = scale(sub(scale(e1, dv2), scale(e2, dv1)), 1.0 / det);
        let dpdv = scale(sub(scale(e2, du1), scale(e1, du2)), 1.0 / det);
        let t = normalize(sub(dpdu, scale(n, dot(n, dpdu))));
        if dot(t, t) < 0.5 {
            return None;
        }
        // Green points up in the image, i.e. along −v.
        let up = scale(dpdv, -1.0);
        let b = cross(n, t);
        let b = if dot(b, up) < 0.0 { scale(b, -1.0) } else { b };
        Some(Frame { t, b, n })
    }

    /// The shading normal at barycentric `bary` of a triangle with frame `frame`.
    pub fn normal(
        &self,
        asset: &Asset,
        primitive: usize,
        triangle: usize,
        bary: [f32; 3],
        frame: &Frame,
    ) -> [f32; 3] {
        let Some(bound) = self.by_primitive.get(primitive).and_then(Option::as_ref) else {
            return frame.n;
        };
        let Some(uv) = self.uvs(asset, primitive, triangle) else {
            return frame.n;
        };
        let at = [0, 1].map(|k| uv[0][k] * bary[0] + uv[1][k] * bary[1] + uv[2][k] * bary[2]);
        let c = sample_raw(&bound.image, &bound.sampler, at);
        let x = (2.0 * c[0] - 1.0) * bound.scale;
        let y = (2.0 * c[1] - 1.0) * bound.scale;
        let z = 2.0 * c[2] - 1.0;
        let v = [0, 1, 2].map(|k| x * frame.t[k] + y * frame.b[k] + z * frame.n[k]);
        let v = normalize(v);
        if dot(v, v) < 0.5 {
            frame.n
        } else {
            v
        }
    }
}

fn wrap(i: i64, n: i64, mode: Wrap) -> usize {
    let i = match mode {
        Wrap::Repeat => i.rem_euclid(n),
        Wrap::ClampToEdge => i.clamp(0, n - 1),
        Wrap::MirroredRepeat => {
            let m = i.rem_euclid(2 * n);
            if m < n {
                m
            } else {
                2 * n - 1 - m
            }
        }
    };
    i as usize
}

/// Bilinear (or nearest) sample of raw texel values in [0, 1], no colour decoding.
fn sample_raw(img: &DecodedImage, sampler: &Sampler, uv: [f32; 2]) -> [f32; 3] {
    let (w, h) = (img.width as i64, img.height as i64);
    if w == 0 || h == 0 || img.pixels.len() as u64 != (w as u64) * (h as u64) {
        return [0.5, 0.5, 1.0];
    }
    let uv = uv.map(|x| if x.is_finite() { x } else { 0.0 });
    let texel = |x: i64, y: i64| {
        let p = img.pixels[wrap(y, h, sampler.wrap_t) * w as usize + wrap(x, w, sampler.wrap_s)];
        [p[0], p[1], p[2]].map(|c| c as f32 / 255.0)
    };
    let fx = uv[0] * w as f32 - 0.5;
    let fy = uv[1] * h as f32 - 0.5;
    if sampler.nearest {
        return texel((fx + 0.5).floor() as i64, (fy + 0.5).floor() as i64);
    }
    let (x0, y0) = (fx.floor() as i64, fy.floor() as i64);
    let (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
    let (a, b, c, d) = (
        texel(x0, y0),
        texel(x0 + 1, y0),
        texel(x0, y0 + 1),
        texel(x0 + 1, y0 + 1),
    );
    [0, 1, 2].map(|k| {
        (a[k] * (1.0 - tx) + b[k] * tx) * (1.0 - ty) + (c[k] * (1.0 - tx) + d[k] * tx) * ty
    })
}
