#!/usr/bin/env bash
# The whole path at size (issue 39): build SIZE pairs of the recommended generator (no fill) from the 400
# redkitchen frames, a SIGKILL at ~90 % and the resume, verify, publish, the Delta table read by deltalake
# and Polars, three queries by `pointreggpt query` against DuckDB on the same table, export of everything
# in the GeoTransformer layout, the training loaders, and the same build as 8 workers into one folder.
# Prints one line per step with seconds, rates and ratios against the peers measured in the same run.
#   SIZE=20000 benchmarks/scale.sh        (default 20000; the peak RSS is also taken at SIZE/10)
# Needs a release build, the test peers (deltalake, polars, duckdb, torch, pointreggpt_data) and the real
# data (POINTREGGPT_REAL_DATA). Work folder: SCALE_BENCH_DIR (default: a temporary folder, removed).
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT="$(pwd)"
BIN="${POINTREGGPT_BIN:-$ROOT/target/release/pointreggpt}"
PYTHON="${PYTHON:-python3}"
REAL="${POINTREGGPT_REAL_DATA:-../shared/realdata}/7scenes-redkitchen"
SIZE="${SIZE:-20000}"
[ -d "$REAL" ] || { echo "scale bench: no real data at $REAL (set POINTREGGPT_REAL_DATA)" >&2; exit 1; }
FRAMES=400
(( SIZE % FRAMES == 0 )) || { echo "scale bench: SIZE must be a multiple of $FRAMES" >&2; exit 1; }
if [[ -n "${SCALE_BENCH_DIR:-}" ]]; then W="$SCALE_BENCH_DIR"; else W="$(mktemp -d)"; trap 'rm -rf "$W"' EXIT; fi
rm -rf "$W"/{small,ds,killed,array,gt}*; mkdir -p "$W"
SETS=(--set "source.path=$REAL" --set inpaint.method=none --set select.every=1)
CONFIG="$ROOT/pipelines/paper-3dmatch-classical.toml"
now() { date +%s.%N; }
since() { awk -v a="$(now)" -v b="$1" 'BEGIN { printf "%.2f", a - b }'; }
rss_mb() { awk '/Maximum resident set size/ {printf "%.0f", $6 / 1024}' "$1"; }

build() { # out samples_per_frame [extra...]: timed build, prints pairs/s and peak RSS
  local out=$1 spf=$2; shift 2
  /usr/bin/time -v "$BIN" --threads 2 build "$CONFIG" "${SETS[@]}" --set "samples_per_frame=$spf" \
    --out "$out" --no-progress --no-publish "$@" > "$out.log" 2> "$out.time"
}

echo "scale benchmark: $SIZE pairs ($((SIZE / FRAMES)) samples of each of $FRAMES redkitchen frames), $(nproc) cores"
small=$((SIZE / 10 / FRAMES)); (( small > 0 )) || small=1
build "$W/small" "$small"
build "$W/ds" "$((SIZE / FRAMES))"
shards=$(ls "$W/ds/manifest" | grep -c '^pairs-')
echo "build: $(grep -o '[0-9.]* pairs/s' "$W/ds.log"), $(grep -o 'time [0-9.]* s' "$W/ds.log"); peak RSS $(rss_mb "$W/small.time") MB at $((small * FRAMES)) pairs, $(rss_mb "$W/ds.time") MB at $SIZE; $shards shards, $(du -sm "$W/ds/shards" | cut -f1) MB"
grep -E '^(ingest|pose|reproject|correct|inpaint|voxelize|validate|pack|sink)' "$W/ds.log" | sed 's/^/  /'

t=$(now); "$BIN" --threads 2 build "$CONFIG" "${SETS[@]}" --set "samples_per_frame=$((SIZE / FRAMES))" --out "$W/ds" --no-progress --no-publish > /dev/null
echo "resume with nothing to do: $(since "$t") s"

# A SIGKILL once ~90 % of the shards are committed, then the resume.
"$BIN" --threads 2 build "$CONFIG" "${SETS[@]}" --set "samples_per_frame=$((SIZE / FRAMES))" --out "$W/killed" --no-progress --no-publish > /dev/null 2>&1 &
pid=$!
until [[ -d "$W/killed/manifest" ]] && (( $(ls "$W/killed/manifest" | grep -c '^pairs-') >= shards * 9 / 10 )); do
  kill -0 "$pid" 2>/dev/null || break
  sleep 0.2
done
kill -9 "$pid" 2>/dev/null || true; wait "$pid" 2>/dev/null || true
before=$(ls "$W/killed/manifest" | grep -c '^pairs-')
t=$(now); "$BIN" --threads 2 build "$CONFIG" "${SETS[@]}" --set "samples_per_frame=$((SIZE / FRAMES))" --out "$W/killed" --no-progress --no-publish > "$W/killed.log"
(( before < shards )) || echo "  (the build ended before the kill: at this SIZE it is too short to interrupt)"
echo "SIGKILL with $before of $shards shards committed; resume: $(since "$t") s ($(grep -o '[0-9]* committed now' "$W/killed.log"))"
same=$("$BIN" query "$W/ds" "select count(*) n, sum(array_length(target_points)) p from pairs" --format csv)
[[ "$same" == "$("$BIN" query "$W/killed" "select count(*) n, sum(array_length(target_points)) p from pairs" --format csv)" ]] \
  && echo "  the resumed dataset has the uninterrupted one's rows and points" || echo "  DIFFERENT from the uninterrupted build"

t=$(now); "$BIN" --threads 2 verify "$W/ds" > /dev/null; echo "verify: $(since "$t") s"
t=$(now); "$BIN" publish "$W/ds" > /dev/null; echo "publish: $(since "$t") s"
"$PYTHON" benchmarks/peers/scale_peers.py delta "$W/ds" | sed 's/^/delta readers: /'

Q1="select status, count(*) n from pairs group by status order by status"
Q2="select floor(overlap_source * 10) / 10 bin, count(*) n from pairs group by bin order by bin"
Q3="select avg(array_length(target_points)) m from pairs"
for q in "$Q1" "$Q2" "$Q3"; do
  t=$(now); "$BIN" query "$W/ds" "$q" --format csv > /dev/null; ours=$(since "$t")
  t=$(now); peer=$("$PYTHON" benchmarks/peers/scale_peers.py duckdb "$W/ds" "$q"); theirs=$(since "$t")
  inner=$(echo "$peer" | "$PYTHON" -c "import json,sys; print('%.3f' % json.load(sys.stdin)[0]['s'])")
  echo "query \"$q\": ours $ours s, DuckDB over the Delta table $theirs s (both a fresh process; DuckDB's query alone $inner s), ours/DuckDB $(awk -v a="$ours" -v b="$theirs" 'BEGIN { printf "%.2f", a / b }')"
done

t=$(now); "$BIN" --threads 2 export "$W/ds" --format geotransformer --out "$W/gt" --no-progress > /dev/null
echo "export --format geotransformer: $(since "$t") s, $(du -sm "$W/gt" | cut -f1) MB"
"$PYTHON" benchmarks/peers/scale_peers.py loaders "$W/ds" | sed 's/^/loaders: /'

# The same build as an array of 8 workers into one folder.
t=$(now)
for i in 0 1 2 3 4 5 6 7; do
  "$BIN" --threads 1 build "$CONFIG" "${SETS[@]}" --set "samples_per_frame=$((SIZE / FRAMES))" --out "$W/array" --no-progress \
    --no-publish --worker "$i" --workers 8 > "$W/array-$i.log" 2>&1 &
done
wait
echo "8 workers into one folder: $(since "$t") s"
rows() { "$BIN" query "$1" "select unit_index, status, overlap_source, array_length(source_points) n, array_length(target_points) m from pairs order by unit_index" --format csv | md5sum | cut -c1-12; }
[[ "$(rows "$W/ds")" == "$(rows "$W/array")" ]] && echo "  the committed rows equal the one-process build's" || echo "  rows DIFFER from the one-process build"
t=$(now); "$BIN" --threads 2 build "$CONFIG" "${SETS[@]}" --set "samples_per_frame=$((SIZE / FRAMES))" --out "$W/array" --no-progress --no-publish > /dev/null
echo "  opening and resuming the array's dataset ($shards shards, as many manifest records): $(since "$t") s"
