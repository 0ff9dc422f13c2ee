//! A pattern-shaped method that exists only in the tests (issue 8: adding a method is one
//! folder and one registry line; here not even that: the tests register it in a
//! [`retex::engine::methods::Registry`]). It replaces every target primitive with unwelded
//! corners carrying planar-projection UVs into the uploaded pattern image, passes the image
//! through unmodified and adds an extra result file.
#![allow(dead_code)]

use retex::engine::asset::constraints::{Constraints, ConstraintsError, MethodId};
use retex::engine::asset::edits::{
    Edit, EncodedImage, PrimitiveGeometry, TextureSlot, TextureWrap,
};
use retex::engine::asset::Asset;
use retex::engine::control::Control;
use retex::engine::methods::{
    InputSpec, Method, MethodError, MethodInput, MethodOutput, ResultFile,
};
use serde_json::{json, Value};

/// A 32×16 JPEG.
pub fn small_jpeg() -> Vec<u8> {
    let img = image::RgbImage::from_fn(32, 16, |x, y| {
        image::Rgb([(x * 8) as u8, (y * 16) as u8, 90])
    });
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Jpeg).unwrap();
    out.into_inner()
}

/// Every corner its own vertex, UVs by planar projection onto x/y of the bounding box, scaled
/// so they run past 1 (REPEAT).
pub fn unwelded_with_planar_uvs(asset: &Asset, p: usize) -> PrimitiveGeometry {
    let prim = &asset.primitives[p];
    let (mut lo, mut hi) = ([f32::MAX; 2], [f32::MIN; 2]);
    for v in &prim.positions {
        for k in 0..2 {
            lo[k] = lo[k].min(v[k]);
            hi[k] = hi[k].max(v[k]);
        }
    }
    let mut g = PrimitiveGeometry::default();
    let mut uv = Vec::new();
    for t in &prim.triangles {
        let base = g.positions.len() as u32;
        for &v in t {
            let q = prim.positions[v as usize];
            g.positions.push(q);
            uv.push([
                2.0 * (q[0] - lo[0]) / (hi[0] - lo[0]),
                2.0 * (q[1] - lo[1]) / (hi[1] - lo[1]),
            ]);
        }
        g.triangles.push([base, base + 1, base + 2]);
    }
    g.tex_coords.push(uv);
    g
}

/// A pattern-shaped method that exists only in this test: planar UVs into the uploaded image,
/// passed through unmodified, plus an extra result file.
pub struct PlanarPattern;

/// The registry entry of [`PlanarPattern`] (a reserved id that retex does not implement yet).
pub static PLANAR_PATTERN: PlanarPattern = PlanarPattern;

impl Method for PlanarPattern {
    fn id(&self) -> MethodId {
        MethodId::Pattern
    }

    /// The same inputs as the real `pattern` method.
    fn inputs(&self) -> InputSpec {
        retex::engine::methods::pattern::Pattern.inputs()
    }

    fn params_schema(&self) -> Value {
        json!({"type": "object", "additionalProperties": false})
    }

    fn check(&self, c: &Constraints) -> Result<(), ConstraintsError> {
        c.method_params::<std::collections::BTreeMap<String, u32>>()
            .map(drop)
    }

    fn run(&self, input: &MethodInput<'_>, control: &Control) -> Result<MethodOutput, MethodError> {
        let pattern = input
            .pattern
            .ok_or_else(|| MethodError::Internal("no pattern".into()))?;
        control.stage("planar uvs", 1)?;
        let t = input.target;
        let mut edits: Vec<Edit> = (0..t.primitives.len())
            .map(|p| Edit::ReplacePrimitive {
                primitive: p,
                geometry: unwelded_with_planar_uvs(t, p),
            })
            .collect();
        edits.push(Edit::SetTexture {
            material: t.primitives[0].material,
            slot: TextureSlot::BaseColor,
            image: EncodedImage::passthrough("pattern", pattern.bytes.clone(), pattern.mime_type),
            tex_coord: 0,
            wrap: TextureWrap::Repeat,
            primitives: (0..t.primitives.len()).collect(),
        });
        let mut out = MethodOutput::target(
            edits,
            &json!({"pattern_size": [pattern.image.width, pattern.image.height]}),
        );
        out.files.push(ResultFile {
            name: "planar.txt".into(),
            media_type: "text/plain".into(),
            bytes: b"planar projection onto x/y".to_vec(),
        });
        Ok(out)
    }
}
