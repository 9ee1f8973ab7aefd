//! GeoTransformer's 3DMatch layout (`ThreeDMatchPairDataset`, `dataset_root` = the export folder):
//!
//! ```text
//! <out>/metadata/train.pkl                      list of dicts, pickle protocol 2 (see below)
//! <out>/data/train/<scene>/cloud_bin_<i>.npy    float32 (N, 3), each cloud in its own camera frame
//! <out>/data/train/<scene>/cloud_bin_<i>.known_share.npy, .view.npy
//!                                               the target cloud's per-point provenance: float32 (N,)
//!                                               and int8 (N,), the `target_known_share` / `target_view`
//!                                               columns (not written for version-1 datasets)
//! <out>/metadata/pairs.tsv                      export index → pair key, unit index, pcd0, pcd1
//! ```
//!
//! Pair number `k` (export order) has `frag_id0 = 2k` (the target cloud, GeoTransformer's `ref`) and
//! `frag_id1 = 2k + 1` (the source cloud, `src`). Each dict is `{scene_name, frag_id0, frag_id1,
//! overlap, pcd0, pcd1, rotation, translation}` with `pcd0`/`pcd1` relative to `<out>/data`,
//! `rotation` float64 (3, 3) and `translation` float64 (3,) = `T_target_from_source`, so that
//! `ref = src @ rotation.T + translation` (GeoTransformer's convention) where the clouds overlap.
//! `overlap` is `overlap_target`, the fraction of `pcd0`'s points with a neighbour (as the authors'
//! mixture loader uses the overlap of its `pcd0`). When the dataset has provenance, the dict also has
//! `pcd0_known_share` and `pcd0_view`, the paths of those two files (GeoTransformer ignores extra keys).

use super::npy::{encode_npy_vector_f32, encode_npy_vector_i8, write_npy, write_npy_points};
use super::pickle::{dumps, Value};
use super::rows::sanitize;
use super::{is_ok, write_text, PairWriter};
use crate::error::{Error, Result};
use crate::shards::row::PairRow;
use std::path::{Path, PathBuf};

/// The subset name: the pickle is `metadata/<SUBSET>.pkl` and the clouds live under `data/<SUBSET>/`.
pub const SUBSET: &str = "train";

/// Writes GeoTransformer's layout; see the module documentation.
pub struct GeoTransformerWriter {
    out: PathBuf,
    entries: Vec<Value>,
    tsv: String,
}

impl GeoTransformerWriter {
    /// A writer into `out` (which exists and is empty).
    pub fn new(out: &Path) -> Self {
        GeoTransformerWriter { out: out.to_path_buf(), entries: Vec::new(), tsv: "index\tpair_key\tunit_index\tpcd0\tpcd1\n".into() }
    }
}

/// The metadata dict of pair `index` whose clouds are at `pcd0` (target) and `pcd1` (source).
pub fn entry(index: u64, row: &PairRow, pcd0: &str, pcd1: &str) -> Value {
    let t = &row.t_target_from_source;
    let rotation = vec![t[0], t[1], t[2], t[4], t[5], t[6], t[8], t[9], t[10]];
    Value::Dict(vec![
        ("scene_name".into(), Value::Str(row.scene.clone())),
        ("frag_id0".into(), Value::Int(2 * index as i64)),
        ("frag_id1".into(), Value::Int(2 * index as i64 + 1)),
        ("overlap".into(), Value::Float(row.overlap_target)),
        ("pcd0".into(), Value::Str(pcd0.into())),
        ("pcd1".into(), Value::Str(pcd1.into())),
        ("rotation".into(), Value::ArrayF64 { shape: vec![3, 3], data: rotation }),
        ("translation".into(), Value::ArrayF64 { shape: vec![3], data: vec![t[3], t[7], t[11]] }),
    ])
}

impl PairWriter for GeoTransformerWriter {
    fn accepts(&self, row: &PairRow) -> bool {
        is_ok(row)
    }

    fn write(&mut self, index: u64, row: &PairRow) -> Result<()> {
        if index > (i64::MAX / 2 - 1) as u64 {
            return Err(Error::Internal("pair index overflows a fragment id".into()));
        }
        let scene = sanitize(&row.scene);
        let pcd0 = format!("{SUBSET}/{scene}/cloud_bin_{}.npy", 2 * index);
        let pcd1 = format!("{SUBSET}/{scene}/cloud_bin_{}.npy", 2 * index + 1);
        let data = self.out.join("data");
        write_npy_points(&data.join(&pcd0), &row.target_points)?;
        write_npy_points(&data.join(&pcd1), &row.source_points)?;
        let mut e = entry(index, row, &pcd0, &pcd1);
        if row.target_known_share.len() == row.target_points.len() && row.target_view.len() == row.target_points.len() {
            let stem = pcd0.trim_end_matches(".npy");
            let (known, view) = (format!("{stem}.known_share.npy"), format!("{stem}.view.npy"));
            write_npy(&data.join(&known), &encode_npy_vector_f32(&row.target_known_share))?;
            let views: Vec<i8> = row.target_view.iter().map(|&v| v as i8).collect();
            write_npy(&data.join(&view), &encode_npy_vector_i8(&views))?;
            if let Value::Dict(items) = &mut e {
                items.push(("pcd0_known_share".into(), Value::Str(known)));
                items.push(("pcd0_view".into(), Value::Str(view)));
            }
        }
        self.entries.push(e);
        self.tsv.push_str(&format!("{index}\t{}\t{}\t{pcd0}\t{pcd1}\n", row.pair_key, row.unit_index));
        Ok(())
    }

    fn finish(&mut self) -> Result<Option<u64>> {
        let meta = self.out.join("metadata");
        std::fs::create_dir_all(&meta).map_err(|e| Error::io(&meta, e))?;
        let list = Value::List(std::mem::take(&mut self.entries));
        let path = meta.join(format!("{SUBSET}.pkl"));
        std::fs::write(&path, dumps(&list)).map_err(|e| Error::io(&path, e))?;
        write_text(&meta.join("pairs.tsv"), &self.tsv)?;
        Ok(None)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::export::npy::read_npy_points;
    use crate::export::tests_support::empty_row;
    use crate::geometry::Point;

    #[test]
    fn writes_clouds_and_a_pickle_with_the_rotation_rows() {
        let dir = tempfile::tempdir().unwrap();
        let mut row = empty_row();
        row.source_points = vec![Point::new(1.0, 2.0, 3.0)];
        row.target_points = vec![Point::new(4.0, 5.0, 6.0), Point::new(7.0, 8.0, 9.0)];
        row.t_target_from_source[3] = 0.5;
        let mut w = GeoTransformerWriter::new(dir.path());
        w.write(3, &row).unwrap();
        assert_eq!(w.finish().unwrap(), None);
        let d = dir.path().join("data/train/s");
        assert_eq!(read_npy_points(&d.join("cloud_bin_6.npy")).unwrap(), row.target_points);
        assert_eq!(read_npy_points(&d.join("cloud_bin_7.npy")).unwrap(), row.source_points);
        let pkl = std::fs::read(dir.path().join("metadata/train.pkl")).unwrap();
        let text = String::from_utf8_lossy(&pkl);
        assert!(text.contains("train/s/cloud_bin_6.npy") && text.contains("rotation") && text.contains("translation"));
        match entry(3, &row, "a", "b") {
            Value::Dict(items) => {
                assert_eq!(items[6].1, Value::ArrayF64 { shape: vec![3, 3], data: vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0] });
                assert_eq!(items[7].1, Value::ArrayF64 { shape: vec![3], data: vec![0.5, 0.0, 0.0] });
            }
            other => panic!("{other:?}"),
        }
    }
}
