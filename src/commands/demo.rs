//! `pointreggpt demo`: one pair from a synthetic scene, every intermediate written out, checked against
//! the scene's exact depth.

use crate::correction::{apply_keep_mask, CorrectionConfig};
use crate::error::{Error, Result};
use crate::geometry::{
    backproject, overlap, project_zbuffer, voxel_downsample, AxisBox, DepthMap, DepthRange, PivotPoseSampler, ResizeCrop,
};
use crate::inpainting::{InpaintConfig, InpaintContext};
use crate::rng::{unit_seed, Rng};
use crate::sources::synthetic::{SyntheticConfig, SyntheticSequence};
use crate::ply;
use crate::sources::{depth_png, text};
use std::io::Write;
use std::path::{Path, PathBuf};

#[derive(Debug, clap::Args)]
pub struct DemoArgs {
    /// Output folder (created if missing). Not `out/demo`, which is where `make demo` puts its dataset.
    #[arg(long, default_value = "out/demo-one-pair")]
    pub out: PathBuf,
    /// Seed of the synthetic scene and of the pose draw.
    #[arg(long, default_value_t = 7)]
    pub seed: u64,
    /// Working resolution (the official 256: 640×480 → 341×256 → centre crop).
    #[arg(long, default_value_t = 256)]
    pub size: u32,
}

pub fn run(args: &DemoArgs, out: &mut dyn Write) -> Result<()> {
    let w = |e: std::io::Error| Error::io("<stdout>", e);
    std::fs::create_dir_all(&args.out).map_err(|e| Error::io(&args.out, e))?;
    let seq = SyntheticSequence::generate(&SyntheticConfig { frames: 1, ..Default::default() }, args.seed)?;
    let frame = seq.frame(0);

    // Source: the official resize-and-crop, then points in the 0.5–10 m range inside the crop box.
    let rc = ResizeCrop::official(frame.intrinsics.width, frame.intrinsics.height, args.size)?;
    let k = rc.official_intrinsics(&frame.intrinsics)?;
    let source_depth = frame.depth.resize_crop(&rc)?;
    let source_points = AxisBox::OFFICIAL.crop(&backproject(&source_depth, &k, DepthRange::OFFICIAL));

    // Target pose and re-projection.
    let mut rng = Rng::new(unit_seed(args.seed, &frame.key, 0));
    let t_target_from_source = PivotPoseSampler::default().sample(&mut rng);
    let proj = project_zbuffer(&source_points, &t_target_from_source, &k, false);
    let (mut condition, mut known) = (proj.depth.clone(), proj.known.clone());
    let corrector = CorrectionConfig::OFFICIAL_MIN_POOL.build();
    let keep = corrector.keep_mask(&condition);
    let dropped_condition = apply_keep_mask(&mut condition, &mut known, &keep);
    let mut target_depth = InpaintConfig::PushPull {}.build()?.inpaint(&condition, &known, &InpaintContext { intrinsics: k, seed: 0, t_target_from_source });
    let mut all_known = vec![true; known.len()];
    let keep = corrector.keep_mask(&target_depth);
    let dropped_output = apply_keep_mask(&mut target_depth, &mut all_known, &keep);
    let target_points = AxisBox::OFFICIAL.crop(&backproject(&target_depth, &k, DepthRange::OFFICIAL));

    let source_vox = voxel_downsample(&source_points, 0.025);
    let target_vox = voxel_downsample(&target_points, 0.025);
    let ov = overlap(&source_vox, &target_vox, &t_target_from_source, 0.0375);

    // The oracle: the scene's exact depth from the target pose, with the same intrinsics.
    let t_world_from_target = frame.t_world_from_camera.expect("synthetic frames have poses") * t_target_from_source.inverse();
    let truth = seq.scene.render_depth(&k, &t_world_from_target);
    let (median_err, penetrated) = compare_with_truth(&proj.depth, &proj.known, &truth);

    let p = |name: &str| args.out.join(name);
    write_depth(&p("source.depth.png"), &source_depth)?;
    write_depth(&p("reprojected.depth.png"), &proj.depth)?;
    write_depth(&p("condition.depth.png"), &condition)?;
    write_depth(&p("target.depth.png"), &target_depth)?;
    write_depth(&p("target_true.depth.png"), &truth)?;
    write_mask(&p("known.mask.png"), &proj.known, k.width, k.height)?;
    ply::write_points(&p("source.ply"), &source_vox)?;
    ply::write_points(&p("target.ply"), &target_vox)?;
    text::write_pose_file(&p("T_target_from_source.txt"), &t_target_from_source)?;
    text::write_intrinsics_file(&p("camera-intrinsics.txt"), &k)?;

    writeln!(out, "synthetic scene seed {}, frame {} ({}x{} -> {}x{})", args.seed, frame.key, frame.intrinsics.width, frame.intrinsics.height, k.width, k.height).map_err(w)?;
    writeln!(
        out,
        "pose: rotation {:.2} deg, translation {:.3} m",
        t_target_from_source.rotation.angle().to_degrees(),
        t_target_from_source.translation.vector.norm()
    )
    .map_err(w)?;
    writeln!(out, "re-projected pixels: {} of {} known; min-pool correction dropped {} (condition) and {} (output)", proj.known.iter().filter(|b| **b).count(), known.len(), dropped_condition, dropped_output).map_err(w)?;
    writeln!(out, "against the exact depth at the target pose: median |dz| {:.4} m over re-projected pixels, {:.1}% penetrated (> 5 cm behind the true surface)", median_err, penetrated * 100.0).map_err(w)?;
    writeln!(out, "clouds at 2.5 cm: source {} points, target {} points; overlap {:.3} (source) / {:.3} (target) at 3.75 cm", source_vox.len(), target_vox.len(), ov.source, ov.target).map_err(w)?;
    writeln!(out, "wrote PLY clouds (each in its own camera frame), 16-bit mm depth PNGs and T_target_from_source.txt to {}", args.out.display()).map_err(w)?;
    Ok(())
}

/// Median |Δz| over pixels both maps have, and the fraction of re-projected pixels more than 5 cm behind
/// the true surface (penetration).
fn compare_with_truth(depth: &DepthMap, known: &[bool], truth: &DepthMap) -> (f64, f64) {
    let mut errs = Vec::new();
    let mut penetrated = 0usize;
    let mut total = 0usize;
    for ((&z, &kn), &t) in depth.data().iter().zip(known).zip(truth.data()) {
        if kn {
            total += 1;
            if t > 0.0 {
                errs.push((z - t).abs() as f64);
                if z - t > 0.05 {
                    penetrated += 1;
                }
            }
        }
    }
    errs.sort_by(f64::total_cmp);
    let median = errs.get(errs.len() / 2).copied().unwrap_or(f64::NAN);
    (median, if total == 0 { 0.0 } else { penetrated as f64 / total as f64 })
}

fn write_depth(path: &Path, d: &DepthMap) -> Result<()> {
    depth_png::write_depth_png(path, d.width(), d.height(), &d.to_raw(1000.0))
}

/// An 8-bit mask PNG (255 = known).
fn write_mask(path: &Path, mask: &[bool], width: u32, height: u32) -> Result<()> {
    let file = std::fs::File::create(path).map_err(|e| Error::io(path, e))?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), width, height);
    enc.set_color(png::ColorType::Grayscale);
    enc.set_depth(png::BitDepth::Eight);
    let data: Vec<u8> = mask.iter().map(|&m| if m { 255 } else { 0 }).collect();
    enc.write_header()
        .and_then(|mut wr| wr.write_image_data(&data))
        .map_err(|e| Error::input(path, format!("cannot write PNG: {e}")))
}
