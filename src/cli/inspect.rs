//! `retex inspect`: what a model holds (meshes, primitives, counts, UV sets, materials,
//! textures and their sizes, world bounding box) and the problems found (load errors, skipped
//! primitives, degenerate triangles, open boundaries, non-manifold edges).

use std::path::Path;

use retex::engine::asset::{load, Asset, BlobSet, IngestLimits};
use retex::engine::mesh::{build_surface, topology, WeldParams};
use serde_json::{json, Value};

/// An f32 shown with 4 decimals (without the f32 → f64 noise in the JSON).
fn round4(x: f32) -> f64 {
    (x as f64 * 1e4).round() / 1e4
}

/// Builds the description of a loaded asset.
pub fn describe(asset: &Asset) -> Value {
    let mut meshes: Vec<Value> = Vec::new();
    for p in &asset.primitives {
        while meshes.len() <= p.mesh {
            meshes.push(json!({"index": meshes.len(), "primitives": []}));
        }
        meshes[p.mesh]["primitives"]
            .as_array_mut()
            .expect("array")
            .push(json!({
                "index": p.primitive,
                "mode": format!("{:?}", p.mode).to_lowercase(),
                "material": p.material,
                "vertices": p.positions.len(),
                "triangles": p.triangles.len(),
                "uv_sets": p.tex_coords.len(),
                "normals": p.normals.is_some(),
                "vertex_colors": p.colors.is_some(),
            }));
    }
    let materials: Vec<Value> = asset
        .materials
        .iter()
        .enumerate()
        .map(|(i, m)| {
            let tex = m.base_color_texture.map(|t| {
                let image = asset.textures.get(t.texture).and_then(|x| x.image);
                let img = image.and_then(|i| asset.images.get(i));
                json!({
                    "texture": t.texture, "image": image, "tex_coord": t.tex_coord,
                    "width": img.map(|i| i.width), "height": img.map(|i| i.height),
                    "transform": t.transform.map(|x| json!({"offset": x.offset, "rotation": x.rotation, "scale": x.scale})),
                })
            });
            json!({"index": i, "name": m.name, "base_color_factor": m.base_color_factor.map(round4), "base_color_texture": tex})
        })
        .collect();
    let images: Vec<Value> = asset
        .images
        .iter()
        .enumerate()
        .map(|(i, im)| json!({"index": i, "mime_type": im.mime_type, "width": im.width, "height": im.height, "bytes": im.bytes.len()}))
        .collect();
    let mut problems: Vec<String> = asset.warnings.clone();
    let surface = match build_surface(asset, &WeldParams::default()) {
        Ok(s) => {
            let t = topology(&s);
            let (lo, hi) = s.bounding_box();
            if s.degenerate_removed > 0 {
                problems.push(format!("{} degenerate triangles", s.degenerate_removed));
            }
            if !t.boundary_loops.is_empty() {
                problems.push(format!("{} open boundary loops", t.boundary_loops.len()));
            }
            if t.non_manifold_edges > 0 {
                problems.push(format!("{} non-manifold edges", t.non_manifold_edges));
            }
            json!({
                "vertices": s.vertex_count(), "faces": s.face_count(), "degenerate_removed": s.degenerate_removed,
                "boundary_loops": t.boundary_loops.len(), "non_manifold_edges": t.non_manifold_edges,
                "components": t.component_count, "euler_characteristic": t.euler_characteristic,
                "bounding_box": {"min": lo.map(round4), "max": hi.map(round4)},
                "diagonal": round4(s.diagonal()), "area": s.area(),
            })
        }
        Err(e) => {
            problems.push(e.to_string());
            Value::Null
        }
    };
    json!({
        "meshes": meshes, "instances": asset.instances.len(), "materials": materials,
        "textures": asset.textures.len(), "images": images, "surface": surface, "problems": problems,
    })
}

/// Runs the command.
pub fn run(path: &Path, as_json: bool) -> Result<(), String> {
    let (main, blobs) = BlobSet::from_path(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let asset = load(&main, &blobs, &IngestLimits::default())
        .map_err(|e| format!("{}: {e}", path.display()))?;
    let d = describe(&asset);
    if as_json {
        println!("{}", serde_json::to_string_pretty(&d).expect("json"));
        return Ok(());
    }
    println!("{}", path.display());
    for m in d["meshes"].as_array().into_iter().flatten() {
        for p in m["primitives"].as_array().into_iter().flatten() {
            println!(
                "  mesh {} primitive {}: {} vertices, {} triangles ({}), material {}, {} UV set(s){}{}",
                m["index"], p["index"], p["vertices"], p["triangles"], p["mode"].as_str().unwrap_or(""), p["material"],
                p["uv_sets"], if p["normals"] == true { ", normals" } else { "" },
                if p["vertex_colors"] == true { ", COLOR_0" } else { "" },
            );
        }
    }
    println!("  {} instance(s) in the scene", d["instances"]);
    for m in d["materials"].as_array().into_iter().flatten() {
        let tex = &m["base_color_texture"];
        let t = if tex.is_null() {
            "no base color texture".to_string()
        } else {
            format!(
                "base color image {} ({}x{}, TEXCOORD_{})",
                tex["image"], tex["width"], tex["height"], tex["tex_coord"]
            )
        };
        println!(
            "  material {} {}: factor {}, {}",
            m["index"], m["name"], m["base_color_factor"], t
        );
    }
    for i in d["images"].as_array().into_iter().flatten() {
        println!(
            "  image {}: {} {}x{}, {} bytes",
            i["index"],
            i["mime_type"].as_str().unwrap_or(""),
            i["width"],
            i["height"],
            i["bytes"]
        );
    }
    let s = &d["surface"];
    if !s.is_null() {
        println!(
            "  surface: {} vertices, {} faces, {} component(s), Euler characteristic {}, bbox {} .. {} (diagonal {:.4})",
            s["vertices"], s["faces"], s["components"], s["euler_characteristic"], s["bounding_box"]["min"],
            s["bounding_box"]["max"], s["diagonal"].as_f64().unwrap_or(0.0),
        );
    }
    let problems = d["problems"].as_array().cloned().unwrap_or_default();
    if problems.is_empty() {
        println!("  no problems found");
    }
    for p in problems {
        println!("  problem: {}", p.as_str().unwrap_or(""));
    }
    Ok(())
}
