//! The ARAP refinement of the atlas's charts (`retex::engine::uv::arap`, Liu et al. 2008): on
//! charts where LSCM distorts area (spherical caps, a cone) it lowers the area-weighted L2 and the
//! L∞ stretch; on a developable strip it is isometric; it never flips a triangle; whole atlases
//! with the option pass every check of `uv_atlas`; degenerate input falls back to `None`; the
//! `output.atlas_parameterization` constraint parses and a bad value is rejected; results are
//! deterministic.

use retex::engine::asset::constraints::{AtlasParameterization, Constraints};
use retex::engine::control::Control;
use retex::engine::mesh::primitives::{grid, icosphere};
use retex::engine::mesh::Surface;
use retex::engine::uv::arap::{chart_stretch, refine, DEFAULT_ITERATIONS};
use retex::engine::uv::atlas::world_frame;
use retex::engine::uv::param::chart_vertices;
use retex::engine::uv::{generate, AtlasError, AtlasParams, Parameterization};
use serde_json::json;

use crate::uv_atlas::{check_atlas, torus};

/// A disc of `rings × segments` (plus a centre vertex) mapped by `place(ρ, θ)`, ρ in [0, 1].
fn polar(rings: usize, segments: usize, place: impl Fn(f64, f64) -> [f64; 3]) -> Surface {
    crate::uv_lscm::disc(rings, segments, 0.0, place)
}

/// A spherical cap of half-angle `degrees` on the unit sphere.
fn cap(degrees: f64) -> Surface {
    let alpha = degrees.to_radians();
    polar(24, 64, |rho, theta| {
        let phi = alpha * rho;
        [phi.sin() * theta.cos(), phi.sin() * theta.sin(), phi.cos()]
    })
}

/// A cone of unit base radius and height `height` (apex at the centre vertex).
fn cone(height: f64) -> Surface {
    polar(24, 64, |rho, theta| {
        [rho * theta.cos(), rho * theta.sin(), height * (1.0 - rho)]
    })
}

/// A strip of a cylinder (radius 0.5, 150° of arc, height 1): developable.
fn cylinder_strip() -> Surface {
    let mut s = grid(40, 20, 1.0 / 20.0);
    for p in &mut s.positions {
        let (a, z) = (f64::from(p[0]) / 2.0 * 150f64.to_radians(), f64::from(p[1]));
        *p = [(0.5 * a.cos()) as f32, (0.5 * a.sin()) as f32, z as f32];
    }
    s
}

/// (LSCM, ARAP) stretch `(L2, L∞)` of the whole surface as one chart.
fn compare(name: &str, s: &Surface) -> ((f64, f64), (f64, f64)) {
    let faces: Vec<u32> = (0..s.faces.len() as u32).collect();
    let vertices = chart_vertices(s, &faces);
    let lscm = world_frame(s, &faces, &vertices).expect("LSCM");
    let arap = refine(s, &faces, &vertices, &lscm, DEFAULT_ITERATIONS).expect("ARAP");
    let again = refine(s, &faces, &vertices, &lscm, DEFAULT_ITERATIONS).expect("ARAP");
    assert_eq!(arap, again, "{name}: not deterministic");
    let a = chart_stretch(s, &faces, &vertices, &lscm).expect("LSCM has no flipped triangle");
    let b = chart_stretch(s, &faces, &vertices, &arap)
        .unwrap_or_else(|| panic!("{name}: ARAP flipped a triangle"));
    println!(
        "{name}: LSCM L2 {:.4} Linf {:.3}; ARAP L2 {:.4} Linf {:.3}",
        a.0, a.1, b.0, b.1
    );
    (a, b)
}

/// ARAP's excess stretch (L2 − 1, L∞ − 1) against LSCM's, and the iteration sweep printed.
/// Measured excess ratios (ARAP / LSCM): L2 0.35 / 0.33 / 0.31 / 0.26 and L∞ 0.47 / 0.43 / 0.39
/// / 0.25 for the caps of 60°, 75°, 90° and the cone; the bounds are 0.5 and 0.6.
#[test]
fn arap_lowers_the_stretch_of_caps_and_cones() {
    for (name, s) in [
        ("cap 60°", cap(60.0)),
        ("cap 75°", cap(75.0)),
        ("cap 90°", cap(90.0)),
        ("cone h=1", cone(1.0)),
    ] {
        let (lscm, arap) = compare(name, &s);
        let ratio = |k: usize| {
            let (a, b) = if k == 0 {
                (lscm.0, arap.0)
            } else {
                (lscm.1, arap.1)
            };
            (b - 1.0) / (a - 1.0)
        };
        println!(
            "{name}: excess ratio L2 {:.2}, Linf {:.2}",
            ratio(0),
            ratio(1)
        );
        assert!(
            lscm.0 > 1.01,
            "{name}: LSCM L2 {:.4} shows no distortion",
            lscm.0
        );
        assert!(
            ratio(0) <= 0.5,
            "{name}: L2 {:.4} vs LSCM {:.4}",
            arap.0,
            lscm.0
        );
        assert!(
            ratio(1) <= 0.6,
            "{name}: Linf {:.3} vs LSCM {:.3}",
            arap.1,
            lscm.1
        );
    }
    for (name, s) in [("cap 90°", cap(90.0)), ("cone h=1", cone(1.0))] {
        let faces: Vec<u32> = (0..s.faces.len() as u32).collect();
        let vertices = chart_vertices(&s, &faces);
        let lscm = world_frame(&s, &faces, &vertices).unwrap();
        let sweep: Vec<String> = [1, 2, 5, 10, 20, 50, 200]
            .iter()
            .map(|it| {
                let r = refine(&s, &faces, &vertices, &lscm, *it).unwrap();
                let (l2, linf) = chart_stretch(&s, &faces, &vertices, &r).unwrap();
                format!("{it}: {l2:.4}/{linf:.3}")
            })
            .collect();
        println!("{name}: iterations: L2/Linf {}", sweep.join(", "));
    }
}

#[test]
fn arap_is_isometric_on_a_developable_strip() {
    let (_, arap) = compare("cylinder strip", &cylinder_strip());
    assert!(arap.0 < 1.005, "L2 {:.5}", arap.0);
    assert!(arap.1 < 1.02, "Linf {:.4}", arap.1);
}

#[test]
fn atlases_with_arap_are_valid() {
    let params = AtlasParams {
        parameterization: Parameterization::Arap {
            iterations: DEFAULT_ITERATIONS,
        },
        ..AtlasParams::default()
    };
    for (name, s) in [
        ("closed sphere", icosphere(1.0, 24)),
        ("torus", torus(1.0, 0.35, 96, 32)),
        ("open sheet", grid(40, 30, 0.1)),
        ("cap 90°", cap(90.0)),
    ] {
        let lscm = check_atlas(&format!("{name} (LSCM)"), &s, &AtlasParams::default());
        let arap = check_atlas(&format!("{name} (ARAP)"), &s, &params);
        assert!(
            arap.report.l2_stretch <= lscm.report.l2_stretch + 0.01,
            "{name}: ARAP L2 {:.4} vs LSCM {:.4}",
            arap.report.l2_stretch,
            lscm.report.l2_stretch
        );
    }
}

#[test]
fn degenerate_input_and_bad_parameters_fall_back_or_fail_clearly() {
    // A chart with a zero-area triangle, and a single triangle: no refinement, no panic.
    let s = Surface::from_triangles(
        vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [2.0, 0.0, 0.0],
        ],
        vec![[0, 1, 2], [0, 1, 3]],
    );
    let frame = vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [2.0, 0.0]];
    assert_eq!(refine(&s, &[0, 1], &[0, 1, 2, 3], &frame, 10), None);
    assert_eq!(refine(&s, &[0], &[0, 1, 2], &frame[..3], 10), None);
    let g = grid(4, 4, 1.0);
    let faces: Vec<u32> = (0..g.faces.len() as u32).collect();
    let vertices = chart_vertices(&g, &faces);
    let f = world_frame(&g, &faces, &vertices).unwrap();
    assert_eq!(refine(&g, &faces, &vertices, &f, 0), None);
    assert_eq!(refine(&g, &faces, &vertices, &f[1..], 5), None);
    for iterations in [0, 1001] {
        let p = AtlasParams {
            parameterization: Parameterization::Arap { iterations },
            ..AtlasParams::default()
        };
        let e = generate(&g, &p, &Control::new()).unwrap_err();
        assert!(matches!(e, AtlasError::InvalidParam(_)), "{e}");
    }
}

#[test]
fn the_constraint_parses_and_a_bad_value_is_rejected() {
    let parse = |v: serde_json::Value| {
        Constraints::from_json(json!({"version": 1, "output": v}).to_string().as_bytes())
    };
    let c = parse(json!({"atlas_parameterization": "arap"})).unwrap();
    assert_eq!(c.output.atlas_parameterization, AtlasParameterization::Arap);
    assert_eq!(
        Parameterization::from(c.output.atlas_parameterization),
        Parameterization::Arap {
            iterations: DEFAULT_ITERATIONS
        }
    );
    let c = parse(json!({"atlas_parameterization": "lscm"})).unwrap();
    assert_eq!(c.output.atlas_parameterization, AtlasParameterization::Lscm);
    let default = parse(json!({})).unwrap();
    assert_eq!(
        default.output.atlas_parameterization,
        AtlasParameterization::default()
    );
    assert!(parse(json!({"atlas_parameterization": "abf"})).is_err());
    assert!(parse(json!({"atlas_parameterization": 3})).is_err());
    let schema = retex::engine::methods::constraints_schema();
    let p = &schema["properties"]["output"]["properties"]["atlas_parameterization"];
    assert_eq!(p["enum"], json!(["lscm", "arap"]));
}
