//! Issue 16, part 1: the preview turntable lights a normal map ("base colour and, where a method
//! outputs one, the normal map lit"). A white quad made in code, seen head-on, with a normal map
//! whose tangent-space normal is a known function of (u, v): the rendered brightness follows the
//! Lambert term of that normal (green up, glTF's convention), not of the flipped one nor of the
//! face normal; a flat normal map renders as no normal map.

use retex::engine::asset::{load, BlobSet, IngestLimits};
use retex::engine::texture::preview::{
    render_turntable, render_turntable_noted, PreviewImage, PreviewParams,
};

/// Texels per side of the normal map.
const MAP: u32 = 256;
/// Pixels of the one view.
const SIZE: u32 = 128;

/// The tangent-space normal encoded at (u, v) (glTF UVs: v grows downwards in the image).
fn bumpy(u: f32, v: f32) -> [f32; 3] {
    let x = 0.6 * (std::f32::consts::TAU * 2.0 * u).sin();
    let y = 0.6 * (std::f32::consts::TAU * 3.0 * v).cos();
    let l = (x * x + y * y + 1.0).sqrt();
    [x / l, y / l, 1.0 / l]
}

fn normal_png(f: impl Fn(f32, f32) -> [f32; 3]) -> Vec<u8> {
    let img = image::RgbImage::from_fn(MAP, MAP, |x, y| {
        let n = f((x as f32 + 0.5) / MAP as f32, (y as f32 + 0.5) / MAP as f32);
        image::Rgb(n.map(|c| ((c * 0.5 + 0.5) * 255.0).round() as u8))
    });
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png).unwrap();
    out.into_inner()
}

/// A 2 × 2 quad in the XY plane facing +Z, UV (0, 0) at its top-left corner, white, with the
/// normal map `png` (or none) as a GLB.
fn quad_glb(png: Option<&[u8]>) -> Vec<u8> {
    let pos: [[f32; 3]; 4] = [[-1., -1., 0.], [1., -1., 0.], [1., 1., 0.], [-1., 1., 0.]];
    let uv: [[f32; 2]; 4] = [[0., 1.], [1., 1.], [1., 0.], [0., 0.]];
    let idx: [u16; 6] = [0, 1, 2, 0, 2, 3];
    let mut bin = Vec::new();
    pos.iter()
        .flatten()
        .for_each(|x| bin.extend(x.to_le_bytes()));
    (0..4).for_each(|_| {
        [0f32, 0., 1.]
            .iter()
            .for_each(|x| bin.extend(x.to_le_bytes()))
    });
    uv.iter()
        .flatten()
        .for_each(|x| bin.extend(x.to_le_bytes()));
    idx.iter().for_each(|x| bin.extend(x.to_le_bytes()));
    let image_at = bin.len();
    if let Some(p) = png {
        bin.extend_from_slice(p);
    }
    let image_len = bin.len() - image_at;
    while bin.len() % 4 != 0 {
        bin.push(0);
    }
    let mut json = serde_json::json!({
        "asset": {"version": "2.0"},
        "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2},
                                    "indices": 3, "material": 0}]}],
        "materials": [{"pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, 1], "metallicFactor": 0}}],
        "buffers": [{"byteLength": bin.len()}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 48},
            {"buffer": 0, "byteOffset": 48, "byteLength": 48},
            {"buffer": 0, "byteOffset": 96, "byteLength": 32},
            {"buffer": 0, "byteOffset": 128, "byteLength": 12},
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
             "min": [-1, -1, 0], "max": [1, 1, 0]},
            {"bufferView": 1, "componentType": 5126, "count": 4, "type": "VEC3"},
            {"bufferView": 2, "componentType": 5126, "count": 4, "type": "VEC2"},
            {"bufferView": 3, "componentType": 5123, "count": 6, "type": "SCALAR"},
        ],
    });
    if png.is_some() {
        json["bufferViews"].as_array_mut().unwrap().push(
            serde_json::json!({"buffer": 0, "byteOffset": image_at, "byteLength": image_len}),
        );
        json["images"] = serde_json::json!([{"bufferView": 4, "mimeType": "image/png"}]);
        // Clamped, so the quad's edges do not blend in the opposite edge's texels.
        json["samplers"] = serde_json::json!([{"magFilter": 9729, "minFilter": 9729, "wrapS": 33071, "wrapT": 33071}]);
        json["textures"] = serde_json::json!([{"source": 0, "sampler": 0}]);
        json["materials"][0]["normalTexture"] = serde_json::json!({"index": 0});
    }
    let mut text = serde_json::to_vec(&json).unwrap();
    while !text.len().is_multiple_of(4) {
        text.push(b' ');
    }
    let mut glb = Vec::new();
    glb.extend(b"glTF");
    glb.extend(2u32.to_le_bytes());
    glb.extend((12 + 8 + text.len() as u32 + 8 + bin.len() as u32).to_le_bytes());
    glb.extend((text.len() as u32).to_le_bytes());
    glb.extend(b"JSON");
    glb.extend(text);
    glb.extend((bin.len() as u32).to_le_bytes());
    glb.extend(b"BIN\0");
    glb.extend(bin);
    glb
}

fn head_on() -> PreviewParams {
    PreviewParams {
        views: 1,
        size: SIZE,
        elevation_degrees: 0.0,
        shading: true,
    }
}

fn render(glb: &[u8]) -> PreviewImage {
    let mut blobs = BlobSet::new();
    blobs.insert("quad.glb", glb.to_vec());
    let asset = load("quad.glb", &blobs, &IngestLimits::default()).unwrap();
    let (image, notes) = render_turntable_noted(&asset, &head_on()).unwrap();
    assert!(notes.is_empty(), "{notes:?}");
    image
}

/// The renderer's light for the head-on view (its module docs: above-left of the camera).
fn light() -> [f32; 3] {
    let l = [-0.3f32, 0.5, 0.8];
    let n = (l[0] * l[0] + l[1] * l[1] + l[2] * l[2]).sqrt();
    l.map(|x| x / n)
}

fn lambert(n: [f32; 3]) -> f32 {
    let l = light();
    0.35 + 0.65 * (n[0] * l[0] + n[1] * l[1] + n[2] * l[2]).max(0.0)
}

/// (u, v, rendered brightness) of every pixel well inside the quad.
fn inside(img: &PreviewImage) -> Vec<(f32, f32, f32)> {
    // Half-width of the view: 1.05 × the quad's radius √2.
    let half = 1.05 * 2f32.sqrt();
    let mut out = Vec::new();
    for y in 0..SIZE {
        for x in 0..SIZE {
            let wx = ((x as f32 + 0.5) / SIZE as f32 * 2.0 - 1.0) * half;
            let wy = (1.0 - (y as f32 + 0.5) / SIZE as f32 * 2.0) * half;
            if wx.abs() < 0.95 && wy.abs() < 0.95 {
                out.push(((wx + 1.0) / 2.0, (1.0 - wy) / 2.0, img.pixel(x, y)[0]));
            }
        }
    }
    out
}

fn mean_abs(points: &[(f32, f32, f32)], expected: impl Fn(f32, f32) -> f32) -> f32 {
    points
        .iter()
        .map(|&(u, v, k)| (k - expected(u, v)).abs())
        .sum::<f32>()
        / points.len() as f32
}

#[test]
fn a_normal_map_is_lit_green_up_and_a_flat_one_changes_nothing() {
    let plain = render(&quad_glb(None));
    let bumped = render(&quad_glb(Some(&normal_png(bumpy))));
    let flat = render(&quad_glb(Some(&normal_png(|_, _| [0.0, 0.0, 1.0]))));

    let p = inside(&plain);
    assert!(p.len() > 5000, "{} pixels inside", p.len());
    // Without a normal map the quad is one flat shade: the face normal's.
    let face = lambert([0.0, 0.0, 1.0]);
    let worst_plain = p.iter().map(|q| (q.2 - face).abs()).fold(0.0, f32::max);
    assert!(worst_plain < 1e-4, "plain quad off by {worst_plain}");

    // With the bumpy map the shading follows the encoded normal ...
    let b = inside(&bumped);
    let fit = mean_abs(&b, |u, v| lambert(bumpy(u, v)));
    // ... and not the face normal, nor the map read with green down (the other convention).
    let as_plain = mean_abs(&b, |_, _| face);
    let green_down = mean_abs(&b, |u, v| {
        let n = bumpy(u, v);
        lambert([n[0], -n[1], n[2]])
    });
    let red_flipped = mean_abs(&b, |u, v| {
        let n = bumpy(u, v);
        lambert([-n[0], n[1], n[2]])
    });
    eprintln!(
        "bumpy quad: mean |error| {fit:.4}; vs face normal {as_plain:.4}, green down {green_down:.4}, red flipped {red_flipped:.4}"
    );
    assert!(fit < 0.01, "lit preview misses the normal map: {fit}");
    for (what, other) in [
        ("face normal", as_plain),
        ("green down", green_down),
        ("red flipped", red_flipped),
    ] {
        assert!(other > 5.0 * fit, "{what} fits as well: {other} vs {fit}");
    }
    let ks: Vec<f32> = b.iter().map(|q| q.2).collect();
    let (lo, hi) = ks
        .iter()
        .fold((f32::MAX, f32::MIN), |(a, c), &k| (a.min(k), c.max(k)));
    assert!(hi - lo > 0.3, "shading range {lo}..{hi}");

    // A flat map (128, 128, 255) is the face normal up to 8-bit rounding.
    let worst_flat = plain
        .pixels
        .iter()
        .zip(&flat.pixels)
        .map(|(a, c)| (a[0] - c[0]).abs().max((a[1] - c[1]).abs()))
        .fold(0.0, f32::max);
    assert!(
        worst_flat < 0.005,
        "flat normal map changes the image by {worst_flat}"
    );
}

#[test]
fn unshaded_previews_ignore_the_normal_map() {
    let mut blobs = BlobSet::new();
    blobs.insert("quad.glb", quad_glb(Some(&normal_png(bumpy))));
    let asset = load("quad.glb", &blobs, &IngestLimits::default()).unwrap();
    let params = PreviewParams {
        shading: false,
        ..head_on()
    };
    let img = render_turntable(&asset, &params).unwrap();
    let ks: Vec<f32> = inside(&img).iter().map(|q| q.2).collect();
    assert!(ks.iter().all(|k| (k - 1.0).abs() < 1e-4), "white, unlit");
}
