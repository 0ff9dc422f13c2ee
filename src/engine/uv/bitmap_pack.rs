//! Outline packing on a bitmap: each chart's triangles, dilated by half the gutter, are
//! rasterised into a coarse occupancy grid, and charts are placed one by one, largest first, at
//! the lowest free position (then leftmost) in any of the four quarter turns, with the common
//! scale (texels per world unit) found by bisection as in [`super::pack`].
//!
//! This is the "Tetris" packing of Lévy et al. 2002 §5 done on a bitmap instead of a horizon
//! (so holes under overhangs stay usable), as xatlas's bitmap packer does (`PackCharts`:
//! conservative chart rasterisation dilated by the padding, first fit over positions and
//! rotations, a bit image per chart and one for the atlas). Differences from xatlas: the texture
//! size is fixed and the scale is searched (xatlas grows the atlas at a fixed texel density);
//! positions are searched exhaustively in scan order but with skip-ahead (a collision of a chart
//! row with the atlas row moves the candidate past the last occupied cell of that run, and a row
//! whose longest free run is shorter than the chart row's longest run rejects a candidate row
//! at once), so no random sampling is needed and the result is deterministic.
//!
//! Coverage is conservative: a grid cell belongs to a chart when its centre is inside the chart
//! (non-zero winding number of the boundary) or it lies within `r = (gutter + 1) / 2` texels (max
//! norm) of a boundary edge (each edge is cut with the cell row's band widened by `r`, and the
//! x-range of that piece, widened by `r`, gives the cells); a cell within `r` of the chart is
//! one or the other. Disjoint cells therefore keep any two charts at least `gutter + 1` texels
//! apart (the skyline's box slack gives the same), and cells inside the grid keep every chart
//! at least `r` texels inside the texture. Turns of 0° and 90° are rasterised; 180° and 270°
//! are those covers turned as bitmaps (exact on cells). Quarter turns keep the triangles'
//! orientation.
//!
//! The scale search starts from the skyline's scale (feasible for the boxes, usually for the
//! outlines; when not, [`super::pack`] keeps the skyline result, as on the icospheres, whose
//! charts are box-like) and probes two scales of the open interval at once (rayon; a third and
//! two thirds of the way on a log scale), so each round shrinks it threefold on two cores. The
//! result depends only on the input: every probe and its outcome are the same for any thread
//! count.
//!
//! Constants: the grid has at most [`GRID`] cells a side (a cell is 4 texels at 2048²: on the
//! shared scans 1024 cells gave the same efficiency to ±0.01 at 2-4× the time); the search stops
//! when the interval is [`TOLERANCE`] wide relative to its ends; [`MAX_FILL`] is its upper end;
//! the [`PROBE_ROWS`] widest chart rows are tested against each atlas row's longest free run
//! before a row of positions is swept. A chart's cover is rasterised from its boundary (the
//! triangles' edges with opposite edges cancelled), cells inside by the winding number at the
//! cell centre, so the cost grows with the boundary, not the triangle count.

use rayon::prelude::*;

use super::pack::Placement;

/// A chart to pack: its flat triangles in world units, bounding box at the origin.
pub struct Outline<'a> {
    /// Vertex positions (world units; the chart's box is `[0, size[0]] × [0, size[1]]`).
    pub points: &'a [[f64; 2]],
    /// Triangles, as indices into `points`.
    pub triangles: Vec<[u32; 3]>,
    /// Bounding-box size, world units.
    pub size: [f64; 2],
}

impl Outline<'_> {
    pub fn area(&self) -> f64 {
        let p = |i: u32| self.points[i as usize];
        self.triangles
            .iter()
            .map(|t| {
                let (a, b, c) = (p(t[0]), p(t[1]), p(t[2]));
                0.5 * ((b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1])).abs()
            })
            .sum()
    }
}

/// Largest number of grid cells along a side of the texture.
pub const GRID: u32 = 512;
/// Relative width of the scale interval at which the search stops (the packing efficiency is
/// then within 0.4 % of the last infeasible scale's).
pub const TOLERANCE: f64 = 0.002;
/// Packing efficiency of the upper end of the scale search (no packing with a gutter gets
/// there).
pub const MAX_FILL: f64 = 0.85;
/// Chart rows tested against the free-run lengths before a sweep.
pub const PROBE_ROWS: usize = 6;
/// Widening of every coverage test, texels (floating-point slack; conservative).
const EPS: f64 = 1e-6;

/// Texels per grid cell for a texture size.
pub fn cell_size(texture_size: u32) -> u32 {
    texture_size.div_ceil(GRID).max(1)
}

/// A `w × h` bit image, rows of 64-bit words.
#[derive(Clone, Debug)]
struct Bits {
    w: usize,
    h: usize,
    words: usize,
    data: Vec<u64>,
}

/// Bits `[lo, hi)` of a word (`lo < hi <= 64`).
fn mask(lo: usize, hi: usize) -> u64 {
    let upper = if hi == 64 { u64::MAX } else { (1u64 << hi) - 1 };
    upper & !((1u64 << lo) - 1)
}

/// Sets bits `[a, b)` of a row.
fn set_run(row: &mut [u64], a: usize, b: usize) {
    if a >= b {
        return;
    }
    let (wa, wb) = (a / 64, (b - 1) / 64);
    for (w, word) in row.iter_mut().enumerate().take(wb + 1).skip(wa) {
        let lo = if w == wa { a % 64 } else { 0 };
        let hi = if w == wb { (b - 1) % 64 + 1 } else { 64 };
        *word |= mask(lo, hi);
    }
}

/// The highest set bit of a row in `[a, b)`.
fn last_set(row: &[u64], a: usize, b: usize) -> Option<usize> {
    if a >= b {
        return None;
    }
    let (wa, wb) = (a / 64, (b - 1) / 64);
    for w in (wa..=wb).rev() {
        let lo = if w == wa { a % 64 } else { 0 };
        let hi = if w == wb { (b - 1) % 64 + 1 } else { 64 };
        let m = row[w] & mask(lo, hi);
        if m != 0 {
            return Some(w * 64 + 63 - m.leading_zeros() as usize);
        }
    }
    None
}

/// The first index in `[from, end)` whose bit is `one`, or `end`.
fn next_bit(row: &[u64], from: usize, end: usize, one: bool) -> usize {
    let mut i = from;
    while i < end {
        let w = i / 64;
        let word = if one { row[w] } else { !row[w] };
        let m = word >> (i % 64);
        if m != 0 {
            return (i + m.trailing_zeros() as usize).min(end);
        }
        i = (w + 1) * 64;
    }
    end
}

/// Appends the runs `[a, b)` of set bits of a row of width `w` to `out`.
fn runs(row: &[u64], w: usize, out: &mut Vec<(usize, usize)>) {
    let mut i = 0;
    while i < w {
        let a = next_bit(row, i, w, true);
        if a >= w {
            break;
        }
        let b = next_bit(row, a, w, false);
        out.push((a, b));
        i = b;
    }
}

/// The longest run of clear bits of a row of width `w`.
fn longest_gap(row: &[u64], w: usize) -> usize {
    let (mut i, mut best) = (0, 0);
    while i < w {
        let a = next_bit(row, i, w, false);
        let b = next_bit(row, a, w, true);
        best = best.max(b - a);
        i = b;
    }
    best
}

impl Bits {
    fn new(w: usize, h: usize) -> Self {
        let words = w.div_ceil(64).max(1);
        Self {
            w,
            h,
            words,
            data: vec![0; words * h],
        }
    }

    fn row(&self, y: usize) -> &[u64] {
        &self.data[y * self.words..(y + 1) * self.words]
    }

    fn row_mut(&mut self, y: usize) -> &mut [u64] {
        &mut self.data[y * self.words..(y + 1) * self.words]
    }
}

/// The chart's boundary as directed segments (world units): the triangles' edges, each triangle
/// counter-clockwise, with opposite edges cancelled (so the winding number of the segments at a
/// point is the number of triangles covering it). Edges are bucketed by their lower vertex.
fn boundary(chart: &Outline) -> Vec<[[f64; 2]; 2]> {
    let n = chart.points.len();
    let p = |i: u32| chart.points[i as usize];
    let mut start = vec![0usize; n + 1];
    let mut edges = Vec::with_capacity(3 * chart.triangles.len());
    for t in &chart.triangles {
        let (a, b, c) = (p(t[0]), p(t[1]), p(t[2]));
        let ccw = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1]) >= 0.0;
        let t = if ccw { *t } else { [t[0], t[2], t[1]] };
        for k in 0..3 {
            let (u, v) = (t[k], t[(k + 1) % 3]);
            edges.push((u.min(v), u.max(v), if u < v { 1i32 } else { -1 }));
            start[u.min(v) as usize + 1] += 1;
        }
    }
    for i in 0..n {
        start[i + 1] += start[i];
    }
    let mut bucket = vec![(0u32, 0i32); edges.len()];
    let mut fill = start.clone();
    for (lo, hi, sign) in edges {
        bucket[fill[lo as usize]] = (hi, sign);
        fill[lo as usize] += 1;
    }
    let mut out = Vec::new();
    for lo in 0..n {
        let b = &mut bucket[start[lo]..start[lo + 1]];
        b.sort_unstable_by_key(|e| e.0);
        let mut i = 0;
        while i < b.len() {
            let hi = b[i].0;
            let mut sum = 0;
            while i < b.len() && b[i].0 == hi {
                sum += b[i].1;
                i += 1;
            }
            let (u, v) = if sum > 0 {
                (lo as u32, hi)
            } else {
                (hi, lo as u32)
            };
            for _ in 0..sum.unsigned_abs() {
                out.push([p(u), p(v)]);
            }
        }
    }
    out
}

/// The cells, `cell` texels wide, of a chart dilated by `r` texels (max norm), the chart given
/// by its boundary `segments` in texels with its lower-left corner at `(r, r)`: cells whose
/// centre has a non-zero winding number (inside) and cells within `r` of a segment (each
/// segment is cut with the cell row's band widened by `r`; the x-range of that piece, widened
/// by `r`, gives the cells). A cell within `r` of the chart either lies within `r` of its
/// boundary or, with its whole neighbourhood, inside it, so the cover is conservative.
fn rasterise(segments: &[[[f64; 2]; 2]], cell: f64, r: f64) -> Bits {
    let rr = r + EPS;
    let top =
        (segments.iter().flatten()).fold([0.0f64; 2], |m, p| [m[0].max(p[0]), m[1].max(p[1])]);
    let count = |t: f64| ((t + rr) / cell).floor().max(0.0) as usize + 1;
    let (w, h) = (count(top[0]), count(top[1]));
    let mut bits = Bits::new(w, h);
    let index = |t: f64, n: usize| ((t / cell).floor().max(0.0) as usize).min(n - 1);
    let mut crossings: Vec<(usize, f64, i32)> = Vec::new();
    for [a, b] in segments {
        let (ymin, ymax) = (a[1].min(b[1]), a[1].max(b[1]));
        for j in index(ymin - rr, h)..=index(ymax + rr, h) {
            let (lo, hi) = (j as f64 * cell - rr, (j + 1) as f64 * cell + rr);
            let x_at = |y: f64| a[0] + (y - a[1]) / (b[1] - a[1]) * (b[0] - a[0]);
            let (mut x0, mut x1) = (f64::MAX, f64::MIN);
            for end in [a, b] {
                if (lo..=hi).contains(&end[1]) {
                    x0 = x0.min(end[0]);
                    x1 = x1.max(end[0]);
                }
            }
            for line in [lo, hi] {
                if (a[1] - line) * (b[1] - line) < 0.0 {
                    x0 = x0.min(x_at(line));
                    x1 = x1.max(x_at(line));
                }
            }
            if x0 <= x1 {
                set_run(bits.row_mut(j), index(x0 - rr, w), index(x1 + rr, w) + 1);
            }
            // The centre line of the row, half-open in y.
            let yc = (j as f64 + 0.5) * cell;
            if (a[1] <= yc) != (b[1] <= yc) {
                crossings.push((j, x_at(yc), if b[1] > a[1] { 1 } else { -1 }));
            }
        }
    }
    crossings.sort_unstable_by(|p, q| p.0.cmp(&q.0).then(p.1.total_cmp(&q.1)));
    let mut wind = 0;
    let mut from = 0.0;
    for &(j, x, dir) in &crossings {
        if wind == 0 {
            from = x;
        }
        wind += dir;
        if wind == 0 {
            // Cells whose centre lies in [from, x].
            let a = ((from / cell - 0.5).ceil().max(0.0) as usize).min(w);
            let b = ((x / cell - 0.5).floor() + 1.0).clamp(0.0, w as f64) as usize;
            set_run(bits.row_mut(j), a, b);
        }
    }
    bits
}

/// One turn of a chart's cover: per row its runs of cells (`runs[start[j]..start[j + 1]]`) and
/// longest run, and the rows to probe first.
#[derive(Debug)]
struct Shape {
    w: usize,
    h: usize,
    runs: Vec<(usize, usize)>,
    start: Vec<usize>,
    longest: Vec<usize>,
    probes: Vec<usize>,
}

impl Shape {
    fn new(bits: &Bits) -> Self {
        let mut runs_ = Vec::new();
        let mut start = vec![0];
        for j in 0..bits.h {
            runs(bits.row(j), bits.w, &mut runs_);
            start.push(runs_.len());
        }
        Self::of_runs(bits.w, runs_, start)
    }

    fn of_runs(w: usize, runs: Vec<(usize, usize)>, start: Vec<usize>) -> Self {
        let h = start.len() - 1;
        let longest: Vec<usize> = (0..h)
            .map(|j| {
                (runs[start[j]..start[j + 1]].iter())
                    .map(|(a, b)| b - a)
                    .max()
                    .unwrap_or(0)
            })
            .collect();
        let mut probes: Vec<usize> = (0..h).collect();
        probes.sort_by(|a, b| longest[*b].cmp(&longest[*a]).then(a.cmp(b)));
        probes.truncate(PROBE_ROWS);
        Self {
            w,
            h,
            runs,
            start,
            longest,
            probes,
        }
    }

    fn row(&self, j: usize) -> &[(usize, usize)] {
        &self.runs[self.start[j]..self.start[j + 1]]
    }

    /// This shape turned by 180°: cell `(i, j)` goes to `(w−1−i, h−1−j)`.
    fn half_turn(&self) -> Self {
        let w = self.w;
        let runs: Vec<(usize, usize)> = self
            .runs
            .iter()
            .rev()
            .map(|(a, b)| (w - b, w - a))
            .collect();
        let n = self.runs.len();
        let start = self.start.iter().rev().map(|s| n - s).collect();
        Self::of_runs(w, runs, start)
    }

    fn cells(&self) -> usize {
        self.runs.iter().map(|(a, b)| b - a).sum()
    }
}

/// A chart's cover at one scale, in its four quarter turns, each with the texel position of the
/// turned chart's origin relative to its cover's lower-left corner.
struct Cover {
    shapes: Vec<(Shape, [f64; 2])>,
    cells: usize,
}

impl Cover {
    /// Turns 0 and 1 are rasterised, 2 and 3 are their covers turned by 180° (exact on cells).
    fn new(segments: &[[[f64; 2]; 2]], scale: f64, cell: f64, r: f64) -> Self {
        let mut shapes: Vec<(Shape, [f64; 2])> = (0..2u8)
            .map(|quarter| {
                let turn = Placement {
                    offset: [0.0; 2],
                    quarter,
                };
                let mut turned: Vec<[[f64; 2]; 2]> = (segments.iter())
                    .map(|s| s.map(|p| turn.apply(p, scale)))
                    .collect();
                let lo = (turned.iter().flatten())
                    .fold([f64::MAX; 2], |m, p| [m[0].min(p[0]), m[1].min(p[1])]);
                let shift = [r - lo[0], r - lo[1]];
                for p in turned.iter_mut().flatten() {
                    *p = [p[0] + shift[0], p[1] + shift[1]];
                }
                (Shape::new(&rasterise(&turned, cell, r)), shift)
            })
            .collect();
        for k in 0..2 {
            let (shape, shift) = &shapes[k];
            // t ↦ (w, h) − t on the cover's box, after the turn k.
            let box_ = [shape.w as f64 * cell, shape.h as f64 * cell];
            let turned = (shape.half_turn(), [box_[0] - shift[0], box_[1] - shift[1]]);
            shapes.push(turned);
        }
        let cells = shapes[0].0.cells();
        Self { shapes, cells }
    }

    /// The placement of turn `k` with its cover's lower-left cell at `(x, y)`.
    fn placement(&self, k: usize, x: usize, y: usize, cell: f64) -> Placement {
        let shift = self.shapes[k].1;
        Placement {
            offset: [x as f64 * cell + shift[0], y as f64 * cell + shift[1]],
            quarter: k as u8,
        }
    }
}

/// The occupancy grid: `g × g` cells and each row's longest free run.
struct Grid {
    g: usize,
    bits: Bits,
    free: Vec<usize>,
}

impl Grid {
    fn new(g: usize) -> Self {
        Self {
            g,
            bits: Bits::new(g, g),
            free: vec![g; g],
        }
    }

    /// The leftmost `x` at which `shape` with its bottom row at `y` meets no occupied cell.
    fn sweep(&self, shape: &Shape, y: usize) -> Option<usize> {
        let mut x = 0;
        let mut first = shape.probes[0];
        'candidates: while x + shape.w <= self.g {
            for j in (first..shape.h).chain(0..first) {
                let row = self.bits.row(y + j);
                for &(a, b) in shape.row(j) {
                    if let Some(last) = last_set(row, x + a, x + b) {
                        x = last + 1 - a;
                        first = j;
                        continue 'candidates;
                    }
                }
            }
            return Some(x);
        }
        None
    }

    /// The lowest-topped free position of any turn, then the leftmost, then the first turn:
    /// `(turn, x, y)`.
    fn find(&self, cover: &Cover) -> Option<(usize, usize, usize)> {
        let mut best: Option<(usize, usize, usize, usize)> = None;
        for (k, (shape, _)) in cover.shapes.iter().enumerate() {
            if shape.w > self.g || shape.h > self.g {
                continue;
            }
            for y in 0..=self.g - shape.h {
                let top = y + shape.h;
                if best.is_some_and(|b| top > b.0) {
                    break;
                }
                let open = (shape.probes.iter()).all(|j| self.free[y + j] >= shape.longest[*j]);
                if !open {
                    continue;
                }
                if let Some(x) = self.sweep(shape, y) {
                    if best.is_none_or(|b| (top, x) < (b.0, b.1)) {
                        best = Some((top, x, k, y));
                    }
                    break;
                }
            }
        }
        best.map(|(_, x, k, y)| (k, x, y))
    }

    fn place(&mut self, shape: &Shape, x: usize, y: usize) {
        for j in 0..shape.h {
            let row = self.bits.row_mut(y + j);
            for &(a, b) in shape.row(j) {
                set_run(row, x + a, x + b);
            }
            self.free[y + j] = longest_gap(self.bits.row(y + j), self.g);
        }
    }
}

/// Packs every chart at `scale` in `order`, or `None` when one does not fit.
fn pack_at(
    charts: &[Vec<[[f64; 2]; 2]>],
    order: &[usize],
    scale: f64,
    texture_size: u32,
    r: f64,
) -> Option<Vec<Placement>> {
    let cell = f64::from(cell_size(texture_size));
    let g = (texture_size / cell_size(texture_size)) as usize;
    let covers: Vec<Cover> = charts
        .par_iter()
        .map(|c| Cover::new(c, scale, cell, r))
        .collect();
    if covers.iter().map(|c| c.cells).sum::<usize>() > g * g {
        return None;
    }
    let mut grid = Grid::new(g);
    let mut out = vec![Placement::default(); charts.len()];
    for &i in order {
        let (k, x, y) = grid.find(&covers[i])?;
        grid.place(&covers[i].shapes[k].0, x, y);
        out[i] = covers[i].placement(k, x, y, cell);
    }
    Some(out)
}

/// Packs chart outlines into a `texture_size`² texture with `gutter` texels (plus one, as the
/// skyline) between charts, searching the scale upward from `lower` (normally the skyline's
/// scale). Returns the scale and placements, or `None` when they do not fit even at `lower`.
pub fn pack_outlines(
    charts: &[Outline],
    texture_size: u32,
    gutter: u32,
    lower: f64,
) -> Option<(f64, Vec<Placement>)> {
    let r = 0.5 * (f64::from(gutter) + 1.0);
    let area: f64 = charts.iter().map(Outline::area).sum();
    // Largest first: by bounding-box area, then by index.
    let mut order: Vec<usize> = (0..charts.len()).collect();
    let key = |i: usize| charts[i].size[0] * charts[i].size[1];
    order.sort_by(|a, b| key(*b).total_cmp(&key(*a)).then(a.cmp(b)));
    let segments: Vec<Vec<[[f64; 2]; 2]>> = charts.par_iter().map(boundary).collect();
    let charts = &segments;
    let pack = |s: f64| pack_at(charts, &order, s, texture_size, r);
    // Two inner points of [lo, hi], a third and two thirds of the way on a log scale, packed
    // at once.
    let probe = |lo: f64, hi: f64| {
        let (a, b) = (lo * (hi / lo).cbrt(), lo * (hi / lo).cbrt().powi(2));
        let (pa, pb) = rayon::join(|| pack(a), || pack(b));
        ((a, pa), (b, pb))
    };
    let mut lo = lower;
    let mut hi = f64::from(texture_size) * (MAX_FILL / area.max(1e-300)).sqrt();
    if hi <= lo * (1.0 + TOLERANCE) {
        return pack(lo).map(|p| (lo, p));
    }
    let (first, mut inner) = rayon::join(|| pack(lo), || probe(lo, hi));
    let mut best = (lo, first?);
    loop {
        // The largest feasible probe becomes the lower end (packing is not monotone in the
        // scale; the search only needs a feasible lower end).
        match inner {
            (_, (b, Some(p))) => {
                lo = b;
                best = (b, p);
            }
            ((a, Some(p)), (b, None)) => {
                (lo, hi) = (a, b);
                best = (a, p);
            }
            ((a, None), _) => hi = a,
        }
        if hi <= lo * (1.0 + TOLERANCE) {
            return Some(best);
        }
        inner = probe(lo, hi);
    }
}

#[cfg(test)]
#[path = "bitmap_pack_tests.rs"]
mod tests;
