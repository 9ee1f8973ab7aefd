//! Tables of [`PairScore`]s: FMR, IR, RR, RRE, RTE per benchmark and sample count, and the paired
//! difference of IR between two descriptors with its 95 % confidence interval.

use super::evaluate::PairScore;
use super::metrics::FMR_INLIER_RATIO;
use std::fmt::Write as _;

/// One row of the table.
#[derive(Clone, Debug, PartialEq)]
pub struct Row {
    pub benchmark: String,
    pub descriptor: String,
    pub samples: usize,
    pub pairs: usize,
    /// Percentages.
    pub fmr: f64,
    pub ir: f64,
    pub rr: f64,
    /// Pairs registration recall counts.
    pub rr_pairs: usize,
    /// Means over the registered pairs (degrees, metres); NaN when none.
    pub rre_deg: f64,
    pub rte_m: f64,
}

fn mean(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x, n + 1));
    if n == 0 {
        f64::NAN
    } else {
        s / n as f64
    }
}

/// Rows per (benchmark, sample count), in first-seen order.
pub fn rows(descriptor: &str, scores: &[PairScore]) -> Vec<Row> {
    let mut keys: Vec<(String, usize)> = Vec::new();
    for s in scores {
        if !keys.contains(&(s.benchmark.clone(), s.samples)) {
            keys.push((s.benchmark.clone(), s.samples));
        }
    }
    keys.into_iter()
        .map(|(b, n)| {
            let sel: Vec<&PairScore> = scores.iter().filter(|s| s.benchmark == b && s.samples == n).collect();
            let rr: Vec<&&PairScore> = sel.iter().filter(|s| s.counts_for_rr).collect();
            let reg: Vec<&&&PairScore> = rr.iter().filter(|s| s.registered).collect();
            Row {
                benchmark: b,
                descriptor: descriptor.to_string(),
                samples: n,
                pairs: sel.len(),
                fmr: 100.0 * mean(sel.iter().map(|s| (s.inlier_ratio > FMR_INLIER_RATIO) as u8 as f64)),
                ir: 100.0 * mean(sel.iter().map(|s| s.inlier_ratio)),
                rr: 100.0 * mean(rr.iter().map(|s| s.registered as u8 as f64)),
                rr_pairs: rr.len(),
                rre_deg: mean(reg.iter().map(|s| s.rre_deg)),
                rte_m: mean(reg.iter().map(|s| s.rte_m)),
            }
        })
        .collect()
}

/// The 0.975 quantile of Student's t with `df` degrees of freedom (table to 30, then the normal's 1.96
/// corrected by the first term of the Cornish–Fisher expansion).
pub fn t975(df: usize) -> f64 {
    const T: [f64; 30] = [
        12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160, 2.145, 2.131,
        2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048, 2.045, 2.042,
    ];
    match df {
        0 => f64::NAN,
        1..=30 => T[df - 1],
        _ => 1.959964 + (1.959964f64.powi(3) + 1.959964) / (4.0 * df as f64),
    }
}

/// Mean of `a − b` over paired values and its 95 % confidence interval (Student's t), in the values' units.
pub fn paired_difference(a: &[f64], b: &[f64]) -> (f64, f64, f64) {
    assert_eq!(a.len(), b.len(), "paired values");
    let d: Vec<f64> = a.iter().zip(b).map(|(x, y)| x - y).collect();
    let n = d.len();
    let m = mean(d.iter().copied());
    if n < 2 {
        return (m, f64::NAN, f64::NAN);
    }
    let var = d.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1) as f64;
    let half = t975(n - 1) * (var / n as f64).sqrt();
    (m, m - half, m + half)
}

/// A paired comparison row: IR(a) − IR(b) in percentage points over the same pairs.
#[derive(Clone, Debug, PartialEq)]
pub struct PairedRow {
    pub benchmark: String,
    pub samples: usize,
    pub pairs: usize,
    pub mean: f64,
    pub lo: f64,
    pub hi: f64,
}

/// Paired IR differences per (benchmark, samples) of two score lists made by one `evaluate` call.
pub fn paired_ir(a: &[PairScore], b: &[PairScore]) -> Vec<PairedRow> {
    let mut out: Vec<PairedRow> = Vec::new();
    for r in rows("", a) {
        let sel = |v: &[PairScore]| {
            v.iter()
                .filter(|s| s.benchmark == r.benchmark && s.samples == r.samples)
                .map(|s| 100.0 * s.inlier_ratio)
                .collect::<Vec<_>>()
        };
        let (m, lo, hi) = paired_difference(&sel(a), &sel(b));
        out.push(PairedRow { benchmark: r.benchmark, samples: r.samples, pairs: r.pairs, mean: m, lo, hi });
    }
    out
}

fn f(x: f64, d: usize) -> String {
    if x.is_finite() {
        format!("{x:.d$}")
    } else {
        "-".into()
    }
}

/// The table as aligned text, one block per benchmark.
pub fn format_table(rows: &[Row]) -> String {
    let mut s = String::new();
    let mut last = "";
    for r in rows {
        if r.benchmark != last {
            let _ = writeln!(
                s,
                "\n{}\n{:<22} {:>7} {:>6} {:>7} {:>7} {:>7} {:>8} {:>8} {:>8}",
                r.benchmark, "descriptor", "samples", "pairs", "FMR%", "IR%", "RR%", "RR pairs", "RRE deg", "RTE m"
            );
            last = &r.benchmark;
        }
        let _ = writeln!(
            s,
            "{:<22} {:>7} {:>6} {:>7} {:>7} {:>7} {:>8} {:>8} {:>8}",
            r.descriptor,
            r.samples,
            r.pairs,
            f(r.fmr, 1),
            f(r.ir, 2),
            f(r.rr, 1),
            r.rr_pairs,
            f(r.rre_deg, 2),
            f(r.rte_m, 3)
        );
    }
    s
}

/// The table as CSV with a header line.
pub fn format_csv(rows: &[Row]) -> String {
    let mut s = String::from("benchmark,descriptor,samples,pairs,fmr_pct,ir_pct,rr_pct,rr_pairs,rre_deg,rte_m\n");
    for r in rows {
        let _ = writeln!(
            s,
            "{},{},{},{},{:.4},{:.4},{:.4},{},{:.4},{:.5}",
            r.benchmark, r.descriptor, r.samples, r.pairs, r.fmr, r.ir, r.rr, r.rr_pairs, r.rre_deg, r.rte_m
        );
    }
    s
}

/// The paired comparison as text.
pub fn format_paired(a: &str, b: &str, rows: &[PairedRow], csv: bool) -> String {
    let mut s = String::new();
    if csv {
        s.push_str("benchmark,samples,pairs,ir_diff_pp,ci95_lo,ci95_hi\n");
        for r in rows {
            let _ = writeln!(s, "{},{},{},{:.4},{:.4},{:.4}", r.benchmark, r.samples, r.pairs, r.mean, r.lo, r.hi);
        }
        return s;
    }
    let _ = writeln!(s, "\npaired IR difference {a} - {b} (percentage points, 95% CI over pairs)");
    for r in rows {
        let _ = writeln!(
            s,
            "{:<14} {:>7} samples {:>5} pairs  {:+.2} [{:+.2}, {:+.2}]",
            r.benchmark, r.samples, r.pairs, r.mean, r.lo, r.hi
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paired_interval_by_hand() {
        // d = 1, 2, 3: mean 2, sd 1, half width t(2)·1/√3 = 4.303/1.732.
        let (m, lo, hi) = paired_difference(&[2.0, 4.0, 6.0], &[1.0, 2.0, 3.0]);
        assert_eq!(m, 2.0);
        assert!((hi - m - 4.303 / 3f64.sqrt()).abs() < 1e-9 && (m - lo - (hi - m)).abs() < 1e-12);
    }
}
