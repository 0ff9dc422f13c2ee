//! Analytic and invariant tests of the Laplace–Beltrami spectrum (shift-invert Lanczos and the
//! dense solver) and of the HKS / WKS signatures, plus an ignored 64K-vertex benchmark.

use std::sync::OnceLock;
use std::time::Instant;

use retex::engine::control::Control;
use retex::engine::geometry::laplacian::{cotan_laplacian, GeometryError, LaplacianParams};
use retex::engine::geometry::signatures::{
    heat_kernel_signature, wave_kernel_signature, HksNormalization, HksParams, WksParams,
};
use retex::engine::geometry::spectrum::{
    laplace_spectrum, Spectrum, SpectrumParams, SpectrumSolver,
};
use retex::engine::linalg::lanczos::{shift_invert_lanczos, LanczosParams};
use retex::engine::linalg::SymbolicCholesky;
use retex::engine::mesh::primitives::icosphere;
use retex::engine::mesh::Surface;

/// The ~10k-vertex unit sphere (frequency 32: 10 242 vertices) and its 36 lowest eigenpairs
/// (complete multiplets l = 0..5), computed once.
fn sphere_spectrum() -> &'static (Surface, Spectrum, f64) {
    static CELL: OnceLock<(Surface, Spectrum, f64)> = OnceLock::new();
    CELL.get_or_init(|| {
        let s = icosphere(1.0, 32);
        let params = SpectrumParams {
            count: 36,
            ..Default::default()
        };
        let t = Instant::now();
        let spec = laplace_spectrum(&s, &params, &Control::new()).unwrap();
        let secs = t.elapsed().as_secs_f64();
        (s, spec, secs)
    })
}

/// An ellipsoid with semi-axes (1, 0.7, 0.5): a shape whose HKS varies over the surface.
fn ellipsoid(frequency: usize, scale: f32) -> Surface {
    let mut s = icosphere(1.0, frequency);
    for p in &mut s.positions {
        *p = [p[0] * scale, p[1] * 0.7 * scale, p[2] * 0.5 * scale];
    }
    s
}

fn params(count: usize, solver: SpectrumSolver) -> SpectrumParams {
    SpectrumParams {
        count,
        solver,
        ..Default::default()
    }
}

#[test]
fn unit_sphere_eigenvalues_are_l_l_plus_1_with_multiplicity_2l_plus_1() {
    let (s, spec, secs) = sphere_spectrum();
    eprintln!(
        "sphere n = {}: {:.2} s, {} solves, {} restarts, values {:?}",
        s.vertex_count(),
        secs,
        spec.operator_applications,
        spec.restarts,
        &spec.values
    );
    assert_eq!(spec.solver, SpectrumSolver::Iterative);
    assert!(spec.converged);
    assert!(spec.values[0].abs() < 1e-8, "λ0 = {}", spec.values[0]);
    for l in 1..=4usize {
        let exact = (l * (l + 1)) as f64;
        for i in l * l..(l + 1) * (l + 1) {
            let rel = (spec.values[i] - exact).abs() / exact;
            assert!(rel < 0.02, "λ{i} = {} vs {exact} (l = {l})", spec.values[i]);
        }
    }
    // Multiplicity exactly 9 for l = 4: the 26th eigenvalue belongs to l = 5 (30).
    assert!(
        (spec.values[25] - 30.0).abs() / 30.0 < 0.02,
        "λ25 = {}",
        spec.values[25]
    );
}

#[test]
fn sphere_eigenvectors_are_m_orthonormal_with_small_residuals() {
    let (_, spec, _) = sphere_spectrum();
    let n = spec.vertex_count();
    let mut worst = 0.0f64;
    for i in 0..spec.len() {
        for j in 0..=i {
            let (a, b) = (spec.vector(i), spec.vector(j));
            let g: f64 = (0..n).map(|x| a[x] * spec.mass[x] * b[x]).sum();
            let expect = if i == j { 1.0 } else { 0.0 };
            worst = worst.max((g - expect).abs());
        }
    }
    eprintln!("max |ΦᵀMΦ − I| = {worst:e}, residuals {:?}", spec.residuals);
    assert!(worst < 1e-8, "ΦᵀMΦ deviates from I by {worst}");
    let r = spec.residuals.iter().copied().fold(0.0, f64::max);
    assert!(r < 1e-8, "largest relative residual {r}");
}

#[test]
fn hks_is_constant_on_the_sphere() {
    let (_, spec, _) = sphere_spectrum();
    let hks = heat_kernel_signature(spec, &HksParams::default()).unwrap();
    assert_eq!(hks.dim(), 8);
    for j in 0..hks.dim() {
        let col = hks.column(j);
        let (lo, hi) = col
            .iter()
            .fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
        let mean = col.iter().sum::<f64>() / col.len() as f64;
        let spread = (hi - lo) / mean;
        eprintln!(
            "t = {:.4}: mean {mean:.6}, spread {spread:e}",
            hks.scales[j]
        );
        assert!(spread < 0.01, "time {j}: relative spread {spread}");
        // Normalized: area-weighted mean 1, and on a sphere every value is near 1.
        assert!((mean - 1.0).abs() < 0.01, "time {j}: mean {mean}");
    }
    // Times follow 4 ln 10 / λ: t_max / t_min = λ_max / λ₁ ≈ 30 / 2.
    let ratio = hks.scales[7] / hks.scales[0];
    assert!((ratio - spec.values[35] / spec.values[1]).abs() < 1e-9 * ratio);
}

#[test]
fn hks_is_scale_invariant_and_raw_hks_scales_by_inverse_area() {
    let p = params(30, SpectrumSolver::Iterative);
    let small = laplace_spectrum(&ellipsoid(16, 1.0), &p, &Control::new()).unwrap();
    let hks_small = heat_kernel_signature(&small, &HksParams::default()).unwrap();
    let col = hks_small.column(0);
    let (lo, hi) = col
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), &v| (a.min(v), b.max(v)));
    assert!(
        hi - lo > 0.05,
        "the ellipsoid HKS should vary: [{lo}, {hi}]"
    );
    // Scaling by 2 is exact in f32; by 3 the positions round (relative 6e-8), hence 1e-5.
    for scale in [2.0f32, 3.0] {
        let big = laplace_spectrum(&ellipsoid(16, scale), &p, &Control::new()).unwrap();
        let hks_big = heat_kernel_signature(&big, &HksParams::default()).unwrap();
        let mut worst = 0.0f64;
        for (a, b) in hks_small.values.iter().zip(&hks_big.values) {
            worst = worst.max((a - b).abs() / a.abs());
        }
        eprintln!("scale {scale}: normalized HKS max relative difference {worst:e}");
        assert!(
            worst < 1e-5,
            "normalized HKS changed by {worst} under scaling by {scale}"
        );
        let s2 = f64::from(scale * scale);
        for (ts, tb) in hks_small.scales.iter().zip(&hks_big.scales) {
            assert!((tb / ts - s2).abs() < 1e-5 * s2, "times scale by s²");
        }
        let raw = HksParams {
            normalization: HksNormalization::None,
            ..Default::default()
        };
        let (rs, rb) = (
            heat_kernel_signature(&small, &raw).unwrap(),
            heat_kernel_signature(&big, &raw).unwrap(),
        );
        for (a, b) in rs.values.iter().zip(&rb.values) {
            assert!(
                (b * s2 - a).abs() < 1e-5 * a.abs(),
                "raw HKS must scale by 1/s²"
            );
        }
    }
}

#[test]
fn lanczos_on_the_shared_cholesky_matches_the_spectrum() {
    let s = ellipsoid(10, 1.0);
    let lap = cotan_laplacian(&s, &LaplacianParams::default()).unwrap();
    let sigma = -1e-6;
    let shifted = lap.stiffness.scaled_plus_diagonal(-1.0, -sigma, &lap.mass);
    let factor = SymbolicCholesky::new(lap.pattern().clone())
        .unwrap()
        .factor(&shifted)
        .unwrap();
    let eig = shift_invert_lanczos(
        &factor,
        &lap.mass,
        20,
        &LanczosParams::default(),
        &mut |_| Ok(()),
    )
    .unwrap();
    assert_eq!(eig.converged, 20);
    let dense = laplace_spectrum(&s, &params(20, SpectrumSolver::Dense), &Control::new()).unwrap();
    for (i, theta) in eig.theta.iter().enumerate() {
        let lambda = sigma + 1.0 / theta;
        let rel = (lambda - dense.values[i]).abs() / dense.values[i].max(dense.values[1]);
        assert!(rel < 1e-8, "λ{i}: {lambda} vs {}", dense.values[i]);
    }
}

#[test]
fn wks_is_finite_non_negative_and_normalized_per_energy() {
    let spec = laplace_spectrum(
        &ellipsoid(12, 1.0),
        &params(60, SpectrumSolver::Auto),
        &Control::new(),
    )
    .unwrap();
    let wks = wave_kernel_signature(&spec, &WksParams::default()).unwrap();
    assert_eq!(wks.dim(), 100);
    assert!(wks.values.iter().all(|v| v.is_finite() && *v >= 0.0));
    for j in 0..wks.dim() {
        let col = wks.column(j);
        let total: f64 = col.iter().zip(&spec.mass).map(|(w, m)| w * m).sum();
        assert!((total - 1.0).abs() < 1e-9, "energy {j}: Σ WKS·M = {total}");
    }
    // Energies ascend inside [log λ₁, log λ_max].
    let (lo, hi) = (spec.values[1].ln(), spec.values[59].ln());
    assert!(wks.scales.windows(2).all(|w| w[1] > w[0]));
    assert!(wks.scales[0] > lo && wks.scales[99] < hi);
}

#[test]
fn dense_and_iterative_solvers_agree_on_a_small_mesh() {
    let s = ellipsoid(10, 1.0);
    let dense = laplace_spectrum(&s, &params(40, SpectrumSolver::Dense), &Control::new()).unwrap();
    let iter =
        laplace_spectrum(&s, &params(40, SpectrumSolver::Iterative), &Control::new()).unwrap();
    assert_eq!(dense.solver, SpectrumSolver::Dense);
    assert_eq!(iter.solver, SpectrumSolver::Iterative);
    let mut worst = 0.0f64;
    for (a, b) in dense.values.iter().zip(&iter.values) {
        worst = worst.max((a - b).abs() / a.max(dense.values[1]));
    }
    eprintln!(
        "n = {}: dense vs iterative max relative difference {worst:e}; dense residual {:e}",
        s.vertex_count(),
        dense.residuals.iter().copied().fold(0.0, f64::max)
    );
    assert!(worst < 1e-6, "eigenvalues differ by {worst}");
    let (hd, hi) = (
        heat_kernel_signature(&dense, &HksParams::default()).unwrap(),
        heat_kernel_signature(&iter, &HksParams::default()).unwrap(),
    );
    for (a, b) in hd.values.iter().zip(&hi.values) {
        assert!((a - b).abs() < 1e-6 * a.abs(), "HKS differs: {a} vs {b}");
    }
}

#[test]
fn iterative_result_is_identical_on_one_and_two_threads() {
    let s = ellipsoid(16, 1.0);
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                laplace_spectrum(&s, &params(30, SpectrumSolver::Iterative), &Control::new())
                    .unwrap()
            })
    };
    let (one, two) = (run(1), run(2));
    assert_eq!(one.values, two.values);
    assert_eq!(one.vectors, two.vectors);
    assert_eq!(one.operator_applications, two.operator_applications);
}

#[test]
fn cancellation_and_invalid_parameters_are_errors() {
    let s = icosphere(1.0, 8);
    let control = Control::new();
    control.cancel();
    let r = laplace_spectrum(&s, &params(10, SpectrumSolver::Iterative), &control);
    assert!(matches!(r, Err(GeometryError::Cancelled(_))), "{r:?}");
    for bad in [
        params(0, SpectrumSolver::Auto),
        params(s.vertex_count(), SpectrumSolver::Auto),
        SpectrumParams {
            shift: 0.0,
            ..params(10, SpectrumSolver::Auto)
        },
    ] {
        let r = laplace_spectrum(&s, &bad, &Control::new());
        assert!(
            matches!(r, Err(GeometryError::InvalidParam { .. })),
            "{r:?}"
        );
    }
    let spec = laplace_spectrum(&s, &params(10, SpectrumSolver::Auto), &Control::new()).unwrap();
    let zero_times = HksParams {
        times: 0,
        ..Default::default()
    };
    assert!(heat_kernel_signature(&spec, &zero_times).is_err());
}

fn peak_memory_kib() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// `cargo test --release --no-default-features --test engine spectra::bench_ -- --ignored --nocapture`
#[test]
#[ignore = "benchmark: run with --release --ignored"]
fn bench_hks_64k_vertices() {
    let s = icosphere(1.0, 80);
    // k = 100 (complete multiplets l = 0..9 on a sphere), block size 8, tolerance 1e-10.
    let p = SpectrumParams::default();
    let mut times = Vec::new();
    let mut last = None;
    for _ in 0..3 {
        let t = Instant::now();
        let spec = laplace_spectrum(&s, &p, &Control::new()).unwrap();
        let t_eig = t.elapsed().as_secs_f64();
        let hks = heat_kernel_signature(&spec, &HksParams::default()).unwrap();
        let total = t.elapsed().as_secs_f64();
        eprintln!(
            "n = {}, k = {}: eigenpairs {t_eig:.2} s, + HKS(8) {total:.2} s; {} solves, {} \
             restarts, converged {}, max residual {:e}",
            s.vertex_count(),
            spec.len(),
            spec.operator_applications,
            spec.restarts,
            spec.converged,
            spec.residuals.iter().copied().fold(0.0, f64::max)
        );
        times.push(total);
        last = Some((spec, hks));
    }
    times.sort_by(f64::total_cmp);
    let (spec, _) = last.unwrap();
    assert!(spec.converged);
    eprintln!(
        "median {:.2} s, peak memory (VmHWM) {:?} KiB, threads {}",
        times[times.len() / 2],
        peak_memory_kib(),
        rayon::current_num_threads()
    );
}
