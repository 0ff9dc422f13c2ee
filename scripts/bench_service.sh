#!/usr/bin/env bash
# Service benchmark (README "Service benchmarks"):
#  1. GET /v1/jobs/{id} throughput and latency with wrk while every worker is busy on long jobs
#     (ToyCar → ToyCar at texture_size 8192);
#  2. submission overhead of a ~20 MB GLB: upload → 202 (validated, stored, enqueued), with curl,
#     median of 5, idle workers;
#  3. the same polls with idle workers, and with 1,000 idle connections held open beside wrk's
#     (scripts/hold_connections.py).
# Usage: scripts/bench_service.sh [path/to/retex]   (default target/release/retex; needs wrk, curl)
set -euo pipefail
cd "$(dirname "$0")/.."
BIN="${1:-target/release/retex}"
ASSETS="${RETEX_SHARED_ASSETS:-../shared/assets}"
TOY="$ASSETS/perf_toy_car_khronos/glTF"
WORK="$(mktemp -d)"
trap 'kill "$PID" 2>/dev/null || true; wait "$PID" 2>/dev/null || true; rm -rf "$WORK"' EXIT

"$BIN" serve --addr 127.0.0.1:0 --data-dir "$WORK/data" --workers 2 --queue-len 64 >"$WORK/out" 2>"$WORK/log" &
PID=$!
for _ in $(seq 100); do grep -q listening "$WORK/out" && break; sleep 0.1; done
BASE="$(sed -n 's/^retex listening on //p' "$WORK/out")"
echo "server: $BASE (pid $PID)"

toycar_form() { # $1 = texture size
  local args=()
  for side in source target; do
    for f in "$TOY"/ToyCar.gltf "$TOY"/*.bin "$TOY"/*.png; do args+=(-F "$side=@$f;filename=$(basename "$f")"); done
  done
  echo "{\"version\":1,\"output\":{\"texture_size\":$1}}" >"$WORK/c$1.json"
  args+=(-F "constraints=@$WORK/c$1.json")
  printf '%s\n' "${args[@]}"
}

# A ~20 MB GLB: ToyCar with three 4096² baked textures.
BIG="$WORK/big.glb"
echo '{"version":1,"output":{"texture_size":4096}}' >"$WORK/c4096.json"
"$BIN" transfer --source "$TOY/ToyCar.gltf" --target "$TOY/ToyCar.gltf" --constraints "$WORK/c4096.json" --out "$BIG" --quiet
echo "big glb: $(stat -c %s "$BIG") bytes"

# 2. Submission overhead (idle workers): upload → 202.
echo '{"version":1,"output":{"texture_size":64}}' >"$WORK/c64.json"
times=()
for i in 1 2 3 4 5; do
  t=$(curl -s -o /dev/null -w '%{http_code} %{time_total}' -F "source=@$BIG" -F "target=@$ASSETS/src_spot_keenan/spot_textured_derived.glb" -F "constraints=@$WORK/c64.json" "$BASE/v1/jobs")
  times+=("${t#* }"); echo "submit $i: $t"
  # let the job finish so workers are idle for the next measurement
  sleep 4
done
printf '%s\n' "${times[@]}" | sort -n | sed -n 3p | awk '{printf "submission of a %.1f MB GLB (+ Spot target), median of 5: %.0f ms\n", '"$(stat -c %s "$BIG")"'/1e6, $1*1000}'

# 1. Busy workers: four slow jobs (two running, two queued), then wrk on one job document.
# 3a. Idle workers: polls of a finished job.
DONE_ID="$(curl -s -F "source=@$ASSETS/src_spot_keenan/spot_textured_derived.glb" -F "target=@$ASSETS/src_spot_keenan/spot_textured_derived.glb" -F "constraints=@$WORK/c64.json" "$BASE/v1/jobs" | sed 's/.*"id":"\([^"]*\)".*/\1/')"
sleep 4
echo "== idle workers"
wrk -t2 -c32 -d15s --latency "$BASE/v1/jobs/$DONE_ID"
# 3b. Idle workers, 1,000 idle connections open.
python3 scripts/hold_connections.py "$BASE" 1000 25 &
HOLD=$!
sleep 3
echo "== idle workers, 1000 idle connections open"
wrk -t2 -c32 -d15s --latency "$BASE/v1/jobs/$DONE_ID"
kill "$HOLD" 2>/dev/null || true; wait "$HOLD" 2>/dev/null || true

echo "== busy workers"
mapfile -t FORM < <(toycar_form 8192)
IDS=()
for i in 1 2 3 4; do
  IDS+=("$(curl -s "${FORM[@]}" "$BASE/v1/jobs" | sed 's/.*"id":"\([^"]*\)".*/\1/')")
done
sleep 3
curl -s "$BASE/metrics" | grep -E '^retex_workers_busy|^retex_queue_depth'
wrk -t2 -c32 -d15s --latency "$BASE/v1/jobs/${IDS[0]}"
curl -s "$BASE/metrics" | grep -E '^retex_workers_busy|^retex_queue_depth'
for id in "${IDS[@]}"; do curl -s -X POST "$BASE/v1/jobs/$id/cancel" >/dev/null; done
