//! The sweep behind the chart merge's two constants (`AtlasParams::merge_max_faces`,
//! `merge_rounds`; issue 15, `src/engine/uv/merge.rs`): the atlas of the six shared scans the
//! README compares with xatlas, for every pair of values, with charts, L2 stretch, packing,
//! seam length and time. Ignored (it reads `../shared/assets` and is a measurement); run with
//! `cargo test --release --test engine bench_sweep_merge_constants -- --ignored --nocapture`. The
//! README keeps its table.
//!
//! Every atlas must also stay valid: no chart above the stretch bound, packing above zero. The
//! test fails if a scan is missing (no vacuous pass).

use retex::engine::control::Control;
use retex::engine::uv::{generate, AtlasParams};

const SCANS: [(&str, &str); 6] = [
    ("cat", "tgt_cat_odedstein/cat-low-resolution.obj"),
    ("fish", "tgt_fish_remeshed_odedstein/fish.obj"),
    (
        "Demosthenes",
        "tgt_demosthenes_bust_odedstein/demosthenes-low-res.obj",
    ),
    (
        "Nefertiti",
        "tgt_nefertiti_bust_odedstein/nefertiti-lowres.obj",
    ),
    ("koala", "perf_koala_odedstein/koala.obj"),
    ("skull", "perf_skull_odedstein/skull.obj"),
];

#[test]
#[ignore = "reads ../shared/assets; a measurement"]
fn bench_sweep_merge_constants() {
    let surfaces: Vec<_> = SCANS
        .iter()
        .map(|(name, rel)| {
            let path = crate::common::shared_assets_dir().join(rel);
            assert!(path.exists(), "missing {}", path.display());
            (*name, crate::common_geometry::read_obj(&path))
        })
        .collect();
    println!(
        "| max faces | rounds | target | charts | L2 | packing | seams / diagonal | atlas ms |"
    );
    println!("|---|---|---|---|---|---|---|---|");
    for (max_faces, rounds) in [
        (0, 0),
        (1000, 8),
        (2000, 8),
        (2000, 16),
        (4000, 8),
        (4000, 16),
        (8000, 16),
    ] {
        let params = AtlasParams {
            merge_max_faces: max_faces,
            merge_rounds: rounds,
            ..AtlasParams::default()
        };
        let (mut charts, mut seams, mut ms) = (0, 0.0, 0.0);
        for (name, s) in &surfaces {
            let t = std::time::Instant::now();
            let a = generate(s, &params, &Control::new()).expect("atlas");
            let elapsed = t.elapsed().as_secs_f64() * 1e3;
            let r = &a.report;
            let seam = r.seam_length / s.diagonal() as f64;
            println!(
                "| {max_faces} | {rounds} | {name} | {} | {:.3} | {:.2} | {:.1} | {:.0} |",
                r.chart_count, r.l2_stretch, r.packing_efficiency, seam, elapsed
            );
            assert!(
                r.packing_efficiency > 0.2,
                "{name}: packing {}",
                r.packing_efficiency
            );
            assert!(
                r.charts
                    .iter()
                    .all(|c| c.l2_stretch <= params.max_stretch + 1e-9),
                "{name}: a chart above the stretch bound"
            );
            charts += r.chart_count;
            seams += seam;
            ms += elapsed;
        }
        println!("| {max_faces} | {rounds} | **all six** | {charts} | | | {seams:.1} | {ms:.0} |");
    }
}
