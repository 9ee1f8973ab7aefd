//! The boost table: per benchmark and sample count, each condition's FMR / IR / RR as the mean over its
//! training seeds with the min–max spread, and the paired IR differences between conditions with a 95 %
//! interval over pairs × seeds (seed k of one condition against seed k of the other; C0, untrained, is
//! the same for every k) and a second one over the seeds' mean differences, the one to read when comparing
//! training conditions: one training run moves all its pairs' scores together, so they are not independent
//! (with `--redraw` the seeds also differ in their training pairs, and this interval covers that draw too).

use crate::registration::report::{paired_difference, rows};
use crate::registration::PairScore;
use std::collections::BTreeMap;
use std::fmt::Write as _;

/// Mean and range over seeds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Spread {
    pub mean: f64,
    pub min: f64,
    pub max: f64,
}

impl Spread {
    pub fn of(v: &[f64]) -> Spread {
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        Spread { mean, min: v.iter().copied().fold(f64::INFINITY, f64::min), max: v.iter().copied().fold(f64::NEG_INFINITY, f64::max) }
    }
}

/// One condition at one benchmark and sample count.
#[derive(Clone, Debug, PartialEq)]
pub struct ConditionRow {
    pub benchmark: String,
    pub samples: usize,
    pub condition: String,
    pub seeds: usize,
    pub pairs: usize,
    pub fmr: Spread,
    pub ir: Spread,
    pub rr: Spread,
}

/// IR(a) − IR(b), percentage points, over pairs × seeds.
#[derive(Clone, Debug, PartialEq)]
pub struct PairedRow {
    pub benchmark: String,
    pub samples: usize,
    pub a: String,
    pub b: String,
    pub n: usize,
    pub mean: f64,
    pub lo: f64,
    pub hi: f64,
    /// Seeds compared, and the 95 % interval over their mean differences (NaN with one seed).
    pub seeds: usize,
    pub seed_lo: f64,
    pub seed_hi: f64,
}

/// Each condition's scores per seed (untrained: one entry), by name in table order → the table's rows, by
/// benchmark and sample count in first-seen order, conditions in order, and the paired differences of
/// `comparisons` (first − second, by name).
pub fn summarize(results: &[(String, Vec<Vec<PairScore>>)], comparisons: &[(String, String)]) -> (Vec<ConditionRow>, Vec<PairedRow>) {
    let by_name: BTreeMap<&str, &Vec<Vec<PairScore>>> = results.iter().map(|(n, v)| (n.as_str(), v)).collect();
    let mut keys: Vec<(String, usize)> = Vec::new();
    for s in results.iter().flat_map(|(_, v)| v).flatten() {
        if !keys.contains(&(s.benchmark.clone(), s.samples)) {
            keys.push((s.benchmark.clone(), s.samples));
        }
    }
    let mut table = Vec::new();
    let mut paired = Vec::new();
    for (bench, n) in &keys {
        for (c, per_seed) in results {
            let r: Vec<_> = per_seed.iter().filter_map(|s| rows(c, s).into_iter().find(|r| &r.benchmark == bench && r.samples == *n)).collect();
            if r.is_empty() {
                continue;
            }
            let pick = |f: fn(&crate::registration::report::Row) -> f64| Spread::of(&r.iter().map(f).collect::<Vec<_>>());
            table.push(ConditionRow {
                benchmark: bench.clone(),
                samples: *n,
                condition: c.clone(),
                seeds: r.len(),
                pairs: r[0].pairs,
                fmr: pick(|r| r.fmr),
                ir: pick(|r| r.ir),
                rr: pick(|r| r.rr),
            });
        }
        for (a, b) in comparisons {
            let (Some(sa), Some(sb)) = (by_name.get(a.as_str()), by_name.get(b.as_str())) else { continue };
            let seeds = sa.len().max(sb.len());
            let (mut va, mut vb) = (Vec::new(), Vec::new());
            let (mut ma, mut mb) = (Vec::new(), Vec::new());
            for k in 0..seeds {
                let sel = |v: &[PairScore]| -> Vec<(String, usize, usize, f64)> {
                    v.iter().filter(|s| &s.benchmark == bench && s.samples == *n).map(|s| (s.scene.clone(), s.i, s.j, 100.0 * s.inlier_ratio)).collect()
                };
                let (x, y) = (sel(&sa[k.min(sa.len() - 1)]), sel(&sb[k.min(sb.len() - 1)]));
                assert!(x.iter().map(|t| (&t.0, t.1, t.2)).eq(y.iter().map(|t| (&t.0, t.1, t.2))), "conditions scored on different pairs");
                va.extend(x.iter().map(|t| t.3));
                vb.extend(y.iter().map(|t| t.3));
                if !x.is_empty() {
                    ma.push(x.iter().map(|t| t.3).sum::<f64>() / x.len() as f64);
                    mb.push(y.iter().map(|t| t.3).sum::<f64>() / y.len() as f64);
                }
            }
            if va.is_empty() {
                continue;
            }
            let (mean, lo, hi) = paired_difference(&va, &vb);
            let (_, seed_lo, seed_hi) = paired_difference(&ma, &mb);
            paired.push(PairedRow { benchmark: bench.clone(), samples: *n, a: a.clone(), b: b.clone(), n: va.len(), mean, lo, hi, seeds: ma.len(), seed_lo, seed_hi });
        }
    }
    (table, paired)
}

/// A condition's name in the table: an alias with what it stands for (`C5x2 (single+classical)`).
fn label(name: &str) -> String {
    match super::conditions::alias_spec(name) {
        Some(spec) => format!("{name} ({spec})"),
        None => name.to_string(),
    }
}

fn spread(s: &Spread, d: usize) -> String {
    format!("{:.d$} [{:.d$}-{:.d$}]", s.mean, s.min, s.max)
}

/// The table as text: one block per benchmark and sample count.
pub fn format_text(table: &[ConditionRow], paired: &[PairedRow]) -> String {
    let mut out = String::new();
    let mut keys: Vec<(&str, usize)> = Vec::new();
    for r in table {
        if !keys.contains(&(r.benchmark.as_str(), r.samples)) {
            keys.push((r.benchmark.as_str(), r.samples));
        }
    }
    for (bench, n) in keys {
        let _ = writeln!(out, "{bench}, {n} samples (mean [min-max] over training seeds)");
        let _ = writeln!(out, "{:<34} {:>5} {:>5}  {:>20}  {:>20}  {:>20}", "condition", "seeds", "pairs", "FMR %", "IR %", "RR %");
        for r in table.iter().filter(|r| r.benchmark == bench && r.samples == n) {
            let name = label(&r.condition);
            let _ = writeln!(out, "{name:<34} {:>5} {:>5}  {:>20}  {:>20}  {:>20}", r.seeds, r.pairs, spread(&r.fmr, 1), spread(&r.ir, 2), spread(&r.rr, 1));
        }
        let rows: Vec<&PairedRow> = paired.iter().filter(|p| p.benchmark == bench && p.samples == n).collect();
        if !rows.is_empty() {
            let _ = writeln!(out, "paired IR difference (percentage points, 95% CI over pairs x seeds; and over the seeds' mean differences)");
            for p in rows {
                let over_seeds = if p.seeds >= 2 { format!("  over {} seeds [{:+.2}, {:+.2}]", p.seeds, p.seed_lo, p.seed_hi) } else { String::new() };
                let _ = writeln!(
                    out,
                    "  {:<30} {:>6} values  {:+.2} [{:+.2}, {:+.2}]{over_seeds}",
                    format!("{} - {}", p.a, p.b),
                    p.n,
                    p.mean,
                    p.lo,
                    p.hi
                );
            }
        }
        out.push('\n');
    }
    out
}

/// The condition rows as CSV.
pub fn format_csv(table: &[ConditionRow]) -> String {
    let mut out = String::from("benchmark,samples,condition,seeds,pairs,fmr_mean,fmr_min,fmr_max,ir_mean,ir_min,ir_max,rr_mean,rr_min,rr_max\n");
    for r in table {
        let s = |x: &Spread| format!("{:.4},{:.4},{:.4}", x.mean, x.min, x.max);
        let _ = writeln!(out, "{},{},{},{},{},{},{},{}", r.benchmark, r.samples, r.condition, r.seeds, r.pairs, s(&r.fmr), s(&r.ir), s(&r.rr));
    }
    out
}

/// The paired differences as CSV.
pub fn format_paired_csv(paired: &[PairedRow]) -> String {
    let mut out = String::from("benchmark,samples,a,b,values,ir_diff_pp,ci_lo,ci_hi,seeds,seed_ci_lo,seed_ci_hi\n");
    for p in paired {
        let _ = writeln!(
            out,
            "{},{},{},{},{},{:.4},{:.4},{:.4},{},{:.4},{:.4}",
            p.benchmark,
            p.samples,
            p.a,
            p.b,
            p.n,
            p.mean,
            p.lo,
            p.hi,
            p.seeds,
            p.seed_lo,
            p.seed_hi
        );
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn score(i: usize, ir: f64) -> PairScore {
        PairScore {
            benchmark: "b".into(),
            scene: "s".into(),
            i,
            j: i + 1,
            samples: 100,
            correspondences: 100,
            inlier_ratio: ir,
            counts_for_rr: true,
            error: if ir > 0.1 { 0.0 } else { f64::INFINITY },
            registered: ir > 0.1,
            rre_deg: 0.0,
            rte_m: 0.0,
        }
    }

    #[test]
    fn spread_over_seeds_and_paired_differences_by_hand() {
        // C0 once: IR 0.05, 0.15. C1 seed 0: 0.10, 0.20; seed 1: 0.30, 0.20.
        let results = vec![
            ("C0".to_string(), vec![vec![score(0, 0.05), score(1, 0.15)]]),
            ("C1".to_string(), vec![vec![score(0, 0.10), score(1, 0.20)], vec![score(0, 0.30), score(1, 0.20)]]),
        ];
        let (table, paired) = summarize(&results, &[("C1".into(), "C0".into())]);
        let c1 = table.iter().find(|r| r.condition == "C1").unwrap();
        assert_eq!((c1.seeds, c1.pairs), (2, 2));
        assert!((c1.ir.mean - 20.0).abs() < 1e-9 && (c1.ir.min - 15.0).abs() < 1e-9 && (c1.ir.max - 25.0).abs() < 1e-9);
        assert_eq!((c1.rr.min, c1.rr.max), (50.0, 100.0));
        // Differences (pp): 5, 5, 25, 5: mean 10, sd 10, t(3) = 3.182, half width 3.182 * 10 / 2.
        let p = &paired[0];
        assert_eq!((p.a.as_str(), p.b.as_str(), p.n), ("C1", "C0", 4));
        assert!((p.mean - 10.0).abs() < 1e-9);
        assert!((p.hi - p.mean - 3.182446 * 5.0).abs() < 1e-2 && (p.mean - p.lo - 3.182446 * 5.0).abs() < 1e-2, "{p:?}");
        // Over seeds: seed 0's mean difference 5, seed 1's 15; mean 10, sd 7.071, t(1) = 12.706, half
        // width 12.706 * 7.071 / sqrt(2) = 63.53.
        assert_eq!(p.seeds, 2);
        assert!((p.seed_hi - 73.53).abs() < 1e-2 && (p.seed_lo + 53.53).abs() < 1e-2, "{p:?}");
        let text = format_text(&table, &paired);
        assert!(text.contains("C1 - C0") && text.contains("over 2 seeds [-53.53, +73.53]"), "{text}");
    }
}
