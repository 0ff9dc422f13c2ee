#!/usr/bin/env python3
"""Fails when Cargo.toml's `rust-version` is lower than a locked dependency's `rust_version`.

Usage: python3 scripts/check_msrv.py [--target TRIPLE ...]

Reads `cargo metadata --format-version 1 --filter-platform TRIPLE` (versions from Cargo.lock)
for each target (default: the Linux, macOS and Windows x86_64 / aarch64 triples), takes the largest
`rust_version` over the packages of the resolve graph, i.e. the ones that can be built for that
target. Packages that only enter the lock file through a `cfg(...)` that no build sets (faer's
`spindle` pulls in `loom` -> `generator` -> `windows-*` under `cfg(loom)`) are not in that graph
and do not count. Exit status: 0 when the declared version is high enough, 1 when it is not,
2 when the metadata cannot be read. Standard library only.
"""

import json
import os
import subprocess
import sys

DEFAULT_TARGETS = [
    "x86_64-unknown-linux-gnu",
    "aarch64-unknown-linux-gnu",
    "x86_64-apple-darwin",
    "aarch64-apple-darwin",
    "x86_64-pc-windows-msvc",
]


def parse_version(text):
    """'1.85' or '1.85.0' -> (1, 85, 0)."""
    parts = [int(p) for p in text.strip().split(".")]
    return tuple(parts + [0] * (3 - len(parts)))


def show(version):
    return ".".join(str(p) for p in version)


ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")


def metadata(target):
    # Not --locked: cargo takes the versions from Cargo.lock when there is one and only adds
    # what the manifest gained since (as the build itself will); without one it resolves the
    # newest compatible versions, the ones a first build would use.
    cmd = ["cargo", "metadata", "--format-version", "1", "--filter-platform", target,
           "--manifest-path", os.path.join(ROOT, "Cargo.toml")]
    out = subprocess.run(cmd, check=True, stdout=subprocess.PIPE, text=True).stdout
    return json.loads(out)


def main(argv):
    targets = []
    args = list(argv)
    while args:
        a = args.pop(0)
        if a == "--target" and args:
            targets.append(args.pop(0))
        else:
            print(__doc__.strip(), file=sys.stderr)
            return 2
    targets = targets or DEFAULT_TARGETS

    if not os.path.exists(os.path.join(ROOT, "Cargo.lock")):
        print("check_msrv: no Cargo.lock: checking the versions cargo resolves now",
              file=sys.stderr)
    declared = None
    worst = {}  # target -> (version, "name version")
    for target in targets:
        try:
            meta = metadata(target)
        except (OSError, subprocess.CalledProcessError, json.JSONDecodeError) as e:
            print(f"check_msrv: cargo metadata for {target} failed: {e}", file=sys.stderr)
            return 2
        root = meta["resolve"]["root"]
        in_graph = {node["id"] for node in meta["resolve"]["nodes"]}
        for p in meta["packages"]:
            if p["id"] == root:
                if not p.get("rust_version"):
                    print("check_msrv: Cargo.toml has no rust-version", file=sys.stderr)
                    return 1
                declared = parse_version(p["rust_version"])
                continue
            if p["id"] not in in_graph or not p.get("rust_version"):
                continue
            v = parse_version(p["rust_version"])
            if target not in worst or v > worst[target][0]:
                worst[target] = (v, f"{p['name']} {p['version']}")

    needed = max(worst.values(), key=lambda w: w[0])
    status = 0
    for target in targets:
        v, who = worst[target]
        ok = declared >= v
        status |= 0 if ok else 1
        print(f"check_msrv: {target}: dependencies need Rust {show(v)} ({who})"
              f"{'' if ok else '  <-- above rust-version'}")
    if status:
        print(f"check_msrv: Cargo.toml says rust-version = \"{show(declared)}\", but the locked "
              f"dependencies need {show(needed[0])} ({needed[1]}): raise rust-version",
              file=sys.stderr)
    else:
        print(f"check_msrv: rust-version {show(declared)} >= {show(needed[0])} ({needed[1]}): ok")
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
