//! `pointreggpt eval registration`: the 3DMatch protocol (FMR, IR, RR, RRE, RTE) on a benchmark folder
//! with a descriptor, and the paired IR difference against a second descriptor.

use crate::error::{Error, Result};
use crate::registration::benchmark::find_benchmarks;
use crate::registration::report::{format_csv, format_paired, format_table, paired_ir, rows};
use crate::registration::{evaluate, Descriptor, EvalConfig};
use crate::runtime::progress::bar;
use std::io::Write;
use std::path::PathBuf;

#[derive(Debug, clap::Args)]
#[command(
    after_help = "Per pair (source = fragment j, target = fragment i of gt.log): both clouds are voxel-downsampled \
(--voxel), described, and N points are sampled from each (for every N of --samples; the same points for every descriptor); \
each sampled source point is matched to its nearest target point in descriptor space (--mutual: mutual nearest only). \
IR: fraction of matches closer than 10 cm under the ground truth; FMR: fraction of pairs with IR above 5 %; RR: RANSAC \
(3-point samples, edge-length check 0.9, --ransac-distance, --ransac-iterations, confidence 0.999) registers a pair when \
the official error x'.Info.x / Info00 of inv(T_gt).T_est (x = [t, q_xyz]) is at most 0.2^2; 3DMatch skips consecutive \
fragments as the official protocol does. RRE (degrees) and RTE (metres) are means over registered pairs. --icp refines each RANSAC pose by point-to-point ICP. Every draw is \
seeded from --seed and the pair, so the same seed gives the same table on any thread count."
)]
pub struct EvalRegistrationArgs {
    /// Benchmark folder: `pointreggpt fragments` output, GeoTransformer's metadata/benchmarks layout, or the
    /// official 3DMatch download (<scene>/cloud_bin_k.ply beside <scene>-evaluation/gt.log, gt.info).
    pub bench: PathBuf,
    /// Descriptor: fpfh (radius 0.125 m), fpfh:RADIUS, fpfh:R1+R2+... (multi-scale, concatenated), or the
    /// path of a patch-network checkpoint written by `pointreggpt train descriptor` (its latest.safetensors).
    #[arg(long, default_value = "fpfh")]
    pub descriptor: String,
    /// A second descriptor: its table too, and the paired IR difference (descriptor − compare) with a 95 % CI.
    #[arg(long)]
    pub compare: Option<String>,
    /// Points sampled from each cloud, comma-separated (the papers report 5000,2500,1000,500,250).
    #[arg(long, value_delimiter = ',', default_value = "5000,1000,250")]
    pub samples: Vec<usize>,
    /// Only these benchmarks (comma-separated names: 3DMatch, 3DLoMatch, single-frame, single-frame-lo).
    #[arg(long, value_delimiter = ',')]
    pub only: Vec<String>,
    /// Clouds are voxel-downsampled to this before description, metres.
    #[arg(long, default_value_t = 0.025)]
    pub voxel: f32,
    /// Keep only mutual nearest-neighbour matches.
    #[arg(long)]
    pub mutual: bool,
    /// RANSAC inlier distance, metres.
    #[arg(long, default_value_t = 0.05)]
    pub ransac_distance: f32,
    /// RANSAC iteration budget per pair and sample count.
    #[arg(long, default_value_t = 50_000)]
    pub ransac_iterations: usize,
    /// Refine each RANSAC pose by this many point-to-point ICP iterations on the whole downsampled
    /// clouds (pairs closer than --ransac-distance; 0: no refinement, the official protocol).
    #[arg(long, default_value_t = 0)]
    pub icp: usize,
    /// Seed of the sampling and RANSAC draws.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// CSV instead of text tables.
    #[arg(long)]
    pub csv: bool,
    /// No progress bar.
    #[arg(long)]
    pub quiet: bool,
}

pub fn run(args: &EvalRegistrationArgs, out: &mut dyn Write) -> Result<()> {
    let w = |e: std::io::Error| Error::io("<stdout>", e);
    if args.samples.is_empty() || args.samples.contains(&0) {
        return Err(Error::config("--samples", "must be positive counts, e.g. 5000,1000,250"));
    }
    if !(args.voxel > 0.0 && args.ransac_distance > 0.0) || args.ransac_iterations == 0 {
        return Err(Error::config("--voxel/--ransac-distance/--ransac-iterations", "must be positive"));
    }
    let mut descriptors = vec![Descriptor::parse(&args.descriptor, "--descriptor")?];
    if let Some(c) = &args.compare {
        descriptors.push(Descriptor::parse(c, "--compare")?);
    }
    let mut config = EvalConfig {
        voxel: args.voxel,
        samples: args.samples.clone(),
        mutual: args.mutual,
        seed: args.seed,
        ..Default::default()
    };
    config.ransac.distance = args.ransac_distance;
    config.ransac.max_iterations = args.ransac_iterations;
    config.icp_iterations = args.icp;
    let benches: Vec<_> = find_benchmarks(&args.bench)?
        .into_iter()
        .filter(|b| args.only.is_empty() || args.only.contains(&b.name))
        .collect();
    if benches.is_empty() {
        return Err(Error::config(
            "--only",
            format!("no benchmark of {} is named {}", args.bench.display(), args.only.join(", ")),
        ));
    }
    let total = benches.iter().map(|b| b.pairs.len() as u64).sum();
    let pb = bar(total, !args.quiet, "pairs");
    let mut scores = vec![Vec::new(); descriptors.len()];
    for b in &benches {
        for (d, s) in evaluate(b, &descriptors, &config, &mut || pb.inc(1))?.into_iter().enumerate() {
            scores[d].extend(s);
        }
    }
    pb.finish_and_clear();
    let mut table = Vec::new();
    for (d, s) in descriptors.iter().zip(&scores) {
        table.extend(rows(&d.name(), s));
    }
    table.sort_by(|a, b| {
        benches.iter().position(|x| x.name == a.benchmark).cmp(&benches.iter().position(|x| x.name == b.benchmark))
    });
    let text = if args.csv { format_csv(&table) } else { format_table(&table) };
    write!(out, "{text}").map_err(w)?;
    if descriptors.len() == 2 {
        let paired = paired_ir(&scores[0], &scores[1]);
        write!(out, "{}", format_paired(&descriptors[0].name(), &descriptors[1].name(), &paired, args.csv))
            .map_err(w)?;
    }
    Ok(())
}
