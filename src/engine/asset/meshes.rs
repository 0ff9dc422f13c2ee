//! Mesh primitives of a glTF asset (glTF 2.0 §3.7.2): attribute semantics and accessor types
//! (including `KHR_mesh_quantization`), index ranges, finite positions, vertex and triangle
//! budgets, and conversion of strips and fans into triangle lists (winding kept).

use gltf::json::mesh::{Mode, Semantic};
use gltf::json::validation::Checked;
use gltf::json::Root;

use super::accessor::{self, Layout};
use super::load::IngestLimits;
use super::model::*;
use super::IngestError;

fn semantic_name(s: &Semantic) -> String {
    match s {
        Semantic::Positions => "POSITION".into(),
        Semantic::Normals => "NORMAL".into(),
        Semantic::Tangents => "TANGENT".into(),
        Semantic::Colors(n) => format!("COLOR_{n}"),
        Semantic::TexCoords(n) => format!("TEXCOORD_{n}"),
        Semantic::Joints(n) => format!("JOINTS_{n}"),
        Semantic::Weights(n) => format!("WEIGHTS_{n}"),
        Semantic::Extras(s) => s.clone(),
    }
}

/// Checks an attribute's accessor type against what glTF (with `KHR_mesh_quantization`) allows.
fn check_type(
    l: &Layout,
    path: &str,
    kinds: &[gltf::json::accessor::Type],
    ok: impl Fn(gltf::json::accessor::ComponentType, bool) -> bool,
    expected: &'static str,
) -> Result<(), IngestError> {
    if kinds.contains(&l.kind) && ok(l.component, l.normalized) {
        Ok(())
    } else {
        Err(IngestError::WrongAccessorType {
            path: path.to_string(),
            accessor: l.accessor,
            found: l.describe(),
            expected,
        })
    }
}

pub(super) fn read_meshes(
    root: &Root,
    layouts: &[Layout],
    buffers: &[Vec<u8>],
    materials: &[Material],
    limits: &IngestLimits,
    warnings: &mut Vec<String>,
) -> Result<Vec<Primitive>, IngestError> {
    use gltf::json::accessor::{ComponentType as C, Type as T};
    let mut out = Vec::new();
    let (mut vertices, mut triangles) = (0u64, 0u64);
    for (mi, mesh) in root.meshes.iter().enumerate() {
        for (pi, prim) in mesh.primitives.iter().enumerate() {
            let path = format!("meshes[{mi}].primitives[{pi}]");
            let mode = match prim.mode {
                Checked::Valid(Mode::Triangles) => TriangleMode::Triangles,
                Checked::Valid(Mode::TriangleStrip) => TriangleMode::Strip,
                Checked::Valid(Mode::TriangleFan) => TriangleMode::Fan,
                Checked::Valid(m) => {
                    warnings.push(format!(
                        "{path}: mode {} (points or lines) skipped",
                        m.as_gl_enum()
                    ));
                    continue;
                }
                Checked::Invalid => {
                    warnings.push(format!("{path}: unknown mode skipped"));
                    continue;
                }
            };
            // Resolve every attribute reference and compare counts before reading anything.
            let mut attrs: Vec<(Semantic, &Layout, String)> = Vec::new();
            for (sem, idx) in &prim.attributes {
                let Checked::Valid(sem) = sem else { continue };
                let apath = format!("{path}.attributes.{}", semantic_name(sem));
                let l = layouts
                    .get(idx.value())
                    .ok_or(IngestError::UnresolvedReference {
                        path: apath.clone(),
                        target: "accessors",
                        index: idx.value(),
                        count: layouts.len(),
                    })?;
                attrs.push((sem.clone(), l, apath));
            }
            let find = |s: &Semantic| {
                attrs
                    .iter()
                    .find(|(x, _, _)| x == s)
                    .map(|(_, l, p)| (*l, p.as_str()))
            };
            let (pos, pos_path) =
                find(&Semantic::Positions).ok_or_else(|| IngestError::MissingPosition {
                    path: format!("{path}.attributes.POSITION"),
                })?;
            let count = pos.count;
            for (_, l, p) in &attrs {
                if l.count != count {
                    return Err(IngestError::UnequalCount {
                        path: p.clone(),
                        accessor: l.accessor,
                        count: l.count,
                        expected: count,
                    });
                }
            }
            vertices = vertices.saturating_add(count);
            if vertices > limits.max_vertices {
                return Err(IngestError::TooManyVertices {
                    count: vertices,
                    max: limits.max_vertices,
                });
            }
            let quantized = |c: C, _n: bool| c != C::U32;
            check_type(
                pos,
                pos_path,
                &[T::Vec3],
                quantized,
                "VEC3 of float, or (KHR_mesh_quantization) of [unsigned] byte/short",
            )?;
            let positions = accessor::read_vec::<3>(pos, buffers)?;
            if let Some(e) = positions
                .iter()
                .position(|p| !p.iter().all(|x| x.is_finite()))
            {
                return Err(IngestError::NonFinite {
                    path: pos_path.to_string(),
                    accessor: pos.accessor,
                    element: e as u64,
                });
            }
            let normals = match find(&Semantic::Normals) {
                Some((l, p)) => {
                    let ok = |c: C, n: bool| c == C::F32 || (n && matches!(c, C::I8 | C::I16));
                    check_type(
                        l,
                        p,
                        &[T::Vec3],
                        ok,
                        "VEC3 of float, or normalized byte/short",
                    )?;
                    Some(accessor::read_vec::<3>(l, buffers)?)
                }
                None => None,
            };
            let mut tex_coords = Vec::new();
            while let Some((l, p)) = find(&Semantic::TexCoords(tex_coords.len() as u32)) {
                check_type(
                    l,
                    p,
                    &[T::Vec2],
                    quantized,
                    "VEC2 of float, normalized unsigned byte/short, or quantized",
                )?;
                tex_coords.push(accessor::read_vec::<2>(l, buffers)?);
            }
            if attrs.iter().any(
                |(s, _, _)| matches!(s, Semantic::TexCoords(n) if *n as usize > tex_coords.len()),
            ) {
                warnings.push(format!("{path}: texture coordinate sets after TEXCOORD_{} are not contiguous and were skipped", tex_coords.len()));
            }
            let colors = match find(&Semantic::Colors(0)) {
                Some((l, p)) => {
                    let ok = |c: C, n: bool| c == C::F32 || (n && matches!(c, C::U8 | C::U16));
                    check_type(
                        l,
                        p,
                        &[T::Vec3, T::Vec4],
                        ok,
                        "VEC3/VEC4 of float or normalized unsigned byte/short",
                    )?;
                    Some(if l.kind == T::Vec3 {
                        accessor::read_vec::<3>(l, buffers)?
                            .into_iter()
                            .map(|[r, g, b]| [r, g, b, 1.0])
                            .collect()
                    } else {
                        accessor::read_vec::<4>(l, buffers)?
                    })
                }
                None => None,
            };
            let triangle_list = match prim.indices {
                Some(idx) => {
                    let ipath = format!("{path}.indices");
                    let l = layouts
                        .get(idx.value())
                        .ok_or(IngestError::UnresolvedReference {
                            path: ipath.clone(),
                            target: "accessors",
                            index: idx.value(),
                            count: layouts.len(),
                        })?;
                    let ok = |c: C, n: bool| !n && matches!(c, C::U8 | C::U16 | C::U32);
                    check_type(
                        l,
                        &ipath,
                        &[T::Scalar],
                        ok,
                        "SCALAR of unsigned byte/short/int",
                    )?;
                    let room = (limits.max_triangles - triangles)
                        .saturating_mul(3)
                        .saturating_add(2);
                    if l.count > room {
                        return Err(IngestError::TooManyTriangles {
                            count: triangles + l.count / 3,
                            max: limits.max_triangles,
                        });
                    }
                    let indices = accessor::read_u32(l, buffers)?;
                    if let Some(k) = indices.iter().position(|&v| v as u64 >= count) {
                        return Err(IngestError::IndexOutOfRange {
                            path: ipath,
                            accessor: l.accessor,
                            position: k as u64,
                            value: indices[k] as u64,
                            vertex_count: count,
                        });
                    }
                    // §3.7.2.1: the maximum value of the component type (primitive restart) is not allowed.
                    let restart = match l.component {
                        C::U8 => 0xFF,
                        C::U16 => 0xFFFF,
                        _ => 0xFFFF_FFFF,
                    };
                    if let Some(k) = indices.iter().position(|&v| v == restart) {
                        return Err(IngestError::PrimitiveRestartIndex {
                            path: ipath,
                            accessor: l.accessor,
                            position: k as u64,
                            value: restart as u64,
                        });
                    }
                    assemble(mode, indices.len(), |i| indices[i])
                }
                None => assemble(mode, count as usize, |i| i as u32),
            };
            let leftover = match mode {
                TriangleMode::Triangles => {
                    prim.indices.map_or(count, |i| layouts[i.value()].count) % 3
                }
                _ => 0,
            };
            if leftover != 0 {
                warnings.push(format!(
                    "{path}: {leftover} trailing indices do not form a triangle and were ignored"
                ));
            }
            triangles = triangles.saturating_add(triangle_list.len() as u64);
            if triangles > limits.max_triangles {
                return Err(IngestError::TooManyTriangles {
                    count: triangles,
                    max: limits.max_triangles,
                });
            }
            let material = prim.material.map(|m| m.value());
            if let Some(m) = material {
                let mat = materials.get(m).ok_or(IngestError::UnresolvedReference {
                    path: format!("{path}.material"),
                    target: "materials",
                    index: m,
                    count: materials.len(),
                })?;
                if let Some(t) = mat.base_color_texture {
                    if t.tex_coord as usize >= tex_coords.len() {
                        warnings.push(format!("{path}: material {m} samples base color from TEXCOORD_{}, which is missing", t.tex_coord));
                    }
                }
            }
            out.push(Primitive {
                mesh: mi,
                primitive: pi,
                material,
                mode,
                positions,
                normals,
                tex_coords,
                colors,
                triangles: triangle_list,
            });
        }
    }
    Ok(out)
}

/// Converts `n` vertex references (index `i` → vertex `v(i)`) in `mode` to a triangle list
/// (glTF 2.0 §3.7.2.1 "Topology Types"): strips keep a consistent winding by swapping the last
/// two corners of odd triangles; fans pivot on the first vertex.
pub(super) fn assemble(mode: TriangleMode, n: usize, v: impl Fn(usize) -> u32) -> Vec<[u32; 3]> {
    match mode {
        TriangleMode::Triangles => (0..n / 3)
            .map(|t| [v(3 * t), v(3 * t + 1), v(3 * t + 2)])
            .collect(),
        TriangleMode::Strip => (0..n.saturating_sub(2))
            .map(|i| {
                if i % 2 == 0 {
                    [v(i), v(i + 1), v(i + 2)]
                } else {
                    [v(i), v(i + 2), v(i + 1)]
                }
            })
            .collect(),
        TriangleMode::Fan => (0..n.saturating_sub(2))
            .map(|i| [v(i + 1), v(i + 2), v(0)])
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strips_and_fans_keep_winding() {
        assert_eq!(
            assemble(TriangleMode::Strip, 5, |i| i as u32),
            [[0, 1, 2], [1, 3, 2], [2, 3, 4]]
        );
        assert_eq!(
            assemble(TriangleMode::Fan, 5, |i| i as u32),
            [[1, 2, 0], [2, 3, 0], [3, 4, 0]]
        );
        assert_eq!(
            assemble(TriangleMode::Triangles, 7, |i| i as u32),
            [[0, 1, 2], [3, 4, 5]]
        );
        assert!(assemble(TriangleMode::Strip, 2, |i| i as u32).is_empty());
    }
}
