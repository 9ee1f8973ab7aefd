//! `pointreggpt inspect`: list the sequences under a folder; with `--check`, also check that their frames
//! decode.

use crate::error::{Error, Result};
use crate::sources::open_sequences;
use std::io::Write;
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
pub struct InspectArgs {
    /// Folder holding one or more sequences.
    pub root: PathBuf,
    #[command(flatten)]
    pub open: super::sequence_args::SequenceArgs,
    /// Decode every frame (depth PNG and pose) and report the ones that fail.
    #[arg(long)]
    pub check: bool,
}

pub fn run(args: &InspectArgs, out: &mut dyn Write) -> Result<()> {
    let w = |e: std::io::Error| Error::io("<stdout>", e);
    let sequences = open_sequences(&args.root, args.open.options()?)?;
    let mut failures = 0usize;
    for seq in &sequences {
        let with_pose = seq.frames.iter().filter(|f| f.has_pose()).count();
        let k = seq.frames.first().map(|f| f.intrinsics);
        writeln!(out, "{}: {} frames ({} with a pose) in {}", seq.name, seq.frames.len(), with_pose, seq.root.display()).map_err(w)?;
        if seq.poses.from_timestamps() {
            writeln!(out, "  ground truth: {} (interpolated across gaps up to {} ms)", seq.poses.describe(), crate::sources::tum::MAX_INTERPOLATION_GAP * 1000.0).map_err(w)?;
        }
        if let Some(k) = k {
            writeln!(out, "  intrinsics {}x{} fx={:.3} fy={:.3} cx={:.3} cy={:.3}", k.width, k.height, k.fx, k.fy, k.cx, k.cy).map_err(w)?;
        }
        if args.check {
            for f in &seq.frames {
                if let Err(e) = f.load() {
                    failures += 1;
                    writeln!(out, "  bad frame {}: {e}", f.key).map_err(w)?;
                }
            }
        }
    }
    if failures > 0 {
        return Err(Error::input(&args.root, format!("{failures} frames failed to load (listed above)")));
    }
    Ok(())
}
