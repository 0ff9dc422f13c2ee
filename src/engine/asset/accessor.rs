//! Buffer views and accessors, checked before anything sized by the file is allocated
//! (glTF 2.0 §3.6.2 "Buffers and Buffer Views", §3.6.2.4 "Data Alignment", §3.6.2.3 "Sparse
//! Accessors", §3.7.2.1 attribute types incl. `KHR_mesh_quantization`).
//!
//! [`check_views`] validates every buffer view (buffer exists, range inside it, `byteStride` in
//! 4..=252 and a multiple of 4). [`layout`] validates one accessor without reading its data:
//! known component type and type, offset aligned to the component size, stride at least the
//! element size, all `count` elements inside the view (u64 arithmetic, no overflow), and for
//! sparse accessors `0 < sparse.count <= count` with both index and value ranges inside their
//! views. Reading ([`read_vec`], [`read_u32`]) then allocates at most `count` elements, applies
//! sparse substitution (indices strictly increasing and `< count`), treats an accessor without a
//! buffer view as zeros, and dequantizes normalized integers (§3.11 "normalized" formulas).

use gltf::json::accessor::{ComponentType, Type};
use gltf::json::validation::Checked;
use gltf::json::Root;

use super::IngestError;

/// A validated buffer view: where its bytes are.
#[derive(Clone, Copy, Debug)]
pub struct ViewRange {
    /// Buffer index.
    pub buffer: usize,
    /// First byte inside the buffer.
    pub offset: usize,
    /// Length in bytes.
    pub len: usize,
    /// `byteStride`, if given.
    pub stride: Option<usize>,
}

/// Validates every buffer view against the buffers' declared `byteLength`s (ingest checks
/// separately that each buffer's data has exactly that length).
///
/// # Errors
/// [`IngestError::UnresolvedReference`], [`IngestError::BufferViewOutOfRange`] or
/// [`IngestError::InvalidStride`].
pub fn check_views(root: &Root, buffer_lengths: &[u64]) -> Result<Vec<ViewRange>, IngestError> {
    let mut out = Vec::with_capacity(root.buffer_views.len());
    for (i, v) in root.buffer_views.iter().enumerate() {
        let buffer = v.buffer.value();
        let data_len = *buffer_lengths
            .get(buffer)
            .ok_or(IngestError::UnresolvedReference {
                path: format!("bufferViews[{i}].buffer"),
                target: "buffers",
                index: buffer,
                count: buffer_lengths.len(),
            })?;
        let offset = v.byte_offset.map_or(0, |o| o.0);
        let len = v.byte_length.0;
        let end = offset.saturating_add(len);
        if end > data_len {
            return Err(IngestError::BufferViewOutOfRange {
                view: i,
                buffer,
                offset,
                end,
                len: data_len,
            });
        }
        if let Some(s) = v.byte_stride {
            if !(4..=252).contains(&s.0) || s.0 % 4 != 0 {
                return Err(IngestError::InvalidStride {
                    view: i,
                    stride: s.0 as u64,
                });
            }
        }
        // end <= data_len, the length of a buffer held in memory, so both fit in usize.
        out.push(ViewRange {
            buffer,
            offset: offset as usize,
            len: len as usize,
            stride: v.byte_stride.map(|s| s.0),
        });
    }
    Ok(out)
}

/// Size in bytes of one component.
pub fn component_size(c: ComponentType) -> usize {
    match c {
        ComponentType::I8 | ComponentType::U8 => 1,
        ComponentType::I16 | ComponentType::U16 => 2,
        ComponentType::U32 | ComponentType::F32 => 4,
    }
}

/// Number of components of a type.
pub fn component_count(t: Type) -> usize {
    match t {
        Type::Scalar => 1,
        Type::Vec2 => 2,
        Type::Vec3 => 3,
        Type::Vec4 | Type::Mat2 => 4,
        Type::Mat3 => 9,
        Type::Mat4 => 16,
    }
}

/// Size in bytes of one element, with the column padding of §3.6.2.4 for small matrices.
fn element_size(c: ComponentType, t: Type) -> usize {
    let cs = component_size(c);
    match (t, cs) {
        (Type::Mat2, 1) => 8,
        (Type::Mat3, 1) => 12,
        (Type::Mat3, 2) => 24,
        _ => cs * component_count(t),
    }
}

/// Where one strided run of elements lives.
#[derive(Clone, Copy, Debug)]
struct Run {
    buffer: usize,
    start: usize,
    stride: usize,
}

/// Sparse substitution, validated.
#[derive(Clone, Copy, Debug)]
struct SparseLayout {
    count: usize,
    index_type: ComponentType,
    indices: Run,
    values: Run,
}

/// A validated accessor, ready to read.
#[derive(Clone, Copy, Debug)]
pub struct Layout {
    /// Accessor index.
    pub accessor: usize,
    /// Element count.
    pub count: u64,
    /// Component type.
    pub component: ComponentType,
    /// Element type.
    pub kind: Type,
    /// `normalized`.
    pub normalized: bool,
    dense: Option<Run>,
    sparse: Option<SparseLayout>,
}

impl Layout {
    /// A readable description such as `VEC2 of 5126 normalized`.
    pub fn describe(&self) -> String {
        let n = if self.normalized { " normalized" } else { "" };
        format!("{:?} of {}{n}", self.kind, self.component.as_gl_enum()).to_uppercase()
    }
}

fn range_check(
    accessor: usize,
    view: usize,
    offset: u64,
    span: u64,
    len: u64,
) -> Result<(), IngestError> {
    let end = offset.saturating_add(span);
    if end > len {
        return Err(IngestError::AccessorOutOfRange {
            accessor,
            view,
            offset,
            end,
            len,
        });
    }
    Ok(())
}

/// Validates accessor `index` against the checked views, without reading data.
///
/// # Errors
/// [`IngestError::UnresolvedReference`], [`IngestError::InvalidAccessor`],
/// [`IngestError::StrideTooSmall`] or [`IngestError::AccessorOutOfRange`].
pub fn layout(root: &Root, views: &[ViewRange], index: usize) -> Result<Layout, IngestError> {
    let invalid = |reason: String| IngestError::InvalidAccessor {
        accessor: index,
        reason,
    };
    let a = root
        .accessors
        .get(index)
        .ok_or_else(|| invalid("does not exist".into()))?;
    let Checked::Valid(gltf::json::accessor::GenericComponentType(component)) = a.component_type
    else {
        return Err(invalid(
            "componentType is not one of 5120, 5121, 5122, 5123, 5125, 5126".into(),
        ));
    };
    let Checked::Valid(kind) = a.type_ else {
        return Err(invalid(
            "type is not one of SCALAR, VEC2..4, MAT2..4".into(),
        ));
    };
    let count = a.count.0;
    let cs = component_size(component) as u64;
    let elem = element_size(component, kind) as u64;
    let get_view = |v: usize, what: &str| {
        views
            .get(v)
            .copied()
            .ok_or(IngestError::UnresolvedReference {
                path: format!("accessors[{index}].{what}"),
                target: "bufferViews",
                index: v,
                count: views.len(),
            })
    };
    let mut dense = None;
    if let Some(v) = a.buffer_view {
        let vi = v.value();
        let view = get_view(vi, "bufferView")?;
        let offset = a.byte_offset.map_or(0, |o| o.0);
        if offset % cs != 0 || !(view.offset as u64 + offset).is_multiple_of(cs) {
            return Err(invalid(format!(
                "byte offset {offset} is not aligned to its {cs}-byte components"
            )));
        }
        let stride = match view.stride {
            Some(s) if (s as u64) < elem => {
                return Err(IngestError::StrideTooSmall {
                    accessor: index,
                    view: vi,
                    stride: s as u64,
                    element: elem,
                })
            }
            Some(s) => s as u64,
            None => elem,
        };
        let span = if count == 0 {
            0
        } else {
            (count - 1).saturating_mul(stride).saturating_add(elem)
        };
        range_check(index, vi, offset, span, view.len as u64)?;
        dense = Some(Run {
            buffer: view.buffer,
            start: view.offset + offset as usize,
            stride: stride as usize,
        });
    } else if a.byte_offset.is_some_and(|o| o.0 != 0) {
        return Err(invalid("has a byteOffset but no bufferView".into()));
    }
    let mut sparse = None;
    if let Some(s) = &a.sparse {
        let scount = s.count.0;
        if scount == 0 || scount > count {
            return Err(invalid(format!(
                "sparse.count {scount} is not in 1..={count}"
            )));
        }
        let Checked::Valid(gltf::json::accessor::IndexComponentType(itype)) =
            s.indices.component_type
        else {
            return Err(invalid(
                "sparse.indices.componentType is not 5121, 5123 or 5125".into(),
            ));
        };
        if !matches!(
            itype,
            ComponentType::U8 | ComponentType::U16 | ComponentType::U32
        ) {
            return Err(invalid(
                "sparse.indices.componentType is not 5121, 5123 or 5125".into(),
            ));
        }
        let iv = s.indices.buffer_view.value();
        let iview = get_view(iv, "sparse.indices.bufferView")?;
        let isize = component_size(itype) as u64;
        let ioff = s.indices.byte_offset.0;
        range_check(
            index,
            iv,
            ioff,
            scount.saturating_mul(isize),
            iview.len as u64,
        )?;
        let vv = s.values.buffer_view.value();
        let vview = get_view(vv, "sparse.values.bufferView")?;
        let voff = s.values.byte_offset.0;
        range_check(
            index,
            vv,
            voff,
            scount.saturating_mul(elem),
            vview.len as u64,
        )?;
        sparse = Some(SparseLayout {
            count: scount as usize,
            index_type: itype,
            indices: Run {
                buffer: iview.buffer,
                start: iview.offset + ioff as usize,
                stride: isize as usize,
            },
            values: Run {
                buffer: vview.buffer,
                start: vview.offset + voff as usize,
                stride: elem as usize,
            },
        });
    }
    Ok(Layout {
        accessor: index,
        count,
        component,
        kind,
        normalized: a.normalized,
        dense,
        sparse,
    })
}

/// Reads component `k` of the element at byte `at` as f64, dequantizing when `normalized`.
fn component(bytes: &[u8], at: usize, c: ComponentType, normalized: bool) -> f64 {
    let b = |i: usize| bytes[at + i];
    match c {
        ComponentType::I8 => {
            let v = b(0) as i8 as f64;
            if normalized {
                (v / 127.0).max(-1.0)
            } else {
                v
            }
        }
        ComponentType::U8 => {
            let v = b(0) as f64;
            if normalized {
                v / 255.0
            } else {
                v
            }
        }
        ComponentType::I16 => {
            let v = i16::from_le_bytes([b(0), b(1)]) as f64;
            if normalized {
                (v / 32767.0).max(-1.0)
            } else {
                v
            }
        }
        ComponentType::U16 => {
            let v = u16::from_le_bytes([b(0), b(1)]) as f64;
            if normalized {
                v / 65535.0
            } else {
                v
            }
        }
        ComponentType::U32 => {
            let v = u32::from_le_bytes([b(0), b(1), b(2), b(3)]) as f64;
            if normalized {
                v / 4_294_967_295.0
            } else {
                v
            }
        }
        ComponentType::F32 => f32::from_le_bytes([b(0), b(1), b(2), b(3)]) as f64,
    }
}

/// Reads an accessor as `count` elements of `N` components, calling `put(element, values)`.
/// Dense data (or zeros) first, then sparse substitution.
fn read_with<const N: usize>(
    l: &Layout,
    buffers: &[Vec<u8>],
    mut put: impl FnMut(usize, [f64; N]),
) -> Result<(), IngestError> {
    let cs = component_size(l.component);
    let count = l.count as usize;
    if let Some(run) = l.dense {
        let bytes = &buffers[run.buffer];
        for i in 0..count {
            let at = run.start + i * run.stride;
            put(
                i,
                std::array::from_fn(|k| component(bytes, at + k * cs, l.component, l.normalized)),
            );
        }
    } else {
        for i in 0..count {
            put(i, [0.0; N]);
        }
    }
    if let Some(s) = l.sparse {
        let ibytes = &buffers[s.indices.buffer];
        let vbytes = &buffers[s.values.buffer];
        let mut previous: Option<u64> = None;
        for j in 0..s.count {
            let idx = component(
                ibytes,
                s.indices.start + j * s.indices.stride,
                s.index_type,
                false,
            ) as u64;
            if idx >= l.count || previous.is_some_and(|p| idx <= p) {
                return Err(IngestError::InvalidAccessor {
                    accessor: l.accessor,
                    reason: format!(
                        "sparse index {idx} at position {j} is not strictly increasing and below count {}",
                        l.count
                    ),
                });
            }
            previous = Some(idx);
            let at = s.values.start + j * s.values.stride;
            put(
                idx as usize,
                std::array::from_fn(|k| component(vbytes, at + k * cs, l.component, l.normalized)),
            );
        }
    }
    Ok(())
}

/// Reads a float-like accessor of `N` components (`N` must equal the type's component count;
/// the caller has checked it) as f32.
///
/// # Errors
/// [`IngestError::InvalidAccessor`] for bad sparse indices or a wrong `N`.
pub fn read_vec<const N: usize>(
    l: &Layout,
    buffers: &[Vec<u8>],
) -> Result<Vec<[f32; N]>, IngestError> {
    if component_count(l.kind) != N || matches!(l.kind, Type::Mat2) {
        return Err(IngestError::InvalidAccessor {
            accessor: l.accessor,
            reason: format!("expected {N} components"),
        });
    }
    let mut out = vec![[0f32; N]; l.count as usize];
    read_with::<N>(l, buffers, |i, v| out[i] = v.map(|x| x as f32))?;
    Ok(out)
}

/// Reads an unsigned-integer scalar accessor (indices) as u32.
///
/// # Errors
/// [`IngestError::InvalidAccessor`] for bad sparse indices or a non-scalar, non-unsigned type.
pub fn read_u32(l: &Layout, buffers: &[Vec<u8>]) -> Result<Vec<u32>, IngestError> {
    if l.kind != Type::Scalar
        || l.normalized
        || !matches!(
            l.component,
            ComponentType::U8 | ComponentType::U16 | ComponentType::U32
        )
    {
        return Err(IngestError::InvalidAccessor {
            accessor: l.accessor,
            reason: "expected an unsigned integer scalar".into(),
        });
    }
    let mut out = vec![0u32; l.count as usize];
    read_with::<1>(l, buffers, |i, v| out[i] = v[0] as u32)?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn root(json: &str) -> Root {
        Root::from_str(json).unwrap()
    }

    #[test]
    fn strided_normalized_and_sparse() {
        // view 0: 2 elements, stride 8, u16 normalized VEC2; view 1: sparse index [1] (u8 + pad),
        // view 2: sparse value (u16 pair).
        let r = root(
            r#"{"asset":{"version":"2.0"},"buffers":[{"byteLength":24}],
            "bufferViews":[{"buffer":0,"byteLength":16,"byteStride":8},{"buffer":0,"byteOffset":16,"byteLength":4},
                           {"buffer":0,"byteOffset":20,"byteLength":4}],
            "accessors":[{"bufferView":0,"componentType":5123,"normalized":true,"type":"VEC2","count":2,
              "sparse":{"count":1,"indices":{"bufferView":1,"componentType":5121},"values":{"bufferView":2}}}]}"#,
        );
        let mut b = vec![0u8; 24];
        b[0..2].copy_from_slice(&65535u16.to_le_bytes());
        b[16] = 1;
        b[22..24].copy_from_slice(&65535u16.to_le_bytes());
        let buffers = vec![b];
        let views = check_views(&r, &[24]).unwrap();
        let l = layout(&r, &views, 0).unwrap();
        let v = read_vec::<2>(&l, &buffers).unwrap();
        assert_eq!(v, vec![[1.0, 0.0], [0.0, 1.0]]);
    }

    #[test]
    fn huge_count_is_refused_before_reading() {
        let r = root(
            r#"{"asset":{"version":"2.0"},"buffers":[{"byteLength":12}],
            "bufferViews":[{"buffer":0,"byteLength":12}],
            "accessors":[{"bufferView":0,"componentType":5126,"type":"VEC3","count":2147483648}]}"#,
        );
        let views = check_views(&r, &[12]).unwrap();
        assert!(matches!(
            layout(&r, &views, 0),
            Err(IngestError::AccessorOutOfRange {
                accessor: 0,
                view: 0,
                ..
            })
        ));
    }

    #[test]
    fn dequantization_formulas() {
        assert_eq!(component(&[0x80], 0, ComponentType::I8, true), -1.0);
        assert_eq!(component(&[127], 0, ComponentType::I8, true), 1.0);
        assert_eq!(component(&[255], 0, ComponentType::U8, true), 1.0);
        assert_eq!(component(&[0x00, 0x80], 0, ComponentType::I16, true), -1.0);
        assert_eq!(component(&[7, 0], 0, ComponentType::U16, false), 7.0);
    }
}
