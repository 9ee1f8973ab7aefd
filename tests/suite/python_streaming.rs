//! `StreamingPairDataset`'s order and its torch.distributed defaults (tests/python/streaming_check.py), on
//! a dataset whose shards hold several row groups and rejected rows: unshuffled it gives the `ok` pairs in
//! file order; shuffled, each consumer gives exactly the pairs of its pieces, in their reading order up to
//! the shuffle buffer (every pair within `buffer_size` places, most pairs moved); consumers' counts differ
//! by at most a piece; and two processes in a torch.distributed group that name no rank stream disjoint
//! halves of the pairs, each what its explicit rank streams. The once-per-epoch and same-bytes checks are
//! in python_package.rs.

use crate::support::{bin, python, synthetic_config};
use std::path::Path;

#[test]
fn the_stream_keeps_file_order_bounds_its_shuffle_and_takes_ranks_from_torch_distributed() {
    let _timing = crate::support::timed();
    let dir = tempfile::tempdir().unwrap();
    // 120 units in shards of 50 (50, 50, 20 rows) in row groups of 7: 8, 8 and 3 groups, some rejected.
    let config = dir.path().join("config.toml");
    std::fs::write(&config, synthetic_config(1, 60, 1, 2, 160, 120, 50) + "[validate]\nmin_overlap = 0.6\n[output]\nrow_group_rows = 7\n").unwrap();
    let ds = dir.path().join("ds");
    let o = bin().args(["build", config.to_str().unwrap(), "--out", ds.to_str().unwrap(), "--no-progress"]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let scratch = dir.path().join("scratch");
    std::fs::create_dir(&scratch).unwrap();
    let plan = dir.path().join("plan.json");
    std::fs::write(&plan, serde_json::json!({"dataset": ds, "scratch": scratch}).to_string()).unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/streaming_check.py");
    let o = crate::support::command(python()).arg(script).arg(&plan).current_dir(dir.path()).output().unwrap();
    let (out, err) = (String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    assert!(o.status.success(), "tests/python/streaming_check.py failed:\n{out}\n{err}");
    let report: serde_json::Value = serde_json::from_str(out.trim().lines().last().unwrap()).unwrap();
    let ok = report["ok"].as_u64().unwrap();
    assert!(ok > 20 && ok < 120, "ok and rejected rows: {report}");
    assert_eq!(report["row_groups"], 19, "{report}");
    assert_eq!(report["per_consumer"].as_array().unwrap().len(), 6, "{report}");
    assert_eq!(report["distributed"].as_array().unwrap().iter().map(|n| n.as_u64().unwrap()).sum::<u64>(), ok, "{report}");
}
