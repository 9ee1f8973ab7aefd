//! Dataset statistics: rows by status (the reject reasons) and the overlap histograms of the `ok`
//! pairs (10 bins over [0, 1], `overlap_source` and `overlap_target`), as a text table and a bar plot.

use super::canvas::{text_width, Canvas, Rgb};
use super::colormap::{BACKGROUND, TEXT};
use crate::shards::row::{PairRow, Status};
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
    fn add(&mut self, row: &PairRow) {
        self.by_status[STATUSES.iter().position(|s| *s == row.status).expect("known status")] += 1;
        if row.status == Status::Ok {
            self.hist_source[overlap_bin(row.overlap_source)] += 1;
            self.hist_target[overlap_bin(row.overlap_target)] += 1;
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
}

fn bin_label(b: usize) -> String {
    format!("[{:.1}, {:.1}{}", b as f64 / 10.0, (b + 1) as f64 / 10.0, if b + 1 == BINS { "]" } else { ")" })
}

impl Stats {
    /// Adds one row.
    pub fn add(&mut self, row: &PairRow) {
        self.total.add(row);
        self.per_scene.entry(row.scene.clone()).or_default().add(row);
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

    #[test]
    fn counts_bins_and_tables() {
        assert_eq!([0.0, 0.05, 0.1, 0.3, 0.7, 0.99, 1.0, -1.0].map(overlap_bin), [0, 0, 1, 3, 7, 9, 9, 0]);
        let mut st = Stats::default();
        for (status, scene, ov) in [(Status::Ok, "a", 0.35), (Status::Ok, "b", 1.0), (Status::LowOverlap, "a", 0.05)] {
            let mut r = empty_row();
            (r.status, r.scene, r.overlap_source, r.overlap_target) = (status, scene.into(), ov, ov / 2.0);
            st.add(&r);
        }
        assert_eq!(st.total.by_status, [2, 1, 0, 0]);
        assert_eq!(st.total.hist_source[3], 1);
        assert_eq!(st.total.hist_source[9], 1);
        assert_eq!(st.total.hist_target[1], 1);
        assert_eq!(st.per_scene["a"].by_status, [1, 1, 0, 0]);
        let text = st.table(true);
        assert!(text.contains("ok                       2\nlow_overlap              1\n"), "{text}");
        assert!(text.contains("[0.9, 1.0]"));
        assert!(text.contains("rows by status per scene"));
        let plot = st.plot();
        assert_eq!((plot.width, plot.height), PLOT_SIZE);
    }
}
