//! `retex bench --method meshmatch`, second table: MeshMatch (Chen et al. 2012, §5.5) at 64K
//! samples on several kinds of input (issue 14 item 6), each stage timed from the job report's
//! stage timings and the peak resident memory measured per pair:
//!
//! - a striped capsule whose far half is stretched 2× (made in code: the source has black and
//!   white ring stripes of period 0.5 on a cylinder x ∈ [0, 4] of radius 0.5, the target the same
//!   capsule with x ∈ [2, 4] stretched to [2, 6] and the right cap carried along; 256 segments
//!   around, rings 1/64 apart before the stretch: 69,378 vertices each), no correspondences;
//! - Spot → the cat (8K-vertex target resampled up to 64K), HKS features, no correspondences;
//! - Spot → the koala scan (50K vertices, 100K triangles), HKS features, no correspondences.
//!
//! The peak is per pair: the kernel's high-water mark is reset (`/proc/self/clear_refs`, value 5)
//! before each pair, so a pair's figure includes what the previous pair left allocated (nothing:
//! every transfer's memory is freed when it returns).

use std::path::Path;

use retex::engine::asset::export::colored_mesh_glb;
use retex::engine::asset::BlobSet;
use retex::engine::mesh::primitives::capsule;

use super::bench_meshmatch::{measure, median, peak_rss_mib, read_asset, Model};

/// Stripe period of the capsule's source, world units.
const STRIPE_PERIOD: f32 = 0.5;

/// Linear grey at x: soft-edged black and white ring stripes.
fn stripe(x: f32) -> f32 {
    let s = (std::f32::consts::TAU * x / STRIPE_PERIOD).sin();
    0.05 + 0.85 * (0.5 + 0.5 * (4.0 * s).tanh())
}

/// The edit: x ∈ [2, 4] stretched to [2, 6], the right cap carried along.
fn stretch(x: f32) -> f32 {
    if x <= 2.0 {
        x
    } else {
        x + (x.min(4.0) - 2.0)
    }
}

/// The striped capsule pair: (source with COLOR_0, bare stretched target).
fn stripes_pair() -> Result<(Model, Model), String> {
    let rings: Vec<f32> = (0..=256).map(|i| 4.0 * i as f32 / 256.0).collect();
    let model = |name: &str, bytes: Vec<u8>| {
        let mut blobs = BlobSet::new();
        blobs.insert(name, bytes);
        (name.to_string(), blobs)
    };
    let source = capsule(0.5, &rings, 256, |x| x);
    let colors: Vec<[f32; 4]> = source
        .positions
        .iter()
        .map(|p| {
            let g = stripe(p[0]);
            [g, g, g, 1.0]
        })
        .collect();
    let source_glb = colored_mesh_glb(&source.positions, &source.faces, Some(&colors))
        .map_err(|e| e.to_string())?;
    let target = capsule(0.5, &rings, 256, stretch);
    let target_glb =
        colored_mesh_glb(&target.positions, &target.faces, None).map_err(|e| e.to_string())?;
    Ok((
        model("stripes.glb", source_glb),
        model("stretched.glb", target_glb),
    ))
}

/// Resets the process's peak resident memory (Linux ≥ 4.0); false where it cannot.
fn reset_peak_rss() -> bool {
    std::fs::write("/proc/self/clear_refs", "5").is_ok()
}

/// Runs every pair `runs` times and prints the table; `spot` is the source of the Spot pairs
/// (already read by the first table).
pub fn run(assets: &Path, spot: Model, runs: usize) -> Result<(), String> {
    let pairs: Vec<(&str, Model, Model)> = {
        let (stripes, stretched) = stripes_pair()?;
        vec![
            (
                "stripes capsule, far half stretched 2× (69K → 69K vertices)",
                stripes,
                stretched,
            ),
            (
                "Spot → cat (8K-vertex target)",
                spot.clone(),
                read_asset(assets, "tgt_cat_odedstein/cat-low-resolution_derived.glb")?,
            ),
            (
                "Spot → koala scan (50K vertices, 100K triangles)",
                spot,
                read_asset(assets, "perf_koala_odedstein/koala_derived.glb")?,
            ),
        ]
    };
    println!(
        "\n| pair (64K samples, no correspondences, median of {runs}) | synthesis vertices (target / source), levels | hierarchies | features | finest level set-up | target fans, one pass | one E-step | one vote | whole synthesis | whole transfer | peak memory |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    for (name, source, target) in &pairs {
        let reset = reset_peak_rss();
        let m = measure((source, target), serde_json::json!({}), runs, false)?;
        let peak = match (reset, peak_rss_mib()) {
            (true, Some(p)) => format!("{p:.0} MiB"),
            _ => "not measured".to_string(),
        };
        let ms = |v: &Vec<f64>| format!("{:.0} ms", median(v.clone()));
        println!(
            "| {name} | {} / {}, {} | {} | {} | {} | {} | {} | {} | {} | {} | {peak} |",
            m.vertices.0,
            m.vertices.1,
            m.levels,
            ms(&m.hierarchy),
            ms(&m.features),
            ms(&m.level0_setup),
            ms(&m.fans),
            ms(&m.e_step),
            ms(&m.vote),
            ms(&m.synth),
            ms(&m.whole),
        );
    }
    Ok(())
}
