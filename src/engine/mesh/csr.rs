//! Compressed adjacency lists (CSR: an `offsets` array of `n + 1` entries and one array of
//! values, row `k` being `values[offsets[k]..offsets[k + 1]]`), built by [`group_by_key`], and
//! the vertex → faces and vertex → neighbours lists of a [`Surface`] built with it.

use rayon::prelude::*;

use super::surface::Surface;

/// Groups `items` `(key, value)` by key (a counting sort, stable): returns `(offsets, values)`
/// with `n + 1` offsets, the values of key `k` being `values[offsets[k]..offsets[k + 1]]` in the
/// order `items` yields them. `items` is iterated twice (to count, then to fill).
///
/// # Panics
/// If a key is `>= n`.
pub fn group_by_key<T, I>(n: usize, items: I) -> (Vec<u32>, Vec<T>)
where
    T: Copy + Default,
    I: Iterator<Item = (u32, T)> + Clone,
{
    let mut offsets = vec![0u32; n + 1];
    for (k, _) in items.clone() {
        offsets[k as usize + 1] += 1;
    }
    for k in 0..n {
        offsets[k + 1] += offsets[k];
    }
    let mut cursor = offsets.clone();
    let mut values = vec![T::default(); offsets[n] as usize];
    for (k, v) in items {
        let c = &mut cursor[k as usize];
        values[*c as usize] = v;
        *c += 1;
    }
    (offsets, values)
}

/// Vertex → incident faces, CSR, faces ascending. A face that repeats a vertex is listed once per
/// corner (unlike [`Topology::vertex_faces`](super::Topology::vertex_faces), which lists it once).
pub fn vertex_faces(surface: &Surface) -> (Vec<u32>, Vec<u32>) {
    let corners = surface
        .faces
        .iter()
        .enumerate()
        .flat_map(|(f, face)| face.iter().map(move |&v| (v, f as u32)));
    group_by_key(surface.positions.len(), corners)
}

/// The directed edges `(a, b)` of `surface`: both directions of every face edge between two
/// distinct vertices, sorted, each once.
pub fn directed_edges(surface: &Surface) -> Vec<(u32, u32)> {
    let mut pairs: Vec<(u32, u32)> = Vec::with_capacity(surface.faces.len() * 6);
    for f in &surface.faces {
        for i in 0..3 {
            let (a, b) = (f[i], f[(i + 1) % 3]);
            if a != b {
                pairs.push((a, b));
                pairs.push((b, a));
            }
        }
    }
    pairs.par_sort_unstable();
    pairs.dedup();
    pairs
}

/// Vertex neighbours (1-ring) of a surface, CSR: `(offsets, neighbours)`, each list ascending:
/// [`directed_edges`] grouped by their first vertex.
pub fn vertex_neighbours(surface: &Surface) -> (Vec<u32>, Vec<u32>) {
    group_by_key(surface.positions.len(), directed_edges(surface).into_iter())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grouping_is_stable_and_covers_empty_rows() {
        let (offsets, values) =
            group_by_key(4, [(2u32, 'a'), (0, 'b'), (2, 'c'), (0, 'd')].into_iter());
        assert_eq!(offsets, vec![0, 2, 2, 4, 4]);
        assert_eq!(values, vec!['b', 'd', 'a', 'c']);
    }

    #[test]
    fn rings_and_incident_faces_of_two_triangles() {
        let s = Surface::from_triangles(vec![[0.0; 3]; 5], vec![[0, 1, 2], [2, 1, 3]]);
        let (o, n) = vertex_neighbours(&s);
        assert_eq!(o, vec![0, 2, 5, 8, 10, 10]);
        assert_eq!(n, vec![1, 2, 0, 2, 3, 0, 1, 3, 1, 2]);
        let (o, f) = vertex_faces(&s);
        assert_eq!(o, vec![0, 1, 3, 5, 6, 6]);
        assert_eq!(f, vec![0, 0, 1, 0, 1, 1]);
    }
}
