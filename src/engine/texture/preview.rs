//! A software turntable preview: the asset rendered with its base color from `views` azimuths
//! around the world +Y axis, side by side in one image strip (view `i` at x = `i · size`).
//!
//! Camera: **orthographic**, looking at the center of the world bounding box from azimuth
//! `360° · i / views` (view 0 looks from +Z towards −Z, the glTF "front"; azimuths grow
//! counter-clockwise seen from above, towards +X) and `elevation_degrees` above the horizon. The
//! view's half-width is 1.05 × the largest distance of a vertex from the box center, so the whole
//! asset is in frame from every direction and at the same scale in every view. Orthographic
//! projection keeps screen-space barycentrics equal to surface barycentrics, so no perspective
//! correction is needed.
//!
//! Rasterization: every triangle of every mesh instance (node transforms applied) is scan-converted
//! at pixel centers with edge functions (f64) into a z-buffer; the nearest triangle wins, ties go to
//! the first in (instance, primitive, triangle) order. Each covered pixel is then colored with
//! [`MaterialSampler::base_color`] at its (primitive, triangle, barycentric) — factor × texture ×
//! COLOR_0, so a transferred texture shows exactly as sampled. With `shading`, the color is
//! multiplied by `0.35 + 0.65 · max(0, n·l)` (Lambert plus ambient; two-sided flat face normals, a
//! light above-left of the camera) so the shape reads; where the material has a normal map, `n`
//! is the normal it encodes ([`super::preview_normals`]). Alpha and alpha modes are ignored: the
//! surface is drawn opaque over the [`BACKGROUND`]. No antialiasing.
//!
//! Parallel over views and bands of 16 rows with rayon; each band is drawn by one task in a fixed
//! triangle order, so the image does not depend on the thread count.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::engine::asset::Asset;
use crate::engine::math::{cross, dot, normal_of, normalize, sub};
use crate::engine::texture::encode::encode_png_srgb;
use crate::engine::texture::preview_normals::{Frame, NormalMaps};
use crate::engine::texture::sample::MaterialSampler;

/// Linear background color (light grey, sRGB 231).
pub const BACKGROUND: [f32; 4] = [0.8, 0.8, 0.8, 1.0];
/// Largest image (views × size²) rendered, in pixels.
pub const MAX_PIXELS: u64 = 1 << 25;
/// Ambient share of the shading.
const AMBIENT: f32 = 0.35;
/// Rows per parallel band.
const BAND: usize = 16;

/// Parameters of [`render_turntable`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PreviewParams {
    /// Number of views around the +Y axis. Default 8, range 1..=64.
    pub views: u32,
    /// Width = height of one view in pixels. Default 256, range 16..=2048.
    pub size: u32,
    /// Camera elevation above the horizon in degrees. Default 20, range [-89, 89].
    pub elevation_degrees: f32,
    /// Lambert + ambient shading; `false` shows the plain base color. Default true.
    pub shading: bool,
}

impl Default for PreviewParams {
    fn default() -> Self {
        Self {
            views: 8,
            size: 256,
            elevation_degrees: 20.0,
            shading: true,
        }
    }
}

impl PreviewParams {
    /// Range-checks the parameters (also `views × size² ≤` [`MAX_PIXELS`]).
    pub fn validate(&self) -> Result<(), PreviewError> {
        let bad = |field: &'static str, message: String| {
            Err(PreviewError::InvalidParams { field, message })
        };
        if !(1..=64).contains(&self.views) {
            return bad(
                "views",
                format!("{} is outside the range 1..=64", self.views),
            );
        }
        if !(16..=2048).contains(&self.size) {
            return bad(
                "size",
                format!("{} is outside the range 16..=2048", self.size),
            );
        }
        if !(-89.0..=89.0).contains(&self.elevation_degrees) {
            return bad(
                "elevation_degrees",
                format!("{} is outside the range [-89, 89]", self.elevation_degrees),
            );
        }
        let pixels = self.views as u64 * self.size as u64 * self.size as u64;
        if pixels > MAX_PIXELS {
            return bad(
                "size",
                format!(
                    "{} views of {} px need {pixels} pixels, more than {MAX_PIXELS}",
                    self.views, self.size
                ),
            );
        }
        Ok(())
    }
}

/// Why a preview could not be rendered.
#[derive(Debug, thiserror::Error)]
pub enum PreviewError {
    /// A parameter is out of range.
    #[error("{field}: {message}")]
    InvalidParams {
        /// The parameter.
        field: &'static str,
        /// What is wrong with it.
        message: String,
    },
    /// The asset has nothing to draw.
    #[error("nothing to render: {0}")]
    Empty(String),
}

/// A rendered strip: `views` square images side by side, linear RGBA, row-major from the top-left.
#[derive(Clone, Debug, PartialEq)]
pub struct PreviewImage {
    /// `views × size` pixels.
    pub width: u32,
    /// `size` pixels.
    pub height: u32,
    /// `width × height` linear RGBA pixels.
    pub pixels: Vec<[f32; 4]>,
}

impl PreviewImage {
    /// The image as an sRGB PNG.
    pub fn to_png(&self) -> Vec<u8> {
        encode_png_srgb(&self.pixels, self.width, self.height)
    }

    /// The pixel at `(x, y)`.
    pub fn pixel(&self, x: u32, y: u32) -> [f32; 4] {
        self.pixels[y as usize * self.width as usize + x as usize]
    }
}

/// A triangle of the scene in world space.
struct WorldTriangle {
    primitive: u32,
    triangle: u32,
    p: [[f32; 3]; 3],
    normal: [f32; 3],
}

/// Every triangle of every instance, in (instance, primitive, triangle) order.
fn world_triangles(asset: &Asset) -> Vec<WorldTriangle> {
    let mut out = Vec::new();
    for inst in &asset.instances {
        for p in asset.primitives_of_mesh(inst.mesh) {
            let prim = &asset.primitives[p];
            for (t, tri) in prim.triangles.iter().enumerate() {
                let w = tri.map(|v| {
                    inst.transform_point(prim.positions[v as usize])
                        .map(|x| x as f32)
                });
                out.push(WorldTriangle {
                    primitive: p as u32,
                    triangle: t as u32,
                    normal: normal_of(w[0], w[1], w[2]),
                    p: w,
                });
            }
        }
    }
    out
}

/// An orthographic camera on the turntable.
struct Camera {
    center: [f32; 3],
    /// Unit vector from the center towards the eye (depth grows towards the eye).
    back: [f32; 3],
    right: [f32; 3],
    up: [f32; 3],
    /// Pixels per world unit.
    scale: f32,
    size: f32,
    light: [f32; 3],
}

impl Camera {
    fn new(center: [f32; 3], radius: f32, azimuth: f32, elevation: f32, size: u32) -> Self {
        let (ce, se) = (elevation.cos(), elevation.sin());
        let back = [ce * azimuth.sin(), se, ce * azimuth.cos()];
        let right = normalize(cross([0.0, 1.0, 0.0], back));
        let up = cross(back, right);
        let light = normalize([
            0.8 * back[0] + 0.5 * up[0] - 0.3 * right[0],
            0.8 * back[1] + 0.5 * up[1] - 0.3 * right[1],
            0.8 * back[2] + 0.5 * up[2] - 0.3 * right[2],
        ]);
        Self {
            center,
            back,
            right,
            up,
            scale: size as f32 / (2.0 * 1.05 * radius),
            size: size as f32,
            light,
        }
    }

    /// Pixel coordinates (x right, y down, origin at the top-left corner) and depth.
    fn project(&self, p: [f32; 3]) -> [f64; 3] {
        let d = sub(p, self.center);
        [
            (self.size * 0.5 + dot(d, self.right) * self.scale) as f64,
            (self.size * 0.5 - dot(d, self.up) * self.scale) as f64,
            dot(d, self.back) as f64,
        ]
    }
}

/// The nearest surface at a pixel: triangle index (into the scene list) and barycentrics.
#[derive(Clone, Copy)]
struct Fragment {
    depth: f64,
    triangle: u32,
    bary: [f32; 3],
}

/// Scan-converts triangle `index` (projected `s`) into the rows `y0..y0 + rows` of a band.
fn draw(
    s: &[[f64; 3]; 3],
    index: u32,
    y0: usize,
    rows: usize,
    size: usize,
    frags: &mut [Option<Fragment>],
) {
    let edge = |a: [f64; 3], b: [f64; 3], x: f64, y: f64| {
        (b[0] - a[0]) * (y - a[1]) - (b[1] - a[1]) * (x - a[0])
    };
    let area = edge(s[0], s[1], s[2][0], s[2][1]);
    if area.abs() < 1e-12 || !area.is_finite() {
        return;
    }
    let (xmin, xmax) = (
        s[0][0].min(s[1][0]).min(s[2][0]),
        s[0][0].max(s[1][0]).max(s[2][0]),
    );
    let (ymin, ymax) = (
        s[0][1].min(s[1][1]).min(s[2][1]),
        s[0][1].max(s[1][1]).max(s[2][1]),
    );
    // Pixel centers at i + 0.5 inside [min, max].
    let first = |lo: f64| (lo - 0.5).ceil().max(0.0) as usize;
    let last = |hi: f64, n: usize| ((hi - 0.5).floor().min(n as f64 - 1.0)) as i64;
    let (x0, x1) = (first(xmin), last(xmax, size));
    let (ya, yb) = (
        first(ymin).max(y0),
        last(ymax, y0 + rows).min((y0 + rows) as i64 - 1),
    );
    if x1 < x0 as i64 || yb < ya as i64 {
        return;
    }
    for y in ya..=yb as usize {
        let py = y as f64 + 0.5;
        for x in x0..=x1 as usize {
            let px = x as f64 + 0.5;
            let w0 = edge(s[1], s[2], px, py) / area;
            let w1 = edge(s[2], s[0], px, py) / area;
            let w2 = edge(s[0], s[1], px, py) / area;
            if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                continue;
            }
            let depth = w0 * s[0][2] + w1 * s[1][2] + w2 * s[2][2];
            let slot = &mut frags[(y - y0) * size + x];
            if slot.is_none_or(|f| depth > f.depth) {
                *slot = Some(Fragment {
                    depth,
                    triangle: index,
                    bary: [w0 as f32, w1 as f32, w2 as f32],
                });
            }
        }
    }
}

/// What a view is shaded with: the base colour, and (with shading) the normal maps and the
/// tangent frame of each triangle that has one.
struct Shading<'a> {
    sampler: MaterialSampler<'a>,
    lit: bool,
    maps: NormalMaps,
    frames: Vec<Option<Frame>>,
}

impl Shading<'_> {
    /// The unit normal the light sees at a fragment, facing the camera (two-sided).
    fn normal(&self, index: usize, t: &WorldTriangle, bary: [f32; 3], back: [f32; 3]) -> [f32; 3] {
        let n = match self.frames.get(index).copied().flatten() {
            Some(frame) => self.maps.normal(
                self.sampler.asset(),
                t.primitive as usize,
                t.triangle as usize,
                bary,
                &frame,
            ),
            None => t.normal,
        };
        if dot(t.normal, back) < 0.0 {
            n.map(|x| -x)
        } else {
            n
        }
    }
}

/// Renders one view into a `size × size` image.
fn render_view(
    tris: &[WorldTriangle],
    shading: &Shading<'_>,
    cam: &Camera,
    size: usize,
) -> Vec<[f32; 4]> {
    let projected: Vec<[[f64; 3]; 3]> = tris.iter().map(|t| t.p.map(|p| cam.project(p))).collect();
    let bands = size.div_ceil(BAND);
    let mut bins: Vec<Vec<u32>> = vec![Vec::new(); bands];
    for (i, s) in projected.iter().enumerate() {
        let ymin = s[0][1].min(s[1][1]).min(s[2][1]);
        let ymax = s[0][1].max(s[1][1]).max(s[2][1]);
        if !(ymin.is_finite() && ymax.is_finite()) || ymax < 0.0 || ymin >= size as f64 {
            continue;
        }
        let b0 = (ymin.max(0.0) as usize / BAND).min(bands - 1);
        let b1 = (ymax.max(0.0) as usize / BAND).min(bands - 1);
        for bin in &mut bins[b0..=b1] {
            bin.push(i as u32);
        }
    }
    let mut pixels = vec![BACKGROUND; size * size];
    pixels
        .par_chunks_mut(BAND * size)
        .enumerate()
        .for_each(|(band, out)| {
            let rows = out.len() / size;
            let mut frags = vec![None; out.len()];
            for &i in &bins[band] {
                draw(
                    &projected[i as usize],
                    i,
                    band * BAND,
                    rows,
                    size,
                    &mut frags,
                );
            }
            for (px, f) in out.iter_mut().zip(&frags) {
                let Some(f) = f else { continue };
                let t = &tris[f.triangle as usize];
                let c =
                    shading
                        .sampler
                        .base_color(t.primitive as usize, t.triangle as usize, f.bary);
                let k = if shading.lit {
                    let n = shading.normal(f.triangle as usize, t, f.bary, cam.back);
                    AMBIENT + (1.0 - AMBIENT) * dot(n, cam.light).max(0.0)
                } else {
                    1.0
                };
                *px = [c[0] * k, c[1] * k, c[2] * k, 1.0];
            }
        });
    pixels
}

/// Renders `asset` from `params.views` azimuths into one strip (see the module docs).
///
/// # Errors
/// [`PreviewError::InvalidParams`] for out-of-range parameters, [`PreviewError::Empty`] when the
/// scene has no triangles or its extent is not finite.
pub fn render_turntable(
    asset: &Asset,
    params: &PreviewParams,
) -> Result<PreviewImage, PreviewError> {
    render_turntable_noted(asset, params).map(|(image, _)| image)
}

/// As [`render_turntable`], with one note per normal map left out of the lighting.
///
/// # Errors
/// As [`render_turntable`].
pub fn render_turntable_noted(
    asset: &Asset,
    params: &PreviewParams,
) -> Result<(PreviewImage, Vec<String>), PreviewError> {
    params.validate()?;
    let tris = world_triangles(asset);
    if tris.is_empty() {
        return Err(PreviewError::Empty("the scene has no triangles".into()));
    }
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in tris.iter().flat_map(|t| t.p) {
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let center = [0, 1, 2].map(|k| 0.5 * (lo[k] + hi[k]));
    let radius = tris
        .iter()
        .flat_map(|t| t.p)
        .map(|p| dot(sub(p, center), sub(p, center)))
        .fold(0.0f32, f32::max)
        .sqrt();
    if !radius.is_finite() || !center.iter().all(|c| c.is_finite()) {
        return Err(PreviewError::Empty(
            "the scene's extent is not finite".into(),
        ));
    }
    let radius = if radius > 0.0 { radius } else { 1.0 };
    let (maps, notes) = if params.shading {
        NormalMaps::new(asset)
    } else {
        (NormalMaps::empty(), Vec::new())
    };
    let frames = if maps.any() {
        tris.iter()
            .map(|t| {
                maps.frame(
                    asset,
                    t.primitive as usize,
                    t.triangle as usize,
                    &t.p,
                    t.normal,
                )
            })
            .collect()
    } else {
        Vec::new()
    };
    let shading = Shading {
        sampler: MaterialSampler::new(asset),
        lit: params.shading,
        maps,
        frames,
    };
    let size = params.size as usize;
    let views: Vec<Vec<[f32; 4]>> = (0..params.views)
        .into_par_iter()
        .map(|i| {
            let azimuth = std::f32::consts::TAU * i as f32 / params.views as f32;
            let cam = Camera::new(
                center,
                radius,
                azimuth,
                params.elevation_degrees.to_radians(),
                params.size,
            );
            render_view(&tris, &shading, &cam, size)
        })
        .collect();
    let width = size * views.len();
    let mut pixels = vec![BACKGROUND; width * size];
    for (i, view) in views.iter().enumerate() {
        for (y, row) in view.chunks_exact(size).enumerate() {
            let start = y * width + i * size;
            pixels[start..start + size].copy_from_slice(row);
        }
    }
    let image = PreviewImage {
        width: width as u32,
        height: params.size,
        pixels,
    };
    Ok((image, notes))
}
