//! Dataset statistics: rows by status (the reject reasons), the overlap histograms of the `ok` pairs (10
//! bins over [0, 1], `overlap_source` and `overlap_target`) and the rows by the path their target took
//! (the scene, or the single map), counted by SQL aggregates ([`counts_sql`], [`paths_sql`]) and shown
//! as a text table and a bar plot.

use super::canvas::{text_width, Canvas, Rgb};
use super::colormap::{BACKGROUND, TEXT};
use crate::error::{Error, Result};
use crate::shards::row::Status;
use arrow::array::{Array, Int64Array, RecordBatch, StringArray};
use arrow::compute::cast;
use arrow::datatypes::DataType;
use std::collections::BTreeMap;
use std::fmt::Write;

/// Histogram bins over [0, 1]: `[0.0, 0.1), …, [0.9, 1.0]`.
pub const BINS: usize = 10;
/// Every status, in table order.
pub const STATUSES: [Status; 4] = [Status::Ok, Status::LowOverlap, Status::TooFewPoints, Status::InputError];
/// The plot size, pixels.
pub const PLOT_SIZE: (u32, u32) = (1000, 420);

const SOURCE_BAR: Rgb = [70, 140, 245];
const TARGET_BAR: Rgb = [245, 150, 50];
const STATUS_BARS: [Rgb; 4] = [[60, 190, 90], [245, 170, 40], [170, 100, 230], [230, 60, 60]];
const AXIS: Rgb = [120, 120, 130];

/// The bin of an overlap value: `min(floor(10·v), 9)`, values below 0 (or NaN) in bin 0.
pub fn overlap_bin(v: f64) -> usize {
    if v.is_nan() || v <= 0.0 {
        0
    } else {
        ((v * BINS as f64).floor() as usize).min(BINS - 1)
    }
}

/// [`overlap_bin`] of `column` in SQL: NaN and values ≤ 0 in bin 0 (NaN first: DataFusion orders it
/// above every number), then `min(floor(10·v), 9)`.
fn bin_sql(column: &str) -> String {
    format!(
        "case when isnan({column}) or {column} <= 0 then 0 when {column} * 10 >= 9 then 9 \
         else cast(floor({column} * 10) as bigint) end"
    )
}

/// The aggregate `stats` runs over the `pairs` table: `scene, status, source_bin, target_bin, n`, the
/// rows per scene, status and pair of overlap bins, of the rows where `predicate` (SQL) holds.
pub fn counts_sql(predicate: Option<&str>) -> String {
    // The predicate stands on lines of its own, so a `--` comment at its end stops there.
    let filter = predicate.map_or(String::new(), |p| format!("where (\n{p}\n)\n"));
    format!(
        "select scene, status, source_bin, target_bin, count(*) as n from (\n\
         select scene, status, {} as source_bin, {} as target_bin from pairs\n{filter}) as binned\n\
         group by scene, status, source_bin, target_bin",
        bin_sql("overlap_source"),
        bin_sql("overlap_target")
    )
}

/// The path a unit's target took: `scene` (a `scene` method had the posed frames around its source
/// frame, `scene_frames > 0`) or `single-map` (the source depth map alone).
pub const PATHS: [&str; 2] = ["scene", "single-map"];

/// The aggregate of the rows per path ([`PATHS`]) and status, of the rows where `predicate` holds
/// (version-3 datasets; older ones have no scene).
pub fn paths_sql(predicate: Option<&str>) -> String {
    let filter = predicate.map_or(String::new(), |p| format!("where (\n{p}\n)\n"));
    format!(
        "select path, status, count(*) as n from (\n\
         select case when scene_frames > 0 then '{}' else '{}' end as path, status from pairs\n{filter}) as p\n\
         group by path, status",
        PATHS[0], PATHS[1]
    )
}

/// Counts over a set of rows.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Counts {
    /// Rows per status, in [`STATUSES`] order.
    pub by_status: [u64; 4],
    /// Histograms of `overlap_source` and `overlap_target` over the `ok` rows.
    pub hist_source: [u64; BINS],
    pub hist_target: [u64; BINS],
}

impl Counts {
    fn add(&mut self, status: Status, source_bin: usize, target_bin: usize, rows: u64) {
        self.by_status[STATUSES.iter().position(|s| *s == status).expect("every status is listed")] += rows;
        if status == Status::Ok {
            self.hist_source[source_bin] += rows;
            self.hist_target[target_bin] += rows;
        }
    }

    /// All rows.
    pub fn rows(&self) -> u64 {
        self.by_status.iter().sum()
    }
}

/// Counts over the whole dataset and per scene.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Stats {
    pub total: Counts,
    pub per_scene: BTreeMap<String, Counts>,
    /// Rows per path ([`PATHS`]) and status (in [`STATUSES`] order).
    pub per_path: BTreeMap<String, [u64; 4]>,
}

fn bin_label(b: usize) -> String {
    format!("[{:.1}, {:.1}{}", b as f64 / 10.0, (b + 1) as f64 / 10.0, if b + 1 == BINS { "]" } else { ")" })
}

impl Stats {
    /// Adds `rows` rows of `scene` with `status` whose overlaps fall in the given bins ([`overlap_bin`]);
    /// a bin past the last is an error.
    pub fn add(&mut self, scene: &str, status: Status, source_bin: usize, target_bin: usize, rows: u64) -> Result<()> {
        if source_bin >= BINS || target_bin >= BINS {
            return Err(Error::Internal(format!("stats: overlap bins {source_bin}, {target_bin} (of {BINS})")));
        }
        self.total.add(status, source_bin, target_bin, rows);
        self.per_scene.entry(scene.to_string()).or_default().add(status, source_bin, target_bin, rows);
        Ok(())
    }

    /// Adds the result of [`paths_sql`].
    pub fn add_paths(&mut self, batches: &[RecordBatch]) -> Result<()> {
        for b in batches {
            let (path, status) = (column::<StringArray>(b, 0, DataType::Utf8)?, column::<StringArray>(b, 1, DataType::Utf8)?);
            let n = column::<Int64Array>(b, 2, DataType::Int64)?;
            for r in 0..b.num_rows() {
                let st = Status::parse(status.value(r)).ok_or_else(|| Error::Parquet(format!("stats: unknown status '{}'", status.value(r))))?;
                self.per_path.entry(path.value(r).to_string()).or_default()[STATUSES.iter().position(|s| *s == st).expect("listed")] += n.value(r) as u64;
            }
        }
        Ok(())
    }

    /// The counts from the result of [`counts_sql`].
    pub fn from_counts(batches: &[RecordBatch]) -> Result<Stats> {
        let mut stats = Stats::default();
        for b in batches {
            let (scene, status) = (column::<StringArray>(b, 0, DataType::Utf8)?, column::<StringArray>(b, 1, DataType::Utf8)?);
            let [source_bin, target_bin, n] = [2, 3, 4].map(|i| column::<Int64Array>(b, i, DataType::Int64));
            let (source_bin, target_bin, n) = (source_bin?, target_bin?, n?);
            let bin = |v: i64| usize::try_from(v).unwrap_or(BINS);
            for r in 0..b.num_rows() {
                let st = Status::parse(status.value(r))
                    .ok_or_else(|| Error::Parquet(format!("stats: unknown status '{}' in the pairs table", status.value(r))))?;
                stats.add(scene.value(r), st, bin(source_bin.value(r)), bin(target_bin.value(r)), n.value(r) as u64)?;
            }
        }
        Ok(stats)
    }

    /// The text report: rows by status and the overlap histograms, then per scene if asked.
    pub fn table(&self, per_scene: bool) -> String {
        let mut s = String::new();
        let t = &self.total;
        let _ = writeln!(s, "rows by status\n{:<16}{:>10}", "status", "rows");
        for (st, n) in STATUSES.iter().zip(t.by_status) {
            let _ = writeln!(s, "{:<16}{n:>10}", st.as_str());
        }
        let _ = writeln!(s, "{:<16}{:>10}\n", "total", t.rows());
        let _ = write!(s, "rows by path of the target\n{:<12}", "path");
        STATUSES.iter().for_each(|st| {
            let _ = write!(s, "{:>16}", st.as_str());
        });
        let _ = writeln!(s);
        for path in PATHS {
            let counts = self.per_path.get(path).copied().unwrap_or_default();
            let _ = write!(s, "{path:<12}");
            counts.iter().for_each(|n| {
                let _ = write!(s, "{n:>16}");
            });
            let _ = writeln!(s);
        }
        let _ = writeln!(s);
        let _ = writeln!(s, "overlap of ok pairs ({} pairs)\n{:<12}{:>16}{:>16}", t.by_status[0], "bin", "overlap_source", "overlap_target");
        for b in 0..BINS {
            let _ = writeln!(s, "{:<12}{:>16}{:>16}", bin_label(b), t.hist_source[b], t.hist_target[b]);
        }
        if !per_scene {
            return s;
        }
        let w = self.per_scene.keys().map(|k| k.len()).max().unwrap_or(5).max(5) + 2;
        let _ = write!(s, "\nrows by status per scene\n{:<w$}", "scene");
        for st in STATUSES {
            let _ = write!(s, "{:>16}", st.as_str());
        }
        let _ = writeln!(s, "{:>10}", "total");
        for (scene, c) in &self.per_scene {
            let _ = write!(s, "{scene:<w$}");
            c.by_status.iter().for_each(|n| {
                let _ = write!(s, "{n:>16}");
            });
            let _ = writeln!(s, "{:>10}", c.rows());
        }
        let _ = write!(s, "\noverlap of ok pairs per scene, overlap_source/overlap_target per bin\n{:<w$}", "scene");
        (0..BINS).for_each(|b| {
            let _ = write!(s, "{:>9}", format!("{:.1}", b as f64 / 10.0));
        });
        s.push('\n');
        for (scene, c) in &self.per_scene {
            let _ = write!(s, "{scene:<w$}");
            (0..BINS).for_each(|b| {
                let _ = write!(s, "{:>9}", format!("{}/{}", c.hist_source[b], c.hist_target[b]));
            });
            s.push('\n');
        }
        s
    }

    /// The bar plot: overlap histograms (left) and rows by status (right).
    pub fn plot(&self) -> Canvas {
        let (w, h) = PLOT_SIZE;
        let mut c = Canvas::new(w, h, BACKGROUND);
        let t = &self.total;
        let (top, bottom) = (60i64, 340i64);
        let plot_h = bottom - top;

        // Left: the two histograms, grouped per bin.
        let (x0, group) = (70i64, 56i64);
        c.text(x0, 16, &format!("OVERLAP OF OK PAIRS ({})", t.by_status[0]), TEXT, 2);
        let max = t.hist_source.iter().chain(&t.hist_target).copied().max().unwrap_or(0).max(1);
        axes(&mut c, x0, top, group * BINS as i64, bottom, max);
        for b in 0..BINS {
            let gx = x0 + b as i64 * group;
            for (k, (n, colour)) in [(t.hist_source[b], SOURCE_BAR), (t.hist_target[b], TARGET_BAR)].into_iter().enumerate() {
                bar(&mut c, gx + 5 + k as i64 * 24, 22, bottom, plot_h, n, max, colour);
            }
            c.text_centered(gx, bottom + 6, &format!("{:.1}", b as f64 / 10.0), TEXT, 1);
        }
        c.text_centered(x0 + group * BINS as i64, bottom + 6, "1.0", TEXT, 1);
        let ly = bottom + 30;
        c.fill_rect(x0, ly, 10, 10, SOURCE_BAR);
        c.text(x0 + 16, ly + 2, "OVERLAP_SOURCE", TEXT, 1);
        c.fill_rect(x0 + 130, ly, 10, 10, TARGET_BAR);
        c.text(x0 + 146, ly + 2, "OVERLAP_TARGET", TEXT, 1);
        c.text(x0 + 280, ly + 2, "10 BINS OVER [0, 1]", TEXT, 1);

        // Right: rows by status (reject reasons).
        let (x1, slot) = (720i64, 66i64);
        c.text(x1 - 20, 16, &format!("ROWS BY STATUS ({})", t.rows()), TEXT, 2);
        let max = t.by_status.iter().copied().max().unwrap_or(0).max(1);
        axes(&mut c, x1, top, slot * 4, bottom, max);
        let names = [["OK", ""], ["LOW", "OVERLAP"], ["TOO FEW", "POINTS"], ["INPUT", "ERROR"]];
        for (k, n) in t.by_status.iter().enumerate() {
            let sx = x1 + k as i64 * slot;
            bar(&mut c, sx + 13, 40, bottom, plot_h, *n, max, STATUS_BARS[k]);
            c.text_centered(sx + slot / 2, bottom + 6, names[k][0], TEXT, 1);
            c.text_centered(sx + slot / 2, bottom + 16, names[k][1], TEXT, 1);
        }
        c
    }
}

/// Column `i` of a counts batch, cast to `data_type` and read as `A`.
fn column<A: Array + Clone + 'static>(b: &RecordBatch, i: usize, data_type: DataType) -> Result<A> {
    let bad = |m: String| Error::Internal(format!("stats: column {i} of the counts: {m}"));
    let c = b.columns().get(i).ok_or_else(|| bad("missing".into()))?;
    let c = cast(c, &data_type).map_err(|e| bad(e.to_string()))?;
    c.as_any().downcast_ref::<A>().cloned().ok_or_else(|| bad(format!("not {data_type}")))
}

/// Axes of a bar chart with integer ticks 0, max/2 and max on the left.
fn axes(c: &mut Canvas, x: i64, top: i64, width: i64, bottom: i64, max: u64) {
    c.fill_rect(x - 1, top - 4, 1, bottom - top + 5, AXIS);
    c.fill_rect(x - 1, bottom, width + 2, 1, AXIS);
    let mut ticks = vec![0, max];
    if max >= 2 {
        ticks.insert(1, max / 2);
    }
    for v in ticks {
        let (y, label) = (bottom - ((bottom - top) as f64 * v as f64 / max as f64).round() as i64, v.to_string());
        c.fill_rect(x - 5, y, 4, 1, AXIS);
        c.text(x - 8 - text_width(&label, 1), y - 3, &label, TEXT, 1);
    }
}

/// One bar of height `n / max` of the plot with its count above it.
#[allow(clippy::too_many_arguments)]
fn bar(c: &mut Canvas, x: i64, w: i64, bottom: i64, plot_h: i64, n: u64, max: u64, colour: Rgb) {
    let h = (plot_h as f64 * n as f64 / max as f64).round() as i64;
    c.fill_rect(x, bottom - h, w, h, colour);
    if n > 0 {
        c.text_centered(x + w / 2, bottom - h - 10, &n.to_string(), TEXT, 1);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::export::tests_support::empty_row;
    use datafusion::prelude::SessionContext;

    #[test]
    fn counts_bins_and_tables() {
        assert_eq!([0.0, 0.05, 0.1, 0.3, 0.7, 0.99, 1.0, -1.0].map(overlap_bin), [0, 0, 1, 3, 7, 9, 9, 0]);
        let mut st = Stats::default();
        for (status, scene, ov) in [(Status::Ok, "a", 0.35), (Status::Ok, "b", 1.0), (Status::LowOverlap, "a", 0.05)] {
            st.add(scene, status, overlap_bin(ov), overlap_bin(ov / 2.0), 1).unwrap();
        }
        assert_eq!(st.total.by_status, [2, 1, 0, 0]);
        assert_eq!(st.total.hist_source[3], 1);
        assert_eq!(st.total.hist_source[9], 1);
        assert_eq!(st.total.hist_target[1], 1);
        assert_eq!(st.per_scene["a"].by_status, [1, 1, 0, 0]);
        assert!(st.add("a", Status::Ok, BINS, 0, 1).is_err());
        st.per_path.insert("scene".into(), [2, 0, 1, 0]);
        let text = st.table(true);
        assert!(text.contains("ok                       2\nlow_overlap              1\n"), "{text}");
        assert!(text.contains("scene                      2               0               1               0\nsingle-map                 0"), "{text}");
        assert!(text.contains("[0.9, 1.0]"));
        assert!(text.contains("rows by status per scene"));
        let plot = st.plot();
        assert_eq!((plot.width, plot.height), PLOT_SIZE);
    }

    /// The SQL aggregate over a batch of rows, as `stats` runs it over the shards.
    fn sql_stats(rows: &[crate::shards::PairRow], predicate: Option<&str>) -> Stats {
        let runtime = tokio::runtime::Builder::new_current_thread().build().unwrap();
        let batches = runtime.block_on(async {
            let ctx = SessionContext::new();
            ctx.register_batch("pairs", crate::shards::pairs_to_batch(rows).unwrap()).unwrap();
            ctx.sql(&counts_sql(predicate)).await.unwrap().collect().await.unwrap()
        });
        Stats::from_counts(&batches).unwrap()
    }

    #[test]
    fn the_sql_bins_are_overlap_bin() {
        let values = [
            0.0, -0.0, 0.05, 0.09999999999999999, 0.1, 0.29, 0.3, 0.6, 0.7, 0.8999999999999999, 0.9, 0.99, 1.0,
            1.5, -1.0, 1e-300, f64::NAN, f64::INFINITY, f64::NEG_INFINITY,
        ];
        // Every value in an `ok` row of its own scene (so the per-scene counts show the bin of each value),
        // then one rejected row per other status (not in the histograms).
        let cases = values.iter().enumerate().map(|(i, v)| (format!("v{i:02}"), Status::Ok, *v));
        let rejected = STATUSES[1..].iter().enumerate().map(|(i, s)| (format!("r{i}"), *s, 0.5));
        let mut rows = Vec::new();
        let mut want = Stats::default();
        let mut want_even = Stats::default();
        for (i, (scene, status, v)) in cases.chain(rejected).enumerate() {
            let target = values[(i + 7) % values.len()];
            let mut r = empty_row();
            (r.scene, r.status, r.overlap_source, r.overlap_target) = (scene.clone(), status, v, target);
            (r.pair_key, r.unit_index) = (format!("{scene}#0"), i as u64);
            want.add(&scene, status, overlap_bin(v), overlap_bin(target), 1).unwrap();
            if i % 2 == 0 {
                want_even.add(&scene, status, overlap_bin(v), overlap_bin(target), 1).unwrap();
            }
            rows.push(r);
        }
        assert_eq!(sql_stats(&rows, None), want);
        let even = "unit_index % 2 = 0 -- a comment stops at the end of the predicate";
        assert_eq!(sql_stats(&rows, Some(even)), want_even);
    }

    #[test]
    fn the_paths_are_counted_by_scene_frames() {
        // An independent count: rows with scene_frames > 0 by status, against the SQL aggregate.
        let mut rows = Vec::new();
        let mut want: BTreeMap<String, [u64; 4]> = BTreeMap::new();
        for i in 0..23u64 {
            let mut r = empty_row();
            r.scene_frames = if i % 3 == 0 { 0 } else { i as u32 };
            r.status = STATUSES[(i % 4) as usize];
            (r.pair_key, r.unit_index) = (format!("p{i}#0"), i);
            want.entry(if r.scene_frames > 0 { "scene" } else { "single-map" }.into()).or_default()[(i % 4) as usize] += 1;
            rows.push(r);
        }
        let runtime = tokio::runtime::Builder::new_current_thread().build().unwrap();
        let batches = runtime.block_on(async {
            let ctx = SessionContext::new();
            ctx.register_batch("pairs", crate::shards::pairs_to_batch(&rows).unwrap()).unwrap();
            ctx.sql(&paths_sql(None)).await.unwrap().collect().await.unwrap()
        });
        let mut st = Stats::default();
        st.add_paths(&batches).unwrap();
        assert_eq!(st.per_path, want);
    }
}
