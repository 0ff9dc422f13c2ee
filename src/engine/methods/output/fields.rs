//! Several outputs from one evaluation per surface point: [`SurfaceFields`] and
//! [`write_fields`].
//!
//! A method whose textures share an expensive per-point step (`detail`: the closest point on the
//! finest level and the texture-space refinement's source reads serve both its normal map and
//! its displacement texture) implements [`SurfaceFields`]: one call per texel writes the values
//! of every output. [`write_fields`] bakes them in one texel loop: the UV layout is rasterized
//! once per group, and every output has its own texels, validity (a texel can have a value in
//! one output and not in another), padding, encoding ([`super::FieldOutput`]: slot, encoding,
//! image names) and report. Nothing is cached per texel beyond the output images themselves.
//!
//! Design choice (issue 13, "refinement cost"): the alternatives were baking each output in
//! its own pass (the expensive step runs once per output: 7.3 s of a 14.4 s `detail` job at
//! 2048²) or caching the shared step per texel between passes (about 160 MB at 2048²). The
//! single-field API ([`super::write_field`]) runs through the same loop with one output
//! ([`Single`]), so its outputs are unchanged.
//!
//! The vertex path (primitives without UVs, outputs that name a vertex attribute) samples the
//! fields once per output and vertex: it is a few thousand to a few hundred thousand points, no
//! method writing several outputs uses it today, and its refined copies differ per output
//! budget.

use super::{atlas::AtlasLayout, FieldOutput, OutputReport, SurfaceField, SurfaceSample};
use crate::engine::asset::constraints::Constraints;
use crate::engine::asset::edits::Edit;
use crate::engine::asset::Asset;
use crate::engine::control::{Cancelled, Control};

/// Fields of 1 to 4 values per point over the edited asset's surface, one per output, evaluated
/// together (each output's stored channels are its [`FieldOutput`]'s encoding).
pub trait SurfaceFields: Sync {
    /// Writes output `k`'s values at `at` into `out[k]` (`out` arrives all `None`; an output
    /// left `None` has no value there: the texel is unmatched in that output and filled by its
    /// padding) and returns a hint for the next nearby sample (same texel row), or `None` to
    /// keep the previous one. `hint` is the last hint returned for a nearby sample, or `None`.
    fn sample(
        &self,
        at: &SurfaceSample,
        hint: Option<u32>,
        out: &mut [Option<[f32; 4]>],
    ) -> Option<u32>;
}

/// One [`SurfaceField`] as a single output: its value where it returns a hint.
pub(super) struct Single<'a>(pub(super) &'a dyn SurfaceField);

impl SurfaceFields for Single<'_> {
    fn sample(
        &self,
        at: &SurfaceSample,
        hint: Option<u32>,
        out: &mut [Option<[f32; 4]>],
    ) -> Option<u32> {
        let mut value = [0.0f32; 4];
        let next = self.0.sample(at, hint, &mut value)?;
        out[0] = Some(value);
        Some(next)
    }
}

/// Output `index` of the `count` outputs of `fields`, read alone (the vertex path).
#[derive(Clone, Copy)]
pub(super) struct OutputOf<'a> {
    pub(super) fields: &'a dyn SurfaceFields,
    pub(super) index: usize,
    pub(super) count: usize,
}

impl OutputOf<'_> {
    /// The output's value at `at` (no hint), `None` where it has none; `scratch` holds every
    /// output's value.
    pub(super) fn sample(
        &self,
        at: &SurfaceSample,
        scratch: &mut Vec<Option<[f32; 4]>>,
    ) -> Option<[f32; 4]> {
        scratch.clear();
        scratch.resize(self.count, None);
        self.fields.sample(at, None, scratch);
        scratch[self.index]
    }
}

/// Writes the outputs of `fields` into `asset`, output `k` as `outputs[k]` says, in one texel
/// loop: through each primitive's base-colour UVs, and through `atlas` (built by the caller with
/// [`super::atlas::build`]; its own edits are the caller's to emit) for its primitives. No atlas
/// is built here. Returns per output its edits and report, as [`super::write_field`] would
/// for that output alone. Control stages `bake` (once), `pad` (groups × outputs) and
/// `vertex_colors` (per output).
///
/// # Errors
/// [`Cancelled`].
pub(crate) fn write_fields(
    asset: &Asset,
    constraints: &Constraints,
    outputs: &[FieldOutput],
    fields: &dyn SurfaceFields,
    atlas: Option<&AtlasLayout>,
    control: &Control,
) -> Result<Vec<(Vec<Edit>, OutputReport)>, Cancelled> {
    let mut report = OutputReport::default();
    let layout = match atlas {
        Some(a) => layout_in_atlas(asset, constraints, a, &mut report),
        None => super::texels::layout(asset, constraints, &mut report.warnings),
    };
    super::finish(
        asset,
        constraints,
        outputs,
        fields,
        layout,
        Vec::new(),
        report,
        control,
    )
}

/// The layout with the primitives of `atlas` baked through it instead of the vertex path; the
/// atlas's report goes into `report`.
fn layout_in_atlas(
    asset: &Asset,
    constraints: &Constraints,
    atlas: &AtlasLayout,
    report: &mut OutputReport,
) -> super::texels::Layout {
    let mut layout = super::texels::layout(asset, constraints, &mut report.warnings);
    let replaced = atlas.primitives();
    layout.vertex_path.retain(|(p, _)| !replaced.contains(p));
    layout.atlas = atlas.tris.clone();
    report.atlas = Some(atlas.report.clone());
    layout
}

#[cfg(test)]
mod tests {
    use std::sync::atomic::{AtomicU64, Ordering};

    use super::*;
    use crate::engine::asset::edits::TextureSlot;
    use crate::engine::methods::output::{write_field, TexelEncoding};

    /// Spot (one primitive with UVs), from the repository's test data.
    fn spot() -> Asset {
        let name = "spot.glb";
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/tests/data/src_spot_keenan/spot_textured_derived.glb"
        );
        let mut blobs = crate::engine::asset::BlobSet::new();
        blobs.insert(name, std::fs::read(path).unwrap());
        crate::engine::asset::load(name, &blobs, &Default::default()).unwrap()
    }

    /// Output 0: the normal as a colour, only where `x > 0` (elsewhere padded); output 1: the
    /// height everywhere. Counts its samples.
    struct Pair(AtomicU64);

    impl Pair {
        fn value(at: &SurfaceSample, k: usize) -> Option<[f32; 4]> {
            let n = at.normal.map(|x| 0.5 + 0.5 * x);
            match k {
                0 => (at.position[0] > 0.0).then_some([n[0], n[1], n[2], 1.0]),
                _ => Some([at.position[1], 0.0, 0.0, 0.0]),
            }
        }
    }

    impl SurfaceFields for Pair {
        fn sample(
            &self,
            at: &SurfaceSample,
            _: Option<u32>,
            out: &mut [Option<[f32; 4]>],
        ) -> Option<u32> {
            self.0.fetch_add(1, Ordering::Relaxed);
            for (k, o) in out.iter_mut().enumerate() {
                *o = Pair::value(at, k);
            }
            Some(0)
        }
    }

    /// Output `k` of [`Pair`] alone.
    struct One(usize);

    impl SurfaceField for One {
        fn sample(&self, at: &SurfaceSample, _: Option<u32>, out: &mut [f32; 4]) -> Option<u32> {
            *out = Pair::value(at, self.0)?;
            Some(0)
        }
    }

    fn outputs(vertex_attribute: Option<&'static str>) -> [FieldOutput; 2] {
        let out = |slot, encoding, name| FieldOutput {
            slot,
            encoding,
            name,
            vertex_attribute,
            vertex_samples: 500,
        };
        [
            out(
                TextureSlot::Normal { scale: 1.0 },
                TexelEncoding::Linear8 { channels: 3 },
                "a",
            ),
            out(TextureSlot::Extras("b"), TexelEncoding::Gray16, "b"),
        ]
    }

    #[test]
    fn two_outputs_from_one_sample_equal_two_single_bakes() {
        let asset = spot();
        let c =
            Constraints::from_json(br#"{"version": 1, "output": {"texture_size": 64}}"#).unwrap();
        let outputs = outputs(None);
        let pair = Pair(AtomicU64::new(0));
        let both = write_fields(&asset, &c, &outputs, &pair, None, &Control::new()).unwrap();
        assert_eq!(both.len(), 2);
        for (k, (edits, report)) in both.iter().enumerate() {
            let (e, r) = write_field(&asset, &c, &outputs[k], &One(k), &Control::new()).unwrap();
            assert_eq!(*edits, e, "output {k}: the same texture");
            assert_eq!(
                serde_json::to_value(report).unwrap(),
                serde_json::to_value(&r).unwrap()
            );
        }
        let t = &both[0].1.textures[0];
        assert_eq!(
            pair.0.load(Ordering::Relaxed),
            t.covered,
            "one sample per texel"
        );
        assert!(t.unmatched > 0 && both[1].1.textures[0].unmatched == 0);
    }

    #[test]
    fn the_vertex_path_reads_each_output() {
        let asset = spot();
        let c = Constraints::from_json(
            br#"{"version": 1, "output": {"texture_size": 64, "vertex_colors": true}}"#,
        )
        .unwrap();
        let outputs = outputs(Some("COLOR_0"));
        let pair = Pair(AtomicU64::new(0));
        let both = write_fields(&asset, &c, &outputs, &pair, None, &Control::new()).unwrap();
        for (k, (edits, report)) in both.iter().enumerate() {
            let (e, r) = write_field(&asset, &c, &outputs[k], &One(k), &Control::new()).unwrap();
            assert!(
                !e.is_empty() && *edits == e,
                "output {k}: the same vertex values"
            );
            assert_eq!(report.vertex_colors.len(), r.vertex_colors.len());
        }
    }

    #[test]
    fn cancellation_is_an_error() {
        let asset = spot();
        let c =
            Constraints::from_json(br#"{"version": 1, "output": {"texture_size": 64}}"#).unwrap();
        let control = Control::new();
        control.cancel();
        let pair = Pair(AtomicU64::new(0));
        let got = write_fields(&asset, &c, &outputs(None), &pair, None, &control);
        assert!(got.is_err());
    }
}
