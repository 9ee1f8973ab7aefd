//! `pointreggpt eval`: its subcommands, and `eval correction` (compare correctors on held-out label shards;
//! tables and CSV). `eval inpaint` is in [`super::eval_inpaint`].

use super::report::report;
use crate::error::{Error, Result};
use crate::training::correction::data::LabelSet;
use crate::training::correction::evaluate::{evaluate_all, format_table, to_csv, THRESHOLDS};
use std::io::Write;
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
pub struct EvalArgs {
    #[command(subcommand)]
    pub what: EvalWhat,
}

#[derive(Debug, clap::Subcommand)]
pub enum EvalWhat {
    /// Compare the handcrafted filters and U-Net checkpoints on held-out correction labels.
    Correction(EvalCorrectionArgs),
    /// Re-project real frames into the stored pose of a later frame, correct, fill, and compare with the
    /// depth captured there.
    Inpaint(super::eval_inpaint::EvalInpaintArgs),
    /// The 3DMatch registration protocol (FMR, IR, RR, RRE, RTE) on a benchmark folder with a descriptor,
    /// and the paired IR difference against a second one (`--compare`).
    Registration(super::eval_registration::EvalRegistrationArgs),
    /// Does a training set make registration better? Trains the patch descriptor on each condition (real,
    /// generated, real + generated pairs; several seeds) and scores all on one benchmark: one table.
    Boost(super::eval_boost::EvalBoostArgs),
}

#[derive(Debug, clap::Args)]
#[command(
    after_help = "Metrics over the pixels with input depth (I_s > 0; only those can be kept or dropped), pooled over all maps: \
2-class mIoU (keep and drop), pixel accuracy, FP = wrong depths kept per map (label drop, predicted keep), FN = good depths \
dropped per map, SAE = the official depth-weighted error per map. U-Nets are reported at tau_m 0.5 and 0.99 (or each --tau); the handcrafted \
filters (min-pool and 3x3 median, 0.0375 m) have no tau_m and are reported once."
)]
pub struct EvalCorrectionArgs {
    /// Held-out label dataset(s): folders or object-store URLs; repeat to combine.
    #[arg(long, required = true, value_parser = crate::commands::locations::dataset)]
    pub labels: Vec<PathBuf>,
    /// U-Net checkpoint with DepthAugment; default the built-in tiny U-Net.
    #[arg(long, default_value = "builtin:models/correction-tiny.safetensors")]
    pub checkpoint: PathBuf,
    /// U-Net checkpoint trained without DepthAugment (adds a row).
    #[arg(long)]
    pub checkpoint_noaug: Option<PathBuf>,
    /// CSV file to write.
    #[arg(long, value_parser = crate::commands::locations::local_output)]
    pub out: PathBuf,
    /// cpu, cuda or cuda:N.
    #[arg(long, default_value = "cpu")]
    pub device: String,
    /// Maps per forward pass.
    #[arg(long, default_value_t = 4)]
    pub batch: usize,
    /// Keep thresholds tau_m the U-Nets are reported at (a pixel is kept when its keep probability is above
    /// it); repeat for several.
    #[arg(long = "tau", default_values_t = THRESHOLDS, value_parser = parse_tau)]
    pub taus: Vec<f32>,
    /// libtorch intra-op threads. 1 by default: on a shared or small machine more threads than idle cores
    /// make libtorch's OpenMP workers spin (a 2-core machine with one other busy process ran a training step
    /// 5-10x slower with 2 threads than with 1).
    #[arg(long, default_value_t = 1)]
    pub torch_threads: i32,
    /// Add the `scene` correction rows: the posed sequence(s) the labels were made from (repeat for several;
    /// matched by sequence name). Each label's scene fuses the frames around its reference frame (the
    /// default [scene] window) WITHOUT its label window and --scene-exclude frames on each side.
    #[arg(long)]
    pub scene_sequence: Vec<PathBuf>,
    /// With --scene-sequence: frames on each side of a label window held out of its scene.
    #[arg(long, default_value_t = 30)]
    pub scene_exclude: usize,
}

fn parse_tau(s: &str) -> std::result::Result<f32, String> {
    match s.parse::<f32>() {
        Ok(t) if (0.0..1.0).contains(&t) => Ok(t),
        _ => Err(format!("tau_m must be a number in [0, 1), got {s:?}")),
    }
}

pub fn run(args: &EvalArgs, out: &mut dyn Write) -> Result<()> {
    match &args.what {
        EvalWhat::Correction(a) => run_correction(a, out),
        EvalWhat::Inpaint(a) => super::eval_inpaint::run(a, out),
        EvalWhat::Registration(a) => super::eval_registration::run(a, out),
        EvalWhat::Boost(a) => super::eval_boost::run(a, out),
    }
}

fn run_correction(a: &EvalCorrectionArgs, out: &mut dyn Write) -> Result<()> {
    let w = |e: std::io::Error| Error::io("<stdout>", e);
    crate::nn::set_torch_threads(a.torch_threads)?;
    let device = crate::nn::parse_device(&a.device)?;
    let set = LabelSet::open_all(&a.labels)?;
    let mut checkpoints = Vec::new();
    if let Some(p) = &a.checkpoint_noaug {
        checkpoints.push(("U-Net, no augmentation".to_string(), p.clone()));
    }
    checkpoints.push(("U-Net + DepthAugment".to_string(), a.checkpoint.clone()));
    let mut rows = evaluate_all(&set, &checkpoints, device, a.batch, &a.taus)?;
    if !a.scene_sequence.is_empty() {
        use crate::correction::{CorrectionConfig, SceneRule};
        use crate::training::correction::evaluate::{evaluate_scene, EvalRow};
        let mut sequences = Vec::new();
        for p in &a.scene_sequence {
            sequences.extend(crate::sources::open_sequences(p, crate::sources::OpenOptions::default())?);
        }
        let config = crate::scene::SceneConfig::default();
        let fallback = CorrectionConfig::OFFICIAL_MIN_POOL.build();
        for (everywhere, behind_only) in [(false, false), (true, false), (false, true), (true, true)] {
            let rule = SceneRule { margin: 0.05, fallback_everywhere: everywhere, behind_only };
            let (c, seen) = evaluate_scene(&set, &sequences, &config, rule, fallback.as_ref(), a.scene_exclude)?;
            let name = format!("scene{}{}", if behind_only { " behind" } else { "" }, if everywhere { "&min-pool" } else { "/min-pool" });
            let method = format!("{name} (saw {:.0}%)", 100.0 * seen);
            rows.push(EvalRow { method, tau_m: None, metrics: c.metrics() });
        }
    }
    let (px, drop) = set.pixel_counts();
    writeln!(
        out,
        "{} maps {}x{}; {} pixels with input depth, {:.1}% labelled drop",
        set.len(),
        set.width,
        set.height,
        px,
        100.0 * drop as f64 / px.max(1) as f64
    )
    .map_err(w)?;
    report(out, &format_table(&rows), &to_csv(&rows), &a.out)
}
