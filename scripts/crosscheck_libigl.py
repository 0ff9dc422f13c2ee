#!/usr/bin/env python3
"""Cross-check retex's cotan Laplacian, mass matrices and principal curvatures against libigl.

Runs the ignored Rust test `crosscheck_libigl_export` (tests/engine/geometry_core.rs), which writes
V, F, L (triplets), both mass matrices and the curvatures of an icosphere and two shared assets
(spot, koala_low_resolution) as .npy files, then compares them with libigl (PyPI `libigl`):

- L vs igl.cotmatrix: same sign convention (negative semi-definite, L_ij = (cot a + cot b)/2,
  L_ii = -sum_j L_ij). Tolerance: max |L - L_igl| <= 1e-9 * max |L_igl|.
- M vs igl.massmatrix (VORONOI = Meyer et al. mixed Voronoi, and BARYCENTRIC). Tolerance:
  max |M - M_igl| <= 1e-9 * max M_igl.
- Curvature vs igl.principal_curvature(V, F, radius=2). libigl fits quadrics over a ring
  neighbourhood (radius 2 is its smallest, closest to retex's one-ring) while retex averages
  per-face tensors (Rusinkiewicz 2004), so values differ by estimator, not by bug; both are
  positive on a sphere with outward normals (same sign convention). Tolerances on the assets:
  correlation of mean curvature H = (k1 + k2)/2 >= 0.9, median |H - H_igl| <= 0.15 * median
  |H_igl|, correlation of Gaussian curvature >= 0.85 and of k1 >= 0.9; maximum-curvature
  directions agree (median |d1 . d1_igl| >= 0.9) where both estimates are clearly anisotropic
  (k1 - k2 >= 0.5 * median |H|). On the icosphere (exact H = 1): retex median |H - 1| <= 0.01,
  libigl <= 0.1 (a sanity check of the comparison itself).

Usage: python3 scripts/crosscheck_libigl.py [--skip-export]
Environment: RETEX_CROSSCHECK_DIR (export folder, default target/crosscheck_libigl),
RETEX_CROSSCHECK_CARGO_ARGS (extra cargo args, e.g. "--no-default-features").
Exit status 1 when any check fails.
"""

import os
import shlex
import subprocess
import sys

import igl
import numpy as np
import scipy.sparse as sp

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OUT = os.environ.get("RETEX_CROSSCHECK_DIR", os.path.join(ROOT, "target", "crosscheck_libigl"))
MESHES = ["icosphere", "spot", "koala_low"]


def export():
    extra = shlex.split(os.environ.get("RETEX_CROSSCHECK_CARGO_ARGS", ""))
    cmd = ["cargo", "test", "--release", *extra, "--test", "engine",
           "geometry_core::crosscheck_libigl_export", "--", "--ignored", "--exact"]
    env = dict(os.environ, RETEX_CROSSCHECK_DIR=OUT)
    subprocess.run(cmd, cwd=ROOT, env=env, check=True)


def load(mesh, name):
    return np.load(os.path.join(OUT, mesh, name + ".npy"))


def check(failures, ok, label, detail):
    print(("PASS " if ok else "FAIL ") + label + ": " + detail)
    if not ok:
        failures.append(label)


def compare_mesh(mesh, failures):
    V, F = load(mesh, "V"), load(mesh, "F")
    n = V.shape[0]
    L = sp.csc_matrix((load(mesh, "L_vals"), (load(mesh, "L_rows"), load(mesh, "L_cols"))),
                      shape=(n, n))
    L_igl = igl.cotmatrix(V, F)
    scale = abs(L_igl).max()
    err = abs(L - L_igl).max()
    check(failures, err <= 1e-9 * scale, f"{mesh} cotmatrix",
          f"max |dL| = {err:.3e}, max |L_igl| = {scale:.3e}")

    for name, kind in [("M_voronoi", igl.MASSMATRIX_TYPE_VORONOI),
                       ("M_barycentric", igl.MASSMATRIX_TYPE_BARYCENTRIC)]:
        m = load(mesh, name)
        m_igl = igl.massmatrix(V, F, kind).diagonal()
        err = np.abs(m - m_igl).max()
        check(failures, err <= 1e-9 * m_igl.max(), f"{mesh} {name}",
              f"max |dM| = {err:.3e}, max M_igl = {m_igl.max():.3e}, sums {m.sum():.6f} / {m_igl.sum():.6f}")

    k1, k2 = load(mesh, "k_max"), load(mesh, "k_min")
    d1 = load(mesh, "dir_max")
    pd1, pd2, pv1, pv2, bad = igl.principal_curvature(V, F, 2)
    good = np.ones(n, dtype=bool)
    good[list(bad)] = False
    h, h_igl = 0.5 * (k1 + k2), 0.5 * (pv1 + pv2)
    if mesh == "icosphere":
        e_ours, e_igl = np.median(np.abs(h - 1)), np.median(np.abs(h_igl - 1))
        check(failures, e_ours <= 0.01 and e_igl <= 0.1, f"{mesh} exact H = 1",
              f"median |H - 1|: retex {e_ours:.2e}, igl {e_igl:.2e}")
        return
    corr = np.corrcoef(h[good], h_igl[good])[0, 1]
    rel = np.median(np.abs(h - h_igl)[good]) / np.median(np.abs(h_igl[good]))
    check(failures, corr >= 0.9 and rel <= 0.15, f"{mesh} mean curvature",
          f"corr {corr:.3f}, median |dH| / median |H_igl| = {rel:.3f} ({(~good).sum()} igl-bad vertices skipped)")
    corr_k = np.corrcoef((k1 * k2)[good], (pv1 * pv2)[good])[0, 1]
    corr_1 = np.corrcoef(k1[good], pv1[good])[0, 1]
    check(failures, corr_k >= 0.85 and corr_1 >= 0.9, f"{mesh} Gaussian and k1",
          f"corr K {corr_k:.3f}, corr k1 {corr_1:.3f}")
    med = np.median(np.abs(h[good]))
    aniso = good & (k1 - k2 >= 0.5 * med) & (pv1 - pv2 >= 0.5 * med)
    align = np.abs(np.sum(d1 * pd1, axis=1))[aniso]
    check(failures, aniso.sum() > 0 and np.median(align) >= 0.9, f"{mesh} max direction",
          f"median |d1 . d1_igl| = {np.median(align):.3f} over {aniso.sum()} anisotropic vertices")


def main():
    if "--skip-export" not in sys.argv:
        export()
    failures = []
    for mesh in MESHES:
        compare_mesh(mesh, failures)
    if failures:
        print(f"{len(failures)} check(s) failed: {', '.join(failures)}")
        sys.exit(1)
    print("all libigl cross-checks passed")


if __name__ == "__main__":
    main()
