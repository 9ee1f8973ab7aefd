# Shared by the shell benchmarks: the repository root as working folder, the binary, Python, the real
# data, timing helpers and a work folder. Source it after `set -euo pipefail`, with NAME (for messages)
# and KEEP (the variable holding a folder to keep the work in) set.
cd "$(dirname "${BASH_SOURCE[0]}")/.."
ROOT="$(pwd)"
BIN="${POINTREGGPT_BIN:-$ROOT/target/release/pointreggpt}"
PYTHON="${PYTHON:-python3}"
REAL="${POINTREGGPT_REAL_DATA:-../shared/realdata}/7scenes-redkitchen"
[ -d "$REAL" ] || { echo "$NAME: no real data at $REAL (set POINTREGGPT_REAL_DATA)" >&2; exit 1; }
if [[ -n "${!KEEP:-}" ]]; then W="${!KEEP}"; else W="$(mktemp -d)"; trap 'rm -rf "$W"' EXIT; fi
mkdir -p "$W"
now() { date +%s.%N; }
since() { awk -v a="$(now)" -v b="$1" 'BEGIN { printf "%.2f", a - b }'; }
