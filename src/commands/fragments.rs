//! `pointreggpt fragments`: a registration benchmark from posed RGB-D sequences, in the official 3DMatch
//! layout (TSDF fragments, or `--single-frames` clouds as a build makes them), for `eval registration`.

use crate::error::{Error, Result};
use crate::ply;
use crate::registration::benchmark::make::{
    fragments_within, fuse_fragment, pair_truths, single_frame_cloud, write_benchmark, Cloud, LO_MATCH_MAX, SINGLE_FRAME_MAX_OVERLAP,
};
use crate::runtime::progress::bar;
use crate::sources::open_sequences;
use super::sequence_args::SequenceArgs;
use crate::stages::ingest::WorkingConfig;
use crate::stages::voxelize::VoxelizeConfig;
use crate::tsdf::TsdfConfig;
use std::io::Write;
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
#[command(
    after_help = "Fragments (default): fragment k fuses frames PER*k .. PER*k+PER-1 (TSDF, 6 mm voxels, 3 cm truncation, the \
3DMatch settings) in the camera of frame PER*k and is written as <out>/<scene>/cloud_bin_k.ply. With --stride S below PER the \
windows overlap: fragment k fuses frames S*k .. S*k+PER-1, so a few frames give many fused pairs (e.g. 200 frames, PER 50, S 10: \
16 fragments). Every pair i < j whose overlap \
(the larger of the two clouds' fractions of points with a neighbour within 3.75 cm under the ground truth, on 2.5 cm voxels) is \
above 30 % goes to metadata/benchmarks/3DMatch/<scene>/, from 10 to 30 % to 3DLoMatch/: gt.log (`i j n` and the 4x4 mapping \
fragment j into fragment i), gt.info (the 6x6 information matrix of j's overlapping points) and gt_overlap.log.\n\n\
--single-frames: frame f and frame f+g for every EVERY-th frame f and every gap g of --gaps, each cloud made as a build makes it \
(256x256 working resolution, depth range, crop box, 2.5 cm voxels), written as <out>/<scene>-frames/cloud_bin_<frame>.ply; pairs \
with overlap from 10 to 90 % go to the benchmarks single-frame (above 30 %) and single-frame-lo (10-30 %)."
)]
pub struct FragmentsArgs {
    /// Sequence folder (3DMatch / 7-Scenes / SUN3D, TUM, ScanNet, or a plain folder with --layout folder).
    /// Every sequence found becomes a scene; frames without a camera pose are left out (counted).
    pub sequence: PathBuf,
    #[command(flatten)]
    pub open: SequenceArgs,
    /// Frames fused into one fragment (3DMatch: 50).
    #[arg(long, default_value_t = 50)]
    pub frames_per_fragment: usize,
    /// Frames between the first frames of consecutive fragments (default: --frames-per-fragment, the
    /// official non-overlapping fragments; smaller: overlapping windows).
    #[arg(long)]
    pub stride: Option<usize>,
    /// First frame used (fragments: a multiple of the stride, so fragment numbers stay the official ones).
    #[arg(long, default_value_t = 0)]
    pub first: usize,
    /// Frames used from --first on (0: to the end of the sequence).
    #[arg(long, default_value_t = 0)]
    pub frames: usize,
    /// Single-frame pairs instead of fused fragments.
    #[arg(long)]
    pub single_frames: bool,
    /// Single frames: a source frame every EVERY frames.
    #[arg(long, default_value_t = 5)]
    pub every: usize,
    /// Single frames: gaps (in frames) between the two frames of a pair, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "5,10,20,30,40,50,60,70,80,90")]
    pub gaps: Vec<usize>,
    /// Output benchmark folder.
    #[arg(long, value_parser = crate::commands::locations::local_output)]
    pub out: PathBuf,
    /// Stop at the first frame without a camera pose (default: leave such frames out and count them).
    #[arg(long)]
    pub strict: bool,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

pub fn run(args: &FragmentsArgs, out: &mut dyn Write) -> Result<()> {
    let per = args.frames_per_fragment;
    let stride = args.stride.unwrap_or(per);
    if per == 0 || stride == 0 || args.every == 0 || args.gaps.iter().any(|&g| g == 0) {
        return Err(Error::config("--frames-per-fragment/--stride/--every/--gaps", "must be at least 1"));
    }
    if !args.single_frames && args.first % stride != 0 {
        return Err(Error::config(
            "--first",
            format!("{} is not a multiple of the fragment stride {stride}: fragment numbers would not be the official ones", args.first),
        ));
    }
    for seq in open_sequences(&args.sequence, args.open.options()?)? {
        let end = if args.frames == 0 { seq.frames.len() } else { (args.first + args.frames).min(seq.frames.len()) };
        if args.first >= end {
            return Err(Error::config(
                "--first/--frames",
                format!("no frames of the {} frames of {} selected", seq.frames.len(), seq.name),
            ));
        }
        let unposed;
        let (scene, clouds, n, names) = if args.single_frames {
            let working = WorkingConfig::default();
            let voxelize = VoxelizeConfig::default();
            let mut frames: Vec<usize> = (args.first..end)
                .step_by(args.every)
                .flat_map(|f| std::iter::once(f).chain(args.gaps.iter().map(move |g| f + g)))
                .filter(|&f| f < end)
                .collect();
            frames.sort_unstable();
            frames.dedup();
            unposed = seq.unposed(frames.iter().copied(), args.strict)?;
            frames.retain(|&f| seq.frames[f].has_pose());
            let pb = bar(frames.len() as u64, !args.quiet, "frames");
            let mut clouds = Vec::new();
            for f in frames {
                clouds.push(single_frame_cloud(&seq, f, &working, &voxelize)?);
                pb.inc(1);
            }
            pb.finish_and_clear();
            (format!("{}-frames", seq.name), clouds, seq.frames.len(), ["single-frame", "single-frame-lo"])
        } else {
            let ks: Vec<usize> = fragments_within(args.first, end, per, stride).collect();
            if ks.is_empty() {
                return Err(Error::config(
                    "--frames",
                    format!("frames {}..{end} of {} hold no whole fragment of {per} frames", args.first, seq.name),
                ));
            }
            unposed = seq.unposed(ks[0] * stride..ks[ks.len() - 1] * stride + per, args.strict)?;
            let tsdf = TsdfConfig::threedmatch();
            let pb = bar(ks.len() as u64, !args.quiet, "fragments");
            let mut clouds = Vec::new();
            for k in ks {
                clouds.extend(fuse_fragment(&seq, k, per, stride, &tsdf, 1.0)?);
                pb.inc(1);
            }
            pb.finish_and_clear();
            (seq.name.clone(), clouds, fragments_within(0, seq.frames.len(), per, stride).len(), ["3DMatch", "3DLoMatch"])
        };
        write_scene(args, &scene, &clouds, n, names, out)?;
        if unposed > 0 || seq.poses.from_timestamps() {
            writeln!(out, "{scene}: {}; {unposed} of the frames used left out for want of a pose", seq.poses.describe()).map_err(|e| Error::io("<stdout>", e))?;
        }
    }
    Ok(())
}

/// Writes the clouds and the two benchmarks of one scene, and a summary line.
fn write_scene(
    args: &FragmentsArgs,
    scene: &str,
    clouds: &[Cloud],
    n: usize,
    names: [&str; 2],
    out: &mut dyn Write,
) -> Result<()> {
    let dir = args.out.join(scene);
    for c in clouds {
        ply::write_points(&dir.join(format!("cloud_bin_{}.ply", c.index)), &c.points)?;
    }
    let singles = args.single_frames;
    // Single frames: only pairs (f, f+g) with f a source frame and g in --gaps.
    let max = if singles { SINGLE_FRAME_MAX_OVERLAP } else { 1.0 };
    let keep = |i: usize, j: usize| !singles || ((i - args.first) % args.every == 0 && args.gaps.contains(&(j - i)));
    let truths = pair_truths(clouds, n, max, &keep);
    let hi: Vec<_> = truths.iter().filter(|p| p.overlap > LO_MATCH_MAX).collect();
    let lo: Vec<_> = truths.iter().filter(|p| p.overlap <= LO_MATCH_MAX).collect();
    write_benchmark(&args.out, names[0], scene, &hi)?;
    write_benchmark(&args.out, names[1], scene, &lo)?;
    writeln!(
        out,
        "{scene}: {} clouds in {}; {} pairs: {} {}, {} {}",
        clouds.len(),
        dir.display(),
        truths.len(),
        hi.len(),
        names[0],
        lo.len(),
        names[1]
    )
    .map_err(|e| Error::io("<stdout>", e))
}
