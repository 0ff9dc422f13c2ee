//! Ingest on the shared edge-case and real assets, and on hand-built malicious inputs: every
//! file either loads with the expected content or fails with the expected error variant, and
//! nothing panics.

use crate::common;

use retex::engine::asset::glb::GlbError;
use retex::engine::asset::*;

fn load_path(rel: &str) -> Result<Asset, IngestError> {
    let (main, blobs) = BlobSet::from_path(&common::shared_asset(rel)).expect("readable asset");
    load(&main, &blobs, &IngestLimits::default())
}

fn ok(rel: &str) -> Asset {
    load_path(rel).unwrap_or_else(|e| panic!("{rel}: {e}"))
}

fn err(rel: &str) -> IngestError {
    match load_path(rel) {
        Ok(_) => panic!("{rel} loaded but should fail"),
        Err(e) => e,
    }
}

fn vertices(a: &Asset) -> usize {
    a.primitives.iter().map(|p| p.positions.len()).sum()
}

fn triangles(a: &Asset) -> usize {
    a.primitives.iter().map(|p| p.triangles.len()).sum()
}

/// Structural invariants every loaded asset must satisfy.
fn assert_consistent(rel: &str, a: &Asset) {
    for p in &a.primitives {
        let n = p.positions.len();
        assert!(p.positions.iter().flatten().all(|x| x.is_finite()), "{rel}");
        assert!(
            p.triangles.iter().flatten().all(|&i| (i as usize) < n),
            "{rel}"
        );
        assert!(p.tex_coords.iter().all(|t| t.len() == n), "{rel}");
        assert!(p.normals.as_ref().is_none_or(|v| v.len() == n), "{rel}");
        assert!(p.colors.as_ref().is_none_or(|v| v.len() == n), "{rel}");
    }
    for img in &a.images {
        if let Some(d) = &img.decoded {
            assert_eq!((d.width, d.height), (img.width, img.height), "{rel}");
            assert_eq!(d.pixels.len(), (d.width * d.height) as usize, "{rel}");
        }
    }
    for (b, declared) in a
        .buffers
        .iter()
        .zip(a.json["buffers"].as_array().into_iter().flatten())
    {
        assert_eq!(
            b.len() as u64,
            declared["byteLength"].as_u64().unwrap(),
            "{rel}"
        );
    }
}

// ---------------------------------------------------------------------------------------------
// glTF-Validator test suite: each file matched to an outcome.

/// `None` = loads; `Some(kind)` = fails with the variant of that [`IngestError::kind`].
const VALIDATOR_SUITE: &[(&str, Option<&str>)] = &[
    ("glb/valid.glb", None),
    ("glb/invalid_magic.glb", Some("invalid-glb")),
    ("glb/empty_file.glb", Some("empty-file")),
    ("glb/no_header.glb", Some("invalid-glb")),
    ("glb/length_mismatch.glb", Some("invalid-glb")),
    ("glb/truncated_chunk_data.glb", Some("invalid-glb")),
    ("glb/truncated_chunk_header.glb", Some("invalid-glb")),
    ("glb/unaligned_chunk.glb", Some("invalid-glb")),
    ("glb/two_bin_chunks.glb", Some("invalid-glb")),
    ("glb/invalid_json_chunk.glb", Some("invalid-json")),
    ("json/invalid_syntax.gltf", Some("invalid-json")),
    ("json/empty_file.gltf", Some("empty-file")),
    ("json/bom.gltf", Some("invalid-json")),
    ("buffer/not_found.gltf", Some("missing-file")),
    (
        "buffer/invalid_uri_data_bytelength.gltf",
        Some("buffer-length-mismatch"),
    ),
    ("buffer/invalid_uri_data.gltf", Some("invalid-uri")),
    ("buffer/non_relative_uri.gltf", Some("forbidden-uri")),
    ("buffer/data_uri.glb", None),
    (
        "buffer/wrong_bytelength.glb",
        Some("buffer-length-mismatch"),
    ),
    ("image/not_found.gltf", Some("missing-file")),
    ("image/invalid_image_data.gltf", Some("image-decode")),
    ("image/unrecognized_format.gltf", Some("unrecognized-image")),
    ("image/invalid_data_uri.gltf", Some("invalid-uri")),
    ("mesh/primitive_no_position.gltf", Some("missing-position")),
    ("mesh/unresolved_indices.gltf", Some("unresolved-reference")),
    ("mesh/accessor_unequal_count.gltf", Some("unequal-count")),
    ("mesh/uv.gltf", None),
    ("mesh/valid.gltf", None),
    (
        "mesh_data/index_buffer_oob.gltf",
        Some("index-out-of-range"),
    ),
    ("mesh_data/index_buffer_degenerate_triangle.gltf", None),
    (
        "mesh_data/index_buffer_primitive_restart.gltf",
        Some("primitive-restart-index"),
    ),
    ("mesh_data/colors_non_clamped.gltf", None),
    (
        "mesh_data/normals_tangents_non_unit_invalid_sign.gltf",
        None,
    ),
    (
        "accessor/invalid_sparse_count_and_stride.gltf",
        Some("invalid-accessor"),
    ),
    ("accessor/small_stride.gltf", Some("stride-too-small")),
    ("accessor_data/get_elements_sparse.gltf", None),
    ("accessor_data/out_of_range_elements_float.gltf", None),
    ("node/node_loop.gltf", Some("invalid-node-hierarchy")),
    ("node/matrix_indecomposable.gltf", None),
    // 1e309 is outside f64: the JSON parser refuses it as "number out of range".
    ("node/infinite_transform.gltf", Some("invalid-json")),
    (
        "material/unresolved_basecolor.gltf",
        Some("unresolved-reference"),
    ),
    (
        "texture/unresolved_source.gltf",
        Some("unresolved-reference"),
    ),
    ("asset/2_1_version.gltf", None),
    ("asset/1_0_version.gltf", Some("unsupported-version")),
];

#[test]
fn validator_suite_files_match_their_expected_outcome() {
    for (rel, expected) in VALIDATOR_SUITE {
        let rel = format!("edge_validator_testsuite/{rel}");
        match (load_path(&rel), expected) {
            (Ok(a), None) => assert_consistent(&rel, &a),
            (Err(e), Some(kind)) => assert_eq!(e.kind(), *kind, "{rel}: {e}"),
            (Ok(_), Some(kind)) => panic!("{rel} loaded, expected {kind}"),
            (Err(e), None) => panic!("{rel} failed: {e}"),
        }
    }
}

#[test]
fn validator_suite_glb_errors_name_the_lie() {
    let glb = |rel: &str| match err(&format!("edge_validator_testsuite/glb/{rel}")) {
        IngestError::Glb(g) => g,
        e => panic!("{rel}: {e}"),
    };
    assert_eq!(glb("no_header.glb"), GlbError::TruncatedHeader { len: 1 });
    assert!(matches!(
        glb("invalid_magic.glb"),
        GlbError::BadMagic { .. }
    ));
    assert!(matches!(
        glb("length_mismatch.glb"),
        GlbError::LengthMismatch { .. }
    ));
    assert!(matches!(
        glb("truncated_chunk_header.glb"),
        GlbError::TruncatedChunkHeader { chunk: 0, .. }
    ));
    assert!(matches!(
        glb("unaligned_chunk.glb"),
        GlbError::UnalignedChunk {
            chunk: 0,
            length: 27
        }
    ));
    assert!(matches!(
        glb("two_bin_chunks.glb"),
        GlbError::FirstChunkNotJson { found: 0x004E_4942 }
    ));
    let e = err("edge_validator_testsuite/mesh/primitive_no_position.gltf");
    assert!(
        matches!(&e, IngestError::MissingPosition { path } if path == "meshes[0].primitives[0].attributes.POSITION"),
        "{e}"
    );
    let e = err("edge_validator_testsuite/node/node_loop.gltf");
    assert!(matches!(e, IngestError::InvalidNodeHierarchy { .. }), "{e}");
    let e = err("edge_validator_testsuite/accessor/small_stride.gltf");
    assert!(
        matches!(
            e,
            IngestError::StrideTooSmall {
                accessor: 0,
                view: 0,
                stride: 4,
                element: 16
            }
        ),
        "{e}"
    );
    let e = err("edge_validator_testsuite/buffer/non_relative_uri.gltf");
    assert!(
        matches!(&e, IngestError::ForbiddenUri { what, uri } if what == "buffers[0]" && uri.starts_with("http://"))
    );
}

// ---------------------------------------------------------------------------------------------
// Edge-case assets.

#[test]
fn every_edge_asset_loads_or_fails_as_expected() {
    let expected_failures: &[(&str, &str)] = &[
        (
            "edge_assimp_malformed/BoxWithInfinites-glTF-Binary/BoxWithInfinites.glb",
            "non-finite",
        ),
        (
            "edge_assimp_malformed/IndexOutOfRange/AllIndicesOutOfRange.gltf",
            "index-out-of-range",
        ),
        (
            "edge_assimp_malformed/IndexOutOfRange/IndexOutOfRange.gltf",
            "index-out-of-range",
        ),
        (
            "edge_assimp_malformed/MissingBin/BoxTextured.gltf",
            "missing-file",
        ),
        (
            "edge_draco_box_khronos/glTF-Draco/Box.gltf",
            "unsupported-extension",
        ),
        (
            "edge_draco_cesium_man_khronos/glTF-Draco/CesiumMan.gltf",
            "unsupported-extension",
        ),
    ];
    let dir = common::shared_assets_dir();
    let mut files = Vec::new();
    fn walk(d: &std::path::Path, out: &mut Vec<std::path::PathBuf>) {
        for e in std::fs::read_dir(d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(&p, out)
            } else if matches!(p.extension().and_then(|x| x.to_str()), Some("gltf" | "glb")) {
                out.push(p)
            }
        }
    }
    for entry in std::fs::read_dir(&dir).unwrap() {
        let p = entry.unwrap().path();
        let name = p.file_name().unwrap().to_string_lossy().into_owned();
        if p.is_dir() && name.starts_with("edge_") && name != "edge_validator_testsuite" {
            walk(&p, &mut files);
        }
    }
    files.sort();
    assert!(files.len() >= 45, "found only {} edge files", files.len());
    for f in files {
        let rel = f
            .strip_prefix(&dir)
            .unwrap()
            .to_string_lossy()
            .replace('\\', "/");
        let expected = expected_failures
            .iter()
            .find(|(r, _)| *r == rel)
            .map(|(_, k)| *k);
        match (load_path(&rel), expected) {
            (Ok(a), None) => {
                assert_consistent(&rel, &a);
                assert!(!a.instances.is_empty(), "{rel}: no mesh instance");
            }
            (Err(e), Some(kind)) => assert_eq!(e.kind(), kind, "{rel}: {e}"),
            (Ok(_), Some(kind)) => panic!("{rel} loaded, expected {kind}"),
            (Err(e), None) => panic!("{rel} failed: {e}"),
        }
    }
}

#[test]
fn draco_is_refused_by_name() {
    for rel in [
        "edge_draco_box_khronos/glTF-Draco/Box.gltf",
        "edge_draco_cesium_man_khronos/glTF-Draco/CesiumMan.gltf",
    ] {
        let e = err(rel);
        assert!(
            matches!(&e, IngestError::UnsupportedExtension(n) if n == "KHR_draco_mesh_compression"),
            "{e}"
        );
    }
}

#[test]
fn sparse_accessor_substitutes_positions() {
    for rel in [
        "edge_simple_sparse_accessor_khronos/glTF/SimpleSparseAccessor.gltf",
        "edge_simple_sparse_accessor_khronos/glTF-Embedded/SimpleSparseAccessor.gltf",
    ] {
        let a = ok(rel);
        let p = &a.primitives[0];
        assert_eq!((p.positions.len(), p.triangles.len()), (14, 12));
        // The dense data of bufferView 1, before substitution.
        let view = &a.json["bufferViews"][1];
        let off = view["byteOffset"].as_u64().unwrap_or(0) as usize;
        let dense: Vec<[f32; 3]> = (0..14)
            .map(|i| {
                std::array::from_fn(|k| {
                    let at = off + 12 * i + 4 * k;
                    f32::from_le_bytes(a.buffers[0][at..at + 4].try_into().unwrap())
                })
            })
            .collect();
        let changed = dense
            .iter()
            .zip(&p.positions)
            .filter(|(d, l)| d != l)
            .count();
        assert_eq!(changed, 3, "{rel}: the 3 sparse values replace 3 vertices");
        let max_y = p.positions.iter().map(|v| v[1]).fold(f32::MIN, f32::max);
        assert_eq!(max_y, 4.0, "{rel}: accessor max after substitution");
    }
}

#[test]
fn primitive_modes_are_converted_or_skipped() {
    let a = ok("edge_mesh_primitive_modes_khronos/glTF/MeshPrimitiveModes.gltf");
    let modes: Vec<TriangleMode> = a.primitives.iter().map(|p| p.mode).collect();
    assert_eq!(
        modes,
        [
            TriangleMode::Triangles,
            TriangleMode::Strip,
            TriangleMode::Fan
        ]
    );
    assert_eq!(a.warnings.len(), 4, "{:?}", a.warnings);
    for (i, mode) in ["00", "01", "02", "03", "07", "08", "09", "10"]
        .iter()
        .enumerate()
    {
        let a = ok(&format!(
            "edge_primitive_modes_asset_generator/Mesh_PrimitiveMode_{mode}.gltf"
        ));
        assert!(a.primitives.is_empty(), "{mode}");
        assert_eq!(a.warnings.len(), 1, "{i}: {:?}", a.warnings);
    }
    // 04..06 non-indexed, 11..13 u32, 14 u8, 15 u16: all give the same 2-triangle quad.
    for mode in ["04", "05", "06", "11", "12", "13", "14", "15"] {
        let a = ok(&format!(
            "edge_primitive_modes_asset_generator/Mesh_PrimitiveMode_{mode}.gltf"
        ));
        assert_eq!(triangles(&a), 2, "{mode}");
        // Both triangles of the quad face the same way (strips keep winding).
        let p = &a.primitives[0];
        let normal = |t: [u32; 3]| {
            let [a, b, c] = t.map(|i| p.positions[i as usize]);
            let (u, v) = ([b[0] - a[0], b[1] - a[1]], [c[0] - a[0], c[1] - a[1]]);
            u[0] * v[1] - u[1] * v[0]
        };
        assert!(
            normal(p.triangles[0]) * normal(p.triangles[1]) > 0.0,
            "{mode}: winding differs"
        );
    }
}

#[test]
fn texture_transform_is_read_into_texture_refs() {
    let a = ok("edge_texture_transform_test_khronos/glTF/TextureTransformTest.gltf");
    let by_name = |n: &str| {
        a.materials
            .iter()
            .find(|m| m.name.as_deref() == Some(n))
            .unwrap()
            .base_color_texture
            .unwrap()
    };
    assert_eq!(by_name("Offset U").transform.unwrap().offset, [0.5, 0.0]);
    assert!(
        (by_name("Rotation").transform.unwrap().rotation - std::f32::consts::FRAC_PI_8).abs()
            < 1e-6
    );
    let all = by_name("All").transform.unwrap();
    assert_eq!((all.offset, all.scale), ([-0.2, -0.1], [1.5, 1.5]));
    assert_eq!(by_name("Correct").transform, None);

    let chair = ok("src_sheen_chair_khronos/glTF/SheenChair.gltf");
    assert!(chair.json["extensionsRequired"]
        .as_array()
        .unwrap()
        .iter()
        .any(|e| e == "KHR_texture_transform"));
    assert_eq!(
        (vertices(&chair), triangles(&chair), chair.primitives.len()),
        (22459, 39936, 4)
    );
    let with_transform = chair
        .materials
        .iter()
        .filter_map(|m| m.base_color_texture)
        .filter(|t| t.transform.is_some());
    assert!(with_transform.count() >= 1);
}

#[test]
fn multiple_scenes_use_the_scene_property() {
    let a = ok("edge_multiple_scenes_khronos/glTF/MultipleScenes.gltf");
    // "scene": 1 holds node 1 (mesh 1).
    assert_eq!(a.instances.len(), 1);
    assert_eq!((a.instances[0].node, a.instances[0].mesh), (1, 1));
    assert_eq!(a.primitives.len(), 2, "both meshes are decoded");
}

#[test]
fn negative_scale_mirrors_and_instancing_keeps_transforms() {
    let a = ok("edge_negative_scale_test_khronos/glTF-Binary/NegativeScaleTest.glb");
    assert!(a.instances.iter().any(|i| i.mirrors()));
    assert!(a.instances.iter().any(|i| !i.mirrors()));
    let s = ok("edge_simple_meshes_khronos/glTF/SimpleMeshes.gltf");
    assert_eq!(s.instances.len(), 2);
    assert_eq!(s.instances[0].mesh, s.instances[1].mesh);
    assert_ne!(s.instances[0].world, s.instances[1].world);
    assert_eq!(s.instanced_triangle_count(), 2);
}

#[test]
fn attributes_colors_quantization_and_legacy_materials() {
    let c = ok("edge_box_vertex_colors_khronos/glTF-Binary/BoxVertexColors.glb");
    let colors = c.primitives[0].colors.as_ref().unwrap();
    assert!(colors.iter().flatten().all(|x| (0.0..=1.0).contains(x)));
    let q = ok("edge_quantized_morph_cube_khronos/glTF-Quantized/AnimatedMorphCube.gltf");
    let p = &q.primitives[0];
    assert!(p
        .normals
        .as_ref()
        .unwrap()
        .iter()
        .all(|n| (n[0] * n[0] + n[1] * n[1] + n[2] * n[2] - 1.0).abs() < 0.02));
    // POSITION is non-normalized u16 (max 10932); the node scale 3.649e-6 (x100) brings it to ~4 units.
    let extent = p
        .positions
        .iter()
        .flatten()
        .fold(0f32, |m, x| m.max(x.abs()));
    assert_eq!(extent, 10932.0);
    let inst = &q.instances[0];
    let world = p
        .positions
        .iter()
        .flat_map(|&v| inst.transform_point(v))
        .fold(0f64, |m, x| m.max(x.abs()));
    assert!(world > 0.5 && world < 10.0, "world extent {world}");
    let m = ok("edge_multi_uv_test_khronos/glTF-Binary/MultiUVTest.glb");
    assert_eq!(m.primitives[0].tex_coords.len(), 2);
    let sg = ok("edge_specgloss_box_assimp/BoxTextured.gltf");
    let t = sg.materials[0]
        .base_color_texture
        .expect("diffuseTexture used as base color");
    assert!(sg.images[sg.textures[t.texture].image.unwrap()]
        .decoded
        .is_some());
    let i = ok("edge_box_interleaved_khronos/glTF-Binary/BoxInterleaved.glb");
    assert_eq!(vertices(&i), 24);
    // The same asset three ways decodes to the same pixels.
    let variants = [
        "glTF/BoxTextured.gltf",
        "glTF-Embedded/BoxTextured.gltf",
        "glTF-Binary/BoxTextured.glb",
    ]
    .map(|v| ok(&format!("edge_box_textured_variants_khronos/{v}")));
    let px = |a: &Asset| a.images[0].decoded.clone().unwrap();
    assert_eq!(px(&variants[0]), px(&variants[1]));
    assert_eq!(px(&variants[0]), px(&variants[2]));
    assert_eq!(
        variants[0].primitives[0].positions,
        variants[2].primitives[0].positions
    );
    let settings = ok("edge_texture_settings_test_khronos/glTF-Binary/TextureSettingsTest.glb");
    let wraps: Vec<Wrap> = settings.textures.iter().map(|t| t.sampler.wrap_s).collect();
    assert!(
        wraps.contains(&Wrap::MirroredRepeat) && wraps.contains(&Wrap::ClampToEdge),
        "{wraps:?}"
    );
}

// ---------------------------------------------------------------------------------------------
// Real sources and targets.

#[test]
fn real_sources_load_with_expected_counts() {
    let spot = ok("src_spot_keenan/spot_textured_derived.glb");
    assert_eq!((vertices(&spot), triangles(&spot)), (3225, 5856));
    let tex = spot.materials[0].base_color_texture.unwrap();
    let img = &spot.images[spot.textures[tex.texture].image.unwrap()];
    let d = img.decoded.as_ref().unwrap();
    assert_eq!(
        (d.width, d.height, img.mime_type.as_str()),
        (1024, 1024, "image/png")
    );

    for rel in [
        "src_fox_khronos/glTF/Fox.gltf",
        "src_fox_khronos/glTF-Binary/Fox.glb",
    ] {
        let fox = ok(rel);
        assert_eq!((vertices(&fox), triangles(&fox)), (1728, 576), "{rel}");
        assert!(
            fox.json["meshes"][0]["primitives"][0]
                .get("indices")
                .is_none(),
            "non-indexed"
        );
        assert!(fox.primitives[0].normals.is_none());
        assert_eq!(fox.primitives[0].triangles[1], [3, 4, 5]);
    }

    let head = ok("src_lee_perry_smith_head/LeePerrySmith_textured_derived.gltf");
    assert_eq!((vertices(&head), triangles(&head)), (9279, 17684));
    let img = head.images.iter().find(|i| i.decoded.is_some()).unwrap();
    assert_eq!(
        (img.mime_type.as_str(), img.width, img.height),
        ("image/jpeg", 1024, 1024)
    );

    let car = ok("perf_toy_car_khronos/glTF/ToyCar.gltf");
    assert_eq!(
        (vertices(&car), triangles(&car), car.primitives.len()),
        (77429, 108936, 3)
    );
    assert_consistent("toy car", &car);

    let e = err("tgt_barramundi_fish_khronos_geometry/glTF/BarramundiFish.gltf");
    assert!(
        matches!(&e, IngestError::MissingFile { name, .. } if name.ends_with(".png")),
        "{e}"
    );
    let fish =
        ok("tgt_barramundi_fish_khronos_geometry/glTF/BarramundiFish_geometry_only_derived.gltf");
    assert_eq!((vertices(&fish), triangles(&fish)), (2188, 3864));
}

#[test]
fn derived_target_glbs_load() {
    let expected = [
        ("tgt_spot_remeshed_odedstein/spot_derived.glb", 11533, 23062),
        (
            "tgt_spot_remeshed_odedstein/spot_low_resolution_derived.glb",
            829,
            1654,
        ),
        (
            "tgt_fish_remeshed_odedstein/fish_low_resolution_derived.glb",
            945,
            1886,
        ),
        (
            "tgt_cat_odedstein/cat-low-resolution_derived.glb",
            7949,
            15894,
        ),
        (
            "tgt_primitives_odedstein_torus/torus_derived.glb",
            2304,
            4608,
        ),
        (
            "tgt_nefertiti_bust_odedstein/nefertiti-lowres_derived.glb",
            35002,
            70000,
        ),
    ];
    for (rel, v, t) in expected {
        let a = ok(rel);
        assert_eq!((vertices(&a), triangles(&a)), (v, t), "{rel}");
        assert_consistent(rel, &a);
    }
    let sofa = ok("tgt_glam_velvet_sofa_khronos/glTF-Binary/GlamVelvetSofa.glb");
    assert_eq!((vertices(&sofa), triangles(&sofa)), (3118, 4196));
}

// ---------------------------------------------------------------------------------------------
// Hand-built malicious inputs.

/// A one-triangle glTF: `tri.bin` holds 3 f32 positions (36 bytes) then 3 u16 indices (6 bytes,
/// padded to 8). `patch` edits the JSON before it is written.
fn triangle(
    patch: impl FnOnce(&mut serde_json::Value),
    positions: [[f32; 3]; 3],
    indices: [u16; 3],
) -> BlobSet {
    let mut bin = Vec::new();
    for v in positions.iter().flatten() {
        bin.extend_from_slice(&v.to_le_bytes());
    }
    for i in indices {
        bin.extend_from_slice(&i.to_le_bytes());
    }
    bin.extend_from_slice(&[0, 0]);
    let mut json = serde_json::json!({
        "asset": {"version": "2.0"},
        "buffers": [{"uri": "tri.bin", "byteLength": 44}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": 36},
            {"buffer": 0, "byteOffset": 36, "byteLength": 6}
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "type": "VEC3", "count": 3},
            {"bufferView": 1, "componentType": 5123, "type": "SCALAR", "count": 3}
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "nodes": [{"mesh": 0}],
        "scenes": [{"nodes": [0]}]
    });
    patch(&mut json);
    let mut blobs = BlobSet::new();
    blobs.insert("tri.gltf", serde_json::to_vec(&json).unwrap());
    blobs.insert("tri.bin", bin);
    blobs
}

const TRI: [[f32; 3]; 3] = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];

fn load_tri(blobs: &BlobSet) -> Result<Asset, IngestError> {
    load("tri.gltf", blobs, &IngestLimits::default())
}

#[test]
fn the_plain_triangle_loads() {
    let a = load_tri(&triangle(|_| {}, TRI, [0, 1, 2])).unwrap();
    assert_eq!(a.primitives[0].triangles, [[0, 1, 2]]);
    assert_eq!(a.instances.len(), 1);
}

#[test]
fn decompression_bomb_png_is_refused_from_its_header() {
    let mut blobs = triangle(
        |j| {
            j["images"] = serde_json::json!([{"uri": "bomb.png"}]);
            j["textures"] = serde_json::json!([{"source": 0}]);
            j["materials"] =
                serde_json::json!([{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]);
            j["meshes"][0]["primitives"][0]["material"] = 0.into();
        },
        TRI,
        [0, 1, 2],
    );
    let png = common::bomb_png(100_000, 100_000);
    assert!(png.len() < 100);
    blobs.insert("bomb.png", png);
    let e = load_tri(&blobs).unwrap_err();
    assert!(
        matches!(
            e,
            IngestError::ImageTooLarge {
                image: 0,
                width: 100_000,
                height: 100_000,
                max: 16384
            }
        ),
        "{e}"
    );
    // Under the side limit but over the pixel limit.
    blobs.insert("bomb.png", common::bomb_png(16000, 16000));
    let limits = IngestLimits {
        max_image_pixels: 1 << 20,
        ..IngestLimits::default()
    };
    let e = load("tri.gltf", &blobs, &limits).unwrap_err();
    assert!(
        matches!(e, IngestError::ImageTooLarge { max: 1_048_576, .. }),
        "{e}"
    );
}

#[test]
fn glb_with_lying_chunk_lengths_is_refused() {
    let json = br#"{"asset":{"version":"2.0"},"buffers":[{"byteLength":4}]}"#;
    let mut json = json.to_vec();
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    let build = |json_len: u32, bin_len: u32| {
        let mut g = b"glTF".to_vec();
        g.extend_from_slice(&2u32.to_le_bytes());
        g.extend_from_slice(&0u32.to_le_bytes());
        g.extend_from_slice(&json_len.to_le_bytes());
        g.extend_from_slice(&0x4E4F_534Au32.to_le_bytes());
        g.extend_from_slice(&json);
        g.extend_from_slice(&bin_len.to_le_bytes());
        g.extend_from_slice(&0x004E_4942u32.to_le_bytes());
        g.extend_from_slice(&[1, 2, 3, 4]);
        let n = g.len() as u32;
        g[8..12].copy_from_slice(&n.to_le_bytes());
        g
    };
    let run = |bytes: Vec<u8>| {
        let mut b = BlobSet::new();
        b.insert("x.glb", bytes);
        load("x.glb", &b, &IngestLimits::default())
    };
    let a = run(build(json.len() as u32, 4)).unwrap();
    assert_eq!(a.buffers, [vec![1, 2, 3, 4]]);
    for (jl, bl) in [
        (json.len() as u32 + 4, 4),
        (json.len() as u32, 8),
        (u32::MAX, 4),
        (json.len() as u32, u32::MAX - 3),
    ] {
        let e = run(build(jl, bl)).unwrap_err();
        assert!(
            matches!(
                e,
                IngestError::Glb(
                    GlbError::TruncatedChunkData { .. } | GlbError::TruncatedChunkHeader { .. }
                )
            ),
            "{jl} {bl}: {e}"
        );
    }
    let mut short = build(json.len() as u32, 4);
    short.pop();
    assert!(matches!(
        run(short),
        Err(IngestError::Glb(GlbError::LengthMismatch { .. }))
    ));
    // A GLB whose BIN chunk is shorter than the buffer's byteLength.
    let mut b = build(json.len() as u32, 4);
    let at = b
        .windows(14)
        .position(|w| w == b"\"byteLength\":4")
        .unwrap()
        + 13;
    b[at] = b'8';
    assert!(matches!(
        run(b),
        Err(IngestError::BufferLengthMismatch {
            buffer: 0,
            declared: 8,
            actual: 4
        })
    ));
}

#[test]
fn buffer_view_past_its_buffer_is_refused() {
    let blobs = triangle(
        |j| j["bufferViews"][1]["byteLength"] = 60.into(),
        TRI,
        [0, 1, 2],
    );
    let e = load_tri(&blobs).unwrap_err();
    assert!(
        matches!(
            e,
            IngestError::BufferViewOutOfRange {
                view: 1,
                buffer: 0,
                offset: 36,
                end: 96,
                len: 44
            }
        ),
        "{e}"
    );
}

#[test]
fn index_out_of_range_is_refused_with_its_path() {
    let e = load_tri(&triangle(|_| {}, TRI, [0, 1, 3])).unwrap_err();
    assert!(
        matches!(&e, IngestError::IndexOutOfRange { path, accessor: 1, position: 2, value: 3, vertex_count: 3 }
            if path == "meshes[0].primitives[0].indices"),
        "{e}"
    );
}

#[test]
fn nan_positions_are_refused() {
    let e = load_tri(&triangle(
        |_| {},
        [[0.0; 3], [f32::NAN, 0.0, 0.0], [0.0; 3]],
        [0, 1, 2],
    ))
    .unwrap_err();
    assert!(
        matches!(
            e,
            IngestError::NonFinite {
                accessor: 0,
                element: 1,
                ..
            }
        ),
        "{e}"
    );
    let e = load_tri(&triangle(
        |j| j["nodes"][0]["scale"] = serde_json::json!([1e39, 1, 1]),
        TRI,
        [0, 1, 2],
    ))
    .unwrap_err();
    assert!(
        matches!(e, IngestError::NonFiniteTransform { node: 0 }),
        "{e}"
    );
}

#[test]
fn uris_leaving_the_upload_are_forbidden() {
    for uri in [
        "../secret.bin",
        "file:///etc/passwd",
        "http://example.com/buffer.bin",
        "https://x/y.bin",
        "/etc/passwd",
        "%2e%2e/secret.bin",
    ] {
        let mut blobs = triangle(|j| j["buffers"][0]["uri"] = uri.into(), TRI, [0, 1, 2]);
        // Even a blob literally named like the escape must not be used.
        blobs.insert("../secret.bin", vec![0; 44]);
        let e = load_tri(&blobs).unwrap_err();
        assert!(
            matches!(&e, IngestError::ForbiddenUri { what, uri: u } if what == "buffers[0]" && u == uri),
            "{uri}: {e}"
        );
        // The same for an image.
        let blobs = triangle(
            |j| j["images"] = serde_json::json!([{ "uri": uri }]),
            TRI,
            [0, 1, 2],
        );
        let e = load_tri(&blobs).unwrap_err();
        assert!(
            matches!(&e, IngestError::ForbiddenUri { what, .. } if what == "images[0]"),
            "{uri}: {e}"
        );
    }
    let e = load_tri(&triangle(
        |j| j["buffers"][0]["uri"] = "other.bin".into(),
        TRI,
        [0, 1, 2],
    ))
    .unwrap_err();
    assert!(
        matches!(&e, IngestError::MissingFile { name, .. } if name == "other.bin"),
        "{e}"
    );
}

#[test]
fn files_in_subfolders_resolve_relative_to_the_main_file() {
    let flat = triangle(
        |j| j["buffers"][0]["uri"] = "data/tri%20bin.bin".into(),
        TRI,
        [0, 1, 2],
    );
    let mut blobs = BlobSet::new();
    blobs.insert("scene/main.gltf", flat.get("tri.gltf").unwrap().to_vec());
    blobs.insert(
        "scene/data/tri bin.bin",
        flat.get("tri.bin").unwrap().to_vec(),
    );
    let a = load("scene/main.gltf", &blobs, &IngestLimits::default()).unwrap();
    assert_eq!(a.primitives[0].positions, TRI);
}

#[test]
fn huge_data_uri_is_refused_over_the_limit() {
    use base64::Engine as _;
    let payload = base64::engine::general_purpose::STANDARD.encode(vec![0u8; 1 << 20]);
    let blobs = triangle(
        |j| {
            j["buffers"].as_array_mut().unwrap().push(serde_json::json!({"uri": format!("data:application/octet-stream;base64,{payload}"), "byteLength": 1 << 20}))
        },
        TRI,
        [0, 1, 2],
    );
    assert!(load_tri(&blobs).is_ok());
    let limits = IngestLimits {
        max_data_uri_bytes: 1000,
        ..IngestLimits::default()
    };
    let e = load("tri.gltf", &blobs, &limits).unwrap_err();
    assert!(
        matches!(&e, IngestError::DataUriTooLarge { what, max: 1000, .. } if what == "buffers[1]"),
        "{e}"
    );
}

#[test]
fn huge_counts_are_refused_before_allocating() {
    // 2^31 VEC3 floats would be 24 GiB; the view has 36 bytes.
    let e = load_tri(&triangle(
        |j| j["accessors"][0]["count"] = (1u64 << 31).into(),
        TRI,
        [0, 1, 2],
    ))
    .unwrap_err();
    assert!(
        matches!(
            e,
            IngestError::AccessorOutOfRange {
                accessor: 0,
                view: 0,
                ..
            }
        ),
        "{e}"
    );
    // Without a bufferView the accessor is zeros: the vertex limit stops it.
    let e = load_tri(&triangle(
        |j| {
            j["accessors"][0] =
                serde_json::json!({"componentType": 5126, "type": "VEC3", "count": 1u64 << 31});
        },
        TRI,
        [0, 1, 2],
    ))
    .unwrap_err();
    assert!(
        matches!(
            e,
            IngestError::TooManyVertices {
                max: 20_000_000,
                ..
            }
        ),
        "{e}"
    );
    // Huge index count without a bufferView: the triangle limit stops it.
    let e = load_tri(&triangle(
        |j| {
            j["accessors"][1] =
                serde_json::json!({"componentType": 5125, "type": "SCALAR", "count": 1u64 << 33})
        },
        TRI,
        [0, 1, 2],
    ))
    .unwrap_err();
    assert!(matches!(e, IngestError::TooManyTriangles { .. }), "{e}");
    // Stride times count overflowing u64 is still a range error.
    let e = load_tri(&triangle(
        |j| {
            j["bufferViews"][0]["byteStride"] = 252.into();
            j["accessors"][0]["count"] = u64::MAX.into();
        },
        TRI,
        [0, 1, 2],
    ))
    .unwrap_err();
    assert!(matches!(e, IngestError::AccessorOutOfRange { .. }), "{e}");
}

#[test]
fn other_limits_and_refusals() {
    let blobs = triangle(|_| {}, TRI, [0, 1, 2]);
    let tiny = |f: fn(&mut IngestLimits)| {
        let mut l = IngestLimits::default();
        f(&mut l);
        load("tri.gltf", &blobs, &l).unwrap_err()
    };
    assert!(matches!(
        tiny(|l| l.max_input_bytes = 10),
        IngestError::InputTooLarge { .. }
    ));
    assert!(matches!(
        tiny(|l| l.max_json_bytes = 10),
        IngestError::JsonTooLarge { .. }
    ));
    assert!(matches!(
        tiny(|l| l.max_vertices = 2),
        IngestError::TooManyVertices { count: 3, max: 2 }
    ));
    assert!(matches!(
        tiny(|l| l.max_triangles = 0),
        IngestError::TooManyTriangles { .. }
    ));
    assert!(matches!(
        tiny(|l| l.max_node_depth = 0),
        IngestError::NodeTooDeep { node: 0, .. }
    ));
    assert!(matches!(
        load("nope.gltf", &blobs, &IngestLimits::default()),
        Err(IngestError::MissingMain { .. })
    ));
    for ext in [
        "EXT_meshopt_compression",
        "KHR_texture_basisu",
        "EXT_texture_webp",
        "ACME_unknown",
    ] {
        let e = load_tri(&triangle(
            |j| j["extensionsRequired"] = serde_json::json!([ext]),
            TRI,
            [0, 1, 2],
        ))
        .unwrap_err();
        assert!(
            matches!(&e, IngestError::UnsupportedExtension(n) if n == ext),
            "{e}"
        );
    }
    let ok_exts = [
        "KHR_texture_transform",
        "KHR_mesh_quantization",
        "KHR_materials_sheen",
        "KHR_lights_punctual",
    ];
    assert!(load_tri(&triangle(
        |j| j["extensionsRequired"] = serde_json::json!(ok_exts),
        TRI,
        [0, 1, 2]
    ))
    .is_ok());
    let e = load_tri(&triangle(
        |j| j["nodes"][0]["children"] = serde_json::json!([0]),
        TRI,
        [0, 1, 2],
    ))
    .unwrap_err();
    assert!(
        matches!(e, IngestError::InvalidNodeHierarchy { node: 0, .. }),
        "{e}"
    );
    let e = load_tri(&triangle(
        |j| j["accessors"][0]["type"] = "VEC2".into(),
        TRI,
        [0, 1, 2],
    ))
    .unwrap_err();
    assert!(
        matches!(e, IngestError::WrongAccessorType { accessor: 0, .. }),
        "{e}"
    );
    let e = load_tri(&triangle(
        |j| j["accessors"][0]["count"] = "three".into(),
        TRI,
        [0, 1, 2],
    ))
    .unwrap_err();
    assert!(
        matches!(&e, IngestError::InvalidDocument { path, .. } if path == "accessors[0]"),
        "{e}"
    );
}

#[test]
fn texcoord_override_and_strips_fans_and_no_scene() {
    // Two UV sets (both the positions' xy), base color via set 0 overridden to set 1 by the transform.
    let a = load_tri(&triangle(
        |j| {
            j["accessors"].as_array_mut().unwrap().push(serde_json::json!(
                {"bufferView": 0, "componentType": 5126, "type": "VEC2", "count": 3, "byteOffset": 0}));
            j["bufferViews"][0]["byteStride"] = 12.into();
            let prim = &mut j["meshes"][0]["primitives"][0];
            prim["attributes"]["TEXCOORD_0"] = 2.into();
            prim["attributes"]["TEXCOORD_1"] = 2.into();
            prim["material"] = 0.into();
            prim["mode"] = 6.into();
            j["materials"] = serde_json::json!([{"pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.5, 0.5, 1],
                "baseColorTexture": {"index": 0, "texCoord": 0,
                    "extensions": {"KHR_texture_transform": {"texCoord": 1, "scale": [2, 2]}}}}}]);
            j["textures"] = serde_json::json!([{}]);
            j.as_object_mut().unwrap().remove("scenes");
        },
        TRI,
        [0, 1, 2],
    ))
    .unwrap();
    let t = a.materials[0].base_color_texture.unwrap();
    assert_eq!((t.tex_coord, t.transform.unwrap().scale), (1, [2.0, 2.0]));
    assert_eq!(a.materials[0].base_color_factor, [0.5, 0.5, 0.5, 1.0]);
    assert_eq!(a.textures[0].image, None);
    let p = &a.primitives[0];
    assert_eq!(
        (p.mode, p.triangles.as_slice()),
        (TriangleMode::Fan, &[[1, 2, 0]][..])
    );
    assert_eq!(p.tex_coords.len(), 2);
    assert_eq!(p.tex_coords[1][1], [1.0, 0.0]);
    // No scenes: every root node is instantiated.
    assert_eq!(a.instances.len(), 1);
}

#[test]
fn a_main_file_that_is_not_gltf_is_named_with_what_is_accepted() {
    let png = common::bomb_png(4, 4);
    let cases: [(&str, &[u8], &str); 5] = [
        (
            "spot.obj",
            b"# Blender\nmtllib spot.mtl\no spot\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/1 3/1\n",
            "is a Wavefront OBJ file",
        ),
        ("texture.glb", &png, "is a PNG image"),
        ("notes.gltf", b"hello, this is not a model\n", "is plain text"),
        ("blank.gltf", b"\n  \n", "is blank"),
        ("empty.glb", b"", "is empty (0 bytes)"),
    ];
    for (name, bytes, expected) in cases {
        let mut blobs = BlobSet::new();
        blobs.insert(name, bytes.to_vec());
        let e = load(name, &blobs, &IngestLimits::default()).unwrap_err();
        let message = e.to_string();
        assert!(message.contains(expected), "{name}: {message}");
        assert!(
            message.contains("retex reads glTF 2.0"),
            "{name}: {message}"
        );
        let kind = if bytes.is_empty() {
            "empty-file"
        } else {
            "not-gltf"
        };
        assert_eq!(e.kind(), kind, "{name}");
    }
}
