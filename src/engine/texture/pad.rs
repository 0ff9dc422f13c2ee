//! Padding of baked textures: fills the texels that no UV triangle covers so that bilinear
//! filtering and mip-mapping never pull black (or garbage) across UV seams.
//!
//! Two stages, the usual practice of texture bakers:
//! 1. **Dilation**, `padding` rounds: every uncovered texel with at least one set 8-neighbour
//!    takes the plain average of its set neighbours (all four channels); texels set in one round
//!    count as set in the next. After `r` rounds every texel within Chebyshev distance `r` of a
//!    covered texel is set.
//! 2. **Pull-push** (Gortler, Grzeszczuk, Szeliski, Cohen, *The Lumigraph*, SIGGRAPH 1996, §3.4):
//!    every texel still empty gets a smooth value from a coverage-weighted image pyramid. Pull:
//!    each coarser texel is the weight-normalized sum of its (up to) 2×2 children, its weight the
//!    children's summed weight clamped to 1. Push: from the coarsest level down, each texel blends
//!    its own value with the bilinearly upsampled coarser level, `w·c + (1 − w)·c_up`; an empty
//!    texel (weight 0) takes `c_up`.
//!
//! Covered texels never change; filled values are convex combinations of covered values, so no
//! channel leaves the range of the covered texels. Deterministic for any thread count (each
//! output value depends only on the previous round or level, never on scheduling). Written by hand: it is small and
//! tied to our coverage masks.

use rayon::prelude::*;
use std::sync::atomic::{AtomicU8, Ordering};

/// How many texels each stage of [`pad`] set.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct PadReport {
    /// Texels set by dilation.
    pub padded: u64,
    /// Texels set by pull-push.
    pub filled: u64,
}

/// Fills the uncovered texels of a linear RGBA image in place: `padding` rounds of 8-neighbour
/// dilation, then pull-push for everything still empty (see the module docs).
///
/// `pixels` and `covered` are row-major `width × height`. Covered texels are never modified.
/// When no texel is covered, or the slice lengths do not match `width × height`, nothing is
/// changed and the report is all zeros.
pub fn pad(
    pixels: &mut [[f32; 4]],
    covered: &[bool],
    width: u32,
    height: u32,
    padding: u32,
) -> PadReport {
    let (w, h) = (width as usize, height as usize);
    let n = w * h;
    if n == 0 || pixels.len() != n || covered.len() != n || !covered.iter().any(|&c| c) {
        return PadReport::default();
    }
    let mut set = covered.to_vec();
    let padded = dilate(pixels, &mut set, w, h, padding);
    let filled = if set.iter().all(|&s| s) {
        0
    } else {
        pull_push(pixels, &set, w, h)
    };
    PadReport { padded, filled }
}

/// The 8-neighbourhood of texel `i` (within the image): indices in the first `n` slots.
#[inline]
fn neighbours(i: usize, w: usize, h: usize) -> ([usize; 8], usize) {
    let (x, y) = (i % w, i / w);
    if x > 0 && y > 0 && x + 1 < w && y + 1 < h {
        return (
            [
                i - w - 1,
                i - w,
                i - w + 1,
                i - 1,
                i + 1,
                i + w - 1,
                i + w,
                i + w + 1,
            ],
            8,
        );
    }
    let mut out = [0usize; 8];
    let mut n = 0;
    for ny in y.saturating_sub(1)..(y + 2).min(h) {
        for nx in x.saturating_sub(1)..(x + 2).min(w) {
            if nx != x || ny != y {
                out[n] = ny * w + nx;
                n += 1;
            }
        }
    }
    (out, n)
}

/// States of a texel during dilation.
const EMPTY: u8 = 0;
const SET: u8 = 1;
const QUEUED: u8 = 2;

/// Dilation rounds; returns the number of texels set. Works on a frontier (the unset texels next
/// to set ones), so a round costs in proportion to the texels it sets. The values of a round are
/// computed from the state before the round, and the frontier is a set (its order, which may
/// vary between runs, does not affect any value), so the result is deterministic.
fn dilate(pixels: &mut [[f32; 4]], set: &mut [bool], w: usize, h: usize, rounds: u32) -> u64 {
    if rounds == 0 {
        return 0;
    }
    let state: Vec<AtomicU8> = set
        .par_iter()
        .map(|&s| AtomicU8::new(if s { SET } else { EMPTY }))
        .collect();
    let is_set = |j: usize| state[j].load(Ordering::Relaxed) == SET;
    let mut frontier: Vec<usize> = (0..h)
        .into_par_iter()
        .flat_map_iter(|y| {
            let state = &state;
            (y * w..(y + 1) * w).filter(move |&i| {
                if state[i].load(Ordering::Relaxed) == SET {
                    return false;
                }
                let (nb, n) = neighbours(i, w, h);
                nb[..n]
                    .iter()
                    .any(|&j| state[j].load(Ordering::Relaxed) == SET)
            })
        })
        .collect();
    frontier
        .par_iter()
        .for_each(|&i| state[i].store(QUEUED, Ordering::Relaxed));
    let mut total = 0u64;
    let mut values: Vec<[f32; 4]> = Vec::new();
    for round in 0..rounds {
        if frontier.is_empty() {
            break;
        }
        {
            let px: &[[f32; 4]] = pixels;
            frontier
                .par_iter()
                .map(|&i| {
                    let (nb, n) = neighbours(i, w, h);
                    let mut sum = [0.0f32; 4];
                    let mut count = 0u32;
                    for &j in &nb[..n] {
                        if is_set(j) {
                            let p = px[j];
                            sum[0] += p[0];
                            sum[1] += p[1];
                            sum[2] += p[2];
                            sum[3] += p[3];
                            count += 1;
                        }
                    }
                    let inv = 1.0 / count.max(1) as f32;
                    sum.map(|s| s * inv)
                })
                .collect_into_vec(&mut values);
        }
        for (&i, v) in frontier.iter().zip(&values) {
            pixels[i] = *v;
        }
        frontier
            .par_iter()
            .for_each(|&i| state[i].store(SET, Ordering::Relaxed));
        total += frontier.len() as u64;
        if round + 1 == rounds {
            break;
        }
        // Next frontier: the empty neighbours of this one; the compare-exchange lists each once.
        frontier = frontier
            .par_chunks(4096)
            .flat_map_iter(|chunk| {
                let state = &state;
                chunk.iter().flat_map(move |&i| {
                    let (nb, n) = neighbours(i, w, h);
                    (0..n).map(move |k| nb[k]).filter(move |&j| {
                        // Plain load first: most neighbours are already set, and a
                        // compare-exchange is far more expensive than a load.
                        state[j].load(Ordering::Relaxed) == EMPTY
                            && state[j]
                                .compare_exchange(
                                    EMPTY,
                                    QUEUED,
                                    Ordering::Relaxed,
                                    Ordering::Relaxed,
                                )
                                .is_ok()
                    })
                })
            })
            .collect();
    }
    set.par_iter_mut()
        .zip(&state)
        .for_each(|(s, st)| *s = st.load(Ordering::Relaxed) == SET);
    total
}

/// One level of the pull-push pyramid.
struct Level {
    w: usize,
    h: usize,
    color: Vec<[f32; 4]>,
    weight: Vec<f32>,
}

/// Pull (down) step: `(w, h)` children, read through `child(i) -> (color, weight)`.
fn pull<F>(w: usize, h: usize, child: F) -> Level
where
    F: Fn(usize) -> ([f32; 4], f32) + Sync,
{
    let (pw, ph) = (w.div_ceil(2), h.div_ceil(2));
    let mut color = vec![[0.0f32; 4]; pw * ph];
    let mut weight = vec![0.0f32; pw * ph];
    color
        .par_chunks_mut(pw)
        .zip(weight.par_chunks_mut(pw))
        .enumerate()
        .for_each(|(py, (crow, wrow))| {
            for px in 0..pw {
                let mut sum = [0.0f32; 4];
                let mut ws = 0.0f32;
                for cy in 2 * py..(2 * py + 2).min(h) {
                    for cx in 2 * px..(2 * px + 2).min(w) {
                        let (c, cw) = child(cy * w + cx);
                        if cw > 0.0 {
                            for k in 0..4 {
                                sum[k] += cw * c[k];
                            }
                            ws += cw;
                        }
                    }
                }
                if ws > 0.0 {
                    let inv = 1.0 / ws;
                    crow[px] = sum.map(|s| s * inv);
                    wrow[px] = ws.min(1.0);
                }
            }
        });
    Level {
        w: pw,
        h: ph,
        color,
        weight,
    }
}

/// Bilinear, clamp-to-edge sample of `level` at the position of child texel `(x, y)` of the next
/// finer level.
#[inline]
fn upsample(level: &Level, x: usize, y: usize) -> [f32; 4] {
    let fx = ((x as f32 + 0.5) * 0.5 - 0.5).clamp(0.0, (level.w - 1) as f32);
    let fy = ((y as f32 + 0.5) * 0.5 - 0.5).clamp(0.0, (level.h - 1) as f32);
    // Non-negative after the clamp: truncation is floor.
    let (x0, y0) = (fx as usize, fy as usize);
    let (x1, y1) = ((x0 + 1).min(level.w - 1), (y0 + 1).min(level.h - 1));
    let (tx, ty) = (fx - x0 as f32, fy - y0 as f32);
    let c = |xx: usize, yy: usize| level.color[yy * level.w + xx];
    let (a, b, cc, d) = (c(x0, y0), c(x1, y0), c(x0, y1), c(x1, y1));
    let mut out = [0.0f32; 4];
    for k in 0..4 {
        out[k] =
            (a[k] * (1.0 - tx) + b[k] * tx) * (1.0 - ty) + (cc[k] * (1.0 - tx) + d[k] * tx) * ty;
    }
    out
}

/// Pull-push fill of every texel with `set == false`; returns how many were filled.
fn pull_push(pixels: &mut [[f32; 4]], set: &[bool], w: usize, h: usize) -> u64 {
    // Pull: level 1 from the image, then halve until 1x1.
    let mut levels: Vec<Level> = Vec::new();
    {
        let px: &[[f32; 4]] = pixels;
        levels.push(pull(w, h, |i| (px[i], if set[i] { 1.0 } else { 0.0 })));
    }
    while levels.last().is_some_and(|l| l.w > 1 || l.h > 1) {
        let top = levels.last().expect("non-empty");
        let next = pull(top.w, top.h, |i| (top.color[i], top.weight[i]));
        levels.push(next);
    }
    // Push: coarsest to level 1, each level blended with the upsampled coarser one.
    for k in (0..levels.len() - 1).rev() {
        let (finer, coarser) = levels.split_at_mut(k + 1);
        let (fine, coarse) = (&mut finer[k], &coarser[0]);
        let fw = fine.w;
        fine.color
            .par_chunks_mut(fw)
            .zip(fine.weight.par_chunks(fw))
            .enumerate()
            .for_each(|(y, (crow, wrow))| {
                for x in 0..fw {
                    let wgt = wrow[x];
                    if wgt < 1.0 {
                        let up = upsample(coarse, x, y);
                        for c in 0..4 {
                            crow[x][c] = wgt * crow[x][c] + (1.0 - wgt) * up[c];
                        }
                    }
                }
            });
    }
    // Level 0: only the empty texels, from the upsampled level 1.
    let level1 = &levels[0];
    pixels
        .par_chunks_mut(w)
        .zip(set.par_chunks(w))
        .enumerate()
        .map(|(y, (row, srow))| {
            let mut filled = 0u64;
            for x in 0..w {
                if !srow[x] {
                    row[x] = upsample(level1, x, y);
                    filled += 1;
                }
            }
            filled
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `w × h` image with the rectangle `[x0, x1) × [y0, y1)` covered by a gradient in
    /// [0.5, 0.9] (alpha 1); the rest is black with alpha 0.
    fn island(
        w: usize,
        h: usize,
        x0: usize,
        x1: usize,
        y0: usize,
        y1: usize,
    ) -> (Vec<[f32; 4]>, Vec<bool>) {
        let mut px = vec![[0.0f32; 4]; w * h];
        let mut cov = vec![false; w * h];
        for y in y0..y1 {
            for x in x0..x1 {
                let t = (x - x0) as f32 / (x1 - x0) as f32;
                let s = (y - y0) as f32 / (y1 - y0) as f32;
                px[y * w + x] = [0.5 + 0.4 * t, 0.9 - 0.4 * s, 0.7, 1.0];
                cov[y * w + x] = true;
            }
        }
        (px, cov)
    }

    #[test]
    fn dilation_reaches_exactly_padding_texels_around_a_square() {
        let (w, h) = (64usize, 64usize);
        let (mut px, cov) = island(w, h, 20, 30, 20, 30);
        let mut set = cov.clone();
        let padded = dilate(&mut px, &mut set, w, h, 3);
        // Chebyshev ring of width 3 around a 10x10 square: 16² − 10².
        assert_eq!(padded, 16 * 16 - 100);
        for y in 0..h {
            for x in 0..w {
                let inside = (17..33).contains(&x) && (17..33).contains(&y);
                assert_eq!(set[y * w + x], inside, "texel ({x}, {y})");
            }
        }
        // Through the public entry: same count, the rest filled by pull-push.
        let (mut px, cov) = island(w, h, 20, 30, 20, 30);
        let report = pad(&mut px, &cov, w as u32, h as u32, 3);
        assert_eq!(
            report,
            PadReport {
                padded: 156,
                filled: (w * h - 256) as u64
            }
        );
    }

    #[test]
    fn covered_texels_never_change_and_nothing_stays_transparent() {
        let (w, h) = (50usize, 37usize);
        let (mut px, mut cov) = island(w, h, 3, 12, 5, 30);
        // A second island with a different color, and a lone covered texel.
        for y in 20..35 {
            for x in 30..47 {
                px[y * w + x] = [0.1, 0.2, 0.95, 1.0];
                cov[y * w + x] = true;
            }
        }
        px[2 * w + 45] = [0.3, 0.3, 0.3, 1.0];
        cov[2 * w + 45] = true;
        let before = px.clone();
        let report = pad(&mut px, &cov, w as u32, h as u32, 2);
        let n_cov = cov.iter().filter(|&&c| c).count() as u64;
        assert_eq!(report.padded + report.filled + n_cov, (w * h) as u64);
        assert!(report.padded > 0 && report.filled > 0);
        for i in 0..w * h {
            if cov[i] {
                assert_eq!(px[i], before[i], "covered texel {i} changed");
            } else {
                assert!(px[i][3] > 0.99, "texel {i} has alpha {}", px[i][3]);
                // Convex combinations of covered values stay inside their range.
                assert!(
                    (0.1 - 1e-4..=0.95 + 1e-4).contains(&px[i][0]),
                    "{:?}",
                    px[i]
                );
                assert!(
                    (0.2 - 1e-4..=0.95 + 1e-4).contains(&px[i][2]),
                    "{:?}",
                    px[i]
                );
            }
        }
    }

    /// Box-filter mip level 2 (4x4 averages, as a GPU mip chain would) of the RGB channels.
    fn mip2(px: &[[f32; 4]], w: usize, h: usize) -> Vec<[f32; 3]> {
        let (mw, mh) = (w / 4, h / 4);
        let mut out = vec![[0.0f32; 3]; mw * mh];
        for my in 0..mh {
            for mx in 0..mw {
                let mut s = [0.0f32; 3];
                for y in 4 * my..4 * my + 4 {
                    for x in 4 * mx..4 * mx + 4 {
                        for k in 0..3 {
                            s[k] += px[y * w + x][k] / 16.0;
                        }
                    }
                }
                out[my * mw + mx] = s;
            }
        }
        out
    }

    #[test]
    fn mip_maps_of_padded_image_do_not_darken_at_seams() {
        let (w, h) = (64usize, 64usize);
        // Island edges not aligned to the 4x4 mip blocks: the blocks across the seam mix in
        // uncovered texels.
        let (unpadded, cov) = island(w, h, 9, 38, 13, 43);
        let mut padded = unpadded.clone();
        pad(&mut padded, &cov, w as u32, h as u32, 2);
        let (m_pad, m_raw) = (mip2(&padded, w, h), mip2(&unpadded, w, h));
        let mut darkened_raw = 0;
        for my in 0..h / 4 {
            for mx in 0..w / 4 {
                let touches =
                    (4 * my..4 * my + 4).any(|y| (4 * mx..4 * mx + 4).any(|x| cov[y * w + x]));
                if !touches {
                    continue;
                }
                let i = my * (w / 4) + mx;
                // Every channel of the island is ≥ 0.5: a padded mip texel must be too.
                for k in 0..3 {
                    assert!(
                        m_pad[i][k] >= 0.5 - 1e-4,
                        "mip texel ({mx}, {my}) darkened: {:?}",
                        m_pad[i]
                    );
                }
                if (0..3).any(|k| m_raw[i][k] < m_pad[i][k] - 0.05) {
                    darkened_raw += 1;
                }
            }
        }
        // Without padding the seam blocks do darken (the property above is not vacuous).
        assert!(
            darkened_raw >= 20,
            "only {darkened_raw} darkened blocks without padding"
        );
    }

    #[test]
    fn all_uncovered_input_is_left_alone() {
        let mut px = vec![[0.25f32, 0.0, 0.0, 0.0]; 16];
        let before = px.clone();
        assert_eq!(pad(&mut px, &[false; 16], 4, 4, 4), PadReport::default());
        assert_eq!(px, before);
        // Mismatched lengths: no change, no panic.
        assert_eq!(pad(&mut px, &[true; 3], 4, 4, 4), PadReport::default());
    }

    #[test]
    fn zero_padding_fills_everything_by_pull_push_and_odd_sizes_work() {
        for (w, h) in [(1usize, 1usize), (1, 9), (13, 1), (31, 17)] {
            let mut px = vec![[0.0f32; 4]; w * h];
            let mut cov = vec![false; w * h];
            px[w * h / 2] = [0.2, 0.4, 0.6, 1.0];
            cov[w * h / 2] = true;
            let r = pad(&mut px, &cov, w as u32, h as u32, 0);
            assert_eq!(
                r,
                PadReport {
                    padded: 0,
                    filled: (w * h - 1) as u64
                }
            );
            for p in &px {
                for k in 0..4 {
                    assert!(
                        (p[k] - [0.2, 0.4, 0.6, 1.0][k]).abs() < 1e-5,
                        "{w}x{h}: {p:?}"
                    );
                }
            }
        }
    }

    #[test]
    fn output_is_identical_for_one_and_two_threads() {
        let (w, h) = (97usize, 61usize);
        let (px, cov) = island(w, h, 10, 40, 7, 22);
        let run = |threads: usize| {
            let mut p = px.clone();
            let r = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| pad(&mut p, &cov, w as u32, h as u32, 4));
            (p, r)
        };
        let (a, ra) = run(1);
        let (b, rb) = run(2);
        assert_eq!(ra, rb);
        assert!(a
            .iter()
            .zip(&b)
            .all(|(x, y)| x.map(f32::to_bits) == y.map(f32::to_bits)));
    }
}
