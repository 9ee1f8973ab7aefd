//! `pointreggpt fuse`: fuse consecutive frames of a sequence (TSDF) and write the surface cloud and mesh
//! as PLY, to look at what the label pipeline sees.

use crate::error::{Error, Result};
use crate::geometry::relative_pose;
use crate::ply;
use crate::sources::open_sequences;
use crate::tsdf::{TsdfConfig, TsdfVolume};
use std::io::Write;
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
pub struct FuseArgs {
    /// Sequence folder (3DMatch / 7-Scenes / SUN3D, TUM, ScanNet, or a plain folder with --layout folder);
    /// frames without a camera pose are left out (counted).
    pub sequence: PathBuf,
    #[command(flatten)]
    pub open: super::sequence_args::SequenceArgs,
    /// Index of the first frame (within the first sequence found).
    #[arg(long, default_value_t = 0)]
    pub first: usize,
    /// Number of frames to fuse (3DMatch fragments: 50).
    #[arg(long, default_value_t = 50)]
    pub frames: usize,
    /// Voxel size, metres (3DMatch: 0.006).
    #[arg(long, default_value_t = 0.006)]
    pub voxel: f32,
    /// Truncation distance, metres (3DMatch: 0.03).
    #[arg(long, default_value_t = 0.03)]
    pub truncation: f32,
    /// Surface points and mesh need a weight above this.
    #[arg(long, default_value_t = 1.0)]
    pub weight_threshold: f32,
    /// Output folder: fused.cloud.ply (points) and fused.mesh.ply (marching cubes), in the first frame's
    /// camera coordinates.
    #[arg(long, default_value = "out/fuse", value_parser = crate::commands::locations::local_output)]
    pub out: PathBuf,
}

pub fn run(args: &FuseArgs, out: &mut dyn Write) -> Result<()> {
    let w = |e: std::io::Error| Error::io("<stdout>", e);
    let seqs = open_sequences(&args.sequence, args.open.options()?)?;
    let seq = seqs.first().ok_or_else(|| Error::input(&args.sequence, "no sequence found"))?;
    let end = args.first + args.frames;
    if args.frames == 0 || end > seq.frames.len() {
        return Err(Error::config("--first/--frames", format!("frames {}..{end} are outside the {} frames of {}", args.first, seq.frames.len(), seq.name)));
    }
    let config = TsdfConfig { voxel_size_m: args.voxel, truncation_m: args.truncation, ..TsdfConfig::threedmatch() };
    config.validate()?;
    let mut volume = TsdfVolume::new(config)?;
    let bar = indicatif::ProgressBar::new(args.frames as u64);
    let mut t_world_from_base = None;
    let unposed = seq.unposed(args.first..end, false)?;
    if unposed == args.frames {
        return Err(Error::input(&seq.frames[args.first].depth_path, format!("none of frames {}..{end} has a camera pose", args.first)));
    }
    for f in seq.frames[args.first..end].iter().filter(|f| f.has_pose()) {
        let frame = f.load()?;
        let pose = frame.t_world_from_camera.ok_or_else(|| Error::input(&frame.depth_path, "frame has no camera pose"))?;
        let base = *t_world_from_base.get_or_insert(pose);
        volume.integrate(&frame.depth, &frame.intrinsics, &relative_pose(&base, &pose))?;
        bar.inc(1);
    }
    bar.finish_and_clear();
    std::fs::create_dir_all(&args.out).map_err(|e| Error::io(&args.out, e))?;
    let points = volume.extract_points(args.weight_threshold);
    let mesh = volume.extract_mesh(args.weight_threshold);
    ply::write_points(&args.out.join("fused.cloud.ply"), &points)?;
    ply::write_mesh(&args.out.join("fused.mesh.ply"), &mesh.vertices, &mesh.triangles)?;
    writeln!(
        out,
        "fused {} frames of {} ({} blocks{}): {} surface points, mesh {} vertices / {} triangles -> {}",
        args.frames - unposed,
        seq.name,
        volume.block_count(),
        if unposed > 0 { format!("; {unposed} frame(s) without a camera pose left out") } else { String::new() },
        points.len(),
        mesh.vertices.len(),
        mesh.triangles.len(),
        args.out.display()
    )
    .map_err(w)
}
