//! Free template vertices: hidden parts that the registration of the originals does not fit
//! (ours; not in the paper, which fits every vertex).
//!
//! A template that is a production head has surfaces no one sees from outside: a mouth bag
//! behind closed lips, eye sockets behind the lids. The joint fairing collapses such cavities,
//! so their vertices reach the originals stage squeezed into the lip or lid slit, and the
//! closest-point rounds keep them there: on a deformed copy of the Lee Perry-Smith scan fitted
//! back onto it (known answer), 4.1 % of the area ends turned over against the true normals,
//! nearly all of it in those cavities (README "elastiface"). With `free_visibility` > 0 the
//! vertices whose ambient visibility (the visible solid angle over 2π,
//! [`crate::engine::geometry::occlusion`], 64 rays from the template's own shape) is below it
//! are *free*: no forward closest point pulls them and no backward pair lands on a triangle of
//! only free corners, so they follow their fitted neighbours through the bending term, as
//! Wrap's "free polygons" do. They are then not on the target's own cavity surface (that is
//! the point: a different or missing cavity should not crush them), so the report measures
//! the fitted faces (no free corner) separately.
//!
//! A connected component with no visible vertex (teeth or eyeballs inside the head) stays
//! fitted: with no closest point and possibly no reference point, nothing would hold it and
//! the system would be singular.

use crate::engine::control::Control;
use crate::engine::geometry::occlusion::{directional_occlusion, OcclusionParams};
use crate::engine::geometry::ray_sets::RayFeatureError;
use crate::engine::mesh::Surface;

use super::system::components;
use super::MethodError;

/// Per template vertex: free (see the module docs). Empty when `threshold` is not positive.
///
/// # Errors
/// [`MethodError::Cancelled`]; [`MethodError::Internal`] if the visibility cannot be computed.
pub fn free_vertices(
    template: &Surface,
    threshold: f64,
    control: &Control,
) -> Result<Vec<bool>, MethodError> {
    if threshold <= 0.0 || template.positions.is_empty() {
        return Ok(Vec::new());
    }
    let occlusion = directional_occlusion(template, None, &OcclusionParams::default(), control)
        .map_err(|e| match e {
            RayFeatureError::Cancelled => MethodError::Cancelled,
            e => MethodError::Internal(format!("template visibility: {e}")),
        })?;
    let mut free: Vec<bool> = (0..template.positions.len())
        .map(|v| f64::from(occlusion.visibility(v)) < threshold)
        .collect();
    let (component, count) = components(free.len(), &template.faces);
    let mut visible = vec![false; count];
    for (v, &f) in free.iter().enumerate() {
        if !f {
            visible[component[v] as usize] = true;
        }
    }
    for (v, f) in free.iter_mut().enumerate() {
        *f &= visible[component[v] as usize];
    }
    Ok(free)
}

/// Free vertices above this share of the template get a warning: most of it is then held by
/// bending alone.
pub const WARN_SHARE: f64 = 0.5;

/// The warning of a `free` mask covering more than [`WARN_SHARE`] of the vertices.
pub fn share_warning(free: &[bool], threshold: f64) -> Option<String> {
    let share = free.iter().filter(|&&f| f).count() as f64 / free.len().max(1) as f64;
    (share > WARN_SHARE).then(|| {
        format!(
            "free_visibility {threshold} leaves {:.0}% of the template's vertices unfitted (they \
             follow by bending only); a smaller value fits more of them",
            100.0 * share
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::engine::mesh::primitives;

    fn shifted(mut s: Surface, by: [f32; 3]) -> Surface {
        for p in &mut s.positions {
            (0..3).for_each(|k| p[k] += by[k]);
        }
        s
    }

    fn merged(a: Surface, b: Surface) -> Surface {
        let n = a.positions.len() as u32;
        let mut positions = a.positions;
        positions.extend(b.positions);
        let mut faces = a.faces;
        faces.extend(b.faces.iter().map(|f| f.map(|v| v + n)));
        Surface::from_triangles(positions, faces)
    }

    #[test]
    fn off_frees_nothing_and_a_convex_shape_has_no_hidden_vertex() {
        let sphere = primitives::icosphere(1.0, 8);
        let control = Control::new();
        assert!(free_vertices(&sphere, 0.0, &control).unwrap().is_empty());
        assert_eq!(share_warning(&[], 0.0), None);
        assert_eq!(share_warning(&[true, false], 0.2), None);
        let warning = share_warning(&[true, true, false], 0.9).unwrap();
        assert!(
            warning.contains("free_visibility 0.9 leaves 67%"),
            "{warning}"
        );
        let free = free_vertices(&sphere, 0.5, &control).unwrap();
        assert_eq!(free.len(), sphere.positions.len());
        assert!(free.iter().all(|f| !f));
    }

    #[test]
    fn a_shell_inside_a_shell_is_hidden_but_a_fully_hidden_component_stays_fitted() {
        // A small sphere inside a large one: every inner vertex sees only the outer shell.
        let outer = primitives::icosphere(1.0, 8);
        let inner = primitives::icosphere(0.3, 4);
        let both = merged(outer.clone(), shifted(inner.clone(), [0.2, 0.0, 0.0]));
        let control = Control::new();
        let free = free_vertices(&both, 0.1, &control).unwrap();
        // The inner component has no visible vertex: it is kept fitted.
        assert!(free.iter().all(|f| !f));
        // Joined to the outer shell by one triangle, the inner sphere is freed; the outer
        // shell is not.
        let n_outer = outer.positions.len() as u32;
        let mut joined = merged(outer, shifted(inner, [0.2, 0.0, 0.0]));
        joined.faces.push([0, n_outer, n_outer + 1]);
        let free = free_vertices(&joined, 0.1, &control).unwrap();
        let inner_free = free[n_outer as usize..].iter().filter(|f| **f).count();
        assert!(
            inner_free > (free.len() - n_outer as usize) * 9 / 10,
            "{inner_free} inner vertices free"
        );
        assert!(free[..n_outer as usize].iter().all(|f| !f));
    }
}
