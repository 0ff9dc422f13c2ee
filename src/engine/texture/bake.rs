//! Rasterization of a UV layout into texels: for every texel of a `width × height` texture, which
//! triangle of the layout covers the texel center and at which barycentrics. This is the first
//! step of every bake (DESIGN.md, "bake"): the texel's surface point is then looked up and the
//! method's field sampled there.
//!
//! Conventions (glTF): UV (0,0) is the top-left corner of the image, `x = u · width`,
//! `y = v · height`; texel `(x, y)` is covered when its center `(x + 0.5, y + 0.5)` is inside a
//! triangle. Barycentrics are those of the texel center in UV space (affine, no perspective).
//!
//! Coverage uses edge functions evaluated in f64 with two rules that make shared edges exact:
//! * each edge function is always evaluated from the lexicographically smaller endpoint, so two
//!   triangles that share an edge get exactly negated values, never both positive;
//! * a texel center exactly on an edge (edge function 0) belongs to the triangle for which the
//!   edge, walked in that triangle's counter-clockwise order, points in the half-open half plane
//!   `dy > 0 || (dy == 0 && dx > 0)` — a top-left style rule, equivalent to nudging the point by
//!   `(−ε, ε²)` — so a texel on an edge (or on a vertex inside a fan) of one chart counts once.
//!
//! Wrapping: UVs outside [0, 1] repeat (`REPEAT`), the way a viewer with the default sampler
//! would show them. Texel indices are computed in the unwrapped plane and taken modulo the size
//! (a triangle beyond ±1024 tiles is first shifted by whole tiles to keep coordinates small).
//! A triangle whose UV bounding box is wider or taller than [`MAX_UV_SPAN`] tiles, or that has a
//! non-finite UV, is skipped (it cannot be baked meaningfully and would cost up to span² full
//! textures of work); [`skipped_triangles`] counts them. Degenerate (zero-area) triangles cover
//! nothing.
//!
//! Overlaps: a texel covered more than once (overlapping or mirrored charts, or a triangle that
//! covers it again in another repeat tile) keeps the lowest triangle index and is counted once in
//! [`TexelMap::overlapped`].
//!
//! Parallelism: triangles are set up in parallel, binned in triangle order into bands of
//! [`BAND_ROWS`] rows, and the bands are rasterized in parallel. Each band processes its
//! triangles in increasing index order, so the output is identical for any thread count.
//! Each row of a triangle only visits the texels between its edge intersections (plus one texel
//! of margin), so the cost is proportional to the covered area plus the number of rows.
//!
//! Written by hand: no maintained crate rasterizes into an index buffer with wrap, exact shared
//! edges and overlap detection.

use rayon::prelude::*;

/// Triangles whose UV bounding box spans more than this many tiles in u or in v are skipped.
pub const MAX_UV_SPAN: f64 = 8.0;

/// UV coordinates within ±this range are rasterized without a tile shift (see `prepare`).
const NO_SHIFT_RANGE: f64 = 1024.0;

/// Rows per band of the parallel rasterization.
pub const BAND_ROWS: u32 = 16;

/// The triangle covering a texel center and the barycentrics of that center.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TexelHit {
    /// Index of the triangle in the slice passed to [`rasterize_uv_layout`].
    pub triangle: u32,
    /// Barycentrics of the texel center with respect to the triangle's vertices in the given
    /// order; non-negative, summing to 1 (up to rounding).
    pub bary: [f32; 3],
}

/// The result of [`rasterize_uv_layout`]: one optional hit per texel, row-major from the top-left.
#[derive(Clone, Debug, PartialEq)]
pub struct TexelMap {
    /// Width in texels.
    pub width: u32,
    /// Height in texels.
    pub height: u32,
    /// `width × height` entries, row-major; `None` for texels no triangle covers.
    pub hits: Vec<Option<TexelHit>>,
    /// Number of texels covered by more than one triangle (or by one triangle in more than one
    /// repeat tile). Each such texel counts once.
    pub overlapped: u64,
}

impl TexelMap {
    /// Number of covered texels.
    pub fn covered(&self) -> u64 {
        self.hits.iter().filter(|h| h.is_some()).count() as u64
    }

    /// Coverage mask, row-major: `true` where a triangle covers the texel.
    pub fn mask(&self) -> Vec<bool> {
        self.hits.iter().map(Option::is_some).collect()
    }

    /// The hit at texel `(x, y)`, `None` when uncovered or out of range.
    pub fn hit(&self, x: u32, y: u32) -> Option<TexelHit> {
        if x >= self.width || y >= self.height {
            return None;
        }
        self.hits[y as usize * self.width as usize + x as usize]
    }
}

/// One edge `a → b` of a counter-clockwise triangle, evaluated from its canonical endpoint.
#[derive(Clone, Copy, Debug)]
struct Edge {
    /// Canonical (lexicographically smaller) endpoint.
    ax: f64,
    ay: f64,
    /// Canonical direction (from the smaller to the larger endpoint).
    dx: f64,
    dy: f64,
    /// +1 when the canonical direction is the triangle's direction, −1 otherwise.
    sign: f64,
    /// Whether points exactly on this edge are inside (the tie rule).
    include_zero: bool,
}

impl Edge {
    fn new(a: [f64; 2], b: [f64; 2]) -> Self {
        let (ca, cb, sign) = if (a[0], a[1]) <= (b[0], b[1]) {
            (a, b, 1.0)
        } else {
            (b, a, -1.0)
        };
        let (odx, ody) = (b[0] - a[0], b[1] - a[1]);
        Edge {
            ax: ca[0],
            ay: ca[1],
            dx: cb[0] - ca[0],
            dy: cb[1] - ca[1],
            sign,
            include_zero: ody > 0.0 || (ody == 0.0 && odx > 0.0),
        }
    }

    /// The row-constant part of the edge function at row center `py`.
    #[inline]
    fn row(&self, py: f64) -> f64 {
        self.dx * (py - self.ay)
    }

    /// The edge function (positive inside) at `px` given the row term `r`.
    #[inline]
    fn eval(&self, r: f64, px: f64) -> f64 {
        self.sign * (r - self.dy * (px - self.ax))
    }

    #[inline]
    fn inside(&self, e: f64) -> bool {
        e > 0.0 || (e == 0.0 && self.include_zero)
    }
}

/// A triangle prepared for rasterization: counter-clockwise (positive edge functions inside)
/// in tile-shifted pixel space.
#[derive(Clone, Copy, Debug)]
struct Setup {
    /// `edges[k]` is the edge opposite oriented vertex `k`.
    edges: [Edge; 3],
    /// `perm[k]` = index in the input triangle of oriented vertex `k`.
    perm: [usize; 3],
    /// Unwrapped texel index ranges (inclusive) that may hold covered texel centers.
    x_lo: i64,
    x_hi: i64,
    y_lo: i64,
    y_hi: i64,
}

enum Prepared {
    Ok(Setup),
    Degenerate,
    Skipped,
}

fn prepare(tri: &[[f32; 2]; 3], width: u32, height: u32) -> Prepared {
    if tri.iter().any(|p| !p[0].is_finite() || !p[1].is_finite()) {
        return Prepared::Skipped;
    }
    let us = tri.map(|p| p[0] as f64);
    let vs = tri.map(|p| p[1] as f64);
    let (umin, umax) = (
        us.iter().cloned().fold(f64::INFINITY, f64::min),
        us.iter().cloned().fold(f64::NEG_INFINITY, f64::max),
    );
    let (vmin, vmax) = (
        vs.iter().cloned().fold(f64::INFINITY, f64::min),
        vs.iter().cloned().fold(f64::NEG_INFINITY, f64::max),
    );
    if umax - umin > MAX_UV_SPAN || vmax - vmin > MAX_UV_SPAN {
        return Prepared::Skipped;
    }
    // UVs within ±NO_SHIFT_RANGE are used as they are, so triangles that share an edge see the
    // very same coordinates and edge-function arithmetic (the shared-edge rule relies on it).
    // Triangles farther out are shifted by whole tiles to keep the pixel coordinates small.
    // Scaling an f32 by the size is exact in f64.
    let shift = |min: f64, max: f64| {
        if min >= -NO_SHIFT_RANGE && max <= NO_SHIFT_RANGE {
            0.0
        } else {
            min.floor()
        }
    };
    let (su, sv) = (shift(umin, umax), shift(vmin, vmax));
    let (w, h) = (width as f64, height as f64);
    let mut p = [[0.0f64; 2]; 3];
    for k in 0..3 {
        p[k] = [(us[k] - su) * w, (vs[k] - sv) * h];
    }
    let area2 = Edge::new(p[0], p[1]);
    let a = area2.eval(area2.row(p[2][1]), p[2][0]);
    if a == 0.0 || !a.is_finite() {
        return Prepared::Degenerate;
    }
    let perm = if a > 0.0 { [0, 1, 2] } else { [0, 2, 1] };
    let v = perm.map(|k| p[k]);
    let edges = [
        Edge::new(v[1], v[2]),
        Edge::new(v[2], v[0]),
        Edge::new(v[0], v[1]),
    ];
    let (xmin, xmax) = (
        p.iter().map(|q| q[0]).fold(f64::INFINITY, f64::min),
        p.iter().map(|q| q[0]).fold(f64::NEG_INFINITY, f64::max),
    );
    let (ymin, ymax) = (
        p.iter().map(|q| q[1]).fold(f64::INFINITY, f64::min),
        p.iter().map(|q| q[1]).fold(f64::NEG_INFINITY, f64::max),
    );
    // Texel centers k + 0.5 within [min, max], one texel of margin for rounding.
    Prepared::Ok(Setup {
        edges,
        perm,
        x_lo: (xmin - 0.5).floor() as i64,
        x_hi: (xmax - 0.5).ceil() as i64,
        y_lo: (ymin - 0.5).floor() as i64,
        y_hi: (ymax - 0.5).ceil() as i64,
    })
}

/// `floor` of a finite f64 of moderate size (a cast and a fix-up; cheaper than the libm call).
#[inline(always)]
fn floor_i64(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) > x {
        t - 1
    } else {
        t
    }
}

/// `ceil` of a finite f64 of moderate size.
#[inline(always)]
fn ceil_i64(x: f64) -> i64 {
    let t = x as i64;
    if (t as f64) < x {
        t + 1
    } else {
        t
    }
}

/// A triangle's visit of one band: which triangle and which repeat tile row.
#[derive(Clone, Copy, Debug)]
struct BandEntry {
    triangle: u32,
    tile_row: i64,
}

/// Rasterizes a UV layout: `triangles[i]` holds the three UVs of triangle `i` (glTF convention,
/// see the module docs). Returns, for each texel, the lowest-index triangle covering its center
/// and the barycentrics of that center.
///
/// Deterministic, and identical for any number of rayon threads. Zero width or height gives an
/// empty map.
pub fn rasterize_uv_layout(triangles: &[[[f32; 2]; 3]], width: u32, height: u32) -> TexelMap {
    let n_texels = width as usize * height as usize;
    if n_texels == 0 {
        return TexelMap {
            width,
            height,
            hits: Vec::new(),
            overlapped: 0,
        };
    }
    let setups: Vec<Option<Setup>> = triangles
        .par_iter()
        .map(|t| match prepare(t, width, height) {
            Prepared::Ok(s) => Some(s),
            Prepared::Degenerate | Prepared::Skipped => None,
        })
        .collect();

    // Binning: chunks of triangles are binned in parallel, then each band concatenates its lists
    // in chunk order, so every band lists its triangles in increasing index order.
    let (w, h) = (width as i64, height as i64);
    let band_count = height.div_ceil(BAND_ROWS) as usize;
    let chunk = (setups.len() / 64).max(2048);
    let partial: Vec<Vec<Vec<BandEntry>>> = setups
        .par_chunks(chunk)
        .enumerate()
        .map(|(c, part)| {
            let mut bands: Vec<Vec<BandEntry>> = vec![Vec::new(); band_count];
            for (k, s) in part.iter().enumerate() {
                let Some(s) = s else { continue };
                let triangle = (c * chunk + k) as u32;
                for tile_row in s.y_lo.div_euclid(h)..=s.y_hi.div_euclid(h) {
                    let lo = (s.y_lo - tile_row * h).max(0);
                    let hi = (s.y_hi - tile_row * h).min(h - 1);
                    if lo > hi {
                        continue;
                    }
                    let (b0, b1) = (
                        lo as usize / BAND_ROWS as usize,
                        hi as usize / BAND_ROWS as usize,
                    );
                    for band in &mut bands[b0..=b1] {
                        band.push(BandEntry { triangle, tile_row });
                    }
                }
            }
            bands
        })
        .collect();
    let bands: Vec<Vec<BandEntry>> = (0..band_count)
        .into_par_iter()
        .map(|b| {
            let mut all = Vec::with_capacity(partial.iter().map(|p| p[b].len()).sum());
            for p in &partial {
                all.extend_from_slice(&p[b]);
            }
            all
        })
        .collect();
    drop(partial);

    // Filled in parallel so the page faults of this large buffer are shared by the threads.
    let mut hits: Vec<Option<TexelHit>> = Vec::new();
    hits.par_extend(rayon::iter::repeat_n(None, n_texels));
    let band_texels = BAND_ROWS as usize * width as usize;
    let overlapped: u64 = hits
        .par_chunks_mut(band_texels)
        .zip(bands.par_iter())
        .enumerate()
        .map(|(band, (out, entries))| {
            let row0 = band as i64 * BAND_ROWS as i64;
            let rows = (out.len() / width as usize) as i64;
            let mut multi = vec![false; out.len()];
            let mut overlapped = 0u64;
            for entry in entries {
                let s = setups[entry.triangle as usize]
                    .as_ref()
                    .expect("binned triangles have a setup");
                let base = entry.tile_row * h;
                let y_from = (s.y_lo - base).max(row0);
                let y_to = (s.y_hi - base).min(row0 + rows - 1);
                for y in y_from..=y_to {
                    let py = (y + base) as f64 + 0.5;
                    let r = s.edges.map(|e| e.row(py));
                    // Span of the row inside all three edges.
                    let (mut lo, mut hi) = (s.x_lo as f64, s.x_hi as f64 + 1.0);
                    let mut empty = false;
                    for (e, &rk) in s.edges.iter().zip(&r) {
                        let slope = e.sign * e.dy;
                        let m = e.sign * rk;
                        if slope > 0.0 {
                            hi = hi.min(e.ax + m / slope);
                        } else if slope < 0.0 {
                            lo = lo.max(e.ax + m / slope);
                        } else if m < 0.0 {
                            empty = true;
                        }
                    }
                    if empty || lo > hi + 2.0 {
                        continue;
                    }
                    let x_from = (ceil_i64(lo - 0.5) - 1).max(s.x_lo);
                    let x_to = (floor_i64(hi - 0.5) + 1).min(s.x_hi);
                    let row_off = (y - row0) as usize * width as usize;
                    let mut xw = x_from.rem_euclid(w) as usize;
                    for x in x_from..=x_to {
                        let px = x as f64 + 0.5;
                        let e0 = s.edges[0].eval(r[0], px);
                        let e1 = s.edges[1].eval(r[1], px);
                        let e2 = s.edges[2].eval(r[2], px);
                        if s.edges[0].inside(e0) && s.edges[1].inside(e1) && s.edges[2].inside(e2) {
                            let t = row_off + xw;
                            if out[t].is_none() {
                                let sum = e0 + e1 + e2;
                                let mut bary = [0.0f32; 3];
                                bary[s.perm[0]] = (e0 / sum) as f32;
                                bary[s.perm[1]] = (e1 / sum) as f32;
                                bary[s.perm[2]] = (e2 / sum) as f32;
                                out[t] = Some(TexelHit {
                                    triangle: entry.triangle,
                                    bary,
                                });
                            } else if !multi[t] {
                                multi[t] = true;
                                overlapped += 1;
                            }
                        }
                        xw += 1;
                        if xw == width as usize {
                            xw = 0;
                        }
                    }
                }
            }
            overlapped
        })
        .sum();

    TexelMap {
        width,
        height,
        hits,
        overlapped,
    }
}

/// Whether [`rasterize_uv_layout`] skips this triangle: a UV is not finite, or its UV bounding box
/// spans more than [`MAX_UV_SPAN`] tiles in u or v. (Degenerate triangles are not "skipped"; they
/// simply cover nothing.)
pub fn is_skipped(triangle: &[[f32; 2]; 3]) -> bool {
    matches!(prepare(triangle, 1, 1), Prepared::Skipped)
}

/// Number of triangles of a layout that [`rasterize_uv_layout`] skips (see [`is_skipped`]), for
/// warnings.
pub fn skipped_triangles(triangles: &[[[f32; 2]; 3]]) -> usize {
    triangles.iter().filter(|t| is_skipped(t)).count()
}

#[cfg(test)]
mod tests {
    use super::*;

    use crate::engine::rng::SplitMix64 as Rng;

    fn area(t: &[[f32; 2]; 3]) -> f64 {
        let (a, b, c) = (t[0], t[1], t[2]);
        0.5 * (((b[0] - a[0]) as f64) * ((c[1] - a[1]) as f64)
            - ((b[1] - a[1]) as f64) * ((c[0] - a[0]) as f64))
            .abs()
    }

    fn unit_square() -> Vec<[[f32; 2]; 3]> {
        // One triangle counter-clockwise and one clockwise (y down): winding must not matter.
        vec![
            [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]],
            [[0.0, 0.0], [0.0, 1.0], [1.0, 1.0]],
        ]
    }

    #[test]
    fn unit_square_covers_every_texel_once() {
        let map = rasterize_uv_layout(&unit_square(), 64, 64);
        assert_eq!(map.covered(), 4096);
        assert_eq!(map.overlapped, 0);
        // The diagonal passes through texel centers: the tie rule gives each to one triangle.
        let on_diagonal: Vec<u32> = (0..64).map(|i| map.hit(i, i).unwrap().triangle).collect();
        assert!(on_diagonal.iter().all(|&t| t == on_diagonal[0]));
        // Non-square sizes too.
        let map = rasterize_uv_layout(&unit_square(), 37, 20);
        assert_eq!((map.covered(), map.overlapped), (37 * 20, 0));
    }

    #[test]
    fn mirrored_duplicate_counts_as_overlap_and_goes_to_lower_index() {
        let tri = [[0.1f32, 0.2], [0.8, 0.3], [0.4, 0.9]];
        let alone = rasterize_uv_layout(&[tri], 64, 64);
        let mirrored = [tri[0], tri[2], tri[1]];
        let other = [[0.9f32, 0.9], [0.95, 0.9], [0.95, 0.95]];
        let map = rasterize_uv_layout(&[other, mirrored, tri], 64, 64);
        assert!(alone.covered() > 500);
        let other_cov = rasterize_uv_layout(&[other], 64, 64).covered();
        assert_eq!(map.overlapped, alone.covered());
        assert_eq!(map.covered(), alone.covered() + other_cov);
        for (i, h) in alone.hits.iter().enumerate() {
            if h.is_some() {
                assert_eq!(map.hits[i].unwrap().triangle, 1);
            }
        }
    }

    #[test]
    fn jittered_grid_with_fans_on_texel_centers_covers_once() {
        let (w, h) = (64u32, 48u32);
        let n = 8;
        let mut rng = Rng::new(7);
        // Interior vertices snapped to texel centers (fans meet exactly on a center), boundary on
        // the border.
        let vert = |i: usize, j: usize, rng: &mut Rng| -> [f32; 2] {
            let coord = |k: usize, size: u32, r: f32| -> f32 {
                if k == 0 || k == n {
                    k as f32 / n as f32
                } else {
                    let c = (k as f32 / n as f32 + (r - 0.5) * 0.08) * size as f32;
                    (c.floor() + 0.5) / size as f32
                }
            };
            let (r1, r2) = (rng.unit_f32(), rng.unit_f32());
            [coord(i, w, r1), coord(j, h, r2)]
        };
        let mut grid = vec![[0.0f32; 2]; (n + 1) * (n + 1)];
        for j in 0..=n {
            for i in 0..=n {
                grid[j * (n + 1) + i] = vert(i, j, &mut rng);
            }
        }
        let g = |i: usize, j: usize| grid[j * (n + 1) + i];
        let mut tris = Vec::new();
        for j in 0..n {
            for i in 0..n {
                if (i + j) % 2 == 0 {
                    tris.push([g(i, j), g(i + 1, j), g(i + 1, j + 1)]);
                    tris.push([g(i, j), g(i + 1, j + 1), g(i, j + 1)]);
                } else {
                    tris.push([g(i, j), g(i + 1, j), g(i, j + 1)]);
                    tris.push([g(i + 1, j), g(i + 1, j + 1), g(i, j + 1)]);
                }
            }
        }
        let map = rasterize_uv_layout(&tris, w, h);
        assert_eq!(map.covered(), (w * h) as u64);
        assert_eq!(map.overlapped, 0);
    }

    #[test]
    fn coverage_matches_analytic_area() {
        let (w, h) = (256u32, 256u32);
        let mut rng = Rng::new(42);
        let mut texels = 0u64;
        let mut analytic = 0.0f64;
        for _ in 0..200 {
            let t = [
                [rng.unit_f32(), rng.unit_f32()],
                [rng.unit_f32(), rng.unit_f32()],
                [rng.unit_f32(), rng.unit_f32()],
            ];
            texels += rasterize_uv_layout(&[t], w, h).covered();
            analytic += area(&t) * (w * h) as f64;
        }
        let rel = (texels as f64 - analytic).abs() / analytic;
        assert!(
            rel < 0.01,
            "covered {texels} vs analytic {analytic:.0}: {rel}"
        );
    }

    #[test]
    fn barycentrics_reproduce_texel_centers() {
        let (w, h) = (256u32, 192u32);
        let mut rng = Rng::new(3);
        let tris: Vec<[[f32; 2]; 3]> = (0..60)
            .map(|_| {
                let c = [rng.unit_f32() * 0.8 + 0.1, rng.unit_f32() * 0.8 + 0.1];
                let mut p = || {
                    [
                        c[0] + (rng.unit_f32() - 0.5) * 0.2,
                        c[1] + (rng.unit_f32() - 0.5) * 0.2,
                    ]
                };
                [p(), p(), p()]
            })
            .collect();
        let map = rasterize_uv_layout(&tris, w, h);
        assert!(map.covered() > 1000);
        let mut worst = 0.0f64;
        for y in 0..h {
            for x in 0..w {
                let Some(hit) = map.hit(x, y) else { continue };
                let t = &tris[hit.triangle as usize];
                assert!(hit.bary.iter().all(|&b| b >= -1e-6), "{hit:?}");
                assert!((hit.bary.iter().sum::<f32>() - 1.0).abs() < 1e-5);
                let mut p = [0.0f64; 2];
                for (b, v) in hit.bary.iter().zip(t) {
                    p[0] += *b as f64 * v[0] as f64 * w as f64;
                    p[1] += *b as f64 * v[1] as f64 * h as f64;
                }
                let err = (p[0] - (x as f64 + 0.5))
                    .abs()
                    .max((p[1] - (y as f64 + 0.5)).abs());
                worst = worst.max(err);
            }
        }
        assert!(worst < 1e-4, "worst texel-center error {worst} texels");
    }

    #[test]
    fn uvs_outside_the_unit_square_repeat() {
        // The unit square shifted by half a tile in u and by 3 tiles in v: still every texel once.
        let shifted: Vec<[[f32; 2]; 3]> = unit_square()
            .iter()
            .map(|t| t.map(|p| [p[0] + 0.5, p[1] - 3.0]))
            .collect();
        let map = rasterize_uv_layout(&shifted, 32, 32);
        assert_eq!((map.covered(), map.overlapped), (1024, 0));
        // A triangle one tile to the right rasterizes like the original.
        let tri = [[0.125f32, 0.25], [0.8125, 0.3125], [0.375, 0.875]];
        let moved = tri.map(|p| [p[0] + 1.0, p[1] - 2.0]);
        assert_eq!(
            rasterize_uv_layout(&[tri], 50, 40),
            rasterize_uv_layout(&[moved], 50, 40)
        );
        // Far away (beyond the no-shift range): still every texel once.
        let far: Vec<[[f32; 2]; 3]> = unit_square()
            .iter()
            .map(|t| t.map(|p| [p[0] + 5000.0, p[1] - 7000.0]))
            .collect();
        let map = rasterize_uv_layout(&far, 32, 32);
        assert_eq!((map.covered(), map.overlapped), (1024, 0));
        // A quad spanning two tiles covers each texel twice: once overlapped.
        let wide: Vec<[[f32; 2]; 3]> = unit_square()
            .iter()
            .map(|t| t.map(|p| [p[0] * 2.0, p[1]]))
            .collect();
        let map = rasterize_uv_layout(&wide, 32, 32);
        assert_eq!((map.covered(), map.overlapped), (1024, 1024));
    }

    #[test]
    fn degenerate_and_absurd_triangles_cover_nothing() {
        let degenerate = [[0.1f32, 0.1], [0.5, 0.5], [0.9, 0.9]];
        let point = [[0.3f32, 0.3]; 3];
        let huge = [[0.0f32, 0.0], [1.0e6, 0.0], [0.0, 1.0e6]];
        let sliver = [[-100.0f32, 0.0], [100.0, 0.5], [0.0, 0.6]];
        let nan = [[f32::NAN, 0.0], [1.0, 0.0], [0.0, 1.0]];
        let inf = [[f32::INFINITY, 0.0], [1.0, 0.0], [0.0, 1.0]];
        let layout = [degenerate, point, huge, sliver, nan, inf];
        let map = rasterize_uv_layout(&layout, 64, 64);
        assert_eq!((map.covered(), map.overlapped), (0, 0));
        assert_eq!(skipped_triangles(&layout), 4);
        assert!(!is_skipped(&degenerate));
        let empty = rasterize_uv_layout(&unit_square(), 0, 10);
        assert!(empty.hits.is_empty());
    }

    #[test]
    fn output_is_identical_for_one_and_two_threads() {
        let mut rng = Rng::new(11);
        let tris: Vec<[[f32; 2]; 3]> = (0..3000)
            .map(|_| {
                let c = [rng.unit_f32() * 3.0 - 1.0, rng.unit_f32() * 3.0 - 1.0];
                let mut p = || {
                    [
                        c[0] + (rng.unit_f32() - 0.5) * 0.1,
                        c[1] + (rng.unit_f32() - 0.5) * 0.1,
                    ]
                };
                [p(), p(), p()]
            })
            .collect();
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| rasterize_uv_layout(&tris, 300, 200))
        };
        let one = run(1);
        let two = run(2);
        assert!(one.covered() > 10_000 && one.overlapped > 0);
        assert_eq!(one, two);
    }
}
