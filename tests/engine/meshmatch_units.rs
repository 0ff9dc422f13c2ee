//! Unit tests of MeshMatch's steps (Chen et al. 2012, §4.2) on small meshes where the right answer
//! is known: propagation spreads a correct match over a grid in one pass, random search never
//! worsens a match and finds far-away correct ones, and voting the identity field (or a shifted
//! one) reproduces the source colours (or the shifted ones). Upsampling is in
//! `meshmatch_defects`.

use retex::engine::control::Control;
use retex::engine::geometry::expmap::RadiusUnit;
use retex::engine::geometry::fans::{FanParams, FanSampler, FanShape, FieldRef};
use retex::engine::methods::meshmatch::em::MAX_CHART_VERTICES;
use retex::engine::methods::meshmatch::levels::MeshLevels;
use retex::engine::methods::meshmatch::matcher::{
    bfs_order, components, usage_penalty, EStep, Nnf, PatchSpace,
};
use retex::engine::methods::meshmatch::vote::{vote, SourcePatches, VoteStencil};

use crate::meshmatch_defects::grid;

/// Shape-only patches (one-float fans, all equal): the dissimilarity of target `t` and source `s`
/// is the squared distance between their grid positions, so the identity is the only zero.
struct ShapeOnly {
    levels: MeshLevels,
    shape: Vec<f32>,
    fans: Vec<f32>,
}

impl ShapeOnly {
    fn new(nx: usize, ny: usize) -> Self {
        let levels = MeshLevels::build(&grid(nx, ny), 32, None, &Control::new()).unwrap();
        let s = levels.surface(0);
        let shape = s.positions.iter().flat_map(|p| [p[0], p[1]]).collect();
        let fans = vec![0.0; s.vertex_count()];
        ShapeOnly {
            levels,
            shape,
            fans,
        }
    }

    fn step(&self, seed: u64, whole_source_draws: bool) -> EStep<'_> {
        EStep {
            space: PatchSpace {
                fan: FanShape {
                    rings: 1,
                    spokes: 1,
                    dim: 1,
                },
                target_fans: &self.fans,
                source_fans: &self.fans,
                target_shape: &self.shape,
                source_shape: &self.shape,
                shape_dim: 2,
                source_allowed: None,
                exclude: None,
                source_penalty: &[],
                ring_weights: &[],
                target_ring_stats: &[],
                source_ring_stats: &[],
            },
            target_adjacency: self.levels.rings(0),
            source_adjacency: self.levels.rings(0),
            source_hierarchy: &self.levels.hierarchy,
            level: 0,
            whole_source_draws,
            randomized_rotations: false,
            fixed: None,
            seed,
        }
    }

    fn positions(&self) -> &[[f32; 3]] {
        &self.levels.surface(0).positions
    }

    /// Mean distance from each match to the right answer (the target vertex itself).
    fn error(&self, nnf: &Nnf) -> f32 {
        let p = self.positions();
        nnf.source
            .iter()
            .enumerate()
            .map(|(t, &s)| {
                let (a, b) = (p[t], p[s as usize]);
                ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt()
            })
            .sum::<f32>()
            / nnf.source.len() as f32
    }
}

/// Propagation: on a 30 × 30 grid every match starts at the far corner except vertex 0's, which is
/// right. One pass in breadth-first order from vertex 0 (one block: updates are seen at once)
/// carries the right match to every vertex, step by step through the neighbours' matches.
#[test]
fn propagation_spreads_a_correct_match_over_the_grid_in_one_pass() {
    let m = ShapeOnly::new(30, 30);
    let n = m.positions().len();
    let far = (n - 1) as u32;
    let mut nnf = Nnf {
        source: vec![far; n],
        rotation: vec![0; n],
        distance: vec![f32::INFINITY; n],
    };
    nnf.source[0] = 0;
    let step = m.step(1, false);
    step.refresh(&mut nnf);
    assert_eq!(nnf.distance[0], 0.0);
    let (labels, _) = components(m.levels.rings(0), n);
    let mut starts = vec![0u32];
    let order = bfs_order(m.levels.rings(0), &labels, &mut starts);
    let changed = step.propagate(&mut nnf, &order);
    let right = (0..n).filter(|&t| nnf.source[t] as usize == t).count();
    eprintln!("{changed} changed, {right} of {n} right");
    assert_eq!(right, n, "propagation left {} wrong", n - right);
    assert_eq!(changed, n - 2, "all but vertex 0 and the far corner change");
    // Without a correct seed, propagation alone cannot find the answer: a baseline.
    let mut stuck = Nnf {
        source: vec![far; n],
        rotation: vec![0; n],
        distance: vec![f32::INFINITY; n],
    };
    step.refresh(&mut stuck);
    step.propagate(&mut stuck, &order);
    assert!(m.error(&stuck) > 2.0, "error {}", m.error(&stuck));
}

/// Random search (Figure 4, with the whole-source draws of the coarsest level synthesised): from
/// random matches, passes with different seeds only ever lower each match's dissimilarity and
/// bring the matches much closer to the right answer (mean error down by more than 3×). Without
/// whole-source draws, draws stay among the descendants of the match's coarsest ancestor, so the
/// error falls less (measured 20.8 → 15.3): a baseline the full search must beat.
#[test]
fn random_search_never_worsens_and_approaches_the_right_matches() {
    let m = ShapeOnly::new(40, 40);
    let n = m.positions().len();
    let mut state = 0x2545_F491_4F6C_DD1Du64;
    let mut nnf = Nnf {
        source: (0..n)
            .map(|_| {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                (state % n as u64) as u32
            })
            .collect(),
        rotation: vec![0; n],
        distance: vec![f32::INFINITY; n],
    };
    m.step(0, false).refresh(&mut nnf);
    let start = m.error(&nnf);
    let search = |whole: bool| {
        let mut nnf = nnf.clone();
        for seed in 1..=10u64 {
            let before = nnf.distance.clone();
            m.step(seed, whole).random_search(&mut nnf);
            for t in 0..n {
                assert!(nnf.distance[t] <= before[t], "vertex {t} worsened");
            }
        }
        m.error(&nnf)
    };
    let (local, end) = (search(false), search(true));
    eprintln!("mean error {start:.2} → {end:.2} after 10 random-search passes ({local:.2} without whole-source draws)");
    assert!(end < start / 3.0, "mean error {start:.2} → {end:.2}");
    assert!(end < local, "{end:.2} vs {local:.2}");
}

/// Voting (Figure 5) on a 48 × 32 grid matched onto itself, colours a linear ramp: the identity
/// field votes back the source colours, and a field shifted by 6 columns votes the colours 6
/// columns over (away from the borders, within 0.01 of a ramp of 1 over 48 units).
#[test]
fn voting_a_known_field_gives_the_known_colours() {
    let surface = grid(48, 32);
    let levels = MeshLevels::build(&surface, 32, None, &Control::new()).unwrap();
    let s = levels.surface(0);
    let n = s.vertex_count();
    let ramp = |p: [f32; 3]| [p[0] / 48.0, p[1] / 48.0, 0.5];
    let colors: Vec<[f32; 3]> = s.positions.iter().map(|&p| ramp(p)).collect();
    let flat: Vec<f32> = colors.iter().flatten().copied().collect();
    let radius = 3.0 * levels.mean_edge[0];
    let params = FanParams {
        radius,
        radius_unit: RadiusUnit::World,
        max_chart_vertices: MAX_CHART_VERTICES,
        ..Default::default()
    };
    let sampler = FanSampler::new(s, &levels.frames[0], &params, &Control::new()).unwrap();
    let fans = sampler
        .sample(
            FieldRef {
                dim: 3,
                values: &flat,
            },
            &Control::new(),
        )
        .unwrap();
    let stencil = VoteStencil::build(sampler.charts(), radius);
    let patches = SourcePatches {
        rings: 3,
        spokes: 18,
        radius,
        fans: &fans.data,
        centers: &colors,
    };
    let index = |x: f32, y: f32| s.positions.iter().position(|p| p[0] == x && p[1] == y);
    for shift in [0.0f32, 6.0] {
        let source: Vec<u32> = s
            .positions
            .iter()
            .enumerate()
            .map(|(t, p)| {
                if p[0] + shift <= 47.0 {
                    index(p[0] + shift, p[1]).unwrap() as u32
                } else {
                    t as u32
                }
            })
            .collect();
        let nnf = Nnf {
            source,
            rotation: vec![0; n],
            distance: vec![0.0; n],
        };
        let voted = vote(&stencil, &nnf, &patches, 0.5 * radius, None, None);
        let mut worst = 0.0f32;
        let mut count = 0;
        for (t, p) in s.positions.iter().enumerate() {
            let inner = p[0] >= 6.0 && p[0] + shift <= 41.0 && p[1] >= 6.0 && p[1] <= 25.0;
            if !inner {
                continue;
            }
            let want = ramp([p[0] + shift, p[1], 0.0]);
            let err = (0..3)
                .map(|k| (voted[t][k] - want[k]).abs())
                .fold(0.0, f32::max);
            worst = worst.max(err);
            count += 1;
        }
        eprintln!("shift {shift}: worst error {worst:.4} over {count} vertices");
        assert!(count > 300);
        assert!(worst <= 0.01, "shift {shift}: worst error {worst:.4}");
    }
}

/// The completeness cost: proportional to each source vertex's uses over the even cover, fixed
/// targets not counted, forbidden sources not in the cover, nothing when the weight is 0.
#[test]
fn usage_penalty_counts_uses_against_an_even_cover() {
    // 6 targets onto 3 sources: 4 on source 0, 2 on source 1, none on 2 (even cover: 2 each).
    let nnf = Nnf {
        source: vec![0, 0, 0, 0, 1, 1],
        rotation: vec![0; 6],
        distance: vec![0.0; 6],
    };
    let p = usage_penalty(&nnf, 3, None, None, 0.5, 10.0);
    assert_eq!(p, vec![10.0, 5.0, 0.0]);
    // Source 2 may not be used: the even cover is 3 each.
    let allowed = [true, true, false];
    let p = usage_penalty(&nnf, 3, Some(&allowed), None, 0.5, 10.0);
    assert!((p[0] - 20.0 / 3.0).abs() < 1e-5 && (p[1] - 10.0 / 3.0).abs() < 1e-5);
    // Two fixed targets on source 0 are not counted: 4 free targets, 2 on each used source.
    let fixed = [true, true, false, false, false, false];
    let p = usage_penalty(&nnf, 3, Some(&allowed), Some(&fixed), 0.5, 10.0);
    assert!(
        (p[0] - 5.0).abs() < 1e-5 && (p[1] - 5.0).abs() < 1e-5,
        "{p:?}"
    );
    assert!(usage_penalty(&nnf, 3, None, None, 0.0, 10.0).is_empty());
}
