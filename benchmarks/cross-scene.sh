#!/usr/bin/env bash
# The cross-scene registration campaign of issue 37 (docs/lab/2026-12-06-cross-scene-plan.md and
# docs/lab/2026-12-06-cross-scene-registration.md): three fused-fragment benchmarks (redkitchen 250-399,
# ICL-NUIM 400-800, TUM cabinet key frames), six `eval boost` runs (trained on redkitchen 0-149 or on
# ICL-NUIM 0-299: A, A-drop, B), then the per-scene tables and the A-drop paired differences.
#
#   benchmarks/cross-scene.sh [OUT]      OUT defaults to out/cross-scene; SEEDS=3 for the plan's 3 seeds
#
# Resumable: rerun the same command (done units and benchmarks are skipped); a larger SEEDS on the same
# OUT trains only the missing seeds. Seed 0 of everything took ~5 h on 2 shared cores. Needs a release
# build (`make build`); the last step needs only a python3 (standard library).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT="${1:-out/cross-scene}"
SEEDS="${SEEDS:-1}"
RD="${POINTREGGPT_REAL_DATA:-../shared/realdata}"
BIN="${BIN:-target/release/pointreggpt}"
PY="${PYTHON:-python3}"
mkdir -p "$OUT"

frag() { # name sequence args...
  local name=$1 seq=$2; shift 2
  [[ -f "$OUT/$name.done" ]] && return
  rm -rf "$OUT/$name"   # a benchmark interrupted half-way is made again
  "$BIN" fragments "$RD/$seq" "$@" --out "$OUT/$name" && touch "$OUT/$name.done"
}
frag bench-R-report 7scenes-redkitchen --frames-per-fragment 25 --stride 10 --first 250 --frames 150
frag bench-I-report icl-nuim-livingroom --frames-per-fragment 25 --stride 20 --first 400 --frames 401
frag bench-T tum-fr3-cabinet-keyframes --frames-per-fragment 3 --stride 3

BENCH=("$OUT/bench-R-report" "$OUT/bench-I-report" "$OUT/bench-T")
COMMON=(--fragment-frames 25 --fragment-stride 5 --pairs 64 --steps 864 --samples 1000 --redraw --reference nofill
  --seeds "$SEEDS" --by-scene --quiet)
declare -A SEQ=([R]="$RD/7scenes-redkitchen@0-149" [I]="$RD/icl-nuim-livingroom@0-299")
for d in R I; do
  "$BIN" eval boost "${BENCH[@]}" "${COMMON[@]}" --sequence "${SEQ[$d]}" --source-frames fragment-starts \
    --conditions fpfh,frag,frag+nofill:8,frag+classical:8,frag+neural:8 \
    --compare frag+classical:8-frag+nofill:8,frag+neural:8-frag+nofill:8 --out "$OUT/$d-A"
  "$BIN" eval boost "${BENCH[@]}" "${COMMON[@]}" --sequence "${SEQ[$d]}" --source-frames every-frame \
    --conditions frag24,frag24+nofill:20,frag24+nofill-lo:20 --compare frag24+nofill-lo:20-frag24+nofill:20 --out "$OUT/$d-B"
  mkdir -p "$OUT/$d-A-drop"; [[ -e "$OUT/$d-A-drop/data" ]] || ln -s ../$d-A/data "$OUT/$d-A-drop/data"
  "$BIN" eval boost "${BENCH[@]}" "${COMMON[@]}" --sequence "${SEQ[$d]}" --source-frames fragment-starts \
    --conditions frag+classical:8 --drop-filled --out "$OUT/$d-A-drop"
done

# --drop-filled against the same pairs kept and against no-fill pairs: pair by pair across the two runs'
# scores, per benchmark and scene, Student t over the pairs of seed 0 (what eval boost prints per run).
"$PY" - "$OUT" <<'EOF'
import csv, glob, math, statistics, sys
T975 = {57: 2.002, 77: 1.991, 78: 1.991, 91: 1.986}
def load(path):
    f = sorted(glob.glob(path + "/scores-*.tsv"))[0]
    return {(r["benchmark"], r["scene"], r["i"], r["j"]): float(r["inlier_ratio"]) for r in csv.DictReader(open(f), delimiter="\t")}
out = sys.argv[1]
for d in "RI":
    drop = load(f"{out}/{d}-A-drop/frag_classical_8/seed-0")
    for base in ["frag_classical_8", "frag_nofill_8"]:
        ref = load(f"{out}/{d}-A/{base}/seed-0")
        groups = {}
        for k, v in drop.items():
            groups.setdefault(k[:2], []).append(100 * (v - ref[k]))
        for (bench, scene), xs in sorted(groups.items()):
            m, h = statistics.mean(xs), T975.get(len(xs) - 1, 1.98) * statistics.stdev(xs) / math.sqrt(len(xs))
            print(f"{d}-> drop-filled - {base:17s} {bench:9s} {scene:28s} {len(xs):3d} pairs {m:+.2f} [{m - h:+.2f}, {m + h:+.2f}]")
EOF
