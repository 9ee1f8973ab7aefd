#!/usr/bin/env bash
# The fill benchmark (issue 17): our fills and the classical peers a practitioner would pick, scored on
# exactly the same held-out real views, in one run. For each gap (10, 40, 120 frames: 24-82 % of a view
# unknown, the build's hole sizes), `pointreggpt eval inpaint` makes the views of 7-Scenes redkitchen
# whose target frame is 300-399 (held out from every training and tuning), scores our fills and dumps the
# views; benchmarks/peers/fill_peers.py scores OpenCV Navier-Stokes and Telea, scipy nearest pixel and
# IP-Basic on the dumped views and prints one table per gap and correction (none, min-pool) with ratios.
# Gap 120 has no source frame in 300-399 with a target in the data, so its sources are 180-279 (targets
# 300-399). Needs a release build (`cargo build --release --bins`) and the bench peers installed.
set -euo pipefail
cd "$(dirname "$0")/.."
REAL="${POINTREGGPT_REAL_DATA:-../shared/realdata}/7scenes-redkitchen"
PYTHON="${PYTHON:-python3}"
BIN="${POINTREGGPT_BIN:-target/release/pointreggpt}"
OUT="${FILL_BENCH_DIR:-$(mktemp -d)}"
VIEWS="${FILL_BENCH_VIEWS:-30}"
[ -d "$REAL" ] || { echo "fill bench: no real data at $REAL (set POINTREGGPT_REAL_DATA)" >&2; exit 1; }
for spec in "10 300 3" "40 300 2" "120 180 3"; do
  read -r gap first every <<<"$spec"
  "$BIN" eval inpaint "$REAL" --gap "$gap" --first "$first" --every "$every" --max-views "$VIEWS" \
    --diffusion models/diffusion-tiny-holes.safetensors --steps 1 --start-step 0 --eta 0 \
    --quiet --out "$OUT/ours-$gap.csv" --dump-views "$OUT/views-$gap" > "$OUT/ours-$gap.txt"
  for corr in none min_pool; do
    "$PYTHON" benchmarks/peers/fill_peers.py --views "$OUT/views-$gap/$corr" --ours "$OUT/ours-$gap.csv" \
      --label "gap $gap" --csv "$OUT/peers-$gap-$corr.csv"
    echo
  done
done
