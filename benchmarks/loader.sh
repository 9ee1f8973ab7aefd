#!/usr/bin/env bash
# The training loaders of pointreggpt_data (issue 50): pairs/s in order, streaming into 0 and 2 DataLoader
# workers, random access into 0 and 2 workers (a uniformly shuffled sampler, and GroupShuffleSampler),
# streaming from a local S3 server (moto on 127.0.0.1), each against pyarrow's own read_row_group loop over
# the same files in the same run (benchmarks/peers/loader_peers.py says what each mode does).
#   benchmarks/loader.sh              20,000 pairs (SIZE; the dataset of benchmarks/scale.sh: no fill, the 400
#                                     redkitchen frames, 50 samples each, row groups of 16)
#   benchmarks/loader.sh 160000       the one-off run at 160,000 pairs (needs ~21 GB)
#   LOADER_PARTS="rowgroups" benchmarks/loader.sh   row groups of 1 2 4 8 16 rows (ROWS) at RG_SIZE (4000) pairs:
#                                     bytes, footer, `pointreggpt query` and DuckDB over the point lists, loaders
# LOADER_PARTS (default "local s3"): local, s3, rowgroups. Work folder: LOADER_BENCH_DIR (default: a temporary
# folder, removed); a dataset already there (ds<SIZE>, rg<N>) is reused, not rebuilt. The S3 part uploads the
# first S3_SHARDS (16: 4,096 pairs) committed shards to moto. RANDOM_LIMIT (default 4000) caps the random-access
# modes with a uniformly shuffled sampler (a row group decoded per pair: slow by design).
# Needs a release build (POINTREGGPT_BIN), the test peers (torch, moto, duckdb, pointreggpt_data) and the real
# data (POINTREGGPT_REAL_DATA).
set -euo pipefail
NAME="loader bench" KEEP=LOADER_BENCH_DIR
source "$(dirname "$0")/lib.sh"
SIZE="${1:-${SIZE:-20000}}"
PARTS=" ${LOADER_PARTS:-local s3} "
ROWS="${ROWS:-1 2 4 8 16}"
RG_SIZE="${RG_SIZE:-4000}"
S3_SHARDS="${S3_SHARDS:-16}"
RANDOM_LIMIT="${RANDOM_LIMIT:-4000}"
FRAMES=400
(( SIZE % FRAMES == 0 && RG_SIZE % FRAMES == 0 )) || { echo "loader bench: SIZE and RG_SIZE must be multiples of $FRAMES" >&2; exit 1; }
part() { [[ "$PARTS" == *" $1 "* ]]; }
PEERS=(benchmarks/peers/loader_peers.py)
build() { # out, pairs, extra --set arguments...
  [[ -f "$1/dataset.toml" && -d "$1/manifest" ]] && return 0
  local t; t=$(now)
  "$BIN" --threads 2 build pipelines/paper-3dmatch-classical.toml --set "source.path=$REAL" --set inpaint.method=none \
    --set select.every=1 --set "samples_per_frame=$(($2 / FRAMES))" "${@:3}" --out "$1" --no-progress > "$1.log" 2>&1
  echo "built $1: $(since "$t") s"
}
show() { # prints the JSON lines of loader_peers.py as a table row each
  "$PYTHON" -c '
import json, sys
for line in sys.stdin:
    r = json.loads(line)
    extra = ", ".join("%s %s" % (k, v) for k, v in r.items() if k not in ("mode", "pairs", "seconds", "pairs_per_s"))
    print("  %-10s %8.0f pairs/s  (%d pairs in %s s; %s)" % (r["mode"], r["pairs_per_s"], r["pairs"], r["seconds"], extra))'
}

echo "loader benchmark: $SIZE pairs, $(nproc) cores, load average $(cut -d' ' -f1-3 /proc/loadavg); parts:$PARTS"
echo "  pointreggpt_data $("$PYTHON" -c 'import pointreggpt_data, pyarrow, torch; print(pointreggpt_data.__version__, "pyarrow", pyarrow.__version__, "torch", torch.__version__)')"

if part local || part s3; then
  build "$W/ds$SIZE" "$SIZE"
  echo "dataset $W/ds$SIZE: $(ls "$W/ds$SIZE/manifest" | grep -c '^pairs-') shards, $(du -sm "$W/ds$SIZE/shards" | cut -f1) MB"
fi

if part local; then
  echo "local disk (peer = pyarrow's read_row_group loop; batch 8, collate; random_*: DataLoader(shuffle=True); group_*: GroupShuffleSampler):"
  "$PYTHON" "${PEERS[@]}" "$W/ds$SIZE" peer in_order stream_0 stream_2 group_0 group_2 | show
  "$PYTHON" "${PEERS[@]}" "$W/ds$SIZE" random_0 random_2 --limit "$RANDOM_LIMIT" | show
  echo "  only the clouds and the pose (fields=MINIMAL_FIELDS):"
  "$PYTHON" "${PEERS[@]}" "$W/ds$SIZE" peer stream_2 group_2 --fields minimal | show
fi

if part s3; then
  port=$("$PYTHON" -c "import socket; s = socket.socket(); s.bind(('127.0.0.1', 0)); print(s.getsockname()[1])")
  "$PYTHON" -m moto.server -H 127.0.0.1 -p "$port" > "$W/moto.log" 2>&1 &
  moto=$!
  trap 'kill $moto 2>/dev/null || true' EXIT
  for _ in $(seq 100); do curl -s -o /dev/null "http://127.0.0.1:$port/" && break; sleep 0.2; done
  export AWS_ENDPOINT_URL="http://127.0.0.1:$port" AWS_ACCESS_KEY_ID=testing AWS_SECRET_ACCESS_KEY=testing AWS_REGION=us-east-1 AWS_EC2_METADATA_DISABLED=true
  unset AWS_PROFILE AWS_SESSION_TOKEN
  t=$(now)
  "$PYTHON" - "$W/ds$SIZE" "$S3_SHARDS" <<'PY'
import os, sys, boto3
src, n = sys.argv[1], int(sys.argv[2])
s3 = boto3.client("s3")
s3.create_bucket(Bucket="bench")
entries = sorted(e for e in os.listdir(f"{src}/manifest") if e.startswith("pairs-"))[:n]
files = ["dataset.toml"] + [f"manifest/{e}" for e in entries]
import json
files += ["shards/" + json.load(open(f"{src}/manifest/{e}"))["file"] for e in entries]
for f in files:
    s3.upload_file(f"{src}/{f}", "bench", f"ds/{f}")
PY
  echo "S3 (moto on 127.0.0.1; the first $S3_SHARDS shards uploaded in $(since "$t") s):"
  url=s3://bench/ds
  "$PYTHON" "${PEERS[@]}" "$url" peer stream_0 stream_2 | show
  rm -rf "$W/s3cache"
  echo "  with cache_dir= (a local copy of each shard on first read): epoch 1 copies, epoch 2 reads the copies"
  "$PYTHON" "${PEERS[@]}" "$url" stream_2 --cache-dir "$W/s3cache" --repeat 2 | show
  echo "  random access: ranged reads of a row group per item (group_2: each group once), then through the local copies"
  "$PYTHON" "${PEERS[@]}" "$url" group_2 | show
  "$PYTHON" "${PEERS[@]}" "$url" random_2 --limit 1000 | show
  "$PYTHON" "${PEERS[@]}" "$url" group_2 --cache-dir "$W/s3cache" | show
  "$PYTHON" "${PEERS[@]}" "$url" random_2 --cache-dir "$W/s3cache" --limit "$RANDOM_LIMIT" | show
  kill "$moto" 2>/dev/null || true
fi

if part rowgroups; then
  echo "row groups ($RG_SIZE pairs per build; bytes of the shards; footer of one 256-row shard; query: mean target length over the point lists)"
  Q="select avg(array_length(target_points)) m from pairs"
  for g in $ROWS; do
    build "$W/rg$g" "$RG_SIZE" --set "output.row_group_rows=$g"
    footer=$("$PYTHON" -c "import pyarrow.parquet as pq, glob; print(pq.ParquetFile(sorted(glob.glob('$W/rg$g/shards/*.parquet'))[0]).metadata.serialized_size)")
    t=$(now); "$BIN" query "$W/rg$g" "$Q" --format csv > /dev/null; ours=$(since "$t")
    t=$(now); "$PYTHON" -c "import duckdb; duckdb.connect(config={'enable_progress_bar': False}).sql(\"select avg(len(target_points)) from read_parquet('$W/rg$g/shards/*.parquet')\").fetchall()"; duck=$(since "$t")
    echo "row_group_rows $g: $(du -sm "$W/rg$g/shards" | cut -f1) MB, footer $footer bytes, query $ours s (DuckDB over the files, a fresh process: $duck s)"
    "$PYTHON" "${PEERS[@]}" "$W/rg$g" peer stream_0 stream_2 group_2 | show
    "$PYTHON" "${PEERS[@]}" "$W/rg$g" random_0 random_2 --limit 1500 | show
  done
fi
