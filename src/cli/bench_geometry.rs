//! `retex bench --method geometry`: timings of the geometry core on a 64K-vertex mesh (a Class I geodesic sphere of frequency 80,
//! 64 002 vertices, 128 000 faces, vertices jittered slightly and pushed back onto the sphere so
//! triangles are irregular): Laplacian and mass, Cholesky symbolic and numeric phases, the heat
//! method (preparation, one query, queries in parallel), curvature and bounded walks.
//!
//! Prints one row per stage with the median and the fastest of several runs, then the process's
//! peak resident memory (`VmHWM` of `/proc/self/status`, Linux only). Needs no assets.

use std::time::Instant;

use retex::engine::control::Control;
use retex::engine::geometry::curvature::{principal_curvatures, CurvatureParams};
use retex::engine::geometry::heat::{HeatGeodesics, HeatParams, Source};
use retex::engine::geometry::laplacian::{cotan_laplacian, GeometryError, LaplacianParams};
use retex::engine::geometry::walk::{WalkGraph, WalkMetric, WalkParams, Walker};
use retex::engine::linalg::SymbolicCholesky;
use retex::engine::mesh::primitives::{icosphere, jitter};
use retex::engine::mesh::Surface;

use super::bench_meshmatch::peak_rss_mib;

/// The geodesic sphere's frequency: 80 → 64 002 vertices.
const FREQUENCY: usize = 80;

/// One measured stage.
struct BenchRow {
    /// Stage name.
    stage: String,
    /// Median wall time over `runs`, seconds.
    median_s: f64,
    /// Fastest run, seconds.
    min_s: f64,
    /// Number of runs.
    runs: usize,
}

/// The benchmark mesh: geodesic sphere of `frequency` (`10 f² + 2` vertices), jittered by 10 %
/// of the edge length and re-projected onto the unit sphere.
fn bench_mesh(frequency: usize) -> Surface {
    let mut s = icosphere(1.0, frequency);
    let edge = 1.1 / frequency as f64;
    jitter(&mut s, 0.1 * edge, [true; 3], 1);
    for p in &mut s.positions {
        let l = p.iter().map(|c| (*c as f64).powi(2)).sum::<f64>().sqrt();
        *p = p.map(|c| (c as f64 / l) as f32);
    }
    s
}

fn time<T>(
    runs: usize,
    mut f: impl FnMut() -> Result<T, GeometryError>,
) -> Result<(f64, f64), GeometryError> {
    let mut t = Vec::with_capacity(runs);
    for _ in 0..runs.max(1) {
        let start = Instant::now();
        std::hint::black_box(f()?);
        t.push(start.elapsed().as_secs_f64());
    }
    t.sort_by(f64::total_cmp);
    Ok((t[t.len() / 2], t[0]))
}

/// Runs every stage `runs` times on [`bench_mesh`]`(frequency)` (80 → 64 002 vertices).
fn bench_geometry(frequency: usize, runs: usize) -> Result<Vec<BenchRow>, GeometryError> {
    let s = bench_mesh(frequency);
    let n = s.vertex_count();
    let mut rows = Vec::new();
    let mut push = |stage: &str, (median_s, min_s): (f64, f64)| {
        rows.push(BenchRow {
            stage: format!("{stage} ({n} vertices)"),
            median_s,
            min_s,
            runs,
        })
    };
    let params = LaplacianParams::default();
    push(
        "cotan Laplacian + mixed Voronoi mass",
        time(runs, || cotan_laplacian(&s, &params))?,
    );
    let lap = cotan_laplacian(&s, &params)?;
    push(
        "Cholesky symbolic (AMD + supernodes)",
        time(runs, || Ok(SymbolicCholesky::new(lap.pattern().clone())?))?,
    );
    let symbolic = SymbolicCholesky::new(lap.pattern().clone())?;
    let h2 = 1e-4;
    let op = lap.stiffness.scaled_plus_diagonal(-h2, 1.0, &lap.mass);
    push(
        "Cholesky numeric (M - tL)",
        time(runs, || Ok(symbolic.factor(&op)?))?,
    );
    let control = Control::new();
    let heat_params = HeatParams::default();
    push(
        "heat method: prepare (L, M, 2 factorizations)",
        time(runs, || HeatGeodesics::new(&s, &heat_params, &control))?,
    );
    let heat = HeatGeodesics::new(&s, &heat_params, &control)?;
    let point = Source::Point {
        face: 777,
        bary: [0.3, 0.3, 0.4],
    };
    push(
        "heat method: distance from a point",
        time(runs, || heat.distance(&[point]))?,
    );
    let queries: Vec<Vec<Source>> = (0..8)
        .map(|k| vec![Source::Vertex((k * n / 8) as u32)])
        .collect();
    let (med, min) = time(runs, || heat.distance_many(&queries, &control))?;
    push(
        "heat method: 8 queries in parallel, per query",
        (med / 8.0, min / 8.0),
    );
    push(
        "principal curvatures (Rusinkiewicz)",
        time(runs, || {
            principal_curvatures(&s, &CurvatureParams::default())
        })?,
    );
    let graph = WalkGraph::new(&s);
    let walk = WalkParams {
        radius: 5.0 * heat.mean_edge(),
        metric: WalkMetric::FastMarching,
    };
    let (med, min) = time(runs, || {
        let mut walker = Walker::new(&graph);
        let mut total = 0usize;
        for v in (0..n).step_by(64) {
            total += walker.walk(v as u32, &walk)?.len();
        }
        Ok(total)
    })?;
    let walks = n.div_ceil(64) as f64;
    push(
        "fast-marching walk r = 5h, per walk (1 thread)",
        (med / walks, min / walks),
    );
    Ok(rows)
}

/// Runs the stages `runs` times each on the 64K-vertex sphere and prints the rows.
pub fn run(runs: usize) -> Result<(), String> {
    let rows = bench_geometry(FREQUENCY, runs).map_err(|e| e.to_string())?;
    for r in &rows {
        println!(
            "{:<64} median {:>10.3} ms   min {:>10.3} ms   ({} runs)",
            r.stage,
            r.median_s * 1e3,
            r.min_s * 1e3,
            r.runs
        );
    }
    if let Some(mib) = peak_rss_mib() {
        println!("peak resident memory (VmHWM): {mib:.0} MiB");
    }
    Ok(())
}
