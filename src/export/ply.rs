//! Plain PLY pairs, one folder per pair (every matching row, rejected ones included):
//!
//! ```text
//! <out>/<pair key, sanitized>/source.ply                 source cloud, source camera frame
//! <out>/<pair key, sanitized>/target.ply                 target cloud, target camera frame, with the vertex
//!                                                        properties `known_share` and `view` (provenance)
//! <out>/<pair key, sanitized>/T_target_from_source.txt   the stored 4×4 (p_t = R·p_s + t)
//! <out>/metadata/pairs.tsv                               folder → pair key, unit index, status
//! ```

use super::rows::unique_name;
use super::{matrix_text, write_text, PairWriter};
use crate::error::Result;
use crate::shards::row::PairRow;
use crate::ply::{write_points, write_points_with_provenance, Provenance};
use std::collections::HashSet;
use std::path::{Path, PathBuf};

/// Writes PLY pairs; see the module documentation.
pub struct PlyWriter {
    out: PathBuf,
    used: HashSet<String>,
    tsv: String,
}

impl PlyWriter {
    /// A writer into `out` (which exists and is empty).
    pub fn new(out: &Path) -> Self {
        // `metadata` is taken by the index file.
        let used = HashSet::from(["metadata".to_string()]);
        PlyWriter { out: out.to_path_buf(), used, tsv: "folder\tpair_key\tunit_index\tstatus\n".into() }
    }
}

impl PairWriter for PlyWriter {
    fn accepts(&self, _row: &PairRow) -> bool {
        true
    }

    fn write(&mut self, _index: u64, row: &PairRow) -> Result<()> {
        let name = unique_name(&mut self.used, &row.pair_key, row.unit_index);
        let dir = self.out.join(&name);
        write_points(&dir.join("source.ply"), &row.source_points)?;
        write_points_with_provenance(&dir.join("target.ply"), &row.target_points, Provenance::of(row))?;
        write_text(&dir.join("T_target_from_source.txt"), &matrix_text(&row.t_target_from_source, 4))?;
        self.tsv.push_str(&format!("{name}\t{}\t{}\t{}\n", row.pair_key, row.unit_index, row.status.as_str()));
        Ok(())
    }

    fn finish(&mut self) -> Result<Option<u64>> {
        write_text(&self.out.join("metadata/pairs.tsv"), &self.tsv)?;
        Ok(None)
    }
}
