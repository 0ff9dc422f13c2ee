//! Base-color sampling exactly as a glTF 2.0 viewer shows it: `KHR_texture_transform`, sampler
//! wrap modes, bilinear (or nearest) filtering in linear space, and the product
//! baseColorFactor × texture × COLOR_0 (glTF 2.0 spec §3.9.2, "metallic-roughness material").
//!
//! Conventions: UV (0,0) is the top-left of the image, v grows downwards; texel `i` has its center
//! at `(i + 0.5) / size`. sRGB texels are decoded to linear *before* they are blended (what a GPU
//! does with an `SRGB8_ALPHA8` texture); alpha is linear. All returned colors are linear RGBA.
//!
//! Texture transform: glTF's `KHR_texture_transform` README prints its rotation in GLSL, where
//! `mat3(...)` is column-major; taken literally that listing rotates the wrong way in glTF's
//! v-down UV space (KhronosGroup/glTF issue #1563). The extension's own example ("offset [0, 1],
//! rotation π/2, scale 0.5 uses only the lower-left quadrant, rotated") and every shipping
//! implementation (Khronos sample viewer, Babylon.js, three.js, Blender IO) use
//! `u' = cos·u + sin·v`, `v' = −sin·u + cos·v`, i.e. the row-major matrix
//! `[[cos, sin], [−sin, cos]]`; [`apply_uv_transform`] does the same, in the order T·R·S.
//!
//! Sampling is hand written (a few lines): it must match glTF sampler semantics exactly, work on
//! our [`DecodedImage`], and must not allocate (it runs millions of times per bake).

use crate::engine::asset::model::{Asset, DecodedImage, Sampler, UvTransform, Wrap};

use super::color::srgb8_table;

/// Applies `KHR_texture_transform`: `uv' = T(offset) · R(rotation) · S(scale) · uv`, with the
/// rotation `[[cos, sin], [−sin, cos]]` (row-major, see the module docs).
#[inline]
pub fn apply_uv_transform(t: &UvTransform, uv: [f32; 2]) -> [f32; 2] {
    let x = uv[0] * t.scale[0];
    let y = uv[1] * t.scale[1];
    if t.rotation == 0.0 {
        return [x + t.offset[0], y + t.offset[1]];
    }
    let (s, c) = t.rotation.sin_cos();
    [c * x + s * y + t.offset[0], -s * x + c * y + t.offset[1]]
}

/// `floor` for finite values of moderate size, as a truncating cast and a fix-up (the baseline
/// x86-64 target has no rounding instruction, so `f32::floor` is a library call).
#[inline(always)]
fn floor_i64(x: f32) -> i64 {
    let t = x as i64;
    if (t as f32) > x {
        t - 1
    } else {
        t
    }
}

/// Maps an integer texel index onto `[0, size)` with a glTF wrap mode.
#[inline]
fn wrap_index(i: i64, size: i64, wrap: Wrap) -> usize {
    if (0..size).contains(&i) {
        return i as usize;
    }
    let r = match wrap {
        Wrap::Repeat => i.rem_euclid(size),
        Wrap::ClampToEdge => i.clamp(0, size - 1),
        Wrap::MirroredRepeat => {
            let m = i.rem_euclid(2 * size);
            if m >= size {
                2 * size - 1 - m
            } else {
                m
            }
        }
    };
    r as usize
}

/// Reduces a coordinate that is far outside [0, 1] without changing what it samples, so the
/// texel arithmetic below stays exact-ish and cannot overflow. Non-finite values become 0.
#[inline]
fn sanitize(c: f32, wrap: Wrap) -> f32 {
    if !c.is_finite() {
        return 0.0;
    }
    if (-4.0..=4.0).contains(&c) {
        return c;
    }
    match wrap {
        Wrap::Repeat => c - c.floor(),
        // Period 2; keep the phase.
        Wrap::MirroredRepeat => c - 2.0 * (c * 0.5).floor(),
        Wrap::ClampToEdge => c.clamp(-1.0, 2.0),
    }
}

/// Decodes one RGBA8 sRGB texel to linear RGBA.
#[inline]
fn texel(table: &[f32; 256], p: [u8; 4]) -> [f32; 4] {
    [
        table[p[0] as usize],
        table[p[1] as usize],
        table[p[2] as usize],
        p[3] as f32 * (1.0 / 255.0),
    ]
}

/// Samples `img` at `uv` with `sampler`'s wrap modes and filter.
///
/// Bilinear: the four texels around `(u·w − 0.5, v·h − 0.5)`, each wrapped per axis
/// (`REPEAT`, `MIRRORED_REPEAT`, `CLAMP_TO_EDGE`), decoded sRGB→linear and then blended.
/// Nearest (`sampler.nearest`): the texel `floor(u·w), floor(v·h)`, wrapped. Non-finite UVs are
/// treated as 0. An image whose pixel count does not match `width × height` (or is empty) returns
/// opaque white, the neutral value of the base-color product. Returns linear RGBA.
#[inline]
pub fn sample_image(img: &DecodedImage, sampler: &Sampler, uv: [f32; 2]) -> [f32; 4] {
    let (w, h) = (img.width as i64, img.height as i64);
    if w == 0 || h == 0 || img.pixels.len() as u64 != (w as u64) * (h as u64) {
        return [1.0; 4];
    }
    let table = srgb8_table();
    let u = sanitize(uv[0], sampler.wrap_s);
    let v = sanitize(uv[1], sampler.wrap_t);
    if sampler.nearest {
        let x = wrap_index(floor_i64(u * w as f32), w, sampler.wrap_s);
        let y = wrap_index(floor_i64(v * h as f32), h, sampler.wrap_t);
        return texel(table, img.pixels[y * w as usize + x]);
    }
    let fx = u * w as f32 - 0.5;
    let fy = v * h as f32 - 0.5;
    let (x0, y0) = (floor_i64(fx), floor_i64(fy));
    let tx = fx - x0 as f32;
    let ty = fy - y0 as f32;
    let xa = wrap_index(x0, w, sampler.wrap_s);
    let xb = wrap_index(x0 + 1, w, sampler.wrap_s);
    let ya = wrap_index(y0, h, sampler.wrap_t) * w as usize;
    let yb = wrap_index(y0 + 1, h, sampler.wrap_t) * w as usize;
    let p00 = texel(table, img.pixels[ya + xa]);
    let p10 = texel(table, img.pixels[ya + xb]);
    let p01 = texel(table, img.pixels[yb + xa]);
    let p11 = texel(table, img.pixels[yb + xb]);
    let w00 = (1.0 - tx) * (1.0 - ty);
    let w10 = tx * (1.0 - ty);
    let w01 = (1.0 - tx) * ty;
    let w11 = tx * ty;
    let mut out = [0.0f32; 4];
    for k in 0..4 {
        out[k] = p00[k] * w00 + p10[k] * w10 + p01[k] * w01 + p11[k] * w11;
    }
    out
}

/// What [`MaterialSampler`] resolved for one primitive.
#[derive(Clone, Copy, Debug)]
struct PrimitiveShading<'a> {
    factor: [f32; 4],
    /// The base-color texture, when it resolves to decoded pixels and the UV set exists.
    texture: Option<BoundTexture<'a>>,
    colors: Option<&'a [[f32; 4]]>,
}

#[derive(Clone, Copy, Debug)]
struct BoundTexture<'a> {
    image: &'a DecodedImage,
    sampler: Sampler,
    uvs: &'a [[f32; 2]],
    transform: Option<UvTransform>,
}

/// Evaluates the base color of surface points of an [`Asset`], exactly as a glTF viewer shows it:
/// `baseColorFactor × texture(uv) × COLOR_0`, all linear RGBA.
///
/// Everything that can be resolved per primitive (material, texture, image, UV set) is resolved
/// once in [`MaterialSampler::new`]; [`MaterialSampler::base_color`] does no allocation.
///
/// Fallbacks (never a panic):
/// * a primitive without material, or whose material index is out of range, uses the glTF
///   default material (factor `[1, 1, 1, 1]`, no texture);
/// * a missing texture, texture without image, image out of range or without decoded pixels, or a
///   missing `TEXCOORD_n` set makes the texture term 1;
/// * missing COLOR_0 makes the color term 1;
/// * `primitive` out of range → opaque white `[1, 1, 1, 1]`;
/// * `triangle` out of range → the material factor alone (texture and color terms 1);
/// * a vertex index beyond the UV (or color) array → that term is 1.
///
/// Barycentrics are used as given (they are expected to sum to 1; they are not renormalized).
#[derive(Clone, Debug)]
pub struct MaterialSampler<'a> {
    asset: &'a Asset,
    primitives: Vec<PrimitiveShading<'a>>,
}

impl<'a> MaterialSampler<'a> {
    /// Resolves materials, textures, images and UV sets of every primitive of `asset`.
    pub fn new(asset: &'a Asset) -> Self {
        let primitives = asset
            .primitives
            .iter()
            .map(|prim| {
                let material = prim.material.and_then(|m| asset.materials.get(m));
                let factor = material.map_or([1.0; 4], |m| m.base_color_factor);
                let texture = material.and_then(|m| m.base_color_texture).and_then(|tr| {
                    let tex = asset.textures.get(tr.texture)?;
                    let image = asset.images.get(tex.image?)?.decoded.as_deref()?;
                    let uvs = prim.tex_coords.get(tr.tex_coord as usize)?;
                    Some(BoundTexture {
                        image,
                        sampler: tex.sampler,
                        uvs: uvs.as_slice(),
                        transform: tr.transform,
                    })
                });
                PrimitiveShading {
                    factor,
                    texture,
                    colors: prim.colors.as_deref(),
                }
            })
            .collect();
        Self { asset, primitives }
    }

    /// The asset this sampler reads.
    pub fn asset(&self) -> &'a Asset {
        self.asset
    }

    /// The UV (after the texture transform) at which the base-color texture of `primitive` is read
    /// at `(triangle, bary)`, or `None` when that primitive has no usable base-color texture.
    pub fn texture_uv(
        &self,
        primitive: usize,
        triangle: usize,
        bary: [f32; 3],
    ) -> Option<[f32; 2]> {
        let shading = self.primitives.get(primitive)?;
        let tex = shading.texture.as_ref()?;
        let tri = self.asset.primitives[primitive].triangles.get(triangle)?;
        let uv = interpolate(tex.uvs, tri, bary)?;
        Some(match &tex.transform {
            Some(t) => apply_uv_transform(t, uv),
            None => uv,
        })
    }

    /// Linear RGBA base color at barycentric `bary` of triangle `triangle` of primitive
    /// `primitive` (indices into [`Asset::primitives`] and [`crate::engine::asset::model::Primitive::triangles`]).
    pub fn base_color(&self, primitive: usize, triangle: usize, bary: [f32; 3]) -> [f32; 4] {
        let Some(shading) = self.primitives.get(primitive) else {
            return [1.0; 4];
        };
        let mut out = shading.factor;
        let Some(tri) = self.asset.primitives[primitive].triangles.get(triangle) else {
            return out;
        };
        if let Some(tex) = &shading.texture {
            if let Some(uv) = interpolate(tex.uvs, tri, bary) {
                let uv = match &tex.transform {
                    Some(t) => apply_uv_transform(t, uv),
                    None => uv,
                };
                let t = sample_image(tex.image, &tex.sampler, uv);
                for k in 0..4 {
                    out[k] *= t[k];
                }
            }
        }
        if let Some(colors) = shading.colors {
            if let Some(c) = interpolate(colors, tri, bary) {
                for k in 0..4 {
                    out[k] *= c[k];
                }
            }
        }
        out
    }
}

/// Barycentric interpolation of a per-vertex attribute; `None` if an index is out of range.
#[inline]
fn interpolate<const N: usize>(
    values: &[[f32; N]],
    tri: &[u32; 3],
    bary: [f32; 3],
) -> Option<[f32; N]> {
    let a = values.get(tri[0] as usize)?;
    let b = values.get(tri[1] as usize)?;
    let c = values.get(tri[2] as usize)?;
    let mut out = [0.0f32; N];
    for k in 0..N {
        out[k] = a[k] * bary[0] + b[k] * bary[1] + c[k] * bary[2];
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::asset::model::{
        ImageSource, Material, Primitive, Texture, TextureRef, TriangleMode,
    };
    use crate::engine::texture::color::srgb8_to_linear;
    use std::f32::consts::FRAC_PI_2;
    use std::sync::Arc;

    fn close(a: [f32; 2], b: [f32; 2]) -> bool {
        (a[0] - b[0]).abs() < 1e-5 && (a[1] - b[1]).abs() < 1e-5
    }

    #[test]
    fn identity_transform_is_identity() {
        let t = UvTransform::default();
        for uv in [[0.0, 0.0], [0.3, 0.7], [-2.5, 13.25]] {
            assert_eq!(apply_uv_transform(&t, uv), uv);
        }
    }

    /// The extension's example: offset [0, 1], rotation π/2, scale 0.5 maps the unit square onto
    /// the lower-left quadrant of the image (v down: v in [0.5, 1]), rotated.
    #[test]
    fn spec_example_maps_unit_square_to_lower_left_quadrant() {
        let t = UvTransform {
            offset: [0.0, 1.0],
            rotation: FRAC_PI_2,
            scale: [0.5, 0.5],
        };
        assert!(close(apply_uv_transform(&t, [0.0, 0.0]), [0.0, 1.0]));
        assert!(close(apply_uv_transform(&t, [1.0, 0.0]), [0.0, 0.5]));
        assert!(close(apply_uv_transform(&t, [0.0, 1.0]), [0.5, 1.0]));
        assert!(close(apply_uv_transform(&t, [1.0, 1.0]), [0.5, 0.5]));
        assert!(close(apply_uv_transform(&t, [0.5, 0.5]), [0.25, 0.75]));
        for i in 0..=10 {
            for j in 0..=10 {
                let p = apply_uv_transform(&t, [i as f32 / 10.0, j as f32 / 10.0]);
                assert!(
                    (-1e-6..=0.5 + 1e-6).contains(&p[0])
                        && (0.5 - 1e-6..=1.0 + 1e-6).contains(&p[1])
                );
            }
        }
        // The second example: offset [0, 1], scale [1, −1] flips v.
        let flip = UvTransform {
            offset: [0.0, 1.0],
            rotation: 0.0,
            scale: [1.0, -1.0],
        };
        assert!(close(apply_uv_transform(&flip, [0.25, 0.2]), [0.25, 0.8]));
    }

    #[test]
    fn transform_order_is_translate_rotate_scale() {
        // Scale first, then rotate, then offset: with scale [2, 1] and a quarter turn, u → −v'.
        let t = UvTransform {
            offset: [0.1, 0.2],
            rotation: FRAC_PI_2,
            scale: [2.0, 1.0],
        };
        // S: (0.5, 0.25) → (1.0, 0.25); R: (0.25, −1.0); T: (0.35, −0.8).
        assert!(close(apply_uv_transform(&t, [0.5, 0.25]), [0.35, -0.8]));
    }

    fn gray_image(values: &[u8], w: u32, h: u32) -> DecodedImage {
        DecodedImage {
            width: w,
            height: h,
            pixels: values.iter().map(|&g| [g, g, g, 255]).collect(),
        }
    }

    fn sampler(wrap: Wrap) -> Sampler {
        Sampler {
            wrap_s: wrap,
            wrap_t: wrap,
            nearest: false,
        }
    }

    fn assert_rgba_close(a: [f32; 4], b: [f32; 4], tol: f32) {
        for k in 0..4 {
            assert!((a[k] - b[k]).abs() <= tol, "{a:?} vs {b:?}");
        }
    }

    #[test]
    fn wrap_modes() {
        // 4x1 ramp: distinct texels so that wrong wrapping shows.
        let img = gray_image(&[10, 80, 160, 250], 4, 1);
        let rep = sampler(Wrap::Repeat);
        let mir = sampler(Wrap::MirroredRepeat);
        let clamp = sampler(Wrap::ClampToEdge);
        for v in [0.5f32, 0.1] {
            assert_rgba_close(
                sample_image(&img, &rep, [1.25, v]),
                sample_image(&img, &rep, [0.25, v]),
                1e-6,
            );
            assert_rgba_close(
                sample_image(&img, &rep, [-0.6, v]),
                sample_image(&img, &rep, [0.4, v]),
                1e-6,
            );
            assert_rgba_close(
                sample_image(&img, &mir, [1.25, v]),
                sample_image(&img, &mir, [0.75, v]),
                1e-6,
            );
            assert_rgba_close(
                sample_image(&img, &mir, [-0.3, v]),
                sample_image(&img, &mir, [0.3, v]),
                1e-6,
            );
            assert_rgba_close(
                sample_image(&img, &mir, [2.3, v]),
                sample_image(&img, &mir, [0.3, v]),
                1e-6,
            );
        }
        let edge = [
            srgb8_to_linear(250),
            srgb8_to_linear(250),
            srgb8_to_linear(250),
            1.0,
        ];
        assert_rgba_close(sample_image(&img, &clamp, [1.7, 0.5]), edge, 1e-6);
        assert_rgba_close(sample_image(&img, &clamp, [0.99, 0.5]), edge, 1e-6);
        let first = [
            srgb8_to_linear(10),
            srgb8_to_linear(10),
            srgb8_to_linear(10),
            1.0,
        ];
        assert_rgba_close(sample_image(&img, &clamp, [-3.0, 0.5]), first, 1e-6);
        // Repeat at the left edge blends the first and the last texel (REPEAT taps wrap).
        let l = sample_image(&img, &rep, [0.0, 0.5]);
        let expect = 0.5 * (srgb8_to_linear(10) + srgb8_to_linear(250));
        assert!((l[0] - expect).abs() < 1e-6);
        // Far away coordinates still sample like their fractional part.
        assert_rgba_close(
            sample_image(&img, &rep, [1000.25, 0.5]),
            sample_image(&img, &rep, [0.25, 0.5]),
            1e-3,
        );
        // Non-finite UVs do not panic.
        let _ = sample_image(&img, &rep, [f32::NAN, f32::INFINITY]);
    }

    #[test]
    fn bilinear_blends_in_linear_space() {
        let img = gray_image(&[0, 255], 2, 1);
        let s = sampler(Wrap::ClampToEdge);
        // Halfway between the two texel centers (0.25 and 0.75).
        let c = sample_image(&img, &s, [0.5, 0.5]);
        assert!(
            (c[0] - 0.5).abs() < 1e-6,
            "linear 0.5 expected, got {}",
            c[0]
        );
        assert!((c[3] - 1.0).abs() < 1e-6);
        // Not the sRGB midpoint (which would decode to ~0.214).
        assert!((c[0] - 0.214).abs() > 0.2);
        // At the texel centers the exact texel values.
        assert!(sample_image(&img, &s, [0.25, 0.5])[0].abs() < 1e-7);
        assert!((sample_image(&img, &s, [0.75, 0.5])[0] - 1.0).abs() < 1e-7);
        // A quarter of the way.
        assert!((sample_image(&img, &s, [0.375, 0.5])[0] - 0.25).abs() < 1e-6);
    }

    #[test]
    fn nearest_and_alpha_is_linear() {
        let img = DecodedImage {
            width: 2,
            height: 1,
            pixels: vec![[255, 0, 0, 0], [0, 0, 255, 255]],
        };
        let mut s = sampler(Wrap::ClampToEdge);
        let c = sample_image(&img, &s, [0.5, 0.5]);
        assert!((c[3] - 0.5).abs() < 1e-6, "alpha blends linearly: {}", c[3]);
        s.nearest = true;
        assert_eq!(sample_image(&img, &s, [0.49, 0.5]), [1.0, 0.0, 0.0, 0.0]);
        assert_eq!(sample_image(&img, &s, [0.51, 0.5]), [0.0, 0.0, 1.0, 1.0]);
        s.wrap_s = Wrap::Repeat;
        assert_eq!(sample_image(&img, &s, [1.51, 0.5]), [0.0, 0.0, 1.0, 1.0]);
    }

    #[test]
    fn malformed_image_gives_neutral_white() {
        let img = DecodedImage {
            width: 3,
            height: 3,
            pixels: vec![[0; 4]; 4],
        };
        assert_eq!(
            sample_image(&img, &Sampler::default(), [0.5, 0.5]),
            [1.0; 4]
        );
    }

    /// One primitive (a quad of two triangles), a 4x4 image, a factor and COLOR_0.
    fn test_asset(with_uvs: bool) -> Asset {
        let mut pixels = vec![[0u8; 4]; 16];
        for (i, p) in pixels.iter_mut().enumerate() {
            *p = [(i * 16) as u8, 200 - (i * 10) as u8, 100, 255 - i as u8];
        }
        let decoded = DecodedImage {
            width: 4,
            height: 4,
            pixels,
        };
        let image = ImageSource {
            bytes: Arc::new(Vec::new()),
            mime_type: "image/png".into(),
            width: 4,
            height: 4,
            decoded_bytes: 64,
            decoded: Some(Arc::new(decoded)),
        };
        let material = Material {
            name: None,
            base_color_factor: [0.5, 0.8, 1.0, 0.9],
            base_color_texture: Some(TextureRef {
                texture: 0,
                tex_coord: 0,
                transform: None,
            }),
            double_sided: false,
        };
        let prim = Primitive {
            mesh: 0,
            primitive: 0,
            material: Some(0),
            mode: TriangleMode::Triangles,
            positions: vec![
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [1.0, 1.0, 0.0],
                [0.0, 1.0, 0.0],
            ],
            normals: None,
            tex_coords: if with_uvs {
                vec![vec![[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]]
            } else {
                Vec::new()
            },
            colors: Some(vec![
                [1.0, 0.5, 0.25, 1.0],
                [0.5, 1.0, 1.0, 0.5],
                [1.0, 1.0, 0.5, 1.0],
                [0.2, 0.4, 0.6, 0.8],
            ]),
            triangles: vec![[0, 1, 2], [0, 2, 3]],
        };
        Asset {
            json: serde_json::Value::Null,
            buffers: Vec::new(),
            images: vec![image],
            textures: vec![Texture {
                image: Some(0),
                sampler: Sampler {
                    wrap_s: Wrap::ClampToEdge,
                    wrap_t: Wrap::ClampToEdge,
                    nearest: false,
                },
            }],
            materials: vec![material],
            primitives: vec![prim],
            instances: Vec::new(),
            warnings: Vec::new(),
        }
    }

    #[test]
    fn material_sampler_multiplies_factor_texel_and_vertex_color() {
        let asset = test_asset(true);
        let ms = MaterialSampler::new(&asset);
        // Triangle 1 = (0, 2, 3); bary chosen so uv lands on the center of texel (1, 2):
        // uv = b0*(0,0) + b1*(1,1) + b2*(0,1) = (b1, b1 + b2) = (0.375, 0.625).
        let bary = [0.375, 0.375, 0.25];
        let c = ms.base_color(0, 1, bary);
        let p = asset.images[0].decoded.as_ref().unwrap().pixels[2 * 4 + 1];
        let texel = [
            srgb8_to_linear(p[0]),
            srgb8_to_linear(p[1]),
            srgb8_to_linear(p[2]),
            p[3] as f32 / 255.0,
        ];
        let colors = asset.primitives[0].colors.as_ref().unwrap();
        let factor = asset.materials[0].base_color_factor;
        for k in 0..4 {
            let vc = colors[0][k] * bary[0] + colors[2][k] * bary[1] + colors[3][k] * bary[2];
            let expect = factor[k] * texel[k] * vc;
            assert!(
                (c[k] - expect).abs() < 1e-5,
                "channel {k}: {} vs {expect}",
                c[k]
            );
        }
        assert_eq!(ms.texture_uv(0, 1, bary), Some([0.375, 0.625]));
    }

    #[test]
    fn material_sampler_fallbacks() {
        let asset = test_asset(false);
        let ms = MaterialSampler::new(&asset);
        let factor = asset.materials[0].base_color_factor;
        let colors = asset.primitives[0].colors.as_ref().unwrap();
        // Missing UV set: texture term 1, factor × COLOR_0.
        let c = ms.base_color(0, 0, [1.0, 0.0, 0.0]);
        for k in 0..4 {
            assert!((c[k] - factor[k] * colors[0][k]).abs() < 1e-6);
        }
        // Without COLOR_0 too: factor only.
        let mut bare = test_asset(false);
        bare.primitives[0].colors = None;
        let ms2 = MaterialSampler::new(&bare);
        assert_eq!(ms2.base_color(0, 0, [0.2, 0.3, 0.5]), factor);
        // Out-of-range indices.
        assert_eq!(ms2.base_color(7, 0, [1.0, 0.0, 0.0]), [1.0; 4]);
        assert_eq!(ms2.base_color(0, 99, [1.0, 0.0, 0.0]), factor);
        // Missing decoded pixels and bad texture index: texture term 1.
        let mut a = test_asset(true);
        a.primitives[0].colors = None;
        a.images[0].decoded = None;
        assert_eq!(
            MaterialSampler::new(&a).base_color(0, 0, [1.0, 0.0, 0.0]),
            factor
        );
        a.materials[0].base_color_texture = Some(TextureRef {
            texture: 5,
            tex_coord: 0,
            transform: None,
        });
        assert_eq!(
            MaterialSampler::new(&a).base_color(0, 0, [1.0, 0.0, 0.0]),
            factor
        );
        // Material index out of range: default material.
        a.primitives[0].material = Some(3);
        assert_eq!(
            MaterialSampler::new(&a).base_color(0, 0, [1.0, 0.0, 0.0]),
            [1.0; 4]
        );
    }

    #[test]
    fn material_sampler_applies_texture_transform() {
        let mut asset = test_asset(true);
        asset.primitives[0].colors = None;
        let t = UvTransform {
            offset: [0.25, 0.0],
            rotation: 0.0,
            scale: [0.5, 1.0],
        };
        asset.materials[0].base_color_texture = Some(TextureRef {
            texture: 0,
            tex_coord: 0,
            transform: Some(t),
        });
        let ms = MaterialSampler::new(&asset);
        let bary = [0.375, 0.375, 0.25];
        let uv = ms.texture_uv(0, 1, bary).unwrap();
        assert!(close(uv, [0.375 * 0.5 + 0.25, 0.625]));
        let img = asset.images[0].decoded.as_ref().unwrap();
        let s = asset.textures[0].sampler;
        let tex = sample_image(img, &s, uv);
        let c = ms.base_color(0, 1, bary);
        for k in 0..4 {
            assert!((c[k] - asset.materials[0].base_color_factor[k] * tex[k]).abs() < 1e-6);
        }
    }
}
