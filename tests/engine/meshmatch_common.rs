//! Helpers of the MeshMatch tests: procedural capsules with stripes, GLB writing and reading,
//! running a transfer from bytes.
#![allow(dead_code)]

use retex::engine::asset::constraints::Constraints;
use retex::engine::asset::export::colored_mesh_glb;
use retex::engine::asset::BlobSet;
use retex::engine::control::Control;
use retex::engine::mesh::primitives;
use retex::engine::pipeline::{transfer, ModelInput, TransferInput, TransferOutput};

/// Builds a GLB of one primitive: positions, triangles and optional COLOR_0 (linear RGBA), with a
/// plain white material.
pub fn glb_of(
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    colors: Option<&[[f32; 4]]>,
) -> Vec<u8> {
    colored_mesh_glb(positions, triangles, colors).unwrap()
}

/// Runs a transfer between two models given as bytes.
pub fn run_bytes(
    source: (&str, Vec<u8>),
    target: (&str, Vec<u8>),
    constraints: serde_json::Value,
) -> TransferOutput {
    let mut sb = BlobSet::new();
    sb.insert(source.0, source.1);
    let mut tb = BlobSet::new();
    tb.insert(target.0, target.1);
    let c: Constraints = serde_json::from_value(constraints).unwrap();
    transfer(
        &TransferInput::pair(
            ModelInput {
                main: source.0,
                blobs: &sb,
            },
            ModelInput {
                main: target.0,
                blobs: &tb,
            },
            c,
        ),
        &Control::new(),
    )
    .unwrap()
}

/// A capsule along +x (`retex::engine::mesh::primitives::capsule`).
pub fn capsule(
    radius: f32,
    profile: &[f32],
    around: usize,
    warp: impl Fn(f32) -> f32,
) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let s = primitives::capsule(radius, profile, around, warp);
    (s.positions, s.faces)
}

/// Reads POSITION and COLOR_0 (as linear RGB) of every primitive of an output GLB, in world space
/// (the test assets have identity nodes).
pub fn colored_points(glb: &[u8]) -> Vec<([f32; 3], [f32; 3])> {
    let asset = crate::common::load_bytes(glb, "out.glb");
    let mut out = Vec::new();
    for p in &asset.primitives {
        if let Some(c) = &p.colors {
            for (x, col) in p.positions.iter().zip(c) {
                out.push((*x, [col[0], col[1], col[2]]));
            }
        }
    }
    out
}

/// Texture statistics of issue 14 (item 1): the source's surface colours clustered by k-means
/// (k = 5, sRGB, area-uniform samples), the area share of every cluster on the source and on an
/// output (output samples go to the nearest source centre), and the total-variation distance.
#[derive(Clone, Debug)]
pub struct ColorStatistics {
    /// Cluster centres, sRGB in [0, 1].
    pub centers: Vec<[f32; 3]>,
    /// Area share of every cluster on the source.
    pub source: Vec<f64>,
    /// Area share of every cluster on the output.
    pub output: Vec<f64>,
    /// Total-variation distance `½ Σ |source − output|`.
    pub tv: f64,
    /// Over clusters covering ≥ 5% of the source: the output/source share ratio farthest from 1
    /// (as `max(r, 1/r)`).
    pub worst_ratio: f64,
}

impl ColorStatistics {
    /// Whether the target holds: every cluster with ≥ 5% of the source within 0.5-2×
    /// and TV ≤ 0.12.
    pub fn kept(&self) -> bool {
        self.worst_ratio <= 2.0 && self.tv <= 0.12
    }
}

impl std::fmt::Display for ColorStatistics {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        for (k, c) in self.centers.iter().enumerate() {
            write!(
                f,
                "[{:.2} {:.2} {:.2}] {:.3}→{:.3}; ",
                c[0], c[1], c[2], self.source[k], self.output[k]
            )?;
        }
        write!(f, "TV {:.3}, worst ratio {:.2}", self.tv, self.worst_ratio)
    }
}

/// `n` area-uniform samples of an asset's base colour (factor × texture × COLOR_0), sRGB, over
/// all its primitives (primitive positions: the test assets have identity or uniform nodes).
pub fn area_uniform_colors(
    asset: &retex::engine::asset::Asset,
    n: usize,
    seed: u64,
) -> Vec<[f32; 3]> {
    area_uniform_colors_where(asset, n, seed, &|_| true)
}

/// [`area_uniform_colors`] over the triangles whose centroid passes `keep`.
pub fn area_uniform_colors_where(
    asset: &retex::engine::asset::Asset,
    n: usize,
    seed: u64,
    keep: &dyn Fn([f32; 3]) -> bool,
) -> Vec<[f32; 3]> {
    use retex::engine::texture::color::linear_to_srgb;
    use retex::engine::texture::sample::MaterialSampler;
    let sampler = MaterialSampler::new(asset);
    let mut cumulative = Vec::new();
    let mut total = 0.0f64;
    for (p, prim) in asset.primitives.iter().enumerate() {
        for (t, tri) in prim.triangles.iter().enumerate() {
            let [a, b, c] = tri.map(|v| prim.positions[v as usize]);
            if !keep(std::array::from_fn(|k| (a[k] + b[k] + c[k]) / 3.0)) {
                continue;
            }
            let u: [f32; 3] = std::array::from_fn(|k| b[k] - a[k]);
            let v: [f32; 3] = std::array::from_fn(|k| c[k] - a[k]);
            let x = [
                u[1] * v[2] - u[2] * v[1],
                u[2] * v[0] - u[0] * v[2],
                u[0] * v[1] - u[1] * v[0],
            ];
            total += 0.5 * ((x[0] * x[0] + x[1] * x[1] + x[2] * x[2]) as f64).sqrt();
            cumulative.push((total, p, t));
        }
    }
    let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let mut uniform = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    (0..n)
        .map(|_| {
            let x = uniform() * total;
            let i = cumulative
                .partition_point(|e| e.0 < x)
                .min(cumulative.len() - 1);
            let (_, p, t) = cumulative[i];
            let (mut r1, mut r2) = (uniform() as f32, uniform() as f32);
            if r1 + r2 > 1.0 {
                (r1, r2) = (1.0 - r1, 1.0 - r2);
            }
            let c = sampler.base_color(p, t, [1.0 - r1 - r2, r1, r2]);
            [0, 1, 2].map(|k| linear_to_srgb(c[k].clamp(0.0, 1.0)))
        })
        .collect()
}

fn nearest(c: [f32; 3], centers: &[[f32; 3]]) -> usize {
    let d = |a: [f32; 3], b: [f32; 3]| (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f32>();
    (0..centers.len())
        .min_by(|&a, &b| d(c, centers[a]).total_cmp(&d(c, centers[b])))
        .unwrap_or(0)
}

/// k-means (k-means++ seeding from a fixed seed, then 50 Lloyd iterations) of `samples`.
pub fn kmeans(samples: &[[f32; 3]], k: usize, seed: u64) -> Vec<[f32; 3]> {
    let mut state = seed.wrapping_mul(0xD1B5_4A32_D192_ED03) | 1;
    let mut uniform = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let d = |a: [f32; 3], b: [f32; 3]| (0..3).map(|i| (a[i] - b[i]).powi(2)).sum::<f32>();
    let mut centers = vec![samples[(uniform() * samples.len() as f64) as usize]];
    while centers.len() < k {
        let w: Vec<f64> = samples
            .iter()
            .map(|&s| centers.iter().map(|&c| d(s, c)).fold(f32::MAX, f32::min) as f64)
            .collect();
        let total: f64 = w.iter().sum();
        if total <= 0.0 {
            break;
        }
        let mut x = uniform() * total;
        let mut pick = samples.len() - 1;
        for (i, wi) in w.iter().enumerate() {
            if x < *wi {
                pick = i;
                break;
            }
            x -= wi;
        }
        centers.push(samples[pick]);
    }
    for _ in 0..50 {
        let mut sum = vec![[0.0f64; 4]; centers.len()];
        for &s in samples {
            let j = nearest(s, &centers);
            for i in 0..3 {
                sum[j][i] += s[i] as f64;
            }
            sum[j][3] += 1.0;
        }
        for (c, s) in centers.iter_mut().zip(&sum) {
            if s[3] > 0.0 {
                *c = [0, 1, 2].map(|i| (s[i] / s[3]) as f32);
            }
        }
    }
    centers
}

/// Area share of every centre's cluster among `samples`.
pub fn cluster_shares(samples: &[[f32; 3]], centers: &[[f32; 3]]) -> Vec<f64> {
    let mut count = vec![0usize; centers.len()];
    for &s in samples {
        count[nearest(s, centers)] += 1;
    }
    count
        .iter()
        .map(|&c| c as f64 / samples.len().max(1) as f64)
        .collect()
}

/// The statistics metric of issue 14 between a source asset and an output asset (20,000 samples
/// each).
pub fn color_statistics(
    source: &retex::engine::asset::Asset,
    output: &retex::engine::asset::Asset,
) -> ColorStatistics {
    let s = area_uniform_colors(source, 20_000, 11);
    let o = area_uniform_colors(output, 20_000, 12);
    statistics_of_samples(&s, &o)
}

/// [`color_statistics`] on samples already drawn.
pub fn statistics_of_samples(source: &[[f32; 3]], output: &[[f32; 3]]) -> ColorStatistics {
    let centers = kmeans(source, 5, 5);
    let (src, out) = (
        cluster_shares(source, &centers),
        cluster_shares(output, &centers),
    );
    let tv = 0.5
        * src
            .iter()
            .zip(&out)
            .map(|(a, b)| (a - b).abs())
            .sum::<f64>();
    let worst_ratio = src
        .iter()
        .zip(&out)
        .filter(|(a, _)| **a >= 0.05)
        .map(|(a, b)| {
            let r = b / a;
            if r > 0.0 {
                r.max(1.0 / r)
            } else {
                f64::INFINITY
            }
        })
        .fold(1.0, f64::max);
    ColorStatistics {
        centers,
        source: src,
        output: out,
        tv,
        worst_ratio,
    }
}

/// Mean stripe period along the top line (y > 0.45, |z| < 0.12) of the x range [a, b], from the
/// number of crossings of the mean grey level in 0.06-wide bins (the target has rings every 0.05).
pub fn measured_period(points: &[([f32; 3], [f32; 3])], a: f32, b: f32) -> f32 {
    let signal: Vec<f32> = top_line_profile(points, a, b, 0.06)
        .into_iter()
        .map(|(_, v)| v as f32)
        .collect();
    let mean = signal.iter().sum::<f32>() / signal.len() as f32;
    // Crossings with a little hysteresis.
    let mut crossings = 0;
    let mut above = signal[0] > mean;
    for &v in &signal {
        if above && v < mean - 0.05 {
            above = false;
            crossings += 1;
        } else if !above && v > mean + 0.05 {
            above = true;
            crossings += 1;
        }
    }
    assert!(crossings >= 2, "no stripes in [{a}, {b}]: {signal:?}");
    2.0 * (b - a) / crossings as f32
}

/// The mean grey of the output points on the capsule's top line (y > 0.45, |z| < 0.12) in bins
/// of about `bin_width` over x in [a, b): (bin centre, grey) for every bin with a point; more
/// than half the bins must have one.
fn top_line_profile(
    points: &[([f32; 3], [f32; 3])],
    a: f32,
    b: f32,
    bin_width: f32,
) -> Vec<(f64, f64)> {
    let bins = ((b - a) / bin_width).round() as usize;
    let mut sum = vec![0.0f64; bins];
    let mut count = vec![0u32; bins];
    for (p, c) in points {
        if p[1] > 0.45 && p[2].abs() < 0.12 && p[0] >= a && p[0] < b {
            let i = ((((p[0] - a) / (b - a)) * bins as f32) as usize).min(bins - 1);
            sum[i] += ((c[0] + c[1] + c[2]) / 3.0) as f64;
            count[i] += 1;
        }
    }
    let samples: Vec<(f64, f64)> = (0..bins)
        .filter(|&i| count[i] > 0)
        .map(|i| {
            let x = a as f64 + (b - a) as f64 * (i as f64 + 0.5) / bins as f64;
            (x, sum[i] / count[i] as f64)
        })
        .collect();
    assert!(
        samples.len() > bins / 2,
        "only {} of {bins} bins sampled",
        samples.len()
    );
    samples
}

/// `from..=to` in steps of about `step` (the rings of a capsule's cylinder).
pub fn profile(from: f32, to: f32, step: f32) -> Vec<f32> {
    let n = ((to - from) / step).round() as usize;
    (0..=n)
        .map(|i| from + (to - from) * i as f32 / n as f32)
        .collect()
}

/// Stripe period of the texture-update case (issue 14 item 5).
pub const UPDATE_PERIOD: f32 = 0.5;

/// Linear grey level of the texture-update source at x: soft-edged black and white ring stripes.
pub fn update_stripe(x: f32) -> f32 {
    let s = (std::f32::consts::TAU * x / UPDATE_PERIOD).sin();
    0.05 + 0.85 * (0.5 + 0.5 * (4.0 * s).tanh())
}

/// The texture-update source's grey at x on its cylinder: COLOR_0 interpolated linearly between
/// its rings, 0.05 apart.
pub fn update_source_grey(x: f32) -> f32 {
    let i = (x / 0.05).floor();
    let t = x / 0.05 - i;
    update_stripe(i * 0.05) * (1.0 - t) + update_stripe((i + 1.0) * 0.05) * t
}

/// The edit of the texture-update case: on a cylinder of `length`, the second half is stretched
/// 2× and the right end carried along; the first half does not move.
pub fn lengthen(x: f32, length: f32) -> f32 {
    let half = 0.5 * length;
    if x <= half {
        x
    } else if x <= length {
        half + 2.0 * (x - half)
    } else {
        x + half
    }
}

/// The texture-update case: a striped capsule (cylinder x ∈ [0, length], radius 0.5, rings every
/// 0.05) and its edited copy ([`lengthen`], tessellated independently: rings every 0.025).
pub struct UpdatePair {
    /// The painted source (COLOR_0).
    pub source: Vec<u8>,
    /// The edited, unpainted target.
    pub target: Vec<u8>,
    /// Target triangles whose vertices all lie in the first half (the part that did not move).
    pub unmoved: Vec<usize>,
}

/// Opaque vertex colours of the striped source at `positions`: [`update_stripe`] along x, the
/// source of the texture-update, stretch-period and restart cases.
pub fn stripe_colors(positions: &[[f32; 3]]) -> Vec<[f32; 4]> {
    positions
        .iter()
        .map(|p| {
            let g = update_stripe(p[0]);
            [g, g, g, 1.0]
        })
        .collect()
}

/// Builds the [`UpdatePair`] for a cylinder of `length`.
pub fn update_pair(length: f32) -> UpdatePair {
    let (sp, st) = capsule(0.5, &profile(0.0, length, 0.05), 64, |x| x);
    let colors = stripe_colors(&sp);
    let (tp, tt) = capsule(0.5, &profile(0.0, length, 0.025), 64, |x| {
        lengthen(x, length)
    });
    let unmoved = tt
        .iter()
        .enumerate()
        .filter(|(_, t)| t.iter().all(|&v| tp[v as usize][0] < 0.5 * length))
        .map(|(i, _)| i)
        .collect();
    UpdatePair {
        source: glb_of(&sp, &st, Some(&colors)),
        target: glb_of(&tp, &tt, None),
        unmoved,
    }
}

/// Largest |output − source| grey on the cylinder's top half over x ∈ [a, b].
pub fn update_copy_error(points: &[([f32; 3], [f32; 3])], a: f32, b: f32) -> (f32, usize) {
    let mut worst = 0.0f32;
    let mut n = 0;
    for (p, c) in points {
        if p[0] >= a && p[0] <= b && p[1] > 0.0 {
            let g = (c[0] + c[1] + c[2]) / 3.0;
            worst = worst.max((g - update_source_grey(p[0])).abs());
            n += 1;
        }
    }
    (worst, n)
}

/// Stripe period along the top line (y > 0.45, |z| < 0.12) over x ∈ [a, b] from the spectrum:
/// the grey level is averaged in 0.04-wide bins, Hann-windowed, and the period between 0.2 and
/// 2 (steps of 0.002) with the largest Fourier power is returned. Finer than counting crossings
/// ([`measured_period`]) on short ranges, where one crossing more or less moves that count's
/// period by 15-25%.
pub fn spectral_period(points: &[([f32; 3], [f32; 3])], a: f32, b: f32) -> f32 {
    let samples = top_line_profile(points, a, b, 0.04);
    let mean = samples.iter().map(|s| s.1).sum::<f64>() / samples.len() as f64;
    let span = (b - a) as f64;
    let windowed: Vec<(f64, f64)> = samples
        .iter()
        .map(|&(x, v)| {
            let w = 0.5 - 0.5 * (std::f64::consts::TAU * (x - a as f64) / span).cos();
            (x, (v - mean) * w)
        })
        .collect();
    let mut best = (0.0f64, 0.0f64);
    let mut period = 0.2f64;
    while period <= 2.0 {
        let f = std::f64::consts::TAU / period;
        let (re, im) = windowed.iter().fold((0.0, 0.0), |(re, im), &(x, v)| {
            (re + v * (f * x).cos(), im + v * (f * x).sin())
        });
        let power = re * re + im * im;
        if power > best.1 {
            best = (period, power);
        }
        period += 0.002;
    }
    best.0 as f32
}
