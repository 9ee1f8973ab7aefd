#!/usr/bin/env bash
# How `output.row_group_rows` trades random access against streaming, size and query time (issue 39): the
# same SIZE-pair build of the recommended generator (no fill, 400 redkitchen frames, shard_size 256) once per
# row-group size, each read by the training loaders (map-style in order and in a random order, streaming into
# 0 and 2 DataLoader workers) and by `pointreggpt query` over the point lists against DuckDB.
#   SIZE=4000 ROWS="8 16 32 64 128" benchmarks/row_groups.sh
# Needs a release build, the test peers (duckdb, deltalake, torch, pointreggpt_data) and the real data
# (POINTREGGPT_REAL_DATA). Work folder: ROW_GROUPS_BENCH_DIR (default: a temporary folder, removed).
set -euo pipefail
NAME="row-group bench" KEEP=ROW_GROUPS_BENCH_DIR
source "$(dirname "$0")/lib.sh"
SIZE="${SIZE:-4000}"
ROWS="${ROWS:-8 16 32 64 128}"  # not GROUPS: bash keeps the group ids there
(( SIZE % 400 == 0 )) || { echo "row-group bench: SIZE must be a multiple of 400" >&2; exit 1; }
Q="select avg(array_length(target_points)) m from pairs"

echo "row-group sizes: $SIZE pairs per build, $(nproc) cores; rates in pairs/s"
for g in $ROWS; do
  out="$W/rg$g"; rm -rf "$out"
  t=$(now)
  "$BIN" --threads 2 build pipelines/paper-3dmatch-classical.toml --set "source.path=$REAL" --set inpaint.method=none \
    --set select.every=1 --set "samples_per_frame=$((SIZE / 400))" --set "output.row_group_rows=$g" \
    --out "$out" --no-progress > /dev/null
  build=$(since "$t")
  t=$(now); "$BIN" query "$out" "$Q" --format csv > /dev/null; ours=$(since "$t")
  t=$(now); "$PYTHON" benchmarks/peers/scale_peers.py duckdb "$out" "$Q" > /dev/null; duck=$(since "$t")
  "$PYTHON" benchmarks/peers/scale_peers.py loaders "$out" | "$PYTHON" -c "
import json, sys
r = json.load(sys.stdin)
f = lambda k: '%.0f' % r[k]['pairs_per_s']
print('row_group_rows %4s: %s MB, build %s s; map in order %s, map random %s, streaming 0 workers %s, 2 workers %s; query over the point lists %s s (DuckDB %s s, ratio %.2f)' % (
    '$g', '$(du -sm "$out/shards" | cut -f1)', '$build', f('map_in_order'), f('map_random'), f('stream_0_workers'),
    f('stream_2_workers'), '$ours', '$duck', $ours / $duck))"
done
