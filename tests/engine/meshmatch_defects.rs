//! MeshMatch review defects (issue 14, item 3), each on a small mesh where the right answer is
//! known: by-example matches whose fans reach outside the painted region, a painted region too
//! narrow for any fan (an error, not a silent fallback), and inputs denser than `samples` (the
//! synthesis mesh is built at the requested density).

use retex::engine::control::Control;
use retex::engine::mesh::Surface;
use retex::engine::methods::meshmatch::em::{synthesize, MatchInput, Mode};
use retex::engine::methods::meshmatch::sampling::synthesis_mesh;
use retex::engine::methods::meshmatch::{MeshMatchParams, ShapeFeatures};

use crate::common::assert_validator_clean;
use crate::meshmatch_common::{capsule, glb_of, run_bytes};

/// A planar grid of `nx × ny` vertices, spacing 1, each square split along the same diagonal.
pub fn grid(nx: usize, ny: usize) -> Surface {
    let positions: Vec<[f32; 3]> = (0..ny)
        .flat_map(|j| (0..nx).map(move |i| [i as f32, j as f32, 0.0]))
        .collect();
    let at = |i: usize, j: usize| (j * nx + i) as u32;
    let mut faces = Vec::new();
    for j in 0..ny - 1 {
        for i in 0..nx - 1 {
            faces.push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
            faces.push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
        }
    }
    Surface::from_triangles(positions, faces)
}

/// Vertical stripes of period 6 (dark 0.05, light 0.9) on the painted part, grey elsewhere.
fn striped(surface: &Surface, painted: &[bool]) -> Vec<[f32; 3]> {
    surface
        .positions
        .iter()
        .zip(painted)
        .map(|(p, &m)| {
            let g = if !m {
                0.5
            } else if (p[0] / 6.0).fract() < 0.5 {
                0.05
            } else {
                0.9
            };
            [g; 3]
        })
        .collect()
}

fn by_example_params(fan_radius: f32) -> MeshMatchParams {
    MeshMatchParams {
        shape_features: ShapeFeatures::None,
        fan_radius,
        iterations: 3,
        ..Default::default()
    }
}

/// Texture by example on an 80 × 40 grid painted where x < 40, with fans of 5 mean edges (so a
/// fan reaches well past 3 rings). Every match of an unpainted vertex must use a painted vertex
/// farther than the fan radius from any unpainted vertex: its whole fan lies in the painted
/// region. Seeds 1-3. (Before the fix the mask was eroded by 3 rings, about 3.4 units here,
/// against a fan radius of 5.7 units, and upsampled matches could land outside it.)
#[test]
fn by_example_matches_keep_their_whole_fan_in_the_painted_region() {
    let surface = grid(80, 40);
    let painted: Vec<bool> = surface.positions.iter().map(|p| p[0] < 39.5).collect();
    let colors = striped(&surface, &painted);
    let unpainted: Vec<[f32; 3]> = surface
        .positions
        .iter()
        .zip(&painted)
        .filter(|(_, &m)| !m)
        .map(|(p, _)| *p)
        .collect();
    let clearance = |p: [f32; 3]| {
        unpainted
            .iter()
            .map(|q| ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)).sqrt())
            .fold(f32::INFINITY, f32::min)
    };
    for seed in 1..=3u64 {
        let out = synthesize(
            &MatchInput {
                source: &surface,
                source_colors: &colors,
                target: &surface,
                correspondences: &[],
                mode: Mode::ByExample(&painted),
            },
            &by_example_params(5.0),
            seed,
            &Control::new(),
        )
        .unwrap();
        let radius = out.report.levels.last().unwrap().fan_radius;
        assert!(radius > 5.0, "fan radius {radius}");
        let mut outside = 0;
        let mut closest = f32::INFINITY;
        for (t, &s) in out.nnf.source.iter().enumerate() {
            if painted[t] {
                continue;
            }
            let c = clearance(surface.positions[s as usize]);
            closest = closest.min(c);
            if !painted[s as usize] || c <= radius {
                outside += 1;
            }
        }
        eprintln!("seed {seed}: fan radius {radius:.2}, closest match {closest:.2} from the unpainted part, {outside} matches reach outside");
        assert_eq!(outside, 0, "seed {seed}: {outside} matches' fans leave the painted region (closest {closest:.2} < radius {radius:.2})");
        // The synthesized half is striped: mostly dark or light, not the original grey.
        let extreme = out
            .colors
            .iter()
            .zip(&painted)
            .filter(|(c, &m)| !m && (c[0] - 0.5).abs() > 0.3)
            .count() as f64
            / unpainted.len() as f64;
        assert!(extreme > 0.9, "seed {seed}: only {extreme:.3} striped");
    }
}

/// A painted strip 5 units wide (x < 4.5) cannot hold a fan of radius 5.7: by-example must say so
/// instead of silently matching with fans that read the unpainted part.
#[test]
fn by_example_with_a_region_narrower_than_a_fan_is_an_error() {
    let surface = grid(60, 30);
    let painted: Vec<bool> = surface.positions.iter().map(|p| p[0] < 4.5).collect();
    let colors = striped(&surface, &painted);
    let result = synthesize(
        &MatchInput {
            source: &surface,
            source_colors: &colors,
            target: &surface,
            correspondences: &[],
            mode: Mode::ByExample(&painted),
        },
        &by_example_params(5.0),
        1,
        &Control::new(),
    );
    match result {
        Ok(_) => panic!("a painted region narrower than one fan was accepted"),
        Err(e) => {
            let text = e.to_string();
            assert!(text.contains("painted region"), "{text}");
            assert!(text.contains("params.example"), "{text}");
        }
    }
}

/// A capsule of `around × rings` vertices (plus caps) of radius 0.5 along x over [0, 4].
fn dense_capsule(around: usize, rings: usize) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let profile: Vec<f32> = (0..rings)
        .map(|i| 4.0 * i as f32 / (rings - 1) as f32)
        .collect();
    capsule(0.5, &profile, around, |x| x)
}

/// A torus of `major × minor` vertices (radii 1 and 0.4).
fn torus(major: usize, minor: usize) -> Surface {
    let mut positions = Vec::with_capacity(major * minor);
    for i in 0..major {
        let u = std::f32::consts::TAU * i as f32 / major as f32;
        for j in 0..minor {
            let v = std::f32::consts::TAU * j as f32 / minor as f32;
            let r = 1.0 + 0.4 * v.cos();
            positions.push([r * u.cos(), r * u.sin(), 0.4 * v.sin()]);
        }
    }
    let at = |i: usize, j: usize| ((i % major) * minor + j % minor) as u32;
    let mut faces = Vec::with_capacity(2 * major * minor);
    for i in 0..major {
        for j in 0..minor {
            faces.push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
            faces.push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
        }
    }
    Surface::from_triangles(positions, faces)
}

/// An input far denser than `samples` (a 204,800-vertex torus, and a 205,602-vertex capsule whose
/// caps are fans of 400 slivers per ring; `samples` 20,000 and 4,096) gives a synthesis mesh at
/// the requested density, within ±25%, of the same area, and every synthesis vertex's link is its
/// closest point on the input (within 1% of the torus' minor radius). The capsule stayed at 6,563
/// vertices for 4,096 while a collapse could not make any single sliver worse.
#[test]
fn a_dense_input_is_decimated_to_the_requested_samples() {
    let (cp, ct) = dense_capsule(400, 500);
    for surface in [torus(640, 320), Surface::from_triangles(cp, ct)] {
        assert!(surface.vertex_count() > 200_000);
        decimated_to_the_requested_samples(&surface);
    }
}

fn decimated_to_the_requested_samples(surface: &Surface) {
    for samples in [20_000usize, 4_096] {
        let mesh = synthesis_mesh(surface, samples, &Control::new()).unwrap();
        let n = mesh.surface.vertex_count();
        let ratio = mesh.surface.area() / surface.area();
        eprintln!(
            "{} input vertices, samples {samples}: {n} synthesis vertices, area ratio {ratio:.4}",
            surface.vertex_count()
        );
        assert!(
            (0.75..=1.25).contains(&(n as f64 / samples as f64)),
            "{n} synthesis vertices for samples = {samples}"
        );
        assert!((0.97..=1.03).contains(&ratio), "area ratio {ratio:.4}");
        assert_eq!(mesh.vertex_link.len(), n);
        for (v, link) in mesh.vertex_link.iter().enumerate() {
            let f = surface.faces[link.face as usize];
            let q: [f32; 3] = std::array::from_fn(|k| {
                (0..3)
                    .map(|c| link.bary[c] * surface.positions[f[c] as usize][k])
                    .sum()
            });
            let p = mesh.surface.positions[v];
            let d = (0..3).map(|k| (p[k] - q[k]).powi(2)).sum::<f32>().sqrt();
            assert!(d < 0.004, "vertex {v} is {d} from its input point");
        }
    }
}

/// End to end: a 200,000-vertex striped capsule as the target with `samples` 20,000 runs at that
/// density, and the baked output is validator-clean and striped.
#[test]
fn a_dense_target_is_transferred_at_the_requested_density() {
    let stripe = |x: f32| if (x * 2.5).fract() < 0.5 { 0.05 } else { 0.9 };
    let (sp, st) = dense_capsule(64, 60);
    let source_colors: Vec<[f32; 4]> = sp
        .iter()
        .map(|q| {
            let g = stripe(q[0]);
            [g, g, g, 1.0]
        })
        .collect();
    let (tp, tt) = dense_capsule(400, 500);
    let target_colors = vec![[0.5f32, 0.5, 0.5, 1.0]; tp.len()];
    let out = run_bytes(
        ("source.glb", glb_of(&sp, &st, Some(&source_colors))),
        ("target.glb", glb_of(&tp, &tt, Some(&target_colors))),
        serde_json::json!({"version": 1, "method": "meshmatch",
            "output": {"vertex_colors": true},
            "params": {"samples": 20000, "source_samples": 4096, "iterations": 2,
                       "shape_features": "none"}}),
    );
    assert_validator_clean(&out.model, "meshmatch_dense_target.glb");
    let r = &out.report.method_report;
    let n = r["target_samples"].as_u64().unwrap() as f64;
    eprintln!("target synthesis vertices {n}");
    assert!((15_000.0..=25_000.0).contains(&n), "{r}");
    let pts = crate::meshmatch_common::colored_points(&out.model);
    let extreme = pts
        .iter()
        .filter(|(_, c)| ((c[0] + c[1] + c[2]) / 3.0 - 0.5).abs() > 0.25)
        .count() as f64
        / pts.len() as f64;
    eprintln!("{extreme:.3} of the output near black or white");
    assert!(extreme > 0.7, "only {extreme:.3} striped");
}

/// Upsampling (§4.2, Figure 6) on a 40 × 20 grid onto itself, from the identity field of level 1,
/// with only x < 9.5 usable (by-example): the known answer is the identity on the usable part, and
/// every other target goes to a usable vertex, never outside it.
#[test]
fn upsampling_the_identity_stays_the_identity_and_inside_the_usable_region() {
    use retex::engine::methods::meshmatch::levels::MeshLevels;
    use retex::engine::methods::meshmatch::matcher::Nnf;
    use retex::engine::methods::meshmatch::upsample::{upsample, Allowed, Side};
    let surface = grid(40, 20);
    let levels = MeshLevels::build(&surface, 64, None, &Control::new()).unwrap();
    assert!(levels.len() >= 2);
    let nc = levels.surface(1).vertex_count();
    let coarse = Nnf {
        source: (0..nc as u32).collect(),
        rotation: vec![0; nc],
        distance: vec![0.0; nc],
    };
    let usable: Vec<bool> = surface.positions.iter().map(|p| p[0] < 9.5).collect();
    let side = Side {
        hierarchy: &levels.hierarchy,
        frames: &levels.frames,
    };
    let allowed = Allowed {
        mask: &usable,
        seed: 1,
    };
    let fine = upsample(&coarse, 0, &side, &side, &levels.bvh[0], 18, Some(allowed));
    let mut identity = 0;
    let mut inside = 0;
    for (t, &s) in fine.source.iter().enumerate() {
        let (pt, ps) = (surface.positions[t], surface.positions[s as usize]);
        assert!(
            usable[s as usize],
            "target {pt:?} matched outside at {ps:?}"
        );
        if usable[t] {
            inside += 1;
            identity += usize::from(s as usize == t);
        }
    }
    let share = identity as f64 / inside as f64;
    eprintln!("identity kept on {share:.3} of the usable part");
    assert!(share >= 0.95, "identity kept on only {share:.3}");
}
