//! `pointreggpt eval inpaint`: re-project real frames into the stored pose of a later frame, correct, fill
//! (or ray-cast the scene) and compare with the depth captured there (tables and CSV).

use super::report::report;
use crate::error::{Error, Result};
use std::io::Write;
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
#[command(
    after_help = "For each selected frame j of each sequence: the frame's points (official working resolution, depth range and \
crop box) are z-buffered into the stored camera of frame j+GAP, corrected (none, min-pool 3.75 cm, the correction U-Net at \
tau_m 0.99), filled (none, push-pull, nearest valid pixel, background = the farther hole border along the epipolar \
direction, IP-Basic = Ku et al. 2018's morphological completion, which leaves pixels far from any known depth empty, so its \
coverage is below 100%; diffusion from pure noise as the authors, except for a network trained with --max-t; diffusion started from the \
noised push-pull or background fill) and compared with the depth captured at j+GAP, where valid. With --pipeline, only the condition \
correction and the fill of each given build config are evaluated (the views use the first config's [working] section). \
Columns: unknown = share of all view pixels unknown after correction (the hole size; a build's target views are 58-82% \
unknown); wrong/m = kept pixels more than 5 cm behind the captured surface (penetration) per map; filled pixels (unknown \
after correction, captured valid): coverage, AbsRel, RMSE, delta<1.25; the same three within 3 px of a captured depth \
edge (edge); flying = share of filled pixels more than 5 cm from both the nearest and the farthest captured depth of their \
3x3 neighbourhood; cloud = mean distance from the filled points to the captured cloud; ms/view = fill time. The output \
correction of the build is not applied. --dump-views writes the views for benchmarks/peers/fill_peers.py."
)]
pub struct EvalInpaintArgs {
    /// Folder of depth sequences with poses (3DMatch / 7-Scenes / TUM / ScanNet layout, or a plain folder
    /// with --layout folder). Pairs with a frame without a camera pose are left out (counted).
    pub sequences: PathBuf,
    #[command(flatten)]
    pub open: super::sequence_args::SequenceArgs,
    /// Stop at a frame without a camera pose instead of leaving its pair out.
    #[arg(long)]
    pub strict: bool,
    /// Frames between the source view and the target view.
    #[arg(long, default_value_t = 10)]
    pub gap: usize,
    /// First source frame of each sequence (frames before it are skipped, e.g. the ones a model trained on).
    #[arg(long, default_value_t = 0)]
    pub first: usize,
    /// Take every EVERY-th source frame.
    #[arg(long, default_value_t = 10)]
    pub every: usize,
    /// At most this many views per sequence (0: no limit).
    #[arg(long, default_value_t = 8)]
    pub max_views: usize,
    /// Diffusion checkpoint (`pointreggpt train diffusion --export`); default the built-in tiny denoiser.
    #[arg(long, default_value = "builtin:models/diffusion-tiny.safetensors")]
    pub diffusion: PathBuf,
    /// DDIM steps of the diffusion fill (at most --start-step + 1).
    #[arg(long, default_value_t = 50)]
    pub steps: usize,
    /// The step the push-pull- and background-started diffusion rows are noised to (the official rows start from pure noise).
    #[arg(long, default_value_t = 500)]
    pub start_step: usize,
    /// RePaint-style resampling of the diffusion fill: blocks of this many DDIM steps (0: off) ...
    #[arg(long, default_value_t = 0)]
    pub resample_jump: usize,
    /// ... each run this many times, re-noised back to the block's start in between.
    #[arg(long, default_value_t = 1)]
    pub resample_repeats: usize,
    /// DDIM eta of the diffusion fill (official 1: fresh noise at every step; 0: deterministic).
    #[arg(long, default_value_t = 1.0)]
    pub eta: f64,
    /// Correction U-Net checkpoint (tau_m 0.99); default the built-in tiny U-Net.
    #[arg(long, default_value = "builtin:models/correction-tiny.safetensors")]
    pub correction: PathBuf,
    /// Seed of the diffusion noise.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// CSV file to write.
    #[arg(long, value_parser = crate::commands::locations::local_output)]
    pub out: PathBuf,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
    /// libtorch intra-op threads.
    #[arg(long, default_value_t = 1)]
    pub torch_threads: i32,
    /// Evaluate exactly the condition correction and the fill of this build config instead of the built-in
    /// rows (repeat to compare configs; rows are named by the file stem; its relative paths are relative to
    /// its folder).
    #[arg(long)]
    pub pipeline: Vec<PathBuf>,
    /// Also write every view (after each correction) to this folder: NNN_condition.npy, NNN_known.npy,
    /// NNN_captured.npy (float32 metres / bool, H x W), views.json (intrinsics, pose, depth range) and each
    /// fill's output, NNN_fill_<fill>.npy (benchmarks/peers/fill_peers.py scores them with the peers);
    /// with --scene also NNN_scene.npy (the scene's depth at the unknown pixels it sees).
    #[arg(long)]
    pub dump_views: Option<PathBuf>,
    /// Add the scene rows: the frames around each source frame (the [scene] window of the first --pipeline
    /// config, else the default: blocks of 30, reach 60, every 3rd frame, 1 cm TSDF) fused and ray-cast at
    /// the target pose, WITHOUT the target frame and --scene-exclude frames on each side of it. Rows: the
    /// `scene` correction (the default: pixels behind the scene's surface dropped, min-pool everywhere too;
    /// `scene2`: the labels' two-sided rule, min-pool where the scene saw nothing; `scene2&mp`: the two-sided
    /// rule and min-pool everywhere), and the fills `scene` (scene only),
    /// `scene+background`, `scene+push_pull`, `scene+nearest` (the fallback fills what the scene did not see).
    #[arg(long)]
    pub scene: bool,
    /// With --scene: frames on each side of the captured target frame held out of its scene (the target
    /// frame itself always is). The default, 30 frames (1 s at 30 Hz), was chosen on redkitchen's tune
    /// frames (docs/lab/2026-12-07-scene-targets.md).
    #[arg(long, default_value_t = 30)]
    pub scene_exclude: usize,
    /// With --scene: a TOML file with the [scene] window and volume (the keys of a build config's [scene]
    /// section at its top level, e.g. `block = 2`, `reach = 3`, `every = 1` for key frames far apart).
    #[arg(long)]
    pub scene_config: Option<PathBuf>,
}

pub(super) fn run(a: &EvalInpaintArgs, out: &mut dyn Write) -> Result<()> {
    use crate::correction::CorrectionConfig;
    use crate::training::eval_inpaint::{dump_views, evaluate, format_table, make_view, scene_of_view, to_csv, NamedCorrector, NamedFill};
    use crate::diffusion::sampler::Resample;
    use crate::inpainting::{DiffusionInpaintConfig, InpaintConfig, Start};
    use crate::nn::ModelPath;
    let w = |e: std::io::Error| Error::io("<stdout>", e);
    if a.gap == 0 || a.every == 0 {
        return Err(Error::config("--gap/--every", "must be at least 1"));
    }
    if a.steps > a.start_step + 1 {
        let most = a.start_step + 1;
        let message = format!("the classically started rows can run at most --start-step + 1 = {most} steps, not {}", a.steps);
        return Err(Error::config("--steps", message));
    }
    crate::nn::set_torch_threads(a.torch_threads)?;
    let pipelines = a
        .pipeline
        .iter()
        .map(|p| {
            let origin = p.display().to_string();
            let config: crate::pipeline::BuildConfig = crate::pipeline::load::load_toml(p, &[])?;
            config.correct.validate()?;
            config.inpaint.validate(&format!("{origin}: inpaint"))?;
            let name = p.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or(origin);
            Ok((name, config))
        })
        .collect::<Result<Vec<_>>>()?;
    let working = pipelines.first().map(|(_, c)| c.working.clone()).unwrap_or_default();
    let scene_config = match &a.scene_config {
        Some(p) => {
            let text = std::fs::read_to_string(p).map_err(|e| Error::io(p, e))?;
            let c: crate::scene::SceneConfig = toml::from_str(&text).map_err(|e| Error::config(p.display().to_string(), e.to_string()))?;
            c.validate()?;
            c
        }
        None => pipelines.first().map(|(_, c)| c.scene.clone()).unwrap_or_default(),
    };
    let with_scene = a.scene || pipelines.iter().any(|(_, c)| c.uses_scene());
    let mut views = Vec::new();
    let mut scene_frames = 0usize;
    let mut unposed = 0;
    for seq in crate::sources::open_sequences(&a.sequences, a.open.options()?)? {
        let mut taken = 0;
        for j in (a.first..seq.frames.len().saturating_sub(a.gap)).step_by(a.every) {
            if a.max_views > 0 && taken == a.max_views {
                break;
            }
            if seq.unposed([j, j + a.gap], a.strict)? > 0 {
                unposed += 1;
                continue;
            }
            let (s, t) = (seq.frames[j].load()?, seq.frames[j + a.gap].load()?);
            let seed = crate::rng::unit_seed(a.seed, &s.key, a.gap as u64);
            let mut view = make_view(&s, &t, &working, seed)?;
            if with_scene {
                let (depth, fused) = scene_of_view(&seq, j, j + a.gap, a.scene_exclude, &scene_config, &view.intrinsics)?;
                scene_frames += fused.len();
                view.scene = Some(depth);
            }
            views.push(view);
            taken += 1;
        }
    }
    if unposed > 0 {
        writeln!(out, "{unposed} frame pair(s) left out: a frame without a camera pose").map_err(|e| Error::io("<stdout>", e))?;
    }
    if views.is_empty() {
        return Err(Error::config("sequences", format!("no posed frame pair {} frames apart after --first {}", a.gap, a.first)));
    }
    if with_scene {
        let exclude = a.scene_exclude;
        writeln!(out, "scenes: {:.1} frames fused per view on average; each view's target frame and {exclude} frames on each side held out", scene_frames as f64 / views.len() as f64)
            .map_err(w)?;
    }
    if !pipelines.is_empty() {
        return run_pipelines(a, &pipelines, &views, &working, out);
    }
    let mut corrections = vec![NamedCorrector::new("none", &CorrectionConfig::None {}), NamedCorrector::new("min_pool", &CorrectionConfig::OFFICIAL_MIN_POOL)];
    let unet = CorrectionConfig::Unet { checkpoint: ModelPath::new(&a.correction.display().to_string()), threshold: 0.99, preset: None };
    unet.validate("--correction")?;
    corrections.push(NamedCorrector::new("unet@0.99", &unet));
    let mut fills = vec![
        NamedFill::new("none", &InpaintConfig::None {})?,
        NamedFill::new("push_pull", &InpaintConfig::PushPull {})?,
        NamedFill::new("nearest", &InpaintConfig::Nearest {})?,
        NamedFill::new("background", &InpaintConfig::Background {})?,
        NamedFill::new("ip_basic", &InpaintConfig::IpBasic {})?,
    ];
    if a.scene {
        let rule = |fallback_everywhere, behind_only| CorrectionConfig::Scene {
            margin: 0.05,
            fallback: Box::new(CorrectionConfig::OFFICIAL_MIN_POOL),
            fallback_everywhere,
            behind_only,
        };
        corrections.push(NamedCorrector::new("scene2", &rule(false, false)));
        corrections.push(NamedCorrector::new("scene2&mp", &rule(true, false)));
        corrections.push(NamedCorrector::new("scene", &rule(true, true)));
        let scene = |fallback: InpaintConfig| InpaintConfig::Scene { fallback: Box::new(fallback) };
        fills.push(NamedFill::new("scene", &scene(InpaintConfig::None {}))?);
        fills.push(NamedFill::new("scene+background", &scene(InpaintConfig::Background {}))?);
        fills.push(NamedFill::new("scene+push_pull", &scene(InpaintConfig::PushPull {}))?);
        fills.push(NamedFill::new("scene+nearest", &scene(InpaintConfig::Nearest {}))?);
    }
    // A network trained only on the nearly clean steps (`train diffusion --max-t`) has no pure-noise row.
    let low_steps_only = crate::diffusion::checkpoint::read_meta(&a.diffusion).ok().and_then(|m| m.trained_below_step()).is_some();
    let started = [
        (Start::Noise, format!("diffusion{}", a.steps)),
        (Start::PushPull, format!("diff{}/pp{}", a.steps, a.start_step)),
        (Start::Background, format!("diff{}/bg{}", a.steps, a.start_step)),
    ];
    for (start, name) in started {
        if start == Start::Noise && low_steps_only {
            continue;
        }
        let diffusion = InpaintConfig::Diffusion(DiffusionInpaintConfig {
            checkpoint: ModelPath::new(&a.diffusion.display().to_string()),
            steps: a.steps,
            eta: a.eta,
            start,
            start_step: a.start_step,
            batch: 1,
            resample: (a.resample_jump > 0).then_some(Resample { jump: a.resample_jump, repeats: a.resample_repeats }),
        });
        diffusion.validate("--diffusion")?;
        fills.push(NamedFill::new(name, &diffusion)?);
    }
    let range = (working.depth_range[0], working.depth_range[1]);
    if let Some(dir) = &a.dump_views {
        dump_views(dir, &views, &corrections, range)?;
    }
    writeln!(out, "{} views ({} frames apart) from {}", views.len(), a.gap, a.sequences.display()).map_err(w)?;
    let bar = crate::runtime::progress::bar(views.len() as u64, !a.quiet, "views");
    let rows = evaluate(&views, &corrections, &fills, range, a.dump_views.as_deref(), || bar.inc(1))?;
    bar.finish_and_clear();
    report(out, &format_table(&rows), &to_csv(&rows), &a.out)
}

/// `eval inpaint --pipeline`: one row per build config, its condition correction and its fill.
fn run_pipelines(
    a: &EvalInpaintArgs,
    pipelines: &[(String, crate::pipeline::config::BuildConfig)],
    views: &[crate::training::eval_inpaint::View],
    working: &crate::stages::ingest::WorkingConfig,
    out: &mut dyn Write,
) -> Result<()> {
    use crate::training::eval_inpaint::{dump_views, evaluate, format_table, to_csv, MethodRow, NamedCorrector, NamedFill};
    let w = |e: std::io::Error| Error::io("<stdout>", e);
    let range = (working.depth_range[0], working.depth_range[1]);
    writeln!(out, "{} views ({} frames apart) from {}", views.len(), a.gap, a.sequences.display()).map_err(w)?;
    let bar = crate::runtime::progress::bar((views.len() * pipelines.len()) as u64, !a.quiet, "views");
    let mut rows: Vec<MethodRow> = Vec::new();
    for (name, config) in pipelines {
        let condition = &config.correct.condition;
        let corrections = [NamedCorrector::new(correction_name(condition), condition)];
        if let Some(dir) = &a.dump_views {
            dump_views(&dir.join(name), views, &corrections, range)?;
        }
        let fills = [NamedFill::new(name.clone(), &config.inpaint)?];
        let dump = a.dump_views.as_ref().map(|dir| dir.join(name));
        rows.extend(evaluate(views, &corrections, &fills, range, dump.as_deref(), || bar.inc(1))?);
    }
    bar.finish_and_clear();
    report(out, &format_table(&rows), &to_csv(&rows), &a.out)
}

/// A correction's row name, as the built-in rows name them.
fn correction_name(c: &crate::correction::CorrectionConfig) -> String {
    use crate::correction::CorrectionConfig as C;
    match c {
        C::None {} => "none".into(),
        C::MinPool { .. } => "min_pool".into(),
        C::Median { .. } => "median".into(),
        C::Unet { threshold, .. } => format!("unet@{threshold}"),
        C::Scene { fallback, fallback_everywhere, behind_only, .. } => {
            format!("scene{}{}{}", if *behind_only { "B" } else { "" }, if *fallback_everywhere { "&" } else { "/" }, correction_name(fallback))
        }
    }
}
