//! The engine's integration tests, one test binary (`cargo test --release --test engine`): ingest,
//! surfaces and BVH, the multiresolution hierarchy, the geometry core, spectra, ray features,
//! geodesic fans, textures, previews, colour output, the `project` and `meshmatch` methods and the
//! constraints schema. Filter by module, e.g. `cargo test --release --test engine project_transfer::`.
//!
//! Benchmarks are ignored tests named `bench_*`
//! (`cargo test --release --test engine bench_ -- --ignored --nocapture`); tests that read the
//! shared assets (`../shared/assets` or `$RETEX_SHARED_ASSETS`) are ignored too and run with
//! `-- --include-ignored --skip bench_ --skip crosscheck_`, as `.ci/run` does.

#[path = "../common/mod.rs"]
mod common;
mod common_geometry;
mod elastiface_common;
mod meshmatch_common;
mod pattern_common;

mod color_output;
mod constraints_schema;
mod correlation;
mod correlation_common;
mod correlation_debug;
mod correlation_nonparametric;
mod correlation_parts;
mod correlation_real;
mod correlation_sampling;
mod correlation_sweep;
mod correlation_synthesis;
mod detail_atlas;
mod detail_displacement;
mod detail_equal_weights;
mod detail_features;
mod detail_method;
mod detail_metric;
mod detail_properties;
mod detail_real_self;
mod detail_refine;
mod detail_remesh;
mod detail_steerable;
mod elastiface;
mod elastiface_blend;
mod elastiface_inputs;
mod elastiface_landmarks;
mod elastiface_real;
mod elastiface_region;
mod elastiface_remeshed;
mod elastiface_shapes;
mod fan_pruning;
mod fuzz_ingest;
mod geodesic_fans;
mod geometry_core;
mod ingest_edge_cases;
mod memory_budget;
mod meshmatch_defects;
mod meshmatch_features;
mod meshmatch_param_sweep;
mod meshmatch_real_pairs;
mod meshmatch_restarts;
mod meshmatch_scale;
mod meshmatch_statistics;
mod meshmatch_stretch_period;
mod meshmatch_stripes;
mod meshmatch_transfer;
mod meshmatch_units;
mod meshmatch_update;
mod method_seam;
mod multires_properties;
mod pattern;
mod pattern_fit;
mod pattern_hierarchy;
mod preview;
mod primitives_capsule;
mod project_transfer;
mod ray_features;
mod shared_pairs;
mod spectra;
mod surface_bvh_properties;
mod texture_properties;
mod uv_arap;
mod uv_atlas;
mod uv_lscm;
mod uv_merge_sweep;
