//! Flattening of a cluster and its flatness error (Soler et al. 2002, §3.2, eq. 1).
//!
//! Deviation from the paper: the paper flattens a cluster through its control polygon (edge
//! lengths and angles kept as far as possible) and places the sub-clusters' control vertices
//! relative to the parent's, recursively down to the faces. Here every disc cluster is
//! flattened directly with free-boundary least-squares conformal maps (Lévy et al. 2002,
//! LSCM: two border vertices pinned, one sparse Cholesky solve), then scaled so that the
//! texture area equals the surface area. Why: the recursion of the paper's topological
//! coordinates is garbled in the available text, and LSCM maps every developable cluster
//! (a flat or folded sheet) isometrically, which is what the issue requires of flat clusters,
//! while curved clusters get a conformal map whose area distortion measures how far they are
//! from flat. Since a cluster's texture coordinates come from one solve over its own vertices,
//! sub-clusters never crack inside a patch (§4.3's averaging is not needed).
//!
//! The LSCM solve itself lives in [`crate::engine::uv::param`], shared with the UV atlas.
//!
//! Flatness error (eq. 1 reads E_flat = |r − 1| with r the surface / texture area ratio): since
//! the total ratio is 1 after scaling, E_flat is the area-weighted mean over faces of
//! |r_f − 1|, r_f = surface area / texture area of face f. Any triangle whose texture area is
//! not positive (flipped or collapsed) makes the cluster "not flat".

use crate::engine::mesh::Surface;
use crate::engine::uv::param::{chart_vertices, flatten_chart};
pub use crate::engine::uv::param::{local_triangle, lscm, signed_area};

/// A flattened cluster.
#[derive(Clone, Debug)]
pub struct Flat {
    /// The cluster's vertices (sorted surface indices).
    pub vertices: Vec<u32>,
    /// Their flattened positions, world units, x right and y down as the image's pixels: a
    /// front-facing (counter-clockwise) face is clockwise here, so the pattern placed by a
    /// rotation and a translation is not mirrored.
    pub frame: Vec<[f64; 2]>,
    /// Area-weighted mean |r_f − 1|.
    pub e_flat: f32,
    /// Triangles with a non-positive texture area.
    pub flipped: usize,
}

impl Flat {
    /// Local index of a surface vertex.
    pub fn local(&self, v: u32) -> Option<usize> {
        self.vertices.binary_search(&v).ok()
    }

    /// Flattened position of a surface vertex of the cluster.
    pub fn at(&self, v: u32) -> Option<[f64; 2]> {
        self.local(v).map(|i| self.frame[i])
    }

    /// Whether the cluster counts as flat enough.
    pub fn is_flat(&self, threshold: f32) -> bool {
        self.flipped == 0 && self.e_flat <= threshold
    }

    /// Bounding box of the frame, `[min, max]`.
    pub fn bbox(&self) -> [[f64; 2]; 2] {
        let mut b = [[f64::MAX; 2], [f64::MIN; 2]];
        for p in &self.frame {
            for k in 0..2 {
                b[0][k] = b[0][k].min(p[k]);
                b[1][k] = b[1][k].max(p[k]);
            }
        }
        b
    }
}

/// Flattens a disc cluster (see the module doc). `None` if the solve fails (degenerate input).
pub fn flatten(surface: &Surface, faces: &[u32]) -> Option<Flat> {
    let vertices = chart_vertices(surface, faces);
    let frame = flatten_chart(surface, faces, &vertices)?;
    let mut flat = Flat {
        vertices,
        frame,
        e_flat: 0.0,
        flipped: 0,
    };
    normalise(surface, faces, &mut flat);
    Some(flat)
}

/// Mirrors a clockwise result, scales texture area to surface area, measures E_flat and flips.
fn normalise(surface: &Surface, faces: &[u32], flat: &mut Flat) {
    let tri = |flat: &Flat, f: u32| {
        let fv = surface.faces[f as usize];
        fv.map(|v| flat.at(v).unwrap_or([0.0; 2]))
    };
    let mut a2 = 0.0;
    let mut a3 = 0.0;
    for f in faces {
        a2 += signed_area(tri(flat, *f));
        a3 += f64::from(surface.face_area(*f as usize));
    }
    if a2 < 0.0 {
        for p in &mut flat.frame {
            p[1] = -p[1];
        }
        a2 = -a2;
    }
    let s = if a2 > 0.0 { (a3 / a2).sqrt() } else { 1.0 };
    for p in &mut flat.frame {
        p[0] *= s;
        p[1] *= s;
    }
    let mut err = 0.0;
    let mut flipped = 0;
    for f in faces {
        let area3 = f64::from(surface.face_area(*f as usize));
        let area2 = signed_area(tri(flat, *f));
        if area2 <= area3 * 1e-9 {
            flipped += 1;
            continue;
        }
        err += area3 * (area3 / area2 - 1.0).abs();
    }
    flat.flipped = flipped;
    flat.e_flat = if a3 > 0.0 { (err / a3) as f32 } else { 0.0 };
    // Image convention (y down): seen from the front, the image's top is the frame's −y, so
    // the pattern is not mirrored.
    for p in &mut flat.frame {
        p[1] = -p[1];
    }
}
