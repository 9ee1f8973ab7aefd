//! Where a benchmark's files are. Three layouts are read:
//! - ours and GeoTransformer's: `<root>/metadata/benchmarks/<benchmark>/<scene>/{gt.log, gt.info, gt_overlap.log}`
//!   with the clouds in `<root>/<scene>/`, `<root>/data/test/<scene>/` or `<root>/fragments/<scene>/`;
//! - the official 3DMatch download: `<root>/<scene>-evaluation/{gt.log, gt.info}` beside `<root>/<scene>/`;
//! - one scene: `gt.log` and `gt.info` beside the clouds in `<root>`.
//!
//! Clouds are `cloud_bin_<k>.ply`. In a `gt.log`, `i j n` with `T` mapping fragment j into fragment i:
//! the source is j, the target i.

use super::gtlog::{read_gt_info, read_gt_log, read_gt_overlap};
use crate::error::{Error, Result};
use nalgebra::{Isometry3, Matrix6};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// The benchmark whose registration recall skips consecutive fragments, as the official protocol does.
pub const SKIPS_CONSECUTIVE: &str = "3DMatch";

/// One pair to evaluate.
#[derive(Clone, Debug)]
pub struct BenchPair {
    pub scene: String,
    pub i: usize,
    pub j: usize,
    pub t_i_from_j: Isometry3<f64>,
    pub info: Matrix6<f64>,
    pub overlap: Option<f64>,
    /// `cloud_bin_i.ply` (target) and `cloud_bin_j.ply` (source).
    pub target_path: PathBuf,
    pub source_path: PathBuf,
}

impl BenchPair {
    /// Whether registration recall counts this pair in benchmark `name`.
    pub fn counts_for_rr(&self, name: &str) -> bool {
        !(name == SKIPS_CONSECUTIVE && self.j == self.i + 1)
    }
}

/// A named list of pairs (3DMatch, 3DLoMatch, single-frame, ...).
#[derive(Clone, Debug)]
pub struct Benchmark {
    pub name: String,
    pub pairs: Vec<BenchPair>,
}

fn sorted_dirs(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut out: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| Error::io(dir, e))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_dir())
        .collect();
    out.sort();
    Ok(out)
}

fn name_of(p: &Path) -> String {
    p.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default()
}

/// The pairs of one scene: `gt.log` and `gt.info` in `eval_dir`, clouds in `clouds`.
fn scene_pairs(scene: &str, eval_dir: &Path, clouds: &Path) -> Result<Vec<BenchPair>> {
    let log = eval_dir.join("gt.log");
    let info_path = eval_dir.join("gt.info");
    let infos: HashMap<(usize, usize), Matrix6<f64>> = read_gt_info(&info_path)?.into_iter().collect();
    let overlap_path = eval_dir.join("gt_overlap.log");
    let overlaps: HashMap<(usize, usize), f64> =
        if overlap_path.is_file() { read_gt_overlap(&overlap_path)?.into_iter().collect() } else { HashMap::new() };
    read_gt_log(&log)?
        .into_iter()
        .map(|p| {
            let info = *infos.get(&(p.i, p.j)).ok_or_else(|| {
                Error::input(&info_path, format!("no information matrix for pair {} {} of {}", p.i, p.j, log.display()))
            })?;
            let cloud = |k: usize| {
                let path = clouds.join(format!("cloud_bin_{k}.ply"));
                if path.is_file() {
                    Ok(path)
                } else {
                    Err(Error::input(
                        &log,
                        format!("pair {} {}: fragment cloud {} does not exist", p.i, p.j, path.display()),
                    ))
                }
            };
            Ok(BenchPair {
                scene: scene.to_string(),
                i: p.i,
                j: p.j,
                t_i_from_j: p.t_i_from_j,
                info,
                overlap: overlaps.get(&(p.i, p.j)).copied(),
                target_path: cloud(p.i)?,
                source_path: cloud(p.j)?,
            })
        })
        .collect()
}

/// The folder holding `scene`'s clouds under `root`.
fn clouds_dir(root: &Path, scene: &str, log_dir: &Path) -> Result<PathBuf> {
    [root.join(scene), root.join("data/test").join(scene), root.join("fragments").join(scene)]
        .into_iter()
        .find(|d| d.join("cloud_bin_0.ply").is_file() || d.is_dir())
        .ok_or_else(|| Error::input(log_dir, format!("no cloud folder for scene `{scene}` (looked for {0}/{scene}, {0}/data/test/{scene}, {0}/fragments/{scene})", root.display())))
}

/// Every benchmark under `root` (see the module doc), 3DMatch and 3DLoMatch first.
pub fn find_benchmarks(root: &Path) -> Result<Vec<Benchmark>> {
    if !root.is_dir() {
        return Err(Error::input(root, "benchmark folder does not exist"));
    }
    let meta = root.join("metadata/benchmarks");
    let mut out = Vec::new();
    if meta.is_dir() {
        for bdir in sorted_dirs(&meta)? {
            let mut pairs = Vec::new();
            for sdir in sorted_dirs(&bdir)? {
                if sdir.join("gt.log").is_file() {
                    let scene = name_of(&sdir);
                    pairs.extend(scene_pairs(&scene, &sdir, &clouds_dir(root, &scene, &sdir)?)?);
                }
            }
            if !pairs.is_empty() {
                out.push(Benchmark { name: name_of(&bdir), pairs });
            }
        }
    } else if root.join("gt.log").is_file() {
        out.push(Benchmark { name: "3DMatch".into(), pairs: scene_pairs(&name_of(root), root, root)? });
    } else {
        let mut pairs = Vec::new();
        for d in sorted_dirs(root)? {
            let n = name_of(&d);
            if let Some(scene) = n.strip_suffix("-evaluation").filter(|_| d.join("gt.log").is_file()) {
                pairs.extend(scene_pairs(scene, &d, &root.join(scene))?);
            }
        }
        if !pairs.is_empty() {
            out.push(Benchmark { name: "3DMatch".into(), pairs });
        }
    }
    if out.is_empty() {
        return Err(Error::input(root, "no benchmark found: expected metadata/benchmarks/<benchmark>/<scene>/gt.log, <scene>-evaluation/gt.log, or gt.log in the folder"));
    }
    let rank = |n: &str| match n {
        "3DMatch" => 0,
        "3DLoMatch" => 1,
        _ => 2,
    };
    out.sort_by(|a, b| rank(&a.name).cmp(&rank(&b.name)).then(a.name.cmp(&b.name)));
    Ok(out)
}
