//! One unit's scores (a condition and seed on every benchmark pair and sample count) as a tab-separated
//! file, written atomically: the file exists only when the unit finished, which is how a rerun resumes.

use crate::atomic::{write_atomic, Publish};
use crate::error::{Error, Result};
use crate::registration::PairScore;
use std::path::Path;

const HEADER: &str = "benchmark\tscene\ti\tj\tsamples\tcorrespondences\tinlier_ratio\tcounts_for_rr\terror\tregistered\trre_deg\trte_m";

/// The scores as text (floats in Rust's shortest round-trip form, so reading gives the same values).
pub fn to_text(scores: &[PairScore]) -> String {
    let mut s = format!("{HEADER}\n");
    for p in scores {
        s.push_str(&format!(
            "{}\t{}\t{}\t{}\t{}\t{}\t{}\t{}\t{}\t{}\t{}\t{}\n",
            p.benchmark, p.scene, p.i, p.j, p.samples, p.correspondences, p.inlier_ratio, p.counts_for_rr, p.error, p.registered, p.rre_deg, p.rte_m
        ));
    }
    s
}

/// Writes `scores` to `path` atomically (the temporary file beside it).
pub fn write(path: &Path, scores: &[PairScore]) -> Result<()> {
    let dir = path.parent().unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    write_atomic(dir, path, to_text(scores).as_bytes(), Publish::Replace)?;
    Ok(())
}

/// Reads a file written by [`write`]; errors name the file and line.
pub fn read(path: &Path) -> Result<Vec<PairScore>> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    let mut lines = text.lines().enumerate();
    if lines.next().map(|(_, l)| l) != Some(HEADER) {
        return Err(Error::input(path, "not a scores file of eval boost (bad header)"));
    }
    lines
        .map(|(n, line)| {
            let bad = |what: &str| Error::input(path, format!("line {}: {what}", n + 1));
            let f: Vec<&str> = line.split('\t').collect();
            if f.len() != 12 {
                return Err(bad(&format!("{} fields, expected 12", f.len())));
            }
            let num = |k: usize| f[k].parse::<f64>().map_err(|_| bad(&format!("`{}` is not a number", f[k])));
            let int = |k: usize| f[k].parse::<usize>().map_err(|_| bad(&format!("`{}` is not a count", f[k])));
            let flag = |k: usize| f[k].parse::<bool>().map_err(|_| bad(&format!("`{}` is not true/false", f[k])));
            Ok(PairScore {
                benchmark: f[0].to_string(),
                scene: f[1].to_string(),
                i: int(2)?,
                j: int(3)?,
                samples: int(4)?,
                correspondences: int(5)?,
                inlier_ratio: num(6)?,
                counts_for_rr: flag(7)?,
                error: num(8)?,
                registered: flag(9)?,
                rre_deg: num(10)?,
                rte_m: num(11)?,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_keeps_every_value_and_bad_lines_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let s = PairScore {
            benchmark: "single-frame".into(),
            scene: "s-frames".into(),
            i: 3,
            j: 9,
            samples: 250,
            correspondences: 250,
            inlier_ratio: 0.1 + 0.2,
            counts_for_rr: true,
            error: f64::INFINITY,
            registered: false,
            rre_deg: f64::NAN,
            rte_m: 1.0 / 3.0,
        };
        let path = dir.path().join("u/scores.tsv");
        write(&path, &[s.clone(), PairScore { error: 0.01, registered: true, rre_deg: 2.5, ..s.clone() }]).unwrap();
        let back = read(&path).unwrap();
        assert_eq!(format!("{back:?}"), format!("{:?}", [s.clone(), PairScore { error: 0.01, registered: true, rre_deg: 2.5, ..s }]));
        std::fs::write(&path, format!("{HEADER}\na\tb\n")).unwrap();
        let e = read(&path).unwrap_err().to_string();
        assert!(e.contains("scores.tsv") && e.contains("line 2"), "{e}");
    }
}
