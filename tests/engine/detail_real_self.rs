//! The `detail` method (Berkiten et al. 2017, §3.3.1) on a real scan with a known answer: the
//! koala scan's sculpted detail (fur, toes, ear ruffles, eyes) synthesised onto the koala's own
//! smooth base. Source and target levels are then the same remeshed surfaces, so the source's
//! displacement at each target vertex is the answer, and the synthesis with the learned metric
//! must reproduce it far better than random patches and better than equal weights (the paper's
//! §5 baselines: "No Metric Learning" and no matching at all). This holds on the koala, not on
//! the skull scan (see the test's comment).

use retex::engine::control::Control;
use retex::engine::methods::detail::displacement::smooth_base;
use retex::engine::methods::detail::metric::MetricKind;
use retex::engine::methods::detail::params::DetailParams;
use retex::engine::methods::detail::pipeline::{transfer_detail, DetailTransfer, PipelineParams};
use retex::engine::methods::detail::synthesis::Choice;

use crate::common_geometry::read_obj;
use crate::detail_features::synthesis::pearson;
use crate::detail_method::std;

/// (Pearson r against the answer, synthesised std / the answer's std).
fn against_the_answer(label: &str, out: &DetailTransfer) -> (f64, f64) {
    let (s, t) = (&out.source_surface, &out.surface);
    assert_eq!(
        s.positions, t.positions,
        "{label}: the target levels are not the source's"
    );
    let r = pearson(&out.displacement, &out.source_displacement);
    let energy = std(&out.displacement) / std(&out.source_displacement);
    println!(
        "{label}: {} finest vertices, r {r:.3}, std {:.5} (answer {:.5}, ratio {energy:.3}), \
         metric rank {}, {:.1} s synthesis",
        t.vertex_count(),
        std(&out.displacement),
        std(&out.source_displacement),
        out.report.metric.rank,
        out.report.seconds.synthesis,
    );
    (r, energy)
}

/// (learned, identity, random patches) of the scan at `path` onto its own derived base.
fn onto_its_own_base(path: &str) -> [(f64, f64); 3] {
    let scan = read_obj(&crate::common::shared_asset(path));
    let d = scan.diagonal() as f64;
    let params = DetailParams::default().pipeline(d, d);
    let base = smooth_base(&scan, &params.base).unwrap();
    let control = Control::new();
    let run = |p: &PipelineParams| transfer_detail(&scan, Some(&base), &base, p, &control).unwrap();
    let learned = against_the_answer("learned", &run(&params));
    let mut identity = params.clone();
    identity.metric_kind = MetricKind::Identity;
    let identity = against_the_answer("identity", &run(&identity));
    let mut random = params.clone();
    random.synthesis.choice = Choice::Random(7);
    let random = against_the_answer("random patches", &run(&random));
    [learned, identity, random]
}

#[test]
#[ignore = "needs ../shared/assets; about 1.5 minutes"]
fn the_koala_scans_detail_onto_its_own_base_reproduces_it() {
    let [learned, identity, random] = onto_its_own_base("perf_koala_odedstein/koala.obj");
    // Measured (r, std ratio): learned 0.711, 0.64; identity 0.576, 0.59; random patches
    // −0.066, 0.45 (0.643 / 0.531 / 0.035 before the remesher stopped leaving degenerate faces
    // on the scan's levels). Not a general property: on the skull scan (the other shared scan
    // with a derived base) learned r is 0.177, identity 0.085, random 0.072 (README "detail"),
    // so the skull is not a test.
    assert!(learned.0 > 0.5, "learned r {learned:?}");
    assert!(
        learned.0 > identity.0,
        "learned {learned:?} vs identity {identity:?}"
    );
    assert!(random.0 < 0.2, "random patches {random:?}");
    assert!(
        learned.0 > random.0 + 0.4,
        "learned {learned:?} vs random {random:?}"
    );
    assert!(
        (0.4..1.3).contains(&learned.1),
        "learned energy {learned:?}"
    );
}
