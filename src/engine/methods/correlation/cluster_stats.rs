//! Per-cluster texture statistics of the constrained Heeger-Bergen synthesis (Mertens et al. 2006,
//! §5.2.1 and §5.2.3): for every source segment the histograms (kept as inverse CDFs,
//! [`Quantiles`]) of the decorrelated colour channels and of every Laplacian band, and a linear
//! regression from guidance to colour; for every target segment the same set interpolated from
//! the nearest source segments by reciprocal squared distance (Shepard 1968), blending inverse CDFs
//! (Matusik et al. 2005) and regression coefficients with the same weights.
//!
//! Statistics are weighted by sample area × mask × feathered membership ([`super::feather`]).
//! The regression is a weighted least-squares fit on the guidance centred on the cluster's mean,
//! with a ridge of [`RIDGE`] × the mean guidance variance of the cluster (retex's constant: a
//! cluster is small in guidance space, so its slopes are poorly determined along axes where it
//! hardly varies; the ridge turns those slopes to 0 instead of to noise). Its residual spread
//! (RMS per channel) is the default initialisation noise (§5.2.3 does not give one).

use rayon::prelude::*;

use super::feather::Membership;
use super::quantiles::Quantiles;

/// Ridge of the per-cluster regression, relative to the cluster's mean guidance variance.
pub const RIDGE: f64 = 1e-2;

/// The texture model of one segment.
#[derive(Clone, Debug, Default)]
pub struct ClusterModel {
    /// Mean guidance (the k-means centre).
    pub centre: [f32; 3],
    /// Inverse CDF of each decorrelated colour channel.
    pub colour: [Quantiles; 3],
    /// Per Laplacian level, the inverse CDF of each channel's band.
    pub bands: Vec<[Quantiles; 3]>,
    /// Per channel: slopes on guidance axes 0..3, then the intercept.
    pub regression: [[f32; 4]; 3],
    /// Residual RMS of the regression per channel.
    pub residual: [f32; 3],
}

impl ClusterModel {
    /// The regression's prediction at guidance `g`.
    pub fn predict(&self, g: [f32; 3]) -> [f32; 3] {
        self.regression
            .map(|r| r[0] * g[0] + r[1] * g[1] + r[2] * g[2] + r[3])
    }
}

/// Solves the `d × d` system `a x = b` (Gaussian elimination, partial pivoting); `None` when
/// singular.
fn solve(mut a: [[f64; 3]; 3], mut b: [f64; 3], d: usize) -> Option<[f64; 3]> {
    for c in 0..d {
        let p = (c..d).max_by(|&i, &j| a[i][c].abs().total_cmp(&a[j][c].abs()))?;
        if a[p][c].abs() < 1e-300 {
            return None;
        }
        a.swap(c, p);
        b.swap(c, p);
        for r in c + 1..d {
            let f = a[r][c] / a[c][c];
            for k in c..d {
                a[r][k] -= f * a[c][k];
            }
            b[r] -= f * b[c];
        }
    }
    let mut x = [0.0f64; 3];
    for c in (0..d).rev() {
        let s: f64 = (c + 1..d).map(|k| a[c][k] * x[k]).sum();
        x[c] = (b[c] - s) / a[c][c];
    }
    Some(x)
}

/// Weighted ridge regression of `y` (3 channels) on the first `d` guidance axes, and its residual
/// RMS. `rows` are (sample, weight).
fn regression(
    guidance: &[[f32; 3]],
    colour: &[[f32; 3]],
    rows: impl Iterator<Item = (usize, f64)> + Clone,
    d: usize,
) -> ([[f32; 4]; 3], [f32; 3]) {
    let (mut sw, mut mg, mut my) = (0.0f64, [0.0f64; 3], [0.0f64; 3]);
    for (i, w) in rows.clone() {
        sw += w;
        for a in 0..3 {
            mg[a] += w * guidance[i][a] as f64;
            my[a] += w * colour[i][a] as f64;
        }
    }
    if sw <= 0.0 {
        return ([[0.0; 4]; 3], [0.0; 3]);
    }
    mg = mg.map(|x| x / sw);
    my = my.map(|x| x / sw);
    let (mut sgg, mut sgy) = ([[0.0f64; 3]; 3], [[0.0f64; 3]; 3]);
    for (i, w) in rows.clone() {
        let g: [f64; 3] = std::array::from_fn(|a| guidance[i][a] as f64 - mg[a]);
        let y: [f64; 3] = std::array::from_fn(|a| colour[i][a] as f64 - my[a]);
        for a in 0..d {
            for b in 0..d {
                sgg[a][b] += w * g[a] * g[b];
            }
            for c in 0..3 {
                sgy[c][a] += w * g[a] * y[c];
            }
        }
    }
    let trace: f64 = (0..d).map(|a| sgg[a][a]).sum::<f64>() / d as f64;
    let ridge = RIDGE * trace + 1e-12 * sw;
    for (a, row) in sgg.iter_mut().enumerate().take(d) {
        row[a] += ridge;
    }
    let mut out = [[0.0f32; 4]; 3];
    for c in 0..3 {
        let slope = solve(sgg, sgy[c], d).unwrap_or([0.0; 3]);
        let icpt = my[c] - (0..d).map(|a| slope[a] * mg[a]).sum::<f64>();
        for a in 0..d {
            out[c][a] = slope[a] as f32;
        }
        out[c][3] = icpt as f32;
    }
    let mut res = [0.0f64; 3];
    for (i, w) in rows {
        let g = guidance[i];
        for c in 0..3 {
            let r = &out[c];
            let p = r[0] * g[0] + r[1] * g[1] + r[2] * g[2] + r[3];
            res[c] += w * ((colour[i][c] - p) as f64).powi(2);
        }
    }
    (out, res.map(|x| (x / sw).sqrt() as f32))
}

/// Quantiles of each channel of `values` over the members of one cluster, weighted by
/// `weight[sample] × membership`.
fn channel_quantiles(
    values: &[[f32; 3]],
    weight: &[f32],
    samples: &[u32],
    member_w: &[f32],
) -> [Quantiles; 3] {
    let w: Vec<f32> = samples
        .iter()
        .zip(member_w)
        .map(|(&i, &m)| weight[i as usize] * m)
        .collect();
    std::array::from_fn(|c| {
        let v: Vec<f32> = samples.iter().map(|&i| values[i as usize][c]).collect();
        Quantiles::new(&v, Some(&w))
    })
}

/// The source data the models are measured on; per-level slices run over the pyramid levels.
pub struct SourceData<'a> {
    /// Decorrelated colour per level-0 sample.
    pub colour: &'a [[f32; 3]],
    /// Guidance per level-0 sample.
    pub guidance: &'a [[f32; 3]],
    /// Guidance axes in use.
    pub dims: usize,
    /// Laplacian bands of the decorrelated colour, per level.
    pub bands: &'a [Vec<[f32; 3]>],
    /// Area × mask per sample, per level.
    pub weight: &'a [Vec<f32>],
    /// Feathered memberships, per level.
    pub membership: &'a [Membership],
    /// Cluster centres.
    pub centres: &'a [[f32; 3]],
}

/// The model of every source cluster (in parallel over clusters).
pub fn source_models(data: &SourceData<'_>) -> Vec<ClusterModel> {
    (0..data.centres.len())
        .into_par_iter()
        .map(|c| {
            let (s0, m0) = data.membership[0].members(c);
            let colour = channel_quantiles(data.colour, &data.weight[0], s0, m0);
            let bands = (0..data.bands.len())
                .map(|l| {
                    let (s, m) = data.membership[l].members(c);
                    channel_quantiles(&data.bands[l], &data.weight[l], s, m)
                })
                .collect();
            let rows = s0
                .iter()
                .zip(m0)
                .map(|(&i, &m)| (i as usize, (data.weight[0][i as usize] * m) as f64));
            let (regression, residual) = regression(data.guidance, data.colour, rows, data.dims);
            ClusterModel {
                centre: data.centres[c],
                colour,
                bands,
                regression,
                residual,
            }
        })
        .collect()
}

/// The model at guidance `centre`, interpolated from the `k` nearest `models` with weights
/// `1/d²` (a model closer than 1e-6 is taken alone). Models without any weighted sample (empty
/// colour histograms) are skipped.
pub fn interpolate(models: &[ClusterModel], centre: [f32; 3], k: usize) -> ClusterModel {
    let mut near: Vec<(f32, usize)> = models
        .iter()
        .enumerate()
        .filter(|(_, m)| !m.colour[0].is_empty())
        .map(|(i, m)| ((0..3).map(|a| (m.centre[a] - centre[a]).powi(2)).sum(), i))
        .collect();
    near.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    near.truncate(k.max(1));
    if near.is_empty() {
        return ClusterModel {
            centre,
            ..Default::default()
        };
    }
    let parts: Vec<(usize, f32)> = if near[0].0 < 1e-12 {
        vec![(near[0].1, 1.0)]
    } else {
        near.iter().map(|&(d, i)| (i, 1.0 / d)).collect()
    };
    let total: f32 = parts.iter().map(|p| p.1).sum();
    let blend = |get: &dyn Fn(&ClusterModel) -> &Quantiles| {
        let ps: Vec<(&Quantiles, f32)> = parts.iter().map(|&(i, w)| (get(&models[i]), w)).collect();
        Quantiles::blend(&ps)
    };
    let levels = models[parts[0].0].bands.len();
    let mut regression = [[0.0f32; 4]; 3];
    let mut residual = [0.0f32; 3];
    for &(i, w) in &parts {
        let t = w / total;
        for c in 0..3 {
            for a in 0..4 {
                regression[c][a] += t * models[i].regression[c][a];
            }
            residual[c] += t * models[i].residual[c];
        }
    }
    ClusterModel {
        centre,
        colour: std::array::from_fn(|c| blend(&|m| &m.colour[c])),
        bands: (0..levels)
            .map(|l| std::array::from_fn(|c| blend(&|m| &m.bands[l][c])))
            .collect(),
        regression,
        residual,
    }
}
