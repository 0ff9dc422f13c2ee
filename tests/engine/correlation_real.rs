//! The `correlation` method on real assets (issue 11): Spot's texture onto the cat, the Lee
//! Perry-Smith head's skin onto the Demosthenes bust. The outputs are written (validator-clean)
//! to `target/test-outputs/correlation_*.glb`; look at them with `retex preview`.

use retex::engine::asset::constraints::Constraints;
use retex::engine::asset::BlobSet;
use retex::engine::control::Control;
use retex::engine::pipeline::{transfer, ModelInput, TransferInput, TransferOutput};
use serde_json::json;

use crate::common::{assert_validator_clean, shared_asset};
use crate::meshmatch_common::colored_points;

const SPOT: &str = "src_spot_keenan/spot_textured_derived.glb";
const CAT: &str = "tgt_cat_odedstein/cat-low-resolution_derived.glb";
const HEAD: &str = "src_lee_perry_smith_head/LeePerrySmith_textured_derived.gltf";
const BUST: &str = "tgt_demosthenes_bust_odedstein/demosthenes-low-res_derived.glb";

fn run(source: &str, target: &str, params: serde_json::Value) -> TransferOutput {
    let (sm, sb) = BlobSet::from_path(&shared_asset(source)).expect("read source");
    let (tm, tb) = BlobSet::from_path(&shared_asset(target)).expect("read target");
    let c: Constraints = serde_json::from_value(
        json!({"version": 1, "method": "correlation", "output": {"uv": "keep"}, "params": params}),
    )
    .unwrap();
    transfer(
        &TransferInput::pair(
            ModelInput {
                main: &sm,
                blobs: &sb,
            },
            ModelInput {
                main: &tm,
                blobs: &tb,
            },
            c,
        ),
        &Control::new(),
    )
    .unwrap()
}

fn luminance(c: [f32; 3]) -> f32 {
    0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
}

#[test]
#[ignore = "needs ../shared/assets"]
fn spot_onto_the_cat_carries_its_black_patches() {
    // Spot is white with black patches and hooves: the cat must get both, not a grey average
    // ("dark": linear luminance below 0.1, sRGB about 0.35).
    let out = run(SPOT, CAT, json!({"samples": 65536}));
    assert_validator_clean(&out.model, "correlation_spot_cat.glb");
    let pts = colored_points(&out.model);
    let lum: Vec<f32> = pts.iter().map(|p| luminance(p.1)).collect();
    let n = lum.len() as f32;
    let dark = lum.iter().filter(|l| **l < 0.1).count() as f32 / n;
    let light = lum.iter().filter(|l| **l > 0.5).count() as f32 / n;
    let r = &out.report.method_report;
    eprintln!(
        "dark share {dark:.3}, light share {light:.3}; correlations {}",
        r["guidance"]["correlations"]
    );
    assert!((0.03..0.5).contains(&dark), "dark share {dark:.3}");
    assert!(light > 0.4, "light share {light:.3}");
    assert!(r["guidance"]["correlations"][0].as_f64().unwrap() > 0.4);
}

#[test]
#[ignore = "needs ../shared/assets"]
fn the_heads_skin_onto_the_bust_keeps_its_colour_statistics() {
    let out = run(HEAD, BUST, json!({"samples": 65536}));
    assert_validator_clean(&out.model, "correlation_head_bust.glb");
    let pts = colored_points(&out.model);
    let n = pts.len() as f32;
    let mean: [f32; 3] = std::array::from_fn(|k| pts.iter().map(|p| p.1[k]).sum::<f32>() / n);
    let spread = (pts
        .iter()
        .map(|p| (luminance(p.1) - luminance(mean)).powi(2))
        .sum::<f32>()
        / n)
        .sqrt();
    let r = &out.report.method_report;
    eprintln!(
        "mean {mean:?}, luminance spread {spread:.3}; correlations {}",
        r["guidance"]["correlations"]
    );
    // Skin: red above green above blue, neither grey nor a flat colour.
    assert!(mean[0] > mean[1] && mean[1] > mean[2], "{mean:?}");
    assert!(spread > 0.01, "flat output: {spread}");
    assert_eq!(r["guidance"]["dims"], 3);
    assert!(r["guidance"]["correlations"][0].as_f64().unwrap() > 0.5);
}
