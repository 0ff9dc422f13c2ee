//! Chart packing: the scale (texels per world unit, the same for every chart, so texel density is
//! uniform up to each chart's own stretch) is the largest at which every chart fits in the square
//! texture with a gutter, found by bisection; [`pack`] runs two packers and keeps the one with
//! the larger scale: the skyline packer of chart bounding boxes here, then the outline packer of
//! [`super::bitmap_pack`], whose scale search starts from the skyline's.
//!
//! Lévy et al. 2002 §5 pack by a "Tetris" descent of the charts' horizon. Here each chart's
//! bounding box (charts are turned to their principal axes first) descends onto the skyline of
//! the boxes placed so far: the boxes go tallest first, each to the position, over every
//! skyline segment and both orientations, where its top is lowest (then leftmost). Unlike the
//! paper's horizon this keeps no holes under overhangs, and it packs boxes, not chart outlines
//! (which [`super::bitmap_pack`] does). It replaced a shelf packer (boxes left to right on
//! shelves as tall as their first box), whose efficiency the README compares. Written here: no
//! crate packs rectangles with this scale search. Constants: 48 bisection steps (the scale's
//! relative resolution is then far below one texel); charts keep one texel of slack on each axis
//! beyond their exact extent so that rounding never makes two charts' texels touch.

use super::bitmap_pack::pack_outlines;
pub use super::bitmap_pack::Outline;

/// Where a chart goes: texel = `offset` + R^`quarter` (scale · p) for a chart point `p` (world
/// units), R the counter-clockwise quarter turn (turns keep the triangles' orientation).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Placement {
    /// Texel position of the chart's origin after the turn.
    pub offset: [f64; 2],
    /// Counter-clockwise quarter turns, 0-3.
    pub quarter: u8,
}

impl Placement {
    /// The texel position of chart point `p` at `scale` texels per unit.
    pub fn apply(&self, p: [f64; 2], scale: f64) -> [f64; 2] {
        let [x, y] = [p[0] * scale, p[1] * scale];
        let q = match self.quarter % 4 {
            0 => [x, y],
            1 => [-y, x],
            2 => [-x, -y],
            _ => [y, -x],
        };
        [self.offset[0] + q[0], self.offset[1] + q[1]]
    }
}

/// Bisection steps over the scale.
const STEPS: usize = 48;

/// The box sizes in texels (chart extent, one texel of slack and the gutter), each turned so
/// that it is wider than tall, in packing order: tallest first, then widest, then by index.
fn boxes(sizes: &[[f64; 2]], scale: f64, gutter: f64) -> Vec<(usize, [f64; 2], bool)> {
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
    order.sort_by(|a, b| {
        b.1[1]
            .total_cmp(&a.1[1])
            .then(b.1[0].total_cmp(&a.1[0]))
            .then(a.0.cmp(&b.0))
    });
    order
}

/// One run of the skyline: from `x` to the next segment's `x`, the packed height is `y`.
#[derive(Clone, Copy, Debug)]
struct Segment {
    x: f64,
    y: f64,
}

/// The lowest position of a `w × h` box on the skyline of `width`: `(top, x, y)` with the
/// smallest top, then the smallest x; `None` if it fits nowhere below `width`.
fn lowest(skyline: &[Segment], w: f64, h: f64, width: f64) -> Option<(f64, f64, f64)> {
    let mut best: Option<(f64, f64, f64)> = None;
    for (i, start) in skyline.iter().enumerate() {
        let x = start.x;
        if x + w > width {
            break;
        }
        // The box rests on the highest segment under [x, x + w).
        let mut y = 0.0f64;
        for s in &skyline[i..] {
            if s.x >= x + w {
                break;
            }
            y = y.max(s.y);
        }
        let top = y + h;
        if top <= width && best.is_none_or(|b| top < b.0) {
            best = Some((top, x, y));
        }
    }
    best
}

/// Raises the skyline over `[x, x + w)` to `top`.
fn raise(skyline: &mut Vec<Segment>, x: f64, w: f64, top: f64) {
    let end = x + w;
    // The height at `end` before the change (the segment that covers it).
    let after = skyline
        .iter()
        .take_while(|s| s.x <= end)
        .last()
        .map_or(0.0, |s| s.y);
    skyline.retain(|s| s.x < x || s.x > end);
    let at = skyline.partition_point(|s| s.x < x);
    skyline.insert(at, Segment { x, y: top });
    if skyline.get(at + 1).is_none_or(|s| s.x > end) {
        skyline.insert(at + 1, Segment { x: end, y: after });
    }
    // Neighbours of equal height are one run.
    skyline.dedup_by(|b, a| a.y == b.y);
}

/// Skyline-packs boxes of `sizes` (world units) scaled by `scale` into a `width`² square with
/// `gutter` texels between boxes, each at the lowest place the skyline offers for it in either
/// orientation; `None` if they do not fit.
fn skyline(sizes: &[[f64; 2]], scale: f64, width: f64, gutter: f64) -> Option<Vec<Placement>> {
    let mut out = vec![Placement::default(); sizes.len()];
    let mut line = vec![Segment { x: 0.0, y: 0.0 }];
    for (i, [w, h], rotated) in boxes(sizes, scale, gutter) {
        let flat = lowest(&line, w, h, width).map(|p| (p, w, h, rotated));
        let upright = lowest(&line, h, w, width).map(|p| (p, h, w, !rotated));
        let ((top, x, y), bw, _, turned) = match (flat, upright) {
            (Some(a), Some(b)) => {
                if (b.0 .0, b.0 .1) < (a.0 .0, a.0 .1) {
                    b
                } else {
                    a
                }
            }
            (a, b) => a.or(b)?,
        };
        // A 90° turn (x, y) → (h − y, x) of the chart's box [0, w] × [0, h].
        let lift = if turned { sizes[i][1] * scale } else { 0.0 };
        out[i] = Placement {
            offset: [x + 0.5 * gutter + 0.5 + lift, y + 0.5 * gutter + 0.5],
            quarter: u8::from(turned),
        };
        raise(&mut line, x, bw, top);
    }
    Some(out)
}

/// Packs charts (outlines with their boxes at the origin) into a `texture_size`² texture with
/// `gutter` texels between charts: the skyline packing of their boxes or the bitmap packing of
/// their outlines, whichever reaches the larger scale (see the module doc). Returns the scale
/// (texels per world unit) and the placements, or `None` when even a vanishing scale does not
/// fit (too many charts for the texture and gutter).
pub fn pack(charts: &[Outline], texture_size: u32, gutter: u32) -> Option<(f64, Vec<Placement>)> {
    let sizes: Vec<[f64; 2]> = charts.iter().map(|c| c.size).collect();
    let boxes = pack_boxes(&sizes, texture_size, gutter)?;
    match pack_outlines(charts, texture_size, gutter, boxes.0) {
        Some(outlines) if outlines.0 > boxes.0 => Some(outlines),
        _ => Some(boxes),
    }
}

/// Skyline-packs charts of bounding-box `sizes` (world units) into a `texture_size`² texture
/// with `gutter` texels between charts. Returns the scale (texels per world unit) and the
/// placements, or `None` when even a vanishing scale does not fit.
pub fn pack_boxes(
    sizes: &[[f64; 2]],
    texture_size: u32,
    gutter: u32,
) -> Option<(f64, Vec<Placement>)> {
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
    let mut best = skyline(sizes, 0.0, width, g).map(|p| (0.0, p))?;
    // The upper bound can be feasible only when the boxes tile the square exactly.
    if let Some(p) = skyline(sizes, hi, width, g) {
        return Some((hi, p));
    }
    for _ in 0..STEPS {
        let mid = 0.5 * (lo + hi);
        match skyline(sizes, mid, width, g) {
            Some(p) => {
                lo = mid;
                best = (mid, p);
            }
            None => hi = mid,
        }
    }
    (best.0 > 0.0).then_some(best)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::rng::SplitMix64;

    /// Random boxes (aspect up to 4, areas over two orders of magnitude): every box inside the
    /// square, no two boxes (with their gutter) overlapping, and the boxes filling most of it.
    #[test]
    fn skyline_packs_without_overlap_and_fills_the_square() {
        for seed in 1..=4u64 {
            let mut rng = SplitMix64::new(seed);
            let sizes: Vec<[f64; 2]> = (0..300)
                .map(|_| {
                    let side = 0.1 + rng.unit_f32() as f64 * 0.9;
                    let aspect = 1.0 + rng.unit_f32() as f64 * 3.0;
                    [side, side / aspect]
                })
                .collect();
            let (width, gutter) = (1024u32, 2u32);
            let (scale, places) = pack_boxes(&sizes, width, gutter).expect("fits");
            let g = f64::from(gutter);
            let rects: Vec<[f64; 4]> = sizes
                .iter()
                .zip(&places)
                .map(|(s, p)| {
                    let (w, h) = if p.quarter == 1 {
                        (s[1], s[0])
                    } else {
                        (s[0], s[1])
                    };
                    let (w, h) = ((w * scale).ceil() + 1.0, (h * scale).ceil() + 1.0);
                    // The box's lower-left corner: the turned chart's, less half a texel.
                    let a = p.apply([0.0, 0.0], scale);
                    let b = p.apply(*s, scale);
                    let (x, y) = (a[0].min(b[0]) - 0.5, a[1].min(b[1]) - 0.5);
                    [x, y, x + w, y + h]
                })
                .collect();
            let mut used = 0.0;
            for (i, a) in rects.iter().enumerate() {
                assert!(a[0] >= 0.0 && a[1] >= 0.0, "seed {seed}: {a:?}");
                assert!(
                    a[2] <= f64::from(width) && a[3] <= f64::from(width),
                    "seed {seed}"
                );
                used += (a[2] - a[0]) * (a[3] - a[1]);
                for b in &rects[i + 1..] {
                    let apart = a[2] + g <= b[0] + 1e-9
                        || b[2] + g <= a[0] + 1e-9
                        || a[3] + g <= b[1] + 1e-9
                        || b[3] + g <= a[1] + 1e-9;
                    assert!(apart, "seed {seed}: {a:?} and {b:?} overlap");
                }
            }
            let fill = used / f64::from(width).powi(2);
            assert!(
                fill > 0.75,
                "seed {seed}: boxes fill {fill:.3} of the square"
            );
        }
    }
}
