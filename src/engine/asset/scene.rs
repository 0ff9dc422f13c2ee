//! The node hierarchy and scene (glTF 2.0 §3.5): a strict forest with no cycles, finite TRS or
//! matrix transforms, world matrices as f64 products, and the choice of scene (the `scene`
//! property, else scene 0, else every root node).

use gltf::json::Root;

use super::load::IngestLimits;
use super::model::*;
use super::IngestError;

type Mat4 = [[f64; 4]; 4];

const IDENTITY: Mat4 = [
    [1.0, 0.0, 0.0, 0.0],
    [0.0, 1.0, 0.0, 0.0],
    [0.0, 0.0, 1.0, 0.0],
    [0.0, 0.0, 0.0, 1.0],
];

/// Column-major product `a * b`.
fn mul(a: &Mat4, b: &Mat4) -> Mat4 {
    let mut out = [[0.0; 4]; 4];
    for (c, col) in out.iter_mut().enumerate() {
        for (r, x) in col.iter_mut().enumerate() {
            *x = (0..4).map(|k| a[k][r] * b[c][k]).sum();
        }
    }
    out
}

/// A node's local matrix (§3.5.3 "Transformations"): `matrix`, or T·R·S.
pub(super) fn local_matrix(node: &gltf::json::Node, index: usize) -> Result<Mat4, IngestError> {
    let non_finite = IngestError::NonFiniteTransform { node: index };
    if let Some(m) = node.matrix {
        if !m.iter().all(|x| x.is_finite()) {
            return Err(non_finite);
        }
        return Ok(std::array::from_fn(|c| {
            std::array::from_fn(|r| m[4 * c + r] as f64)
        }));
    }
    let t = node.translation.unwrap_or([0.0; 3]).map(f64::from);
    let q = node
        .rotation
        .as_ref()
        .map_or([0.0, 0.0, 0.0, 1.0], |q| q.0)
        .map(f64::from);
    let s = node.scale.unwrap_or([1.0; 3]).map(f64::from);
    if !(t.iter().chain(&q).chain(&s).all(|x| x.is_finite())) {
        return Err(non_finite);
    }
    let norm = q.iter().map(|x| x * x).sum::<f64>().sqrt();
    let [x, y, z, w] = if norm > 0.0 {
        q.map(|v| v / norm)
    } else {
        [0.0, 0.0, 0.0, 1.0]
    };
    let rot = [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - z * w),
            2.0 * (x * z + y * w),
        ],
        [
            2.0 * (x * y + z * w),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - x * w),
        ],
        [
            2.0 * (x * z - y * w),
            2.0 * (y * z + x * w),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ];
    let mut m = IDENTITY;
    for c in 0..3 {
        for r in 0..3 {
            m[c][r] = rot[r][c] * s[c];
        }
    }
    m[3] = [t[0], t[1], t[2], 1.0];
    Ok(m)
}

/// Checks that the nodes form a forest (§3.5.2 "Node Hierarchy") and returns the mesh instances
/// of the chosen scene: `scene`, else scene 0, else every root node.
pub(super) fn scene_instances(
    root: &Root,
    limits: &IngestLimits,
) -> Result<Vec<MeshInstance>, IngestError> {
    let n = root.nodes.len();
    let node_ref = |path: String, i: usize| {
        if i < n {
            Ok(i)
        } else {
            Err(IngestError::UnresolvedReference {
                path,
                target: "nodes",
                index: i,
                count: n,
            })
        }
    };
    let mut parent: Vec<Option<usize>> = vec![None; n];
    for (i, node) in root.nodes.iter().enumerate() {
        if let Some(m) = node.mesh {
            if m.value() >= root.meshes.len() {
                return Err(IngestError::UnresolvedReference {
                    path: format!("nodes[{i}].mesh"),
                    target: "meshes",
                    index: m.value(),
                    count: root.meshes.len(),
                });
            }
        }
        for (j, c) in node.children.iter().flatten().enumerate() {
            let c = node_ref(format!("nodes[{i}].children[{j}]"), c.value())?;
            if c == i {
                return Err(IngestError::InvalidNodeHierarchy {
                    node: c,
                    reason: "is its own child".into(),
                });
            }
            if parent[c].is_some() {
                return Err(IngestError::InvalidNodeHierarchy {
                    node: c,
                    reason: "has more than one parent".into(),
                });
            }
            parent[c] = Some(i);
        }
    }
    // With at most one parent each, nodes unreachable from a parentless node lie on a cycle.
    let mut reached = vec![false; n];
    let mut stack: Vec<usize> = (0..n).filter(|&i| parent[i].is_none()).collect();
    while let Some(i) = stack.pop() {
        reached[i] = true;
        stack.extend(root.nodes[i].children.iter().flatten().map(|c| c.value()));
    }
    if let Some(i) = reached.iter().position(|r| !r) {
        return Err(IngestError::InvalidNodeHierarchy {
            node: i,
            reason: "is part of a cycle of children".into(),
        });
    }
    let roots: Vec<usize> = match (root.scene, root.scenes.first()) {
        (Some(s), _) => {
            let scene = root
                .scenes
                .get(s.value())
                .ok_or(IngestError::UnresolvedReference {
                    path: "scene".into(),
                    target: "scenes",
                    index: s.value(),
                    count: root.scenes.len(),
                })?;
            let si = s.value();
            scene
                .nodes
                .iter()
                .enumerate()
                .map(|(j, x)| node_ref(format!("scenes[{si}].nodes[{j}]"), x.value()))
                .collect::<Result<_, _>>()?
        }
        (None, Some(scene)) => scene
            .nodes
            .iter()
            .enumerate()
            .map(|(j, x)| node_ref(format!("scenes[0].nodes[{j}]"), x.value()))
            .collect::<Result<_, _>>()?,
        (None, None) => (0..n).filter(|&i| parent[i].is_none()).collect(),
    };
    let mut instances = Vec::new();
    let mut stack: Vec<(usize, Mat4, u64)> =
        roots.iter().rev().map(|&r| (r, IDENTITY, 1)).collect();
    while let Some((i, parent_world, depth)) = stack.pop() {
        if depth > limits.max_node_depth {
            return Err(IngestError::NodeTooDeep {
                node: i,
                depth,
                max: limits.max_node_depth,
            });
        }
        let node = &root.nodes[i];
        let world = mul(&parent_world, &local_matrix(node, i)?);
        if !world.iter().flatten().all(|x| x.is_finite()) {
            return Err(IngestError::NonFiniteTransform { node: i });
        }
        if let Some(m) = node.mesh {
            instances.push(MeshInstance {
                node: i,
                mesh: m.value(),
                world,
            });
        }
        for c in node.children.iter().flatten().rev() {
            stack.push((c.value(), world, depth + 1));
        }
    }
    Ok(instances)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trs_matches_hand_product() {
        let node: gltf::json::Node = serde_json::from_str(
            r#"{"translation":[1,2,3],"rotation":[0,0,0.7071067811865476,0.7071067811865476],"scale":[2,2,2]}"#,
        )
        .unwrap();
        let m = local_matrix(&node, 0).unwrap();
        let inst = MeshInstance {
            node: 0,
            mesh: 0,
            world: m,
        };
        let p = inst.transform_point([1.0, 0.0, 0.0]);
        // scale 2, rotate 90° about z: (1,0,0) -> (0,2,0), then translate.
        assert!(
            (p[0] - 1.0).abs() < 1e-6 && (p[1] - 4.0).abs() < 1e-6 && (p[2] - 3.0).abs() < 1e-6,
            "{p:?}"
        );
    }
}
