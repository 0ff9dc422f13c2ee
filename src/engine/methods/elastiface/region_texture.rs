//! The texture half of the part-based morph (§5 of Zell & Botsch 2013: "for local blending a
//! gradient-based technique should be employed [Pérez et al. 2003]").
//!
//! Per material of the source with a base-colour UV set, the source's UV layout is rasterized
//! ([`rasterize_uv_layout`], as the shared texel loop does) and at every covered texel three
//! values are taken at its surface point: the template's own colour `a` (factor × texture ×
//! COLOR_0, [`MaterialSampler::base_color`]), the re-laid target colour `b` (§4,
//! [`super::texture::RelaidColor`]; the template's where the target has none) and the region
//! weight ρ (the vertex weights of [`super::region`] interpolated barycentrically), ω = w·ρ.
//!
//! **The region's texels** Ω are the covered texels with ρ > 0; every other covered texel keeps
//! the template's colour `a`. Inside Ω the discrete Poisson equation of Pérez et al. (eq. 7)
//! with a mixed guidance field is solved per channel (RGBA, linear colour):
//! `Σ_{q∈N(p)} (f_p − f_q) = Σ_{q∈N(p)} g_pq`, `g_pq = (1 − ω̄)(a_p − a_q) + ω̄(b_p − b_q)`,
//! ω̄ = (ω_p + ω_q)/2, where `N(p)` are the covered 4-neighbours of p and a neighbour outside Ω
//! is a Dirichlet value `f_q = a_q` (the template). Uncovered neighbours are left out (a
//! Neumann border at the UV islands' edges); covered neighbours across an island border in the
//! image count as neighbours (a deviation: the guidance there blends two colour differences that
//! are both meaningless, as in any texel-grid method). A connected part of Ω that touches no
//! Dirichlet texel (the region covers a whole UV island) has its right-hand side made
//! compatible (mean removed), one texel pinned and is shifted so that its mean equals that of
//! the linear blend `(1 − ω)a + ωb`: with ω constant this is the linear blend itself.
//!
//! Solver: one sparse Cholesky factorisation (AMD ordering) per material, 4 right-hand sides.
//! Its memory grows faster than the texel count, so Ω is capped at
//! `params.blend.max_region_texels` (default 1,048,576): a larger region is refused naming
//! `params.blend.region` (lower `output.texture_size` or the region).
//! Padding and encoding as the shared texel loop (pull-push padding, sRGB 8-bit PNG).

use rayon::prelude::*;

use crate::engine::asset::constraints::{Constraints, ConstraintsError};
use crate::engine::asset::edits::{Edit, EncodedImage, TextureSlot, TextureWrap};
use crate::engine::asset::Asset;
use crate::engine::control::Control;
use crate::engine::linalg::SymbolicCholesky;
use crate::engine::methods::output::{SurfaceField, SurfaceSample, TextureReport};
use crate::engine::texture::bake::rasterize_uv_layout;
use crate::engine::texture::encode::encode_png_srgb;
use crate::engine::texture::pad::pad;
use crate::engine::texture::sample::MaterialSampler;

use super::system::{PatternBuilder, Values};
use super::texture::RelaidColor;
use super::MethodError;

/// What the texel blend needs.
pub struct RegionTexture<'a> {
    /// The target's colour at the fitted source (without a blend).
    pub relaid: &'a RelaidColor<'a>,
    /// The template's own colour.
    pub template: MaterialSampler<'a>,
    /// Region weight per welded source vertex.
    pub weights: &'a [f64],
    /// The blend weight w.
    pub w: f64,
    /// Cap on the region's texels per material.
    pub max_texels: usize,
}

/// One triangle of a material group.
struct Tri {
    primitive: usize,
    triangle: usize,
}

/// The base-colour UV set of primitive `p`, when it has it.
fn uv_set(asset: &Asset, p: usize) -> Option<usize> {
    let set = asset.primitives[p]
        .material
        .and_then(|m| asset.materials.get(m))
        .and_then(|m| m.base_color_texture)
        .map_or(0, |t| t.tex_coord) as usize;
    (asset.primitives[p].tex_coords.len() > set).then_some(set)
}

/// One covered texel's template colour, re-laid colour (if matched) and ω.
type TexelSample = ([f32; 4], Option<[f32; 4]>, f64);

/// A material group: its triangles and their UVs.
type Group = (Vec<Tri>, Vec<[[f32; 2]; 3]>);

/// Texel values of one group: template, re-laid, ω, covered.
struct Texels {
    a: Vec<[f32; 4]>,
    b: Vec<[f32; 4]>,
    omega: Vec<f64>,
    covered: Vec<bool>,
    unmatched: u64,
}

impl RegionTexture<'_> {
    fn sample(&self, t: &Tri, bary: [f32; 3]) -> TexelSample {
        let source = self.relaid.source;
        let a = self.template.base_color(t.primitive, t.triangle, bary);
        let at = SurfaceSample {
            primitive: t.primitive,
            triangle: t.triangle,
            barycentric: bary,
            position: [0.0; 3],
            normal: [0.0; 3],
        };
        let mut b = [0.0f32; 4];
        let b = self.relaid.sample(&at, None, &mut b).map(|_| b);
        let tri = source.primitives[t.primitive].triangles[t.triangle];
        let map = &self.relaid.welded[t.primitive];
        let rho: f64 = (0..3)
            .map(|k| match map.get(tri[k] as usize) {
                Some(&w) if w != u32::MAX => f64::from(bary[k]) * self.weights[w as usize],
                _ => 0.0,
            })
            .sum();
        (a, b, self.w * rho.clamp(0.0, 1.0))
    }

    fn texels(&self, tris: &[Tri], uvs: &[[[f32; 2]; 3]], size: u32) -> Texels {
        let map = rasterize_uv_layout(uvs, size, size);
        let values: Vec<Option<TexelSample>> = map
            .hits
            .par_iter()
            .map(|h| h.map(|h| self.sample(&tris[h.triangle as usize], h.bary)))
            .collect();
        let n = values.len();
        let mut t = Texels {
            a: vec![[0.0; 4]; n],
            b: vec![[0.0; 4]; n],
            omega: vec![0.0; n],
            covered: vec![false; n],
            unmatched: 0,
        };
        for (i, v) in values.into_iter().enumerate() {
            if let Some((a, b, o)) = v {
                t.a[i] = a;
                t.b[i] = b.unwrap_or(a);
                t.unmatched += u64::from(b.is_none());
                t.omega[i] = o;
                t.covered[i] = true;
            }
        }
        t
    }
}

/// Writes the region-blended base colour of every textured source primitive.
///
/// # Errors
/// [`MethodError::Constraints`] when a region exceeds the texel cap, [`MethodError::Cancelled`],
/// [`MethodError::Internal`] for a failed solve.
pub fn region_textures(
    rt: &RegionTexture<'_>,
    constraints: &Constraints,
    control: &Control,
) -> Result<(Vec<Edit>, Vec<TextureReport>), MethodError> {
    let source = rt.relaid.source;
    let mut groups: std::collections::BTreeMap<Option<usize>, Group> = Default::default();
    for (p, prim) in source.primitives.iter().enumerate() {
        let Some(set) = uv_set(source, p) else {
            continue;
        };
        let g = groups.entry(prim.material).or_default();
        for (ti, t) in prim.triangles.iter().enumerate() {
            g.0.push(Tri {
                primitive: p,
                triangle: ti,
            });
            g.1.push(t.map(|v| prim.tex_coords[set][v as usize]));
        }
    }
    let size = constraints.output.texture_size;
    let stage = control.stage("region_texture", groups.len() as u64)?;
    let mut edits = Vec::new();
    let mut reports = Vec::new();
    for (material, (tris, uvs)) in groups {
        let t = rt.texels(&tris, &uvs, size);
        control.check()?;
        let mut pixels = solve_texels(&t, size as usize, rt.max_texels)?;
        let covered = t.covered.iter().filter(|c| **c).count() as u64;
        let pr = pad(
            &mut pixels,
            &t.covered,
            size,
            size,
            constraints.output.padding,
        );
        let mut prims: Vec<usize> = tris.iter().map(|t| t.primitive).collect();
        prims.sort_unstable();
        prims.dedup();
        let name = match material {
            Some(m) => format!("retex_basecolor_material{m}"),
            None => "retex_basecolor_default".to_string(),
        };
        let tex_coord = uv_set(source, tris[0].primitive).unwrap_or(0) as u32;
        reports.push(TextureReport {
            material,
            size,
            tex_coord,
            triangles: tris.len(),
            covered,
            overlapped: 0,
            unmatched: t.unmatched,
            padded: pr.padded,
            filled: pr.filled,
        });
        edits.push(Edit::SetTexture {
            material,
            slot: TextureSlot::BaseColor,
            image: EncodedImage::srgb8_png(name, encode_png_srgb(&pixels, size, size)),
            tex_coord,
            wrap: TextureWrap::Repeat,
            primitives: prims,
        });
        stage.tick(1)?;
    }
    Ok((edits, reports))
}

/// The covered 4-neighbours of texel `i`.
fn neighbours(i: usize, size: usize, covered: &[bool]) -> impl Iterator<Item = usize> + '_ {
    let (x, y) = (i % size, i / size);
    [
        (x > 0).then(|| i - 1),
        (x + 1 < size).then(|| i + 1),
        (y > 0).then(|| i - size),
        (y + 1 < size).then(|| i + size),
    ]
    .into_iter()
    .flatten()
    .filter(|&q| covered[q])
}

/// The texels: the template outside the region, the Poisson solution inside.
fn solve_texels(t: &Texels, size: usize, cap: usize) -> Result<Vec<[f32; 4]>, MethodError> {
    let mut out = t.a.clone();
    let mut unknown = vec![u32::MAX; t.a.len()];
    let mut region = Vec::new();
    for i in 0..t.a.len() {
        if t.covered[i] && t.omega[i] > 0.0 {
            unknown[i] = region.len() as u32;
            region.push(i);
        }
    }
    if region.is_empty() {
        return Ok(out);
    }
    if region.len() > cap {
        return Err(MethodError::Constraints(ConstraintsError::new(
            "params.blend.region",
            format!(
                "the region covers {} texels of one texture, more than \
                 params.blend.max_region_texels ({cap}) for its gradient-domain solve; lower \
                 output.texture_size or the region",
                region.len()
            ),
        )));
    }
    let floating = floating_parts(&region, &unknown, size, &t.covered);
    let mut pinned = vec![false; region.len()];
    for part in &floating {
        pinned[part[0]] = true;
    }
    let lin = |i: usize, c: usize| {
        let o = t.omega[i] as f32;
        (1.0 - o) * t.a[i][c] + o * t.b[i][c]
    };
    let mut pattern = PatternBuilder::new(region.len());
    let mut cols = Vec::new();
    for (k, &i) in region.iter().enumerate() {
        cols.clear();
        cols.extend(
            neighbours(i, size, &t.covered)
                .map(|q| unknown[q])
                .filter(|&u| u != u32::MAX && !pinned[u as usize] && !pinned[k])
                .map(|u| u as usize),
        );
        pattern.clique_row(k, &cols);
    }
    let pattern = pattern.build()?;
    let mut values = Values::zeros(&pattern);
    let mut rhs = vec![vec![0.0f64; region.len()]; 4];
    for (k, &i) in region.iter().enumerate() {
        if pinned[k] {
            values.add(k, k, 1.0);
            for (c, r) in rhs.iter_mut().enumerate() {
                r[k] = f64::from(lin(i, c));
            }
            continue;
        }
        for q in neighbours(i, size, &t.covered) {
            values.add(k, k, 1.0);
            let o = 0.5 * (t.omega[i] + t.omega[q]);
            let u = unknown[q];
            for (c, r) in rhs.iter_mut().enumerate() {
                let g = (1.0 - o) * f64::from(t.a[i][c] - t.a[q][c])
                    + o * f64::from(t.b[i][c] - t.b[q][c]);
                r[k] += g;
                if u == u32::MAX {
                    r[k] += f64::from(t.a[q][c]);
                } else if pinned[u as usize] {
                    r[k] += f64::from(lin(q, c));
                }
            }
            if u != u32::MAX && !pinned[u as usize] {
                values.add(k, u as usize, -1.0);
            }
        }
    }
    // A floating part needs no compatibility fix: `g` is antisymmetric per edge, so its
    // equations sum to zero and dropping the pinned texel's equation loses nothing.
    let matrix = values.into_matrix()?;
    let factor = SymbolicCholesky::new(matrix.pattern().clone())
        .and_then(|s| s.factor(&matrix))
        .map_err(|e| MethodError::Internal(format!("region texture factorisation: {e}")))?;
    factor
        .solve_many(&mut rhs)
        .map_err(|e| MethodError::Internal(format!("region texture solve: {e}")))?;
    for part in &floating {
        for c in 0..4 {
            let n = part.len() as f64;
            let shift = part
                .iter()
                .map(|&k| f64::from(lin(region[k], c)) - rhs[c][k])
                .sum::<f64>()
                / n;
            for &k in part {
                rhs[c][k] += shift;
            }
        }
    }
    for (k, &i) in region.iter().enumerate() {
        for c in 0..4 {
            out[i][c] = rhs[c][k] as f32;
        }
    }
    Ok(out)
}

/// Connected parts of the region (over covered 4-neighbours) with no neighbour outside it:
/// their unknowns, the first one to be pinned.
fn floating_parts(
    region: &[usize],
    unknown: &[u32],
    size: usize,
    covered: &[bool],
) -> Vec<Vec<usize>> {
    let mut seen = vec![false; region.len()];
    let mut parts = Vec::new();
    for start in 0..region.len() {
        if seen[start] {
            continue;
        }
        seen[start] = true;
        let mut part = vec![start];
        let mut touches = false;
        let mut head = 0;
        while head < part.len() {
            let i = region[part[head]];
            head += 1;
            for q in neighbours(i, size, covered) {
                match unknown[q] {
                    u32::MAX => touches = true,
                    u if !seen[u as usize] => {
                        seen[u as usize] = true;
                        part.push(u as usize);
                    }
                    _ => {}
                }
            }
        }
        if !touches {
            parts.push(part);
        }
    }
    parts
}
