//! The source → target pairs proposed in shared/assets/INDEX.md all transfer and validate: a
//! multi-material target with texture transforms, a target with its own UVs under a rotated
//! node, skinned and non-indexed sources, an open-boundary bust, a genus-1 target. All of them
//! read the shared assets, so they are ignored by default (`.ci/run` runs them).

use crate::common::*;
use retex::engine::asset::constraints::Constraints;
use retex::engine::asset::BlobSet;
use retex::engine::control::Control;
use retex::engine::pipeline::{transfer, ModelInput, TransferInput};

fn pair(source: &str, target: &str, name: &str) -> serde_json::Value {
    let (sm, sb) = BlobSet::from_path(&shared_asset(source)).unwrap();
    let (tm, tb) = BlobSet::from_path(&shared_asset(target)).unwrap();
    let c = Constraints::from_json(br#"{"version": 1, "output": {"texture_size": 256}, "params": {"vertex_color_samples": 20000}}"#).unwrap();
    let input = TransferInput::pair(
        ModelInput {
            main: &sm,
            blobs: &sb,
        },
        ModelInput {
            main: &tm,
            blobs: &tb,
        },
        c,
    );
    let out =
        transfer(&input, &Control::new()).unwrap_or_else(|e| panic!("{source} → {target}: {e}"));
    assert_validator_clean(&out.model, name);
    serde_json::to_value(&out.report).unwrap()
}

#[test]
#[ignore = "needs the shared assets (RETEX_SHARED_ASSETS or ../shared/assets)"]
fn furniture_with_texture_transforms_onto_a_multi_primitive_sofa() {
    let r = pair(
        "src_sheen_chair_khronos/glTF/SheenChair.gltf",
        "tgt_glam_velvet_sofa_khronos/glTF-Binary/GlamVelvetSofa.glb",
        "pair_chair_sofa.glb",
    );
    let textures = r["method_report"]["textures"].as_array().unwrap();
    assert!(!textures.is_empty());
    for t in textures {
        assert!(t["covered"].as_u64().unwrap() > 0, "{t}");
    }
}

#[test]
#[ignore = "needs the shared assets (RETEX_SHARED_ASSETS or ../shared/assets)"]
fn fish_onto_a_fish_with_its_own_uvs_and_a_rotated_node() {
    let r = pair(
        "src_blub_keenan/blub_textured_derived.glb",
        "tgt_barramundi_fish_khronos_geometry/glTF/BarramundiFish_geometry_only_derived.gltf",
        "pair_blub_barramundi.glb",
    );
    assert_eq!(
        r["method_report"]["textures"].as_array().unwrap().len(),
        1,
        "{}",
        r["method_report"]
    );
}

#[test]
#[ignore = "needs the shared assets (RETEX_SHARED_ASSETS or ../shared/assets)"]
fn skinned_non_indexed_fox_onto_an_untextured_koala() {
    let r = pair(
        "src_fox_khronos/glTF-Binary/Fox.glb",
        "perf_koala_odedstein/koala_low_resolution_derived.glb",
        "pair_fox_koala.glb",
    );
    // The UV-less koala is baked through a generated atlas (`output.uv = "auto"`).
    let atlas = &r["method_report"]["atlas"];
    assert!(atlas["chart_count"].as_u64().unwrap_or(0) > 0, "{atlas}");
    let stretch = atlas["l2_stretch"].as_f64().unwrap();
    assert!((1.0..1.2).contains(&stretch), "L2 stretch {stretch}");
    assert!(r["method_report"]["vertex_colors"]
        .as_array()
        .unwrap()
        .is_empty());
}

#[test]
#[ignore = "needs the shared assets (RETEX_SHARED_ASSETS or ../shared/assets)"]
fn head_onto_an_open_bust_and_spot_onto_a_torus() {
    pair(
        "src_lee_perry_smith_head/LeePerrySmith_textured_derived.gltf",
        "tgt_demosthenes_bust_odedstein/demosthenes-low-res_derived.glb",
        "pair_head_bust.glb",
    );
    pair(
        "src_spot_keenan/spot_textured_derived.glb",
        "tgt_primitives_odedstein_torus/torus_derived.glb",
        "pair_spot_torus.glb",
    );
}

#[test]
#[ignore = "needs the shared assets (RETEX_SHARED_ASSETS or ../shared/assets)"]
fn skinned_source_onto_a_skinned_target_keeps_the_rig() {
    let r = pair(
        "src_spot_keenan/spot_textured_derived.glb",
        "src_cesium_man_khronos/glTF-Binary/CesiumMan.glb",
        "pair_spot_cesium_man.glb",
    );
    assert_eq!(r["method_report"]["textures"].as_array().unwrap().len(), 1);
}
