#!/usr/bin/env bash
# The whole path at size (issue 39): build SIZE pairs of the recommended generator (no fill) from the 400
# redkitchen frames, a SIGKILL at ~90 % and the resume, verify, publish, the Delta table read by deltalake
# and Polars, three queries by `pointreggpt query` against DuckDB on the same table, export of everything
# in the GeoTransformer layout, the training loaders, and the same build as 8 workers into one folder and
# into a local S3 server (moto on 127.0.0.1).
# Prints one line per step with seconds, rates and ratios against the peers measured in the same run.
#   SIZE=20000 benchmarks/scale.sh        (default 20000; the peak RSS is also taken at SIZE/10)
#   SIZE=160000 SCALE_PARTS="build resume verify delta query loaders" benchmarks/scale.sh
#                                         (the one-off run at the paper's size: the parts that fit one disk)
# SCALE_PARTS (default: every part) picks among build scene resume kill verify delta query export loaders
# array s3; every part after `build` reads the dataset it made (kept in SCALE_BENCH_DIR between runs).
# `scene` builds the same units with the scene-made targets (`scene` correction and fill, fallback min-pool
# and no fill) and prints its pairs/s against the no-fill build of the same run (issue 49: at least half).
# Needs a release build, the test peers (deltalake, polars, duckdb, torch, moto, pointreggpt_data) and the
# real data (POINTREGGPT_REAL_DATA). Work folder: SCALE_BENCH_DIR (default: a temporary folder, removed).
set -euo pipefail
NAME="scale bench" KEEP=SCALE_BENCH_DIR
source "$(dirname "$0")/lib.sh"
SIZE="${SIZE:-20000}"
PARTS=" ${SCALE_PARTS:-build scene resume kill verify delta query export loaders array s3} "
FRAMES=400
(( SIZE % FRAMES == 0 )) || { echo "scale bench: SIZE must be a multiple of $FRAMES" >&2; exit 1; }
part() { [[ "$PARTS" == *" $1 "* ]]; }
SETS=(--set "source.path=$REAL" --set inpaint.method=none --set select.every=1 --set "samples_per_frame=$((SIZE / FRAMES))")
# SCALE_SHARD_SIZE replaces the config's 256 (the test suite runs every part on 40 pairs in shards of 4, so
# that each of the 8 array workers has shards to commit: tests/suite/scripts.rs).
[[ -z "${SCALE_SHARD_SIZE:-}" ]] || SETS+=(--set "shard_size=$SCALE_SHARD_SIZE")
CONFIG="$ROOT/pipelines/paper-3dmatch-classical.toml"
rss_mb() { awk '/Maximum resident set size/ {printf "%.0f", $6 / 1024}' "$1"; }
build() { "$BIN" --threads "${2:-2}" build "$CONFIG" "${SETS[@]}" --out "$1" --no-progress --no-publish "${@:3}"; }
committed() { ls "$1/manifest" 2>/dev/null | grep -c '^pairs-' || true; }
rows() { "$BIN" query "$1" "select unit_index, status, overlap_source, array_length(source_points) n, array_length(target_points) m from pairs order by unit_index" --format csv | md5sum | cut -c1-12; }

echo "scale benchmark: $SIZE pairs ($((SIZE / FRAMES)) samples of each of $FRAMES redkitchen frames), $(nproc) cores; parts:$PARTS"
if part build; then
  rm -rf "$W"/{small,ds,killed,array,gt}*
  small=$((SIZE / 10 / FRAMES)); (( small > 0 )) || small=1
  /usr/bin/time -v "$BIN" --threads 2 build "$CONFIG" "${SETS[@]}" --set "samples_per_frame=$small" --out "$W/small" \
    --no-progress --no-publish > "$W/small.log" 2> "$W/small.time"
  rm -rf "$W/small"   # only its peak RSS is wanted; at 160,000 pairs the disk is needed for the big one
  /usr/bin/time -v "$BIN" --threads 2 build "$CONFIG" "${SETS[@]}" --out "$W/ds" --no-progress --no-publish > "$W/ds.log" 2> "$W/ds.time"
  echo "build: $(grep -o '[0-9.]* pairs/s' "$W/ds.log"), $(grep -o 'time [0-9.]* s' "$W/ds.log"); peak RSS $(rss_mb "$W/small.time") MB at $((small * FRAMES)) pairs, $(rss_mb "$W/ds.time") MB at $SIZE; $(committed "$W/ds") shards, $(du -sm "$W/ds/shards" | cut -f1) MB"
  grep -E '^(ingest|pose|reproject|correct|inpaint|voxelize|validate|pack|sink)' "$W/ds.log" | sed 's/^/  /'
fi
[[ -d "$W/ds/manifest" ]] || { echo "scale bench: no dataset at $W/ds: run the build part first" >&2; exit 1; }

if part scene; then # the scene-made targets on the same units: one fusion per 30 source frames
  rm -rf "$W/scene"
  SCENE=(--set 'correct.condition={ method = "scene", margin = 0.05, fallback = { method = "min_pool", threshold = 0.0375 } }'
    --set 'correct.output={ method = "scene", margin = 0.05, fallback = { method = "min_pool", threshold = 0.0375 } }'
    --set 'inpaint={ method = "scene", fallback = { method = "none" } }')
  /usr/bin/time -v "$BIN" --threads 2 build "$CONFIG" "${SETS[@]}" "${SCENE[@]}" --out "$W/scene" --no-progress --no-publish > "$W/scene.log" 2> "$W/scene.time"
  nofill=$(grep -o '[0-9.]* pairs/s' "$W/ds.log" | cut -d' ' -f1); scene=$(grep -o '[0-9.]* pairs/s' "$W/scene.log" | cut -d' ' -f1)
  echo "scene build: $scene pairs/s, $(grep -o 'scenes fused [0-9]*' "$W/scene.log"), peak RSS $(rss_mb "$W/scene.time") MB; $(awk -v a="$scene" -v b="$nofill" 'BEGIN { printf "%.2f", a / b }') x the no-fill build's $nofill pairs/s (target >= 0.5)"
  grep -E '^(ingest|pose|reproject|scene|correct|inpaint|voxelize|validate|pack|sink)' "$W/scene.log" | sed 's/^/  /'
  rm -rf "$W/scene"
fi
shards=$(committed "$W/ds")

if part resume; then
  t=$(now); build "$W/ds" > /dev/null; echo "resume with nothing to do: $(since "$t") s"
fi

if part kill; then # a SIGKILL once ~90 % of the shards are committed, then the resume
  rm -rf "$W/killed"
  build "$W/killed" > /dev/null 2>&1 &
  pid=$!
  until (( $(committed "$W/killed") >= shards * 9 / 10 )); do
    kill -0 "$pid" 2>/dev/null || break
    sleep 0.2
  done
  kill -9 "$pid" 2>/dev/null || true; wait "$pid" 2>/dev/null || true
  before=$(committed "$W/killed")
  t=$(now); build "$W/killed" > "$W/killed.log"
  (( before < shards )) || echo "  (the build ended before the kill: at this SIZE it is too short to interrupt)"
  echo "SIGKILL with $before of $shards shards committed; resume: $(since "$t") s ($(grep -o '[0-9]* committed now' "$W/killed.log"))"
  [[ "$(rows "$W/ds")" == "$(rows "$W/killed")" ]] \
    && echo "  the resumed dataset has the uninterrupted one's rows and points" || echo "  DIFFERENT from the uninterrupted build"
  rm -rf "$W/killed"
fi

if part verify; then
  t=$(now); "$BIN" --threads 2 verify "$W/ds" > /dev/null; echo "verify: $(since "$t") s"
fi

if part delta; then
  t=$(now); "$BIN" publish "$W/ds" > /dev/null; echo "publish: $(since "$t") s"
  "$PYTHON" benchmarks/peers/scale_peers.py delta "$W/ds" | sed 's/^/delta readers: /'
fi

if part query; then
  [[ -d "$W/ds/_delta_log" ]] || "$BIN" publish "$W/ds" > /dev/null
  Q1="select status, count(*) n from pairs group by status order by status"
  Q2="select floor(overlap_source * 10) / 10 bin, count(*) n from pairs group by bin order by bin"
  Q3="select avg(array_length(target_points)) m from pairs"
  for q in "$Q1" "$Q2" "$Q3"; do
    t=$(now); "$BIN" query "$W/ds" "$q" --format csv > /dev/null; ours=$(since "$t")
    t=$(now); peer=$("$PYTHON" benchmarks/peers/scale_peers.py duckdb "$W/ds" "$q"); theirs=$(since "$t")
    inner=$(echo "$peer" | "$PYTHON" -c "import json,sys; print('%.3f' % json.load(sys.stdin)[0]['s'])")
    echo "query \"$q\": ours $ours s, DuckDB over the Delta table $theirs s (both a fresh process; DuckDB's query alone $inner s), ours/DuckDB $(awk -v a="$ours" -v b="$theirs" 'BEGIN { printf "%.2f", a / b }')"
  done
fi

if part export; then
  rm -rf "$W/gt"
  t=$(now); "$BIN" --threads 2 export "$W/ds" --format geotransformer --out "$W/gt" --no-progress > /dev/null
  echo "export --format geotransformer: $(since "$t") s, $(du -sm "$W/gt" | cut -f1) MB"
  rm -rf "$W/gt"
fi

if part loaders; then
  "$PYTHON" benchmarks/peers/scale_peers.py loaders "$W/ds" | sed 's/^/loaders: /'
fi

array() { # out: the build as 8 workers of one thread each; prints the time, compares the rows
  local out=$1 i pids=()
  t=$(now)
  for i in 0 1 2 3 4 5 6 7; do
    build "$out" 1 --worker "$i" --workers 8 > "$W/array-$i.log" 2>&1 &
    pids+=($!)
  done
  wait "${pids[@]}" # not a bare `wait`: the S3 server runs in the background too
  echo "8 workers into $out: $(since "$t") s"
  [[ "$(rows "$W/ds")" == "$(rows "$out")" ]] && echo "  the committed rows equal the one-process build's" || echo "  rows DIFFER from the one-process build"
  t=$(now); build "$out" > /dev/null
  echo "  opening and resuming it ($shards shards, as many manifest records): $(since "$t") s"
}

if part array; then
  rm -rf "$W/array"
  array "$W/array"
  rm -rf "$W/array"
fi

if part s3; then # the same array into a local S3 server (moto, 127.0.0.1 only, explicit credentials)
  port=$("$PYTHON" -c "import socket; s = socket.socket(); s.bind(('127.0.0.1', 0)); print(s.getsockname()[1])")
  "$PYTHON" -m moto.server -H 127.0.0.1 -p "$port" > "$W/moto.log" 2>&1 &
  moto=$!
  for _ in $(seq 100); do curl -s -o /dev/null "http://127.0.0.1:$port/" && break; sleep 0.2; done
  curl -s -f -X PUT "http://127.0.0.1:$port/bench" > /dev/null
  export AWS_ENDPOINT_URL="http://127.0.0.1:$port" AWS_ACCESS_KEY_ID=testing AWS_SECRET_ACCESS_KEY=testing AWS_REGION=us-east-1
  unset AWS_PROFILE AWS_SESSION_TOKEN
  array s3://bench/array
  kill "$moto"; wait "$moto" 2>/dev/null || true
fi
