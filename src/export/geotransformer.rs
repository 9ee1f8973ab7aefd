//! GeoTransformer's 3DMatch layout (`ThreeDMatchPairDataset`, `dataset_root` = the export folder):
//!
//! ```text
//! <out>/metadata/train.pkl                      list of dicts, pickle protocol 2 (see below)
//! <out>/data/train/<scene>/cloud_bin_<i>.pth    float32 (N, 3) numpy array saved as torch.save saves it
//!                                               (pth.rs), each cloud in its own camera frame
//! <out>/data/train/<scene>/cloud_bin_<i>.known_share.pth, .scene_share.pth, .view.pth
//!                                               the target cloud's per-point provenance: float32 (N,),
//!                                               float32 (N,) and int8 (N,) numpy arrays, the
//!                                               `target_known_share` / `target_scene_share` /
//!                                               `target_view` columns (not written for version-1 datasets)
//! <out>/metadata/pairs.tsv                      export index → pair key, unit index, pcd0, pcd1
//! ```
//!
//! GeoTransformer reads every cloud with `torch.load(osp.join(data_root, pcd))`, as it reads the `.pth`
//! files of its own 3DMatch data (numpy arrays saved with `torch.save`); PyTorch ≥ 2.6 defaults to
//! `weights_only=True`, which refuses numpy arrays in its files and ours alike, so the loader needs
//! `weights_only=False` (or numpy's reconstruct functions in `torch.serialization.add_safe_globals`).
//! `CloudFormat::Npy` (`--cloud-format npy`) writes `.npy` files (np.load) instead, every path in `.npy`.
//!
//! Pair number `k` (export order) has `frag_id0 = 2k` (the target cloud, GeoTransformer's `ref`) and
//! `frag_id1 = 2k + 1` (the source cloud, `src`). Each dict is `{scene_name, frag_id0, frag_id1,
//! overlap, pcd0, pcd1, rotation, translation}` with `pcd0`/`pcd1` relative to `<out>/data`,
//! `rotation` float64 (3, 3) and `translation` float64 (3,) = `T_target_from_source`, so that
//! `ref = src @ rotation.T + translation` (GeoTransformer's convention) where the clouds overlap.
//! `overlap` is `overlap_target`, the fraction of `pcd0`'s points with a neighbour (as the authors'
//! mixture loader uses the overlap of its `pcd0`). When the dataset has provenance, the dict also has
//! `pcd0_known_share`, `pcd0_scene_share` and `pcd0_view`, the paths of those files (GeoTransformer
//! ignores extra keys).

use super::npy::{encode_npy_points, encode_npy_vector_f32, encode_npy_vector_i8, write_npy};
use super::pickle::{dumps, Value};
use super::pth::{archive_name, encode_pth, encode_pth_points, write_pth};
use super::rows::sanitize;
use super::{is_ok, write_text, PairWriter};
use crate::error::{Error, Result};
use crate::shards::row::PairRow;
use std::path::{Path, PathBuf};

/// The subset name: the pickle is `metadata/<SUBSET>.pkl` and the clouds live under `data/<SUBSET>/`.
pub const SUBSET: &str = "train";

/// The file format of the clouds (and provenance arrays) of a GeoTransformer export.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum CloudFormat {
    /// `.pth`: numpy arrays in PyTorch's zip serialization, what GeoTransformer's loader reads with
    /// `torch.load` (as its own 3DMatch files).
    #[default]
    Pth,
    /// `.npy`: numpy arrays for `np.load` (GeoTransformer's loader then needs a one-line change).
    Npy,
}

impl CloudFormat {
    /// The file extension, with its dot.
    pub fn extension(self) -> &'static str {
        match self {
            CloudFormat::Pth => ".pth",
            CloudFormat::Npy => ".npy",
        }
    }
}

/// Writes GeoTransformer's layout; see the module documentation.
pub struct GeoTransformerWriter {
    out: PathBuf,
    clouds: CloudFormat,
    entries: Vec<Value>,
    tsv: String,
}

impl GeoTransformerWriter {
    /// A writer into `out` (which exists and is empty) with clouds as `clouds` files.
    pub fn new(out: &Path, clouds: CloudFormat) -> Self {
        GeoTransformerWriter { out: out.to_path_buf(), clouds, entries: Vec::new(), tsv: "index\tpair_key\tunit_index\tpcd0\tpcd1\n".into() }
    }

    /// Writes `value` (a numpy array) to `data/<rel>` in the cloud format; `npy` is its `.npy` bytes.
    fn write_array(&self, rel: &str, value: Value, npy: impl FnOnce() -> Vec<u8>) -> Result<()> {
        let path = self.out.join("data").join(rel);
        match self.clouds {
            CloudFormat::Pth => write_pth(&path, &encode_pth(&archive_name(&path), &value)),
            CloudFormat::Npy => write_npy(&path, &npy()),
        }
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
        let ext = self.clouds.extension();
        let pcd0 = format!("{SUBSET}/{scene}/cloud_bin_{}{ext}", 2 * index);
        let pcd1 = format!("{SUBSET}/{scene}/cloud_bin_{}{ext}", 2 * index + 1);
        let data = self.out.join("data");
        for (rel, points) in [(&pcd0, &row.target_points), (&pcd1, &row.source_points)] {
            match self.clouds {
                CloudFormat::Pth => {
                    let path = data.join(rel);
                    write_pth(&path, &encode_pth_points(&archive_name(&path), points))?
                }
                CloudFormat::Npy => write_npy(&data.join(rel), &encode_npy_points(points))?,
            }
        }
        let mut e = entry(index, row, &pcd0, &pcd1);
        let n = row.target_points.len();
        if row.target_known_share.len() == n && row.target_scene_share.len() == n && row.target_view.len() == n {
            let stem = pcd0.trim_end_matches(ext);
            let (known, scene, view) = (format!("{stem}.known_share{ext}"), format!("{stem}.scene_share{ext}"), format!("{stem}.view{ext}"));
            for (file, shares) in [(&known, &row.target_known_share), (&scene, &row.target_scene_share)] {
                self.write_array(file, Value::ArrayF32 { shape: vec![n], data: shares.clone() }, || encode_npy_vector_f32(shares))?;
            }
            let views: Vec<i8> = row.target_view.iter().map(|&v| v as i8).collect();
            self.write_array(&view, Value::ArrayI8 { shape: vec![views.len()], data: views.clone() }, || encode_npy_vector_i8(&views))?;
            if let Value::Dict(items) = &mut e {
                items.push(("pcd0_known_share".into(), Value::Str(known)));
                items.push(("pcd0_scene_share".into(), Value::Str(scene)));
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
        let mut w = GeoTransformerWriter::new(dir.path(), CloudFormat::Npy);
        w.write(3, &row).unwrap();
        assert_eq!(w.finish().unwrap(), None);
        let d = dir.path().join("data/train/s");
        assert_eq!(read_npy_points(&d.join("cloud_bin_6.npy")).unwrap(), row.target_points);
        assert_eq!(read_npy_points(&d.join("cloud_bin_7.npy")).unwrap(), row.source_points);
        let pkl = std::fs::read(dir.path().join("metadata/train.pkl")).unwrap();
        let text = String::from_utf8_lossy(&pkl);
        assert!(text.contains("train/s/cloud_bin_6.npy") && text.contains("rotation") && text.contains("translation"));
        // The default: .pth clouds (their bytes are what pth.rs encodes) and .pth paths in the pickle.
        let pth = tempfile::tempdir().unwrap();
        let mut w = GeoTransformerWriter::new(pth.path(), CloudFormat::default());
        row.target_known_share = vec![1.0, 0.5];
        row.target_scene_share = vec![0.0, 0.25];
        row.target_view = vec![0, 1];
        w.write(3, &row).unwrap();
        w.finish().unwrap();
        let d = pth.path().join("data/train/s");
        assert_eq!(std::fs::read(d.join("cloud_bin_6.pth")).unwrap(), encode_pth_points("cloud_bin_6", &row.target_points));
        assert_eq!(std::fs::read(d.join("cloud_bin_7.pth")).unwrap(), encode_pth_points("cloud_bin_7", &row.source_points));
        let view = Value::ArrayI8 { shape: vec![2], data: vec![0, 1] };
        assert_eq!(std::fs::read(d.join("cloud_bin_6.view.pth")).unwrap(), encode_pth("cloud_bin_6.view", &view));
        assert!(d.join("cloud_bin_6.known_share.pth").exists() && !d.join("cloud_bin_6.npy").exists());
        let scene = Value::ArrayF32 { shape: vec![2], data: vec![0.0, 0.25] };
        assert_eq!(std::fs::read(d.join("cloud_bin_6.scene_share.pth")).unwrap(), encode_pth("cloud_bin_6.scene_share", &scene));
        let text = String::from_utf8_lossy(&std::fs::read(pth.path().join("metadata/train.pkl")).unwrap()).into_owned();
        assert!(text.contains("train/s/cloud_bin_6.pth") && text.contains("train/s/cloud_bin_6.view.pth") && !text.contains(".npy"));
        match entry(3, &row, "a", "b") {
            Value::Dict(items) => {
                assert_eq!(items[6].1, Value::ArrayF64 { shape: vec![3, 3], data: vec![1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0] });
                assert_eq!(items[7].1, Value::ArrayF64 { shape: vec![3], data: vec![0.5, 0.0, 0.0] });
            }
            other => panic!("{other:?}"),
        }
    }
}
