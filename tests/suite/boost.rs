//! `pointreggpt eval boost` on tiny synthetic runs: the table's numbers against an independent
//! aggregation of the per-pair scores, the same table twice from scratch (determinism), a rerun redoes no
//! finished unit (the scores files keep their inodes), the real pairs of C1 follow the generated pairs'
//! source-side overlap histogram (both overlaps counted here: C3's from the dataset's rows, C1's by brute
//! force from the clouds and poses), every alias of the single-frame protocol and `--model fpfh-mlp` run
//! with the counts they promise, other training settings are refused, and the fragment regime end to end.

use crate::support;

use pointreggpt::geometry::{pose_from_rows, Point};
use pointreggpt::shards::dataset::Dataset;
use std::collections::{BTreeMap, HashMap};
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};
use crate::support::bin;

fn run_ok(args: &[&str]) -> String {
    let o = bin().args(args).output().unwrap();
    assert!(o.status.success(), "{args:?}: {}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout).into_owned()
}

fn boost(bench: &Path, seq: &Path, out: &Path) -> String {
    boost_with(bench, seq, out, &[])
}

fn boost_with(bench: &Path, seq: &Path, out: &Path, extra: &[&str]) -> String {
    run_ok(&boost_args(bench, seq, out, extra).iter().map(String::as_str).collect::<Vec<_>>())
}

/// The tiny run's arguments; `extra` is appended (an option in it replaces the tiny run's).
fn boost_args(bench: &Path, seq: &Path, out: &Path, extra: &[&str]) -> Vec<String> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let classical = root.join("pipelines/paper-3dmatch-classical.toml");
    let models = root.join("models");
    let mut args = vec![
        "eval", "boost", bench.to_str().unwrap(), "--sequence", seq.to_str().unwrap(), "--first", "0", "--frames", "30",
        "--conditions", "C0,C1,C3", "--seeds", "2", "--pairs", "24", "--steps", "3", "--samples", "200,50",
        "--real-every", "1", "--real-gaps", "2,4,6,8,10,12,14,16,18,20", "--classical-config", classical.to_str().unwrap(),
        "--models", models.to_str().unwrap(), "--out", out.to_str().unwrap(), "--quiet",
    ];
    // An option given in `extra` replaces the default one: the flag, and its value when it takes one.
    for flag in extra.iter().filter(|a| a.starts_with("--")) {
        if let Some(i) = args.iter().position(|a| a == flag) {
            let takes_value = args.get(i + 1).is_some_and(|v| !v.starts_with("--"));
            args.drain(i..=i + usize::from(takes_value));
        }
    }
    args.extend_from_slice(extra);
    args.into_iter().map(str::to_string).collect()
}

/// A unit's scores files (one per benchmark scoring).
fn scores_files(unit: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(unit).unwrap().map(|e| e.unwrap().path())
        .filter(|p| p.file_name().unwrap().to_str().unwrap().starts_with("scores-")).collect();
    v.sort();
    v
}

/// (benchmark, samples) → per-pair inlier ratios, from a unit's scores file (columns: benchmark, scene, i,
/// j, samples, correspondences, inlier_ratio, ...).
fn pair_irs(path: &Path) -> BTreeMap<(String, usize), Vec<((String, usize, usize), f64)>> {
    let mut out: BTreeMap<(String, usize), Vec<((String, usize, usize), f64)>> = BTreeMap::new();
    for line in std::fs::read_to_string(path).unwrap().lines().skip(1) {
        let f: Vec<&str> = line.split('\t').collect();
        let key = (f[1].to_string(), f[2].parse().unwrap(), f[3].parse().unwrap());
        out.entry((f[0].to_string(), f[4].parse().unwrap())).or_default().push((key, f[6].parse().unwrap()));
    }
    out
}

/// Checks boost.csv (IR mean / min / max over seeds) and boost-paired.csv (the paired difference's mean)
/// against the per-pair scores of the units, aggregated here.
fn check_table_against_scores(out: &Path, units: &[(&str, Vec<&str>)], paired: &[(&str, &str)]) {
    let csv = std::fs::read_to_string(out.join("boost.csv")).unwrap();
    let mut per_condition: HashMap<&str, Vec<BTreeMap<(String, usize), Vec<((String, usize, usize), f64)>>>> = HashMap::new();
    for (c, dirs) in units {
        for d in dirs {
            let files = scores_files(&out.join(d));
            assert_eq!(files.len(), 1, "{d}: {files:?}");
            per_condition.entry(c).or_default().push(pair_irs(&files[0]));
        }
    }
    let mut checked = 0;
    for line in csv.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let Some(seeds) = per_condition.get(f[2]) else { continue };
        let key = (f[0].to_string(), f[1].parse::<usize>().unwrap());
        let irs: Vec<f64> = seeds.iter().map(|s| 100.0 * s[&key].iter().map(|p| p.1).sum::<f64>() / s[&key].len() as f64).collect();
        let mean = irs.iter().sum::<f64>() / irs.len() as f64;
        let (min, max) = irs.iter().fold((f64::MAX, f64::MIN), |(a, b), &x| (a.min(x), b.max(x)));
        let got: Vec<f64> = f[8..11].iter().map(|v| v.parse().unwrap()).collect();
        assert_eq!(f[3].parse::<usize>().unwrap(), seeds.len(), "{line}");
        assert_eq!(f[4].parse::<usize>().unwrap(), seeds[0][&key].len(), "{line}: pairs");
        for (g, w) in got.iter().zip([mean, min, max]) {
            assert!((g - w).abs() < 1e-3, "{line}: IR {g} vs {w} from the scores");
        }
        checked += 1;
    }
    assert!(checked >= per_condition.len(), "{checked} rows checked");
    let paired_csv = std::fs::read_to_string(out.join("boost-paired.csv")).unwrap();
    for (a, b) in paired {
        for line in paired_csv.lines().skip(1).filter(|l| { let f: Vec<&str> = l.split(',').collect(); f[2] == *a && f[3] == *b }) {
            let f: Vec<&str> = line.split(',').collect();
            let key = (f[0].to_string(), f[1].parse::<usize>().unwrap());
            let (sa, sb) = (&per_condition[a], &per_condition[b]);
            let mut diffs = Vec::new();
            for k in 0..sa.len().max(sb.len()) {
                let (x, y) = (&sa[k.min(sa.len() - 1)][&key], &sb[k.min(sb.len() - 1)][&key]);
                for (p, q) in x.iter().zip(y) {
                    assert_eq!(p.0, q.0, "paired on the same pairs");
                    diffs.push(100.0 * (p.1 - q.1));
                }
            }
            let mean = diffs.iter().sum::<f64>() / diffs.len() as f64;
            assert_eq!(f[4].parse::<usize>().unwrap(), diffs.len(), "{line}");
            assert!((f[5].parse::<f64>().unwrap() - mean).abs() < 1e-3, "{line}: mean difference {mean} from the scores");
        }
    }
}

/// The source-side overlap of real pair (i, j) of `seq` (source frame j, target frame i), by brute
/// force: the fraction of j's cloud (`clouds/cloud_bin_<j>.ply`, as `fragments --single-frames` makes it)
/// with a point of i's cloud within 3.75 cm under the captured poses.
fn brute_force_source_overlap(clouds: &Path, seq: &Path, i: usize, j: usize) -> f64 {
    let read = |k: usize| pointreggpt::ply::read_ply(&clouds.join(format!("cloud_bin_{k}.ply"))).unwrap();
    let pose = |k: usize| {
        let text = std::fs::read_to_string(seq.join(format!("frame-{k:06}.pose.txt"))).unwrap();
        let v: Vec<f64> = text.split_whitespace().map(|x| x.parse().unwrap()).collect();
        pose_from_rows(&v.try_into().unwrap()).unwrap()
    };
    let t = (pose(i).inverse() * pose(j)).cast::<f32>();
    let (source, target) = (read(j), read(i));
    let near = source.iter().filter(|p| { let q: Point = t * *p; target.iter().any(|x| (x - q).norm() < 0.0375) }).count();
    near as f64 / source.len() as f64
}

/// `training-pairs.tsv`: (key, overlap, source-side overlap) per line.
fn read_tsv(path: &Path) -> Vec<(String, f64, f64)> {
    std::fs::read_to_string(path).unwrap().lines().skip(1).map(|l| {
        let f: Vec<&str> = l.split('\t').collect();
        (f[0].to_string(), f[1].parse().unwrap(), f[2].parse().unwrap())
    }).collect()
}

#[test]
fn a_tiny_run_writes_the_table_deterministically_and_resumes_without_redoing_units() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let seq = support::synthetic_sequence(50, 500);
    // The benchmark: single-frame pairs of another synthetic scene, which no training sees.
    let bench = support::single_frame_bench(40, 200, &[]);

    let (a, b) = (dir.path().join("a"), dir.path().join("b"));
    let first = boost(&bench, &seq, &a);
    assert!(first.contains("5 units scored (4 of them trained first), 0 already done"), "{first}");
    let table = std::fs::read_to_string(a.join("boost.txt")).unwrap();
    for want in ["C0 (fpfh)", "C1 (single)", "C3 (classical)", "C1 - C0", "C3 - C0", "200 samples", "50 samples"] {
        assert!(table.contains(want), "{want} missing from\n{table}");
    }
    let csv = std::fs::read_to_string(a.join("boost.csv")).unwrap();
    let c3_rows: Vec<&str> = csv.lines().filter(|l| l.split(',').nth(2) == Some("C3")).collect();
    assert_eq!(c3_rows.len(), 2, "{csv}");
    // The table's numbers, aggregated here from the units' per-pair scores.
    let units = ["C0", "C1/seed-0", "C1/seed-1", "C3/seed-0", "C3/seed-1"];
    check_table_against_scores(&a, &[("C0", vec!["C0"]), ("C1", vec!["C1/seed-0", "C1/seed-1"]), ("C3", vec!["C3/seed-0", "C3/seed-1"])], &[("C1", "C0"), ("C3", "C0")]);

    // Resume: nothing is redone (an atomic rewrite would give each scores file a new inode) and the table
    // is the same.
    let scores: Vec<PathBuf> = units.iter().map(|u| scores_files(&a.join(u))).inspect(|f| assert_eq!(f.len(), 1, "{f:?}")).map(|mut f| f.remove(0)).collect();
    let inode = |p: &Path| std::fs::metadata(p).unwrap().ino();
    let inodes: Vec<_> = scores.iter().map(|p| inode(p)).collect();
    let again = boost(&bench, &seq, &a);
    assert!(again.contains("0 units scored (0 of them trained first), 5 already done"), "{again}");
    assert_eq!(inodes, scores.iter().map(|p| inode(p)).collect::<Vec<_>>(), "no scores file was rewritten");
    assert_eq!(std::fs::read_to_string(a.join("boost.txt")).unwrap(), table);

    // Another benchmark with the same --out: every unit is scored on it, none retrained (the checkpoints
    // keep their modification times), the first scores stay, and the table counts the new pairs.
    let bench2 = dir.path().join("bench2");
    run_ok(&["fragments", support::synthetic_sequence(40, 200).to_str().unwrap(), "--single-frames", "--gaps", "10,15", "--every", "3", "--out", bench2.to_str().unwrap(), "--quiet"]);
    let checkpoints: Vec<PathBuf> = units[1..].iter().map(|u| a.join(u).join("latest.safetensors")).collect();
    let ck_inodes: Vec<_> = checkpoints.iter().map(|p| inode(p)).collect();
    let third = boost(&bench2, &seq, &a);
    assert!(third.contains("5 units scored (0 of them trained first), 0 already done"), "{third}");
    assert_eq!(ck_inodes, checkpoints.iter().map(|p| inode(p)).collect::<Vec<_>>(), "no checkpoint was rewritten");
    assert!(units.iter().all(|u| scores_files(&a.join(u)).len() == 2));
    let pairs_in = |bench: &Path| -> usize {
        let log = std::fs::read_to_string(bench.join("metadata/benchmarks/single-frame/synthetic-200-frames/gt.log")).unwrap();
        log.lines().count() / 5
    };
    let (n1, n2) = (pairs_in(&bench), pairs_in(&bench2));
    assert_ne!(n1, n2, "the two benchmarks must differ for this check");
    // boost.csv: benchmark,samples,condition,seeds,pairs,...
    let c1_pairs = |csv: &str| -> usize {
        let row = csv.lines().map(|l| l.split(',').collect::<Vec<_>>()).find(|f| f[0] == "single-frame" && f[2] == "C1").unwrap();
        row[4].parse().unwrap()
    };
    assert_eq!(c1_pairs(&csv), n1, "{csv}");
    assert_eq!(c1_pairs(&std::fs::read_to_string(a.join("boost.csv")).unwrap()), n2);

    // --redraw with the same --out: seed 0 keeps the protocol's draw (its units are reused), seed 1 of
    // each trained condition draws its own training pairs into seed-1-redrawn/.
    let redrawn = boost_with(&bench, &seq, &a, &["--redraw"]);
    assert!(redrawn.contains("2 units scored (2 of them trained first), 3 already done"), "{redrawn}");
    let listing = |unit: &str| std::fs::read_to_string(a.join(unit).join("training-pairs.tsv")).unwrap();
    assert_ne!(listing("C1/seed-1-redrawn"), listing("C1/seed-1"), "a redraw draws other real pairs");

    // Other training settings with the same --out are refused before any work, naming the record and
    // the setting; the table and every unit stay as they were.
    let before = std::fs::read_to_string(a.join("boost.txt")).unwrap();
    let o = bin().args(boost_args(&bench, &seq, &a, &["--steps", "4"])).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "a rerun with other --steps must fail");
    assert!(err.contains("boost-settings.json") && err.contains("train.steps: recorded 3, now 4"), "{err}");
    assert_eq!(std::fs::read_to_string(a.join("boost.txt")).unwrap(), before);
    assert_eq!(ck_inodes, checkpoints.iter().map(|p| inode(p)).collect::<Vec<_>>(), "no unit retrained");

    // Conditions that read no network run without the models folder (the record names it as given).
    let c = dir.path().join("c");
    let no_models = c.join("no-models");
    boost_with(&bench, &seq, &c, &["--conditions", "C0", "--models", no_models.to_str().unwrap()]);
    assert!(std::fs::read_to_string(c.join("boost-settings.json")).unwrap().contains("no-models"));

    // Determinism: a second run from scratch gives the same table.
    boost(&bench, &seq, &b);
    assert_eq!(std::fs::read_to_string(b.join("boost.txt")).unwrap(), table);

    // C1's real pairs follow the source-side overlap histogram of C3's: C3's overlaps counted from the
    // dataset's rows, C1's by brute force from the clouds `fragments --single-frames` makes of the training
    // frames and the captured poses; every 10 % bin of C1 within one pair of C3's share scaled to C1's count.
    let rows = Dataset::open(a.join("data/classical")).unwrap().read_pairs().unwrap();
    let overlap: HashMap<String, f64> = rows.iter().map(|r| (r.pair_key.clone(), r.overlap_source)).collect();
    let clouds_bench = dir.path().join("train-frames");
    run_ok(&["fragments", seq.to_str().unwrap(), "--single-frames", "--first", "0", "--frames", "30", "--every", "1", "--gaps", "2,4,6,8,10,12,14,16,18,20", "--out", clouds_bench.to_str().unwrap(), "--quiet"]);
    let clouds = clouds_bench.join("synthetic-500-frames");
    let real_overlap = |key: &str| -> f64 {
        let f: Vec<&str> = key.split('/').collect();
        brute_force_source_overlap(&clouds, &seq, f[1].parse().unwrap(), f[2].parse().unwrap())
    };
    // Checked for the protocol's draw and for a redraw.
    let bins = |v: &[f64]| -> Vec<usize> {
        let mut h = vec![0usize; 9];
        for &x in v {
            assert!((0.1..=1.0).contains(&x), "overlap {x} outside 10-100 %");
            h[(((x - 0.1) / 0.1).floor() as usize).min(8)] += 1;
        }
        h
    };
    for seed in ["seed-0", "seed-1-redrawn"] {
        let c3: Vec<f64> = read_tsv(&a.join("C3").join(seed).join("training-pairs.tsv")).iter().map(|(k, _, _)| overlap[k]).collect();
        let c1: Vec<f64> = read_tsv(&a.join("C1").join(seed).join("training-pairs.tsv")).iter().map(|(k, _, _)| real_overlap(k)).collect();
        assert!(c3.len() >= 10 && c1.len() >= 5, "{seed}: {} generated, {} real pairs", c3.len(), c1.len());
        let (h3, h1) = (bins(&c3), bins(&c1));
        for b in 0..9 {
            let share = c1.len() as f64 * h3[b] as f64 / c3.len() as f64;
            assert!((h1[b] as f64 - share).abs() < 1.0, "{seed}, bin {b}: {} real pairs, {share:.2} wanted ({h1:?} vs {h3:?})", h1[b]);
        }
    }
}

/// Frame index of a generated pair key `<scene>/frame-000015#3`.
fn frame_of(key: &str) -> usize {
    let frame = key.split('/').nth(1).unwrap();
    frame.trim_start_matches("frame-").split('#').next().unwrap().parse().unwrap()
}

#[test]
fn the_fragment_regime_runs_end_to_end() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let (seq, held_out) = (support::synthetic_sequence(60, 500), support::synthetic_sequence(40, 200));
    // Two benchmark folders of the held-out scene: fused fragments (3DMatch / 3DLoMatch) and single frames.
    let (frags, singles) = (dir.path().join("frags"), dir.path().join("singles"));
    run_ok(&["fragments", held_out.to_str().unwrap(), "--frames-per-fragment", "10", "--stride", "5", "--out", frags.to_str().unwrap(), "--quiet"]);
    run_ok(&["fragments", held_out.to_str().unwrap(), "--single-frames", "--out", singles.to_str().unwrap(), "--quiet"]);
    // The training fragments' pairs, made by the `fragments` command: what `frag` must train on.
    let train_frags = dir.path().join("train-frags");
    run_ok(&["fragments", seq.to_str().unwrap(), "--frames-per-fragment", "10", "--stride", "5", "--out", train_frags.to_str().unwrap(), "--quiet"]);
    let gt_pairs = |root: &Path, bench: &str| -> usize {
        std::fs::read_to_string(root.join("metadata/benchmarks").join(bench).join("synthetic-500/gt.log")).map_or(0, |t| t.lines().count() / 5)
    };
    let fragment_pairs = gt_pairs(&train_frags, "3DMatch") + gt_pairs(&train_frags, "3DLoMatch");
    assert!(fragment_pairs >= 8, "the test wants a few fragment pairs, got {fragment_pairs}");

    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let out = dir.path().join("boost");
    let classical = root.join("pipelines/paper-3dmatch-classical.toml");
    let args = [
        "eval", "boost", frags.to_str().unwrap(), singles.to_str().unwrap(), "--sequence", seq.to_str().unwrap(), "--first", "0", "--frames", "60",
        "--conditions", "fpfh,frag,frag+nofill:2,frag+reproj:2,frag+single:2,frag4+nofill-lo:2",
        "--fragment-frames", "10", "--fragment-stride", "5", "--source-frames", "fragment-starts", "--reference", "nofill",
        "--seeds", "1", "--pairs", "100", "--epochs", "0.5", "--samples", "200", "--real-every", "1", "--real-gaps", "2,4,6,8,10,12",
        "--classical-config", classical.to_str().unwrap(), "--out", out.to_str().unwrap(), "--quiet",
    ];
    let stdout = run_ok(&args);
    assert!(stdout.contains("6 units scored (5 of them trained first), 0 already done"), "{stdout}");
    let table = std::fs::read_to_string(out.join("boost.txt")).unwrap();
    for want in ["3DMatch, 200 samples", "single-frame, 200 samples", "frag+nofill:2 - frag", "frag+single:2 - frag", "frag - fpfh"] {
        assert!(table.contains(want), "{want} missing from\n{table}");
    }
    // --by-scene: the same units, tables per benchmark and scene (the fragments' scene is synthetic-200,
    // the single frames' synthetic-200-frames); nothing is retrained or rescored.
    let by_scene = run_ok(&[&args[..], &["--by-scene"]].concat());
    assert!(by_scene.contains("0 units scored (0 of them trained first), 6 already done"), "{by_scene}");
    let scene_table = std::fs::read_to_string(out.join("boost.txt")).unwrap();
    for want in ["3DMatch synthetic-200, 200 samples", "single-frame synthetic-200-frames, 200 samples"] {
        assert!(scene_table.contains(want), "{want} missing from\n{scene_table}");
    }
    assert!(!scene_table.contains("3DMatch, 200 samples"), "{scene_table}");
    run_ok(&args); // back to the pooled tables for the checks below
    let listing = |unit: &str| read_tsv(&out.join(unit).join("seed-0/training-pairs.tsv"));
    let (frag, nofill, reproj, single, scarce) =
        (listing("frag"), listing("frag_nofill_2"), listing("frag_reproj_2"), listing("frag_single_2"), listing("frag4_nofill-lo_2"));
    // `frag` trains on every pair of the training fragments, as the `fragments` command counts them.
    assert_eq!(frag.len(), fragment_pairs);
    let n = frag.len();
    let generated = |l: &[(String, f64, f64)]| -> Vec<String> { l.iter().filter(|(k, _, _)| !k.contains("-fragments/")).map(|(k, _, _)| k.clone()).collect() };
    // 2:1 mixes: the base's n real pairs, then 2n others (the real single frames: as many as their
    // histogram match allows, at most 2n).
    for (name, l) in [("nofill", &nofill), ("reproj", &reproj), ("single", &single)] {
        assert_eq!(l[..n].iter().map(|t| &t.0).collect::<Vec<_>>(), frag.iter().map(|t| &t.0).collect::<Vec<_>>(), "{name}: the same real base");
    }
    assert_eq!((nofill.len(), reproj.len()), (3 * n, 3 * n));
    assert!(single.len() > n && single.len() <= 3 * n, "{} single-frame pairs", single.len() - n);
    // Real single-frame keys are `<scene>/<i>/<j>` with frames i < j.
    assert!(single[n..].iter().all(|(k, _, _)| { let f: Vec<&str> = k.split('/').collect(); f.len() == 3 && f[1].parse::<usize>().unwrap() < f[2].parse::<usize>().unwrap() }));
    // Generated pairs come from the fragments' first frames (every 5th frame) and are paired unit by unit.
    let (g_nofill, g_reproj) = (generated(&nofill), generated(&reproj));
    assert_eq!(g_nofill.len(), 2 * n);
    assert!(g_nofill.iter().chain(&g_reproj).all(|k| frame_of(k) % 5 == 0), "{g_nofill:?}");
    assert_eq!(g_nofill, g_reproj, "the two generators' pairs share their units");
    // The scarce-real condition: 4 real fragment pairs and 8 low-overlap-targeted generated ones.
    assert_eq!(scarce.len(), 12);
    assert_eq!(scarce.iter().filter(|(k, _, _)| k.contains("-fragments/")).count(), 4);
    // -lo steers poses to lower overlaps: its pool has a larger share at 10-30 % (source side, from rows).
    let low_share = |name: &str| -> f64 {
        let rows = Dataset::open(out.join("data").join(name)).unwrap().read_pairs().unwrap();
        let ok: Vec<f64> = rows.iter().filter(|r| r.status == pointreggpt::shards::Status::Ok).map(|r| r.overlap_source).collect();
        ok.iter().filter(|&&o| o <= 0.3).count() as f64 / ok.len() as f64
    };
    assert!(low_share("nofill-lo") > low_share("nofill") + 0.2, "{} vs {}", low_share("nofill-lo"), low_share("nofill"));
    // Training by exposure: half an epoch of 3n pairs at 4 pairs per step.
    let last_step = |unit: &str| -> u64 {
        let log = std::fs::read_to_string(out.join(unit).join("seed-0/loss.jsonl")).unwrap();
        let line = log.lines().last().unwrap();
        serde_json::from_str::<serde_json::Value>(line).unwrap()["step"].as_u64().unwrap()
    };
    assert_eq!(last_step("frag_nofill_2"), ((0.5 * (3 * n) as f64) / 4.0).ceil() as u64);
    assert_eq!(last_step("frag"), ((0.5 * n as f64) / 4.0).ceil() as u64);
}

/// Whether a training-pairs key names a real single-frame pair (`<scene>/<i>/<j>`) rather than a generated
/// one (`<scene>/frame-000012#3`).
fn is_real(key: &str) -> bool {
    !key.contains('#')
}

#[test]
fn every_alias_and_the_fpfh_mlp_run_with_their_counts_and_other_settings_are_refused() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    // The tiny run's training scene: its real single-frame pairs cover the classical generator's overlap
    // histogram, so C5 and C6 get real pairs (a scene whose pairs miss a bin gets none: "no training pairs").
    let seq = support::synthetic_sequence(50, 500);
    let bench = support::single_frame_bench(40, 200, &["--every", "10"]);
    let out = dir.path().join("all");
    let extra = ["--conditions", "C2,C4,C5,C5x2,C6,C6x2", "--seeds", "1", "--pairs", "12", "--steps", "2", "--samples", "100", "--model", "fpfh-mlp"];
    let stdout = boost_with(&bench, &seq, &out, &extra);
    assert!(stdout.contains("6 units scored (6 of them trained first), 0 already done"), "{stdout}");
    let table = std::fs::read_to_string(out.join("boost.txt")).unwrap();
    for want in ["C2 (reproj)", "C4 (neural)", "C5 (single:0.5+classical:0.5)", "C5x2 (single+classical)", "C6x2 (single+neural)", "C5 - C1"] {
        if want == "C5 - C1" {
            assert!(!table.contains(want), "C1 did not run: no C5 - C1 row\n{table}");
        } else {
            assert!(table.contains(want), "{want} missing from\n{table}");
        }
    }
    // The mixes' counts: C5 takes ⌈n/2⌉ real and ⌊n/2⌋ generated pairs of C1's n, C5x2 n and n.
    let listing = |c: &str| read_tsv(&out.join(c).join("seed-0/training-pairs.tsv"));
    let split = |c: &str| -> (usize, usize) { let l = listing(c); let r = l.iter().filter(|(k, _, _)| is_real(k)).count(); (r, l.len() - r) };
    let (r2, g2) = split("C5x2");
    assert!(r2 > 0 && g2 == r2, "C5x2: {r2} real, {g2} generated");
    assert_eq!(split("C5"), (r2.div_ceil(2), r2 / 2));
    assert_eq!(split("C6x2"), (r2, r2));
    assert_eq!(split("C6"), (r2.div_ceil(2), r2 / 2));
    assert_eq!(split("C2"), (0, 12));
    assert_eq!(split("C4"), (0, 12));
    // C6's generated pairs come from the neural generator: its dataset was built with the U-Net and the
    // diffusion refiner; C2's from re-projection only.
    let config = |g: &str| std::fs::read_to_string(out.join("data").join(g).join("dataset.toml")).unwrap();
    assert!(config("neural").contains("method = \"unet\"") && config("neural").contains("method = \"diffusion\""));
    assert!(config("reproj").contains("[inpaint]\nmethod = \"none\""));
    assert!(listing("C6").iter().filter(|(k, _, _)| !is_real(k)).all(|(k, _, _)| listing("C4").iter().any(|(l, _, _)| l == k)), "C6 draws from C4's pool");
    // Every unit trained the MLP on FPFH.
    let meta = pointreggpt::registration::learned::read_meta(&out.join("C5/seed-0/latest.safetensors")).unwrap();
    assert!(matches!(meta.model, pointreggpt::registration::learned::DescriptorModel::FpfhMlp { .. }), "{:?}", meta.model);

    // Any other training setting with the same --out is refused, naming it; nothing is retrained.
    let classical = dir.path().join("classical.toml");
    let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("pipelines/paper-3dmatch-classical.toml")).unwrap();
    assert_eq!(text.matches("\nvoxel = 0.025\n").count(), 1, "the classical config's voxel size");
    std::fs::write(&classical, text.replace("\nvoxel = 0.025\n", "\nvoxel = 0.03\n")).unwrap();
    for (flag, value, named) in [
        ("--pairs", "13", "pairs: recorded 12, now 13"),
        ("--frames", "29", "frames: recorded 30, now 29"),
        ("--real-gaps", "2,4", "real_gaps"),
        ("--model", "patch", "train.model"),
        ("--epochs", "2", "train.epochs"),
        ("--classical-config", classical.to_str().unwrap(), "classical.voxelize.voxel"),
    ] {
        // `extra` with `flag`'s value replaced (or the flag added).
        let mut args = extra.to_vec();
        match args.iter().position(|a| *a == flag) {
            Some(i) => args[i + 1] = value,
            None => args.extend([flag, value]),
        }
        let o = bin().args(boost_args(&bench, &seq, &out, &args)).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && err.contains(named), "{flag} {value}: {err}");
    }
    // The same settings again: every unit is done.
    assert!(boost_with(&bench, &seq, &out, &extra).contains("0 units scored (0 of them trained first), 6 already done"));
}

/// The scene of a real single-frame key `<scene>/<i>/<j>` or a generated key `<scene>/frame-000012#3`.
fn scene_of(key: &str) -> &str {
    key.split('/').next().unwrap()
}

/// Several training sequences (`--sequence` twice), a benchmark of two scenes read `--by-scene`, and
/// `--compare`: real and generated pairs come from both sequences (a run that used only the first, or
/// numbered the units of both alike so that generators paired pairs of different sequences, fails), the
/// generators' pairs still pair up unit by unit; each per-scene table row is the aggregation of the
/// per-pair scores of that scene alone (the scenes' pair counts add up to the pooled table's); and the
/// difference asked for with `--compare` appears, equal to the paired mean of the scores, and not without it.
#[test]
fn several_sequences_tables_by_scene_and_compare() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    let (a, b) = (support::synthetic_sequence(50, 500), support::synthetic_sequence(30, 501));
    let bench = dir.path().join("bench");
    for seed in [200, 201] {
        let held_out = support::synthetic_sequence(40, seed);
        run_ok(&["fragments", held_out.to_str().unwrap(), "--single-frames", "--every", "10", "--out", bench.to_str().unwrap(), "--quiet"]);
    }
    let out = dir.path().join("boost");
    // 30 frames of each sequence, one generated pair per frame (60 units per generator): --pairs 40 takes
    // generated pairs of both. (The generated draw takes the units in unit order, sequence by sequence:
    // with --pairs 30 or less they would all be the first sequence's.)
    let (seq_a, seq_b) = (format!("{}@0-29", a.display()), format!("{}@0-29", b.display()));
    let args = |extra: &[&str]| -> Vec<String> {
        let mut v = boost_args(&bench, &a, &out, &["--conditions", "C0,C1,C2,C3", "--seeds", "1", "--pairs", "40", "--steps", "2", "--samples", "100"]);
        // Both sequences, each with its frames, in place of the tiny run's one.
        let i = v.iter().position(|x| x == "--sequence").unwrap();
        v.splice(i..i + 2, ["--sequence".to_string(), seq_a.clone(), "--sequence".to_string(), seq_b.clone()]);
        v.extend(extra.iter().map(|s| s.to_string()));
        v
    };
    let run_args = |extra: &[&str]| run_ok(&args(extra).iter().map(String::as_str).collect::<Vec<_>>());
    let first = run_args(&["--by-scene", "--compare", "C2-C1"]);
    assert!(first.contains("4 units scored (3 of them trained first), 0 already done"), "{first}");

    // Both sequences gave pairs: each generator a dataset per sequence, every training set pairs of both.
    for g in ["classical", "reproj"] {
        for k in ["0", "1"] {
            assert!(out.join("data").join(g).join(k).join("dataset.toml").is_file(), "no {g} dataset of sequence {k}");
        }
    }
    let listing = |c: &str| read_tsv(&out.join(c).join("seed-0/training-pairs.tsv"));
    let scenes = |c: &str| listing(c).iter().map(|(k, _, _)| scene_of(k).to_string()).collect::<std::collections::BTreeSet<_>>();
    for c in ["C1", "C2", "C3"] {
        assert_eq!(scenes(c), ["synthetic-500".to_string(), "synthetic-501".to_string()].into(), "{c}: the scenes of its training pairs");
    }
    // The two generators' pairs pair up unit by unit: the same keys in the same order.
    let keys = |c: &str| listing(c).into_iter().map(|(k, _, _)| k).collect::<Vec<_>>();
    assert_eq!(keys("C2"), keys("C3"), "C2's and C3's generated pairs share their units");
    assert_eq!(keys("C2").len(), 40);

    // --by-scene: a row per benchmark scene, each the aggregation of that scene's per-pair scores.
    let scores = |unit: &str| {
        let files = scores_files(&out.join(unit));
        assert_eq!(files.len(), 1, "{unit}: {files:?}");
        std::fs::read_to_string(&files[0]).unwrap()
    };
    let units = [("C0", "C0"), ("C1", "C1/seed-0"), ("C2", "C2/seed-0"), ("C3", "C3/seed-0")];
    // (condition, scene) -> per-pair inlier ratios at 100 samples.
    let mut per_scene: BTreeMap<(String, String), Vec<((String, usize, usize), f64)>> = BTreeMap::new();
    for (c, unit) in units {
        for line in scores(unit).lines().skip(1) {
            let f: Vec<&str> = line.split('\t').collect();
            assert_eq!(f[4], "100");
            per_scene.entry((c.to_string(), f[1].to_string())).or_default().push(((f[1].to_string(), f[2].parse().unwrap(), f[3].parse().unwrap()), f[6].parse().unwrap()));
        }
    }
    let scene_names: std::collections::BTreeSet<String> = per_scene.keys().map(|(_, s)| s.clone()).collect();
    assert_eq!(scene_names, ["synthetic-200-frames".to_string(), "synthetic-201-frames".to_string()].into());
    let csv = std::fs::read_to_string(out.join("boost.csv")).unwrap();
    let mut rows = 0;
    for line in csv.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let scene = f[0].strip_prefix("single-frame ").unwrap_or_else(|| panic!("not a per-scene row: {line}"));
        let pairs = &per_scene[&(f[2].to_string(), scene.to_string())];
        let mean = 100.0 * pairs.iter().map(|p| p.1).sum::<f64>() / pairs.len() as f64;
        assert_eq!(f[4].parse::<usize>().unwrap(), pairs.len(), "{line}: pairs of {scene}");
        assert!((f[8].parse::<f64>().unwrap() - mean).abs() < 1e-3, "{line}: IR {mean} from {scene}'s scores");
        rows += 1;
    }
    assert_eq!(rows, 4 * 2, "a row per condition and scene:\n{csv}");
    // --compare: the asked difference, the paired mean of the scores (per scene here).
    let paired = std::fs::read_to_string(out.join("boost-paired.csv")).unwrap();
    let compared: Vec<&str> = paired.lines().filter(|l| { let f: Vec<&str> = l.split(',').collect(); f[2] == "C2" && f[3] == "C1" }).collect();
    assert_eq!(compared.len(), 2, "one C2 - C1 row per scene:\n{paired}");
    for line in compared {
        let f: Vec<&str> = line.split(',').collect();
        let scene = f[0].strip_prefix("single-frame ").unwrap();
        let (x, y) = (&per_scene[&("C2".to_string(), scene.to_string())], &per_scene[&("C1".to_string(), scene.to_string())]);
        let diffs: Vec<f64> = x.iter().zip(y).map(|(p, q)| { assert_eq!(p.0, q.0, "paired on the same pairs"); 100.0 * (p.1 - q.1) }).collect();
        assert_eq!(f[4].parse::<usize>().unwrap(), diffs.len(), "{line}");
        assert!((f[5].parse::<f64>().unwrap() - diffs.iter().sum::<f64>() / diffs.len() as f64).abs() < 1e-3, "{line}");
    }

    // Pooled, without --compare: nothing is redone; the scenes' pair counts add up; no C2 - C1 row; the
    // pooled numbers are the scores' (C2 - C1 checked through --compare above, C3 - C2 by default).
    let pooled = run_args(&[]);
    assert!(pooled.contains("0 units scored (0 of them trained first), 4 already done"), "{pooled}");
    let csv = std::fs::read_to_string(out.join("boost.csv")).unwrap();
    for line in csv.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        assert_eq!(f[0], "single-frame", "{line}");
        let total: usize = scene_names.iter().map(|s| per_scene[&(f[2].to_string(), s.clone())].len()).sum();
        assert_eq!(f[4].parse::<usize>().unwrap(), total, "{line}: the scenes' pairs together");
    }
    let paired = std::fs::read_to_string(out.join("boost-paired.csv")).unwrap();
    assert!(!paired.lines().any(|l| l.contains(",C2,C1,")), "a C2 - C1 row without --compare:\n{paired}");
    check_table_against_scores(&out, &[("C0", vec!["C0"]), ("C1", vec!["C1/seed-0"]), ("C2", vec!["C2/seed-0"]), ("C3", vec!["C3/seed-0"])], &[("C3", "C2"), ("C1", "C0")]);
}

/// The posed-input configs the README recommends are the generators `eval boost` measured: the shipped
/// classical config with the generator's overrides, every frame a source, 4 views each.
#[test]
fn the_shipped_nofill_and_scene_configs_are_the_generators_eval_boost_measures() {
    let _timing = crate::support::timed();
    use pointreggpt::pipeline::config::BuildConfig;
    use pointreggpt::pipeline::load::load_toml;
    use pointreggpt::training::boost::conditions::{Generator, GeneratorKind};
    let pipelines = Path::new(env!("CARGO_MANIFEST_DIR")).join("pipelines");
    let generator = |kind| -> BuildConfig {
        let mut sets: Vec<String> =
            Generator { kind, lo: false }.overrides(Path::new("models")).into_iter().map(|(k, v)| format!("{k}={v}")).collect();
        sets.extend(["select.every=1".to_string(), "samples_per_frame=4".to_string()]);
        load_toml(&pipelines.join("paper-3dmatch-classical.toml"), &sets).unwrap()
    };
    let shipped = |name: &str| -> BuildConfig { load_toml(&pipelines.join(name), &[]).unwrap() };
    assert_eq!(shipped("paper-3dmatch-nofill.toml"), generator(GeneratorKind::NoFill));
    assert_eq!(shipped("paper-3dmatch-scene.toml"), generator(GeneratorKind::Scene));
    // The comparison can fail: the classical generator (its background fill) is neither.
    assert_ne!(shipped("paper-3dmatch-nofill.toml"), generator(GeneratorKind::Classical));
    assert_ne!(shipped("paper-3dmatch-scene.toml"), generator(GeneratorKind::NoFill));
}
