#!/usr/bin/env python3
"""Side-by-side UV atlases (issue 15): retex's atlas, xatlas (PyPI `xatlas`) and PyMeshLab's
Voronoi atlas (PyPI `pymeshlab`, `generate_voronoi_atlas_parametrization`) on the shared UV-less
targets: time, charts, L2 stretch, packing efficiency and seam length, one Markdown table.

    pip install xatlas trimesh pymeshlab numpy
    python3 scripts/atlas_compare.py --assets ../shared/assets --retex target/release/retex

Every peer runs in its own subprocess (xatlas' Python build segfaults on some closed meshes;
a crash there is reported as such, never taken for a result). The measures are computed here
the same way for the peers, from per-corner UVs:

* L2 stretch: Sander et al. 2001, the area-weighted RMS of sqrt((G^2 + g^2) / 2) over the
  triangles, after scaling all UVs so that the atlas's total UV area equals the surface area
  (Sander's normalisation); triangles with non-positive UV area (mirrored or collapsed) are left
  out and counted.
* packing: total UV-triangle area inside the unit square (1 = the whole texture used).
* seam length: total 3-D length of the edges on which two faces give either endpoint a
  different UV (each edge once), divided by the bounding-box diagonal.
* charts: face components joined across edges where the faces' UVs agree.
* PyMeshLab's Voronoi atlas returns a new layer with more faces than the input (faces along
  region borders are duplicated; `faces` in its row); the measures are taken on that layer.

retex's figures come from its own report (`atlas` in report.json of `retex transfer`, Spot onto
the target, default constraints: 2048^2, padding 4): its time is the sum of the `atlas_*`
stages. Peer times are the wall time of the atlas call alone (not loading).
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

TARGETS = [
    ("cat", "tgt_cat_odedstein/cat-low-resolution.obj", "tgt_cat_odedstein/cat-low-resolution_derived.glb"),
    ("fish", "tgt_fish_remeshed_odedstein/fish.obj", "tgt_fish_remeshed_odedstein/fish_derived.glb"),
    ("Demosthenes (bust scan, open)", "tgt_demosthenes_bust_odedstein/demosthenes-low-res.obj",
     "tgt_demosthenes_bust_odedstein/demosthenes-low-res_derived.glb"),
    ("Nefertiti (bust scan)", "tgt_nefertiti_bust_odedstein/nefertiti-lowres.obj",
     "tgt_nefertiti_bust_odedstein/nefertiti-lowres_derived.glb"),
    ("koala", "perf_koala_odedstein/koala.obj", "perf_koala_odedstein/koala_derived.glb"),
    ("skull (genus 2)", "perf_skull_odedstein/skull.obj", "perf_skull_odedstein/skull_derived.glb"),
]
SOURCE = "src_spot_keenan/spot_textured_derived.glb"


def measures(positions, faces, corner_uv):
    """positions (V,3), faces (F,3) original vertex ids, corner_uv (F,3,2) -> dict."""
    import numpy as np

    p = positions[faces]  # F,3,3
    q = corner_uv.astype(np.float64)
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    area3 = 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)
    d1, d2 = q[:, 1] - q[:, 0], q[:, 2] - q[:, 0]
    area2 = 0.5 * (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
    ok = area2 > 0
    packing = float(np.abs(area2).sum())
    scale = np.sqrt(area3.sum() / np.abs(area2).sum())
    s, t = q[..., 0] * scale, q[..., 1] * scale
    a = area2 * scale * scale
    with np.errstate(divide="ignore", invalid="ignore"):
        ss = (p[:, 0] * (t[:, 1] - t[:, 2])[:, None] + p[:, 1] * (t[:, 2] - t[:, 0])[:, None]
              + p[:, 2] * (t[:, 0] - t[:, 1])[:, None]) / (2 * a[:, None])
        st = (p[:, 0] * (s[:, 2] - s[:, 1])[:, None] + p[:, 1] * (s[:, 0] - s[:, 2])[:, None]
              + p[:, 2] * (s[:, 1] - s[:, 0])[:, None]) / (2 * a[:, None])
        l2sq = 0.5 * ((ss * ss).sum(1) + (st * st).sum(1))
    l2 = float(np.sqrt((area3[ok] * l2sq[ok]).sum() / area3[ok].sum()))
    # Seams and charts.
    edges = {}
    for f in range(len(faces)):
        for k in range(3):
            a_, b_ = int(faces[f, k]), int(faces[f, (k + 1) % 3])
            key = (min(a_, b_), max(a_, b_))
            uv = {a_: tuple(q[f, k]), b_: tuple(q[f, (k + 1) % 3])}
            edges.setdefault(key, []).append((f, uv))
    parent = list(range(len(faces)))

    def find(x):
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    seam = 0.0
    for (a_, b_), lst in edges.items():
        # Faces agreeing on both endpoints' UVs are joined; an edge where any two faces
        # disagree is a seam (counted once). Boundary edges are no seams.
        split = False
        for i, (f, u) in enumerate(lst):
            for g, v in lst[i + 1:]:
                if u[a_] == v[a_] and u[b_] == v[b_]:
                    parent[find(f)] = find(g)
                else:
                    split = True
        if split:
            seam += float(np.linalg.norm(positions[a_] - positions[b_]))
    charts = len({find(f) for f in range(len(faces))})
    diag = float(np.linalg.norm(positions.max(0) - positions.min(0)))
    return {"charts": charts, "l2": l2, "packing": packing, "seams": seam / diag,
            "left_out": int((~ok).sum())}


def load_obj(path):
    import numpy as np
    import trimesh

    m = trimesh.load(path, process=False, force="mesh")
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


def run_xatlas(path):
    import numpy as np
    import xatlas

    v, f = load_obj(path)
    atlas = xatlas.Atlas()
    atlas.add_mesh(v.astype(np.float32), f.astype(np.uint32))
    opts = xatlas.PackOptions()
    opts.resolution = 2048
    opts.padding = 4
    t0 = time.perf_counter()
    atlas.generate(pack_options=opts)
    ms = (time.perf_counter() - t0) * 1e3
    vmap, idx, uvs = atlas[0]
    corner = uvs[idx]
    # xatlas' faces keep the input order; their corners map back through vmap.
    assert (vmap[idx] == f).all()
    out = measures(v, f, corner)
    out["ms"] = ms
    return out


def run_pymeshlab(path):
    import numpy as np
    import pymeshlab

    v, f = load_obj(path)
    ms_ = pymeshlab.MeshSet()
    ms_.add_mesh(pymeshlab.Mesh(v, f))
    t0 = time.perf_counter()
    ms_.generate_voronoi_atlas_parametrization()
    ms = (time.perf_counter() - t0) * 1e3
    # The filter adds a layer (the mesh cut along the regions, with wedge UVs).
    m = next(ms_.mesh(i) for i in range(ms_.mesh_number()) if ms_.mesh(i).has_wedge_tex_coord())
    pv = m.vertex_matrix()
    pf = m.face_matrix()
    corner = m.wedge_tex_coord_matrix().reshape(-1, 3, 2)
    out_faces = len(pf)
    out = measures(pv, pf, corner)
    out["ms"] = ms
    out["faces"] = out_faces
    return out


def peer(kind, path):
    """Runs one peer in a subprocess; returns its dict or a string saying how it failed."""
    try:
        r = subprocess.run([sys.executable, __file__, "--one", kind, path],
                           capture_output=True, text=True, timeout=1800)
    except subprocess.TimeoutExpired:
        return "timeout (30 min)"
    if r.returncode != 0:
        tail = (r.stderr.strip().splitlines() or [""])[-1][:80]
        return f"exit {r.returncode}" + (f": {tail}" if tail else "")
    return json.loads(r.stdout.strip().splitlines()[-1])


def run_retex(retex, assets, glb):
    with tempfile.TemporaryDirectory() as d:
        cmd = [retex, "transfer", "--source", os.path.join(assets, SOURCE), "--target",
               os.path.join(assets, glb), "--out", os.path.join(d, "out.glb"),
               "--artifacts", d, "--quiet"]
        r = subprocess.run(cmd, capture_output=True, text=True)
        if r.returncode != 0:
            return f"exit {r.returncode}"
        rep = json.load(open(os.path.join(d, "report.json")))
    a = rep["method_report"]["atlas"] if "method_report" in rep else rep["atlas"]
    ms = sum(t["ms"] for t in rep["timings"] if t["stage"].startswith("atlas_"))
    return {"ms": ms, "charts": a["chart_count"], "l2": a["l2_stretch"],
            "packing": a["packing_efficiency"], "seams": None, "seam_length": a["seam_length"],
            "left_out": a["flipped"]}


def cell(r, diag=None):
    if isinstance(r, str):
        return f"{r} | | | | "
    seams = r["seams"] if r["seams"] is not None else (r["seam_length"] / diag if diag else float("nan"))
    return f"{r['ms']:,.0f} ms | {r['charts']} | {r['l2']:.3f} | {r['packing']:.2f} | {seams:.1f}"


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--assets", default="../shared/assets")
    ap.add_argument("--retex", default="target/release/retex")
    ap.add_argument("--one", nargs=2, help=argparse.SUPPRESS)
    ap.add_argument("--only", help="comma-separated target labels' first words")
    ap.add_argument("--retex-only", action="store_true", help="skip the peers")
    args = ap.parse_args()
    if args.one:
        kind, path = args.one
        print(json.dumps(run_xatlas(path) if kind == "xatlas" else run_pymeshlab(path)))
        return
    print("| target | tool | time | charts | L2 | packing | seams / diagonal |")
    print("|---|---|---|---|---|---|---|")
    for label, obj, glb in TARGETS:
        if args.only and label.split()[0].lower() not in args.only.lower().split(","):
            continue
        path = os.path.join(args.assets, obj)
        import numpy as np
        v, _ = load_obj(path)
        diag = float(np.linalg.norm(v.max(0) - v.min(0)))
        rows = [("retex", run_retex(args.retex, args.assets, glb))]
        if not args.retex_only:
            rows += [("xatlas", peer("xatlas", path)),
                     ("PyMeshLab Voronoi", peer("pymeshlab", path))]
        for tool, r in rows:
            print(f"| {label} | {tool} | {cell(r, diag)} |", flush=True)


if __name__ == "__main__":
    main()
