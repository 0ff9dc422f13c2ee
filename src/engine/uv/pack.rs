//! Chart packing: shelf packing with 90° rotation and a gutter, the scale (texels per world
//! unit, the same for every chart, so texel density is uniform up to each chart's own stretch)
//! chosen by bisection as the largest at which every chart fits in the square texture.
//!
//! Lévy et al. 2002 §5 pack by a "Tetris" descent of the charts' horizon; here the simpler shelf
//! algorithm (charts turned so that they are wider than tall, sorted by height, placed left to
//! right on shelves stacked bottom to top) replaces it. Why: it is linear after the sort,
//! deterministic, and the bisection over the scale makes it fill the square; the packing
//! efficiency it reaches is reported (see [`super::report`]) and compared in the README.
//! Constants: 48 bisection steps (the scale's relative resolution is then far below one
//! texel); charts keep one texel of slack on each axis beyond their exact extent so that
//! rounding never makes two charts' texels touch.

/// Where a chart goes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Placement {
    /// Lower-left corner of the chart's (rotated) bounding box, in texels.
    pub offset: [f64; 2],
    /// Whether the chart is turned by 90°.
    pub rotated: bool,
}

/// Bisection steps over the scale.
const STEPS: usize = 48;

/// Shelf-packs boxes of `sizes` (world units) scaled by `scale` into a `width`² square with
/// `gutter` texels between boxes; `None` if they do not fit.
fn shelf(sizes: &[[f64; 2]], scale: f64, width: f64, gutter: f64) -> Option<Vec<Placement>> {
    let mut order: Vec<(usize, [f64; 2], bool)> = sizes
        .iter()
        .enumerate()
        .map(|(i, s)| {
            let rotated = s[1] > s[0];
            let (w, h) = if rotated { (s[1], s[0]) } else { (s[0], s[1]) };
            (
                i,
                [
                    (w * scale).ceil() + 1.0 + gutter,
                    (h * scale).ceil() + 1.0 + gutter,
                ],
                rotated,
            )
        })
        .collect();
    order.sort_by(|a, b| b.1[1].total_cmp(&a.1[1]).then(a.0.cmp(&b.0)));
    let mut out = vec![
        Placement {
            offset: [0.0; 2],
            rotated: false
        };
        sizes.len()
    ];
    let (mut x, mut y, mut shelf_h) = (0.0f64, 0.0f64, 0.0f64);
    for (i, [w, h], rotated) in order {
        if w > width {
            return None;
        }
        if x + w > width {
            y += shelf_h;
            x = 0.0;
            shelf_h = 0.0;
        }
        if y + h > width {
            return None;
        }
        out[i] = Placement {
            offset: [x + 0.5 * gutter + 0.5, y + 0.5 * gutter + 0.5],
            rotated,
        };
        x += w;
        shelf_h = shelf_h.max(h);
    }
    Some(out)
}

/// Packs charts of bounding-box `sizes` (world units) into a `texture_size`² texture with
/// `gutter` texels between charts. Returns the scale (texels per world unit) and the
/// placements, or `None` when even a vanishing scale does not fit (too many charts for the
/// texture and gutter).
pub fn pack(sizes: &[[f64; 2]], texture_size: u32, gutter: u32) -> Option<(f64, Vec<Placement>)> {
    let width = f64::from(texture_size);
    let g = f64::from(gutter);
    let area: f64 = sizes
        .iter()
        .map(|s| s[0].max(1e-300) * s[1].max(1e-300))
        .sum();
    let longest = sizes
        .iter()
        .map(|s| s[0].max(s[1]))
        .fold(0.0f64, f64::max)
        .max(1e-300);
    let mut hi = (width / area.sqrt()).min(width / longest);
    let mut lo = 0.0;
    let mut best = shelf(sizes, 0.0, width, g).map(|p| (0.0, p))?;
    // The upper bound can be feasible only when every chart is a square filling its shelf.
    if let Some(p) = shelf(sizes, hi, width, g) {
        return Some((hi, p));
    }
    for _ in 0..STEPS {
        let mid = 0.5 * (lo + hi);
        match shelf(sizes, mid, width, g) {
            Some(p) => {
                lo = mid;
                best = (mid, p);
            }
            None => hi = mid,
        }
    }
    (best.0 > 0.0).then_some(best)
}
