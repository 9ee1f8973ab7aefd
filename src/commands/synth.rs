//! `pointreggpt synth`: write synthetic sequences in the 3DMatch layout.

use crate::error::{Error, Result};
use crate::sources::synthetic::{SyntheticConfig, SyntheticSequence};
use std::io::Write;
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
pub struct SynthArgs {
    /// Output folder; each scene goes to `<out>/synthetic-<seed>/`.
    #[arg(long, value_parser = crate::commands::locations::local_output)]
    pub out: PathBuf,
    /// Number of scenes (seeds `seed`, `seed+1`, ...).
    #[arg(long, default_value_t = 1)]
    pub scenes: u64,
    /// Frames per scene (30 per second of hand-held motion).
    #[arg(long, default_value_t = 100)]
    pub frames: usize,
    /// Seed of the first scene.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

pub fn run(args: &SynthArgs, out: &mut dyn Write) -> Result<()> {
    if args.frames == 0 || args.scenes == 0 {
        return Err(Error::config("--frames/--scenes", "must be at least 1"));
    }
    let config = SyntheticConfig { frames: args.frames, ..Default::default() };
    let bar = indicatif::ProgressBar::new(args.scenes * args.frames as u64).with_message("frames");
    for s in 0..args.scenes {
        let seq = SyntheticSequence::generate(&config, args.seed + s)?;
        let dir = args.out.join(seq.name());
        seq.write_3dmatch(&dir)?;
        bar.inc(args.frames as u64);
        writeln!(out, "wrote {} frames to {}", seq.len(), dir.display()).map_err(|e| Error::io("<stdout>", e))?;
    }
    bar.finish_and_clear();
    Ok(())
}
