//! `write_color_field` with hand-made fields: a constant field bakes that color everywhere, a
//! field that declines everywhere still yields a padded texture, cancellation stops the bake.

use std::sync::atomic::{AtomicU64, Ordering};

use crate::common::*;
use retex::engine::asset::constraints::Constraints;
use retex::engine::asset::edits::{Edit, EncodedImage, PrimitiveGeometry};
use retex::engine::control::{Cancelled, Control};
use retex::engine::methods::color_output::{write_color_field, ColorField};
use retex::engine::texture::encode::decode_png_linear;

const SPOT: &str = "src_spot_keenan/spot_textured_derived.glb";
const BOX_COLORS: &str = "edge_box_vertex_colors_khronos/glTF-Binary/BoxVertexColors.glb";

struct Constant([f32; 4]);

impl ColorField for Constant {
    fn color_at(&self, _: [f32; 3], _: [f32; 3], _: Option<u32>) -> Option<([f32; 4], u32)> {
        Some((self.0, 0))
    }
}

/// Cancels its control after `after` calls.
struct Cancelling {
    control: Control,
    calls: AtomicU64,
    after: u64,
}

impl ColorField for Cancelling {
    fn color_at(&self, _: [f32; 3], _: [f32; 3], _: Option<u32>) -> Option<([f32; 4], u32)> {
        if self.calls.fetch_add(1, Ordering::Relaxed) + 1 == self.after {
            self.control.cancel();
        }
        None
    }
}

fn constraints(json: &str) -> Constraints {
    Constraints::from_json(json.as_bytes()).unwrap()
}

#[test]
fn a_constant_field_bakes_its_color_and_colors_vertices() {
    let spot = load_path(&test_data(SPOT));
    let c = constraints(r#"{"version": 1, "output": {"texture_size": 64}}"#);
    let color = [0.25, 0.5, 0.75, 1.0];
    let control = Control::new();
    let (edits, report) = write_color_field(&spot, &c, 1000, &Constant(color), &control).unwrap();
    let textures: Vec<&EncodedImage> = edits
        .iter()
        .filter_map(|e| match e {
            Edit::SetTexture { image, .. } => Some(image),
            _ => None,
        })
        .collect();
    assert_eq!(textures.len(), 1);
    assert_eq!(report.textures.len(), 1);
    assert_eq!(report.textures[0].unmatched, 0);
    let stages: Vec<String> = control.timings().into_iter().map(|t| t.stage).collect();
    assert_eq!(stages, ["bake", "pad"]);
    let (w, h, px) = decode_png_linear(&textures[0].bytes).unwrap();
    assert_eq!((w, h), (64, 64));
    for p in px {
        for k in 0..3 {
            assert!((p[k] - color[k]).abs() < 0.01, "{p:?}");
        }
    }
    // With `uv: keep`, a primitive without UVs gets COLOR_0 on a refined copy.
    let boxed = load_path(&test_data(BOX_COLORS));
    let c = constraints(r#"{"version": 1, "output": {"texture_size": 64, "uv": "keep"}}"#);
    let (edits, report) =
        write_color_field(&boxed, &c, 500, &Constant(color), &Control::new()).unwrap();
    assert!(!edits.iter().any(|e| matches!(e, Edit::SetTexture { .. })));
    let refined: Vec<&PrimitiveGeometry> = edits
        .iter()
        .filter_map(|e| match e {
            Edit::ReplacePrimitive { geometry, .. } => Some(geometry),
            _ => None,
        })
        .collect();
    assert_eq!(refined.len(), 1);
    assert!(refined[0]
        .colors
        .as_ref()
        .unwrap()
        .iter()
        .all(|c| *c == color));
    assert_eq!(report.vertex_colors[0].unmatched, 0);
    assert!(!report.warnings.is_empty());
}

#[test]
fn cancelling_during_the_bake_stops_it() {
    let spot = load_path(&test_data(SPOT));
    let c = constraints(r#"{"version": 1, "output": {"texture_size": 512}}"#);
    let control = Control::new();
    let field = Cancelling {
        control: control.clone(),
        calls: AtomicU64::new(0),
        after: 100,
    };
    let r = write_color_field(&spot, &c, 1000, &field, &control);
    assert_eq!(r.err(), Some(Cancelled));
    // Far fewer texels than the ~100k covered ones were evaluated.
    assert!(field.calls.load(Ordering::Relaxed) < 60_000);
}
