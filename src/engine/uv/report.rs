//! The atlas quality report: per chart and overall L2 and L∞ stretch (Sander et al. 2001, §3),
//! angle distortion, texel-density spread, packing efficiency, chart count and seam length.
//!
//! Definitions (constants the papers leave open):
//! - Stretch is measured on each chart's parameterisation scaled so that its texture area
//!   equals its surface area (Sander et al. normalise the whole atlas the same way), so 1 is
//!   the optimum and values grow with distortion. Chart and overall L2 are the area-weighted
//!   root mean square of the triangles' L2; L∞ is the largest Γ.
//! - Angle distortion of a triangle is Γ/γ (1 for a conformal map); reported as the
//!   area-weighted mean and the maximum.
//! - Texel density of a triangle is √(texture area in texels / surface area), texels per world
//!   unit; the spread is the area-weighted 5th and 95th percentile and their ratio.
//! - Packing efficiency is the charts' total texture area over the texture's area.
//! - Seam length is the total world length of the edges whose faces lie in different charts
//!   (edges with more than two faces count once).

use serde::Serialize;

/// Figures of one chart.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct ChartReport {
    /// Faces in the chart.
    pub faces: usize,
    /// Surface area, world units².
    pub area: f64,
    /// Area-weighted RMS of the triangles' L2 stretch.
    pub l2_stretch: f64,
    /// Largest singular value Γ over the chart's triangles.
    pub linf_stretch: f64,
    /// Area-weighted mean of Γ/γ.
    pub angle_distortion: f64,
    /// Texels per world unit (√(texel area / surface area) of the whole chart).
    pub texel_density: f64,
}

/// The whole atlas.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct AtlasReport {
    /// Charts.
    pub chart_count: usize,
    /// Charts with a single triangle (what the splits end at).
    pub single_triangle_charts: usize,
    /// Overall area-weighted RMS L2 stretch.
    pub l2_stretch: f64,
    /// Largest Γ over all triangles.
    pub linf_stretch: f64,
    /// Area-weighted mean Γ/γ.
    pub angle_distortion: f64,
    /// Largest Γ/γ.
    pub angle_distortion_max: f64,
    /// Texels per world unit of the packing scale.
    pub texels_per_unit: f64,
    /// Area-weighted 5th percentile of the triangles' texel density.
    pub texel_density_p5: f64,
    /// Area-weighted 95th percentile of the triangles' texel density.
    pub texel_density_p95: f64,
    /// `texel_density_p95 / texel_density_p5` (1 = uniform).
    pub texel_density_spread: f64,
    /// Charts' texture area / texture area.
    pub packing_efficiency: f64,
    /// Total world length of the seams.
    pub seam_length: f64,
    /// Edges on seams.
    pub seam_edges: usize,
    /// UV triangles with non-positive area (0 by construction).
    pub flipped: usize,
    /// Texture size the atlas was packed for.
    pub texture_size: u32,
    /// Gutter between charts, texels.
    pub gutter: u32,
    /// One entry per chart, in chart order.
    pub charts: Vec<ChartReport>,
}

/// Per-triangle measures gathered by the atlas.
#[derive(Clone, Copy, Debug, Default)]
pub struct TriangleMeasure {
    /// Surface area.
    pub area: f64,
    /// L2 stretch squared.
    pub l2_sq: f64,
    /// Γ.
    pub big: f64,
    /// γ.
    pub small: f64,
    /// Texels per world unit.
    pub density: f64,
}

/// Aggregates one chart's triangles.
pub fn chart_report(tris: &[TriangleMeasure], texels_per_unit: f64) -> ChartReport {
    let area: f64 = tris.iter().map(|t| t.area).sum();
    let w = area.max(1e-300);
    ChartReport {
        faces: tris.len(),
        area,
        l2_stretch: (tris.iter().map(|t| t.area * t.l2_sq).sum::<f64>() / w).sqrt(),
        linf_stretch: tris.iter().map(|t| t.big).fold(0.0, f64::max),
        angle_distortion: tris
            .iter()
            .map(|t| t.area * t.big / t.small.max(1e-300))
            .sum::<f64>()
            / w,
        texel_density: texels_per_unit,
    }
}

/// Area-weighted percentile of `values` (pairs of value and weight).
fn percentile(mut values: Vec<(f64, f64)>, q: f64) -> f64 {
    values.sort_by(|a, b| a.0.total_cmp(&b.0));
    let total: f64 = values.iter().map(|v| v.1).sum();
    let mut acc = 0.0;
    for (v, w) in &values {
        acc += w;
        if acc >= q * total {
            return *v;
        }
    }
    values.last().map_or(0.0, |v| v.0)
}

/// Overall figures from every triangle (chart entries, seams and packing given).
pub struct Totals {
    /// Chart entries.
    pub charts: Vec<ChartReport>,
    /// Seam length and edge count.
    pub seams: (f64, usize),
    /// Charts' texture area fraction.
    pub packing_efficiency: f64,
    /// Packing scale.
    pub texels_per_unit: f64,
    /// Texture size and gutter.
    pub texture: (u32, u32),
}

/// Builds the report.
pub fn atlas_report(tris: &[TriangleMeasure], totals: Totals) -> AtlasReport {
    let all = chart_report(tris, totals.texels_per_unit);
    let density: Vec<(f64, f64)> = tris.iter().map(|t| (t.density, t.area)).collect();
    let p5 = percentile(density.clone(), 0.05);
    let p95 = percentile(density, 0.95);
    AtlasReport {
        chart_count: totals.charts.len(),
        single_triangle_charts: totals.charts.iter().filter(|c| c.faces == 1).count(),
        l2_stretch: all.l2_stretch,
        linf_stretch: all.linf_stretch,
        angle_distortion: all.angle_distortion,
        angle_distortion_max: tris
            .iter()
            .map(|t| t.big / t.small.max(1e-300))
            .fold(0.0, f64::max),
        texels_per_unit: totals.texels_per_unit,
        texel_density_p5: p5,
        texel_density_p95: p95,
        texel_density_spread: if p5 > 0.0 { p95 / p5 } else { f64::INFINITY },
        packing_efficiency: totals.packing_efficiency,
        seam_length: totals.seams.0,
        seam_edges: totals.seams.1,
        flipped: 0,
        texture_size: totals.texture.0,
        gutter: totals.texture.1,
        charts: totals.charts,
    }
}
