#!/usr/bin/env bash
# Validates api/openapi.yaml with the PyPI openapi-spec-validator (in a throwaway venv).
# The Rust test tests/service/openapi.rs checks that the file matches the code.
set -euo pipefail
cd "$(dirname "$0")/.."
venv="${TMPDIR:-/tmp}/retex-oasv"
[ -x "$venv/bin/openapi-spec-validator" ] || { python3 -m venv "$venv" && "$venv/bin/pip" install -q openapi-spec-validator; }
"$venv/bin/openapi-spec-validator" api/openapi.yaml
