//! Exponential map and geodesic fans: analytic cases on a plane and a sphere, rotation
//! recovery, determinism across thread counts, errors; and an ignored benchmark
//! (`cargo test --release --no-default-features --test engine geodesic_fans::bench_ -- --ignored --nocapture`).

use glam::{DVec3, Quat, Vec3};
use retex::engine::control::Control;
use retex::engine::geometry::expmap::{
    exponential_map, local_frames, ExpMap, ExpMapError, ExpMapParams, FrameParams, LocalFrames,
    RadiusUnit,
};
use retex::engine::geometry::fans::{
    geodesic_fans, FanError, FanFilter, FanParams, FanShape, Fans, FieldRef,
};
use retex::engine::mesh::surface::Surface;
use std::collections::HashMap;
use std::f32::consts::TAU;

// Fixtures

/// Geodesic icosphere of frequency `n` on the unit sphere: `10 n² + 2` vertices. Points on shared
/// edges are keyed by their exact integer barycentric weights on the icosahedron's corners, so
/// they are welded exactly.
fn icosphere(n: u32) -> Surface {
    let t = (1.0 + 5f64.sqrt()) / 2.0;
    #[rustfmt::skip]
    let corners: [[f64; 3]; 12] = [
        [-1.0, t, 0.0], [1.0, t, 0.0], [-1.0, -t, 0.0], [1.0, -t, 0.0],
        [0.0, -1.0, t], [0.0, 1.0, t], [0.0, -1.0, -t], [0.0, 1.0, -t],
        [t, 0.0, -1.0], [t, 0.0, 1.0], [-t, 0.0, -1.0], [-t, 0.0, 1.0],
    ];
    #[rustfmt::skip]
    let ico: [[u32; 3]; 20] = [
        [0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11],
        [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6], [7, 1, 8],
        [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9],
        [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1],
    ];
    let mut index: HashMap<Vec<(u32, u32)>, u32> = HashMap::new();
    let mut positions = Vec::new();
    let mut faces = Vec::new();
    for f in ico {
        let mut id = |i: u32, j: u32| -> u32 {
            let mut key: Vec<(u32, u32)> = [(f[0], n - i - j), (f[1], i), (f[2], j)]
                .into_iter()
                .filter(|&(_, w)| w > 0)
                .collect();
            key.sort_unstable();
            *index.entry(key.clone()).or_insert_with(|| {
                let p: DVec3 = (key.iter())
                    .map(|&(c, w)| w as f64 * DVec3::from(corners[c as usize]))
                    .sum();
                positions.push(p.normalize().as_vec3().into());
                (positions.len() - 1) as u32
            })
        };
        for i in 0..n {
            for j in 0..n - i {
                faces.push([id(i, j), id(i + 1, j), id(i, j + 1)]);
                if i + j + 1 < n {
                    faces.push([id(i + 1, j), id(i + 1, j + 1), id(i, j + 1)]);
                }
            }
        }
    }
    Surface::from_triangles(positions, faces)
}

/// Deterministic pseudo-random in [-0.5, 0.5).
fn jitter(i: u32) -> f32 {
    let mut x = i.wrapping_mul(0x9E37_79B9) ^ 0x85EB_CA6B;
    x ^= x >> 15;
    x = x.wrapping_mul(0x2C1B_3C6D);
    x ^= x >> 12;
    (x >> 8) as f32 / (1u32 << 24) as f32 - 0.5
}

/// `(n+1)²` vertices on `[0, 1]²` in the plane z = 0, interior vertices jittered in-plane by up
/// to `jit` grid spacings.
fn plane_grid(n: u32, jit: f32) -> Surface {
    let h = 1.0 / n as f32;
    let mut positions = Vec::new();
    for j in 0..=n {
        for i in 0..=n {
            let id = j * (n + 1) + i;
            let jit = if i > 0 && j > 0 && i < n && j < n {
                jit
            } else {
                0.0
            };
            let (dx, dy) = (jit * jitter(2 * id), jit * jitter(2 * id + 1));
            positions.push([(i as f32 + dx) * h, (j as f32 + dy) * h, 0.0]);
        }
    }
    let mut faces = Vec::new();
    let v = |i: u32, j: u32| j * (n + 1) + i;
    for j in 0..n {
        for i in 0..n {
            faces.push([v(i, j), v(i + 1, j), v(i + 1, j + 1)]);
            faces.push([v(i, j), v(i + 1, j + 1), v(i, j + 1)]);
        }
    }
    Surface::from_triangles(positions, faces)
}

/// A polar disk in z = 0: the centre (vertex 0) and `rings` rings of `spokes` vertices at radii
/// `1..=rings` and angles `2πm/spokes`. Invariant under rotation by `2π/spokes`.
fn polar_disk(rings: u32, spokes: u32) -> Surface {
    let mut positions = vec![[0.0f32; 3]];
    for k in 1..=rings {
        for m in 0..spokes {
            let a = TAU * m as f32 / spokes as f32;
            positions.push([k as f32 * a.cos(), k as f32 * a.sin(), 0.0]);
        }
    }
    let v = |k: u32, m: u32| 1 + (k - 1) * spokes + m % spokes;
    let mut faces = Vec::new();
    for m in 0..spokes {
        faces.push([0, v(1, m), v(1, m + 1)]);
        for k in 1..rings {
            faces.push([v(k, m), v(k + 1, m), v(k + 1, m + 1)]);
            faces.push([v(k, m), v(k + 1, m + 1), v(k, m + 1)]);
        }
    }
    Surface::from_triangles(positions, faces)
}

fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn angle_diff(a: f32, b: f32) -> f32 {
    let d = (a - b).rem_euclid(TAU);
    d.min(TAU - d)
}

/// Exponential-map parameters with a radius in world units.
fn world_radius(radius: f32, upwind_average: bool) -> ExpMapParams {
    let radius_unit = RadiusUnit::World;
    ExpMapParams {
        radius,
        radius_unit,
        upwind_average,
        ..Default::default()
    }
}

fn frames_of(s: &Surface) -> LocalFrames {
    local_frames(s, &FrameParams::default())
}

/// Fans of an RGB field (3 floats per vertex).
fn rgb_fans(s: &Surface, frames: &LocalFrames, values: &[f32], params: &FanParams) -> Fans {
    let field = FieldRef { dim: 3, values };
    geodesic_fans(s, frames, field, params, &Control::new()).unwrap()
}

fn rgb_fans_result(s: &Surface, values: &[f32], params: &FanParams) -> Result<Fans, FanError> {
    let field = FieldRef { dim: 3, values };
    geodesic_fans(s, &frames_of(s), field, params, &Control::new())
}

/// The MeshMatch fan shape for RGB: 3 rings, 18 spokes.
const SHAPE: FanShape = FanShape {
    rings: 3,
    spokes: 18,
    dim: 3,
};

// Exponential map

/// On a plane the chart of every vertex is its planar polar coordinates in its own frame.
#[test]
fn expmap_on_plane_reproduces_polar_coordinates() {
    let s = plane_grid(40, 0.3);
    let frames = frames_of(&s);
    let params = world_radius(0.15, false);
    let map = exponential_map(&s, &frames, &params, &Control::new()).unwrap();
    let mut checked = 0;
    for p in 0..s.vertex_count() {
        let c = s.positions[p];
        let inside = (0..2).all(|k| c[k] > 0.2 && c[k] < 0.8);
        let (verts, coords) = map.chart(p);
        assert_eq!(verts[0] as usize, p);
        for (&q, &xy) in verts.iter().zip(coords) {
            let d = sub(s.positions[q as usize], c);
            let (r, theta) = ExpMap::polar(xy);
            let r_true = Vec3::from(s.positions[q as usize]).distance(c.into());
            assert!(
                (r - r_true).abs() < 0.01 * map.radius,
                "source {p} vertex {q}: r {r} vs {r_true}"
            );
            if r_true > 0.1 * map.radius {
                let t_true = dot(d, frames.bitangent[p]).atan2(dot(d, frames.tangent[p]));
                assert!(
                    angle_diff(theta, t_true) < 1e-3,
                    "source {p} vertex {q}: θ {theta} vs {t_true}"
                );
            }
            checked += 1;
        }
        if inside {
            // Complete: every vertex within 99% of the radius is in the chart.
            let near = |r: f32| r < 0.99 * map.radius;
            let want = s
                .positions
                .iter()
                .filter(|&&q| near(Vec3::from(q).distance(c.into())))
                .count();
            let have = coords
                .iter()
                .filter(|xy| near(ExpMap::polar(**xy).0))
                .count();
            assert_eq!(have, want, "source {p}");
        }
    }
    assert!(checked > 100_000, "{checked}");
}

/// Mean relative error of chart radius against great-circle distance and of the angle against
/// the analytic logarithm map, over all (source, vertex) pairs at least 10% of the radius
/// apart; and the worst relative radius error.
fn sphere_errors(s: &Surface, frames: &LocalFrames, map: &ExpMap) -> (f64, f64, f32) {
    let (mut rel, mut ang, mut count) = (0.0f64, 0.0f64, 0usize);
    let mut worst = 0.0f32;
    for p in 0..s.vertex_count() {
        let c = s.positions[p];
        let (verts, coords) = map.chart(p);
        for (&q, &xy) in verts.iter().zip(coords).skip(1) {
            let x = s.positions[q as usize];
            let gc = dot(x, c).clamp(-1.0, 1.0).acos();
            if gc < 0.1 * map.radius {
                continue;
            }
            let (r, theta) = ExpMap::polar(xy);
            let e = (r - gc).abs() / gc;
            worst = worst.max(e);
            rel += e as f64;
            let proj = sub(x, c.map(|k| k * dot(x, c)));
            let t_true = dot(proj, frames.bitangent[p]).atan2(dot(proj, frames.tangent[p]));
            ang += angle_diff(theta, t_true) as f64;
            count += 1;
        }
    }
    (rel / count as f64, ang / count as f64, worst)
}

/// On a ~10k-vertex unit sphere, chart radii match great-circle distances.
#[test]
fn expmap_on_sphere_matches_great_circle_distance() {
    let s = icosphere(32);
    assert_eq!(s.vertex_count(), 10242);
    let frames = frames_of(&s);
    for upwind_average in [false, true] {
        let params = world_radius(0.4, upwind_average);
        let map = exponential_map(&s, &frames, &params, &Control::new()).unwrap();
        let (rel, ang, worst) = sphere_errors(&s, &frames, &map);
        let msg = format!(
            "upwind {upwind_average}: mean rel r error {rel:.1e}, worst {worst:.1e}, \
             mean θ error {ang:.1e} rad"
        );
        println!("sphere expmap {msg}, {} chart entries", map.vertex.len());
        assert!(rel < 0.02 && worst < 0.01 && ang < 0.01, "{msg}");
    }
}

#[test]
fn expmap_rejects_bad_input_and_honours_cancellation() {
    let s = plane_grid(8, 0.0);
    let frames = frames_of(&s);
    let bad = ExpMapParams {
        radius: -1.0,
        ..Default::default()
    };
    assert!(matches!(
        exponential_map(&s, &frames, &bad, &Control::new()),
        Err(ExpMapError::InvalidParam { name: "radius", .. })
    ));
    let short = LocalFrames::default();
    assert!(matches!(
        exponential_map(&s, &short, &ExpMapParams::default(), &Control::new()),
        Err(ExpMapError::FrameCount { got: 0, .. })
    ));
    let c = Control::new();
    c.cancel();
    assert_eq!(
        exponential_map(&s, &frames, &ExpMapParams::default(), &c),
        Err(ExpMapError::Cancelled)
    );
}

#[test]
fn frames_are_orthonormal_and_follow_up_where_defined() {
    let s = icosphere(8);
    let params = FrameParams {
        up: Some([0.0, 0.0, 1.0]),
        min_up_projection: 0.1,
    };
    let frames = local_frames(&s, &params);
    for v in 0..s.vertex_count() {
        let f = |a: &[[f32; 3]]| Vec3::from(a[v]);
        let (n, t, b) = (f(&frames.normal), f(&frames.tangent), f(&frames.bitangent));
        assert!(
            (n.cross(t) - b).length() < 1e-5 && t.dot(n).abs() < 1e-5,
            "vertex {v}"
        );
        assert!(
            [n, t, b].iter().all(|x| (x.length() - 1.0).abs() < 1e-5),
            "vertex {v}"
        );
        // Where the projected up is long enough, the tangent is its direction.
        let projected_up = Vec3::Z - n * n.z;
        if projected_up.length() > 0.45 {
            assert!((t - projected_up.normalize()).length() < 1e-4, "vertex {v}");
        }
    }
}

// Fans

/// Three linear channels on the plane.
#[rustfmt::skip]
fn lin(p: [f32; 3]) -> [f32; 3] {
    [2.0 * p[0] - 3.0 * p[1] + 1.0, 0.5 * p[0] + p[1], -p[0] + 0.25]
}

/// Max |fan − analytic| over fans whose samples (plus the filter reach when `full`)
/// stay inside the unit square; with the number of fans checked.
fn linear_fan_error(s: &Surface, fr: &LocalFrames, fans: &Fans, full: bool) -> (f32, usize) {
    let shape = fans.shape();
    let margin = fans.radius + if full { 3.0 * fans.sigma } else { 0.0 };
    let (mut worst, mut count) = (0.0f32, 0);
    for v in 0..s.vertex_count() {
        let c = s.positions[v];
        if !(0..2).all(|k| c[k] > margin && c[k] < 1.0 - margin) {
            continue;
        }
        let fan = fans.fan(v);
        for ring in 0..shape.rings {
            for spoke in 0..shape.spokes {
                let [x, y] = shape.sample_position(fans.radius, ring, spoke);
                let (t, b) = (fr.tangent[v], fr.bitangent[v]);
                let p: [f32; 3] = std::array::from_fn(|k| c[k] + x * t[k] + y * b[k]);
                let want = lin(p);
                let got = &fan[(ring * shape.spokes + spoke) * 3..][..3];
                for k in 0..3 {
                    worst = worst.max((got[k] - want[k]).abs());
                }
            }
        }
        count += 1;
    }
    (worst, count)
}

/// Gaussian-filtered linear = linear: fans of a linear field on a (jittered) plane equal the
/// field at the sample points.
#[test]
fn fans_of_linear_field_on_plane_match_analytic_samples() {
    let s = plane_grid(60, 0.3);
    let frames = frames_of(&s);
    let field: Vec<f32> = s.positions.iter().flat_map(|&p| lin(p)).collect();
    let local = rgb_fans(&s, &frames, &field, &FanParams::default());
    let (err, n) = linear_fan_error(&s, &frames, &local, false);
    println!("local-linear: max error {err:.2e} over {n} fans");
    assert!(n > 1000 && err < 1e-4, "local-linear: {err} over {n} fans");
    let gauss_params = FanParams {
        filter: FanFilter::Gaussian,
        ..Default::default()
    };
    let gauss = rgb_fans(&s, &frames, &field, &gauss_params);
    let (err, n) = linear_fan_error(&s, &frames, &gauss, true);
    // Plain Gaussian mean: exact only up to the bias of the weighted centroid of the discrete,
    // jittered samples. Bound: centroid within 0.2 grid spacings (h = 1/60) of the sample point,
    // times the largest gradient |(2, -3)| = 3.61.
    println!("gaussian: max error {err:.2e} over {n} fans");
    let bound = 0.2 / 60.0 * 3.61;
    assert!(n > 500 && err < bound, "gaussian: {err} over {n} fans");
}

/// `bumpy_field(scale · p)` at every vertex.
fn bumpy_values(s: &Surface, scale: f32) -> Vec<f32> {
    (s.positions.iter())
        .flat_map(|&p| bumpy_field(p.map(|c| scale * c)))
        .collect()
}

/// A smooth field without rotational symmetry.
#[rustfmt::skip]
fn bumpy_field(p: [f32; 3]) -> [f32; 3] {
    [(1.3 * p[0] + 0.4 * p[1]).sin(), (0.7 * p[1] - 0.2 * p[0] * p[1]).cos(), 0.1 * p[0] * p[0] + 0.3 * p[1]]
}

/// For k in 0..18: fans at vertex `v` of `field_scale · bumpy_field` and of that field rotated
/// counter-clockwise by k·20° about the axis through `v` along its normal; returns, per k, the
/// best rotation found and the ratio of its distance to the next best one.
fn rotations_found(
    s: &Surface,
    v: usize,
    params: &FanParams,
    field_scale: f32,
) -> Vec<(usize, f32)> {
    let frames = frames_of(s);
    let (c0, n) = (Vec3::from(s.positions[v]), Vec3::from(frames.normal[v]));
    let fan_of = |angle: f32| {
        // The rotated field at x is the original at R(−angle) x (rotation about c0 along n).
        let rot = Quat::from_axis_angle(n, -angle);
        let values: Vec<f32> = (s.positions.iter())
            .flat_map(|&x| bumpy_field((field_scale * (c0 + rot * (Vec3::from(x) - c0))).into()))
            .collect();
        rgb_fans(s, &frames, &values, params).fan(v).to_vec()
    };
    let base = fan_of(0.0);
    (0..18)
        .map(|k| {
            let rotated = fan_of(k as f32 * TAU / 18.0);
            let (best, d) = SHAPE.best_rotation(&base, &rotated);
            let second = (0..18)
                .filter(|&j| j != best)
                .map(|j| SHAPE.distance(&base, &rotated, j))
                .fold(f32::INFINITY, f32::min);
            (best, d / second)
        })
        .collect()
}

/// On a disk invariant under 10° rotations, rotating the field by k·20° about the centre
/// shifts the centre fan by exactly k spokes.
#[test]
fn best_rotation_recovers_field_rotation_on_symmetric_disk() {
    let params = FanParams {
        radius: 4.0,
        radius_unit: RadiusUnit::World,
        ..Default::default()
    };
    let found = rotations_found(&polar_disk(8, 36), 0, &params, 1.0);
    for (k, &(best, ratio)) in found.iter().enumerate() {
        assert_eq!(best, k, "ratio to next best {ratio}");
        assert!(ratio < 1e-3, "k {k}: best / next best distance {ratio}");
    }
}

/// On an icosphere (no symmetry), a field rotated about a vertex's normal gives the matching
/// spoke shift up to resampling (measured best / next-best distance ratio ≤ 5e-5).
#[test]
fn best_rotation_recovers_field_rotation_on_sphere() {
    let s = icosphere(24);
    for v in [77, 3000] {
        let found = rotations_found(&s, v, &FanParams::default(), 6.0);
        for (k, &(best, ratio)) in found.iter().enumerate() {
            assert_eq!(best, k, "vertex {v}: ratio to next best {ratio}");
            assert!(ratio < 1e-3, "vertex {v} k {k}: best / next best {ratio}");
        }
    }
}

/// A synthetic fan cyclically shifted by k spokes: distance 0 at k, best rotation k.
#[test]
fn best_rotation_recovers_cyclic_shift_of_synthetic_fan() {
    let a: Vec<f32> = (0..SHAPE.len() as u32).map(jitter).collect();
    for k in 0..18 {
        let mut b = vec![0.0f32; SHAPE.len()];
        for ring in 0..3 {
            for j in 0..18 {
                for c in 0..3 {
                    b[(ring * 18 + (j + k) % 18) * 3 + c] = a[(ring * 18 + j) * 3 + c];
                }
            }
        }
        assert_eq!(SHAPE.distance(&a, &b, k), 0.0);
        assert_eq!(SHAPE.best_rotation(&a, &b), (k, 0.0));
        assert!(SHAPE.distance(&a, &b, (k + 1) % 18) > 0.1);
    }
}

#[test]
fn fans_are_identical_with_one_and_two_threads() {
    let s = icosphere(12);
    let frames = frames_of(&s);
    let values = bumpy_values(&s, 4.0);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let map =
                exponential_map(&s, &frames, &ExpMapParams::default(), &Control::new()).unwrap();
            let fans = rgb_fans(&s, &frames, &values, &FanParams::default());
            (map, fans)
        })
    };
    let (m1, f1) = run(1);
    let (m2, f2) = run(2);
    assert_eq!(m1, m2);
    assert_eq!(f1.data.len(), s.vertex_count() * 162);
    let bits = |f: &Fans| f.data.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&f1), bits(&f2));
}

#[test]
fn fans_reject_bad_input_and_honour_cancellation() {
    let s = plane_grid(8, 0.0);
    let values = vec![0.0f32; 81 * 3];
    let r = rgb_fans_result(&s, &values[..80], &FanParams::default());
    assert!(matches!(r, Err(FanError::LengthMismatch { got: 80, .. })));
    let p: FanParams = serde_json::from_str(r#"{"rings": 0}"#).unwrap();
    assert_eq!((p.spokes, p.filter), (18, FanFilter::LocalLinear));
    let r = rgb_fans_result(&s, &values, &p);
    assert!(matches!(
        r,
        Err(FanError::InvalidParam { name: "rings", .. })
    ));
    // No faces: no mean edge length to measure the radius in.
    let pts = Surface::from_triangles(vec![[0.0; 3]; 2], vec![]);
    let r = rgb_fans_result(&pts, &[0.0; 6], &FanParams::default());
    assert!(matches!(r, Err(FanError::InvalidParam { value: 0.0, .. })));
    let (frames, dim, values) = (frames_of(&s), 3, &values[..]);
    let field = FieldRef { dim, values };
    let c = Control::new();
    geodesic_fans(&s, &frames, field, &FanParams::default(), &c).unwrap();
    let progress = c.progress();
    assert_eq!(
        (progress.stage.as_str(), progress.stage_fraction),
        ("geodesic fans", 1.0)
    );
    c.cancel();
    let r = geodesic_fans(&s, &frames, field, &FanParams::default(), &c);
    assert_eq!(r, Err(FanError::Cancelled));
}

// Benchmark

/// Field `index` (0-based, after the pid) of a `/proc/self/<file>` line starting with `key`
/// (`key` empty: the single line of `stat`, fields after the command name).
fn proc_field(file: &str, key: &str, index: usize) -> f64 {
    let text = std::fs::read_to_string(format!("/proc/self/{file}")).unwrap_or_default();
    let line = text.lines().find(|l| l.starts_with(key)).unwrap_or("");
    let rest = if key.is_empty() {
        &line[line.rfind(')').map_or(0, |i| i + 1)..]
    } else {
        line
    };
    rest.split_whitespace()
        .nth(index)
        .and_then(|v| v.parse().ok())
        .unwrap_or(0.0)
}

/// CPU seconds (user + system, all threads) used so far; clock ticks assumed 100 Hz.
fn cpu_seconds() -> f64 {
    (proc_field("stat", "", 11) + proc_field("stat", "", 12)) / 100.0
}

/// Geodesic fans R=3, A=18, RGB on a 64K-vertex icosphere. Run with
/// `cargo test --release --no-default-features --test engine geodesic_fans::bench_ -- --ignored --nocapture`.
#[test]
#[ignore = "benchmark: run with --ignored --nocapture"]
fn bench_geodesic_fans_64k() {
    let s = icosphere(80);
    let values = bumpy_values(&s, 6.0);
    let threads = rayon::current_num_threads();
    let (mut frame_times, mut times, mut cpu) = (Vec::new(), Vec::new(), Vec::new());
    let mut fans = Fans::default();
    for _ in 0..7 {
        let t0 = std::time::Instant::now();
        let frames = frames_of(&s);
        let t1 = std::time::Instant::now();
        let c1 = cpu_seconds();
        fans = rgb_fans(&s, &frames, &values, &FanParams::default());
        let t2 = std::time::Instant::now();
        cpu.push(cpu_seconds() - c1);
        frame_times.push((t1 - t0).as_secs_f64());
        times.push((t2 - t1).as_secs_f64());
    }
    for v in [&mut times, &mut frame_times, &mut cpu] {
        v.sort_by(f64::total_cmp);
    }
    println!(
        "geodesic fans R=3 A=18 RGB, {} vertices, {threads} threads, 7 runs: wall median {:.3} s \
         (min {:.3}, max {:.3}); CPU (all threads) median {:.2} s; frames median {:.3} s; \
         {} floats; VmHWM {:.0} MiB",
        s.vertex_count(),
        times[3],
        times[0],
        times[6],
        cpu[3],
        frame_times[3],
        fans.data.len(),
        proc_field("status", "VmHWM:", 1) / 1024.0
    );
}

/// A prepared [`FanSampler`] gives exactly the fans of [`geodesic_fans`] for any field, with or
/// without its filter weights kept, and a chart cap bounds every chart.
#[test]
fn fan_sampler_reuses_charts_and_matches_geodesic_fans() {
    use retex::engine::geometry::fans::FanSampler;
    let s = retex::engine::mesh::primitives::icosphere(1.0, 12);
    let frames = frames_of(&s);
    let params = FanParams::default();
    let sampler = FanSampler::new(&s, &frames, &params, &Control::new()).unwrap();
    let mut cached = FanSampler::new(&s, &frames, &params, &Control::new()).unwrap();
    assert_eq!(cached.cached_weights(), 0);
    cached.cache_weights(&Control::new()).unwrap();
    // About 8 weights per sample with the default filter (σ = half the ring spacing, 3σ reach).
    let per_sample = cached.cached_weights() as f64 / (s.vertex_count() * 54) as f64;
    assert!(
        (4.0..16.0).contains(&per_sample),
        "{per_sample} weights per sample"
    );
    for phase in [0.0f32, 1.3] {
        let field: Vec<f32> = s
            .positions
            .iter()
            .flat_map(|p| [(3.0 * p[0] + phase).sin(), p[1] * p[2], (2.0 * p[2]).cos()])
            .collect();
        let f = FieldRef {
            dim: 3,
            values: &field,
        };
        let a = sampler.sample(f, &Control::new()).unwrap();
        let b = geodesic_fans(&s, &frames, f, &params, &Control::new()).unwrap();
        assert_eq!(a, b);
        // The kept weights give the same fans, bit for bit, for any field.
        assert_eq!(cached.sample(f, &Control::new()).unwrap(), b);
    }
    let capped = FanSampler::new(
        &s,
        &frames,
        &FanParams {
            max_chart_vertices: 10,
            ..Default::default()
        },
        &Control::new(),
    )
    .unwrap();
    let c = capped.charts();
    assert!((0..s.vertex_count()).all(|v| c.chart(v).0.len() <= 10 && c.chart(v).0[0] == v as u32));
}
