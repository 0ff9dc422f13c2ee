//! The source colour per surface sample of the `correlation` method (issue 11, §3.1): box-filtered
//! over about the sample's own area by MeshMatch's sampling, not a single texture lookup. A
//! checkerboard finer than the sample spacing gives per-sample colours near its mean (a point
//! sample would give ± the full contrast), a checkerboard coarser than the spacing keeps its
//! contrast.

use retex::engine::control::Control;
use retex::engine::mesh::{build_surface, WeldParams};
use retex::engine::methods::correlation::pyramid::SurfacePyramid;
use retex::engine::methods::correlation::sample_colors;

use crate::common::load_bytes;
use crate::correlation_common::luminance;
use crate::elastiface_common::{grid, mesh_glb, texture_png, MeshData};

/// A flat unit square in the xz plane, `n` × `n` cells, UV = (x, z).
fn square(n: usize) -> MeshData {
    grid(n, n, |u, v| [u, 0.0, v])
}

const DARK: f64 = 0.1;
const LIGHT: f64 = 0.9;

fn checker(cells: f64, u: f64, v: f64) -> f64 {
    if ((u * cells).floor() + (v * cells).floor()) as i64 % 2 == 0 {
        DARK
    } else {
        LIGHT
    }
}

fn mean_std(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    (
        m,
        (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / n).sqrt(),
    )
}

/// Per-sample luminance of the sampled colours and of point samples of the checker at the
/// samples' places (the single lookup the filter replaces).
fn sampled(cells: f64, samples: usize) -> (Vec<f64>, Vec<f64>) {
    let png = texture_png(1024, 1024, |u, v| [checker(cells, u, v); 3]);
    let asset = load_bytes(
        &mesh_glb(&square(32), Some(png.as_slice()), 1.0),
        "checker.glb",
    );
    let surface = build_surface(&asset, &WeldParams::default()).unwrap();
    let pyr = SurfacePyramid::build(&surface, samples, 1, &Control::new()).unwrap();
    let colors = sample_colors(&asset, &surface, &pyr);
    let filtered = colors.iter().map(|c| f64::from(luminance(*c))).collect();
    let point = pyr
        .mesh(0)
        .positions
        .iter()
        .map(|p| checker(cells, f64::from(p[0]), f64::from(p[2])))
        .collect();
    (filtered, point)
}

#[test]
fn sample_colours_average_a_checker_finer_than_the_samples() {
    // 4096 samples on the unit square: spacing about 1/64. Fine: 243.7 cells per axis (about 4
    // per spacing, 4.2 texels per cell, so the texture's own bilinear filter does not average
    // them; not a power of two, so the samples, which bisection puts at dyadic places, do not
    // all fall on cell corners); coarse: 4.3 cells per axis (about 15 spacings per cell).
    let mid = 0.5 * (DARK + LIGHT);
    for samples in [4096usize, 16384] {
        let (fine, fine_point) = sampled(243.7, samples);
        let (coarse, _) = sampled(4.3, samples);
        let (fm, fs) = mean_std(&fine);
        let (_, fps) = mean_std(&fine_point);
        let (cm, cs) = mean_std(&coarse);
        eprintln!(
            "{samples} samples: fine checker mean {fm:.3} std {fs:.3} (point samples std {fps:.3}); coarse mean {cm:.3} std {cs:.3}"
        );
        assert!((fm - mid).abs() < 0.05, "fine mean {fm:.3}");
        assert!(fs < 0.5 * fps, "fine std {fs:.3} vs point {fps:.3}");
        assert!(cs > 0.8 * 0.5 * (LIGHT - DARK), "coarse std {cs:.3}");
        assert!((cm - mid).abs() < 0.1, "coarse mean {cm:.3}");
    }
}
