//! Inpaint: fill the unknown target pixels, keeping the known ones bit-exact; with `scene`, first from the
//! unit's scene where it has a surface ([`paste_scene`]), then the rest by the fallback.

use super::{streams, PairUnit};
use crate::error::Result;
use crate::inpainting::{InpaintContext, Inpainter};
use crate::rng::Rng;
use crate::runtime::Stage;
use crate::scene::paste_scene;

pub struct Inpaint {
    /// The method's inpainter (for `scene`, its fallback's).
    pub inpainter: Box<dyn Inpainter>,
    /// Whether the method is `scene`: units with a scene take its depth first.
    pub scene: bool,
}

impl Stage<PairUnit> for Inpaint {
    fn name(&self) -> &'static str {
        "inpaint"
    }

    fn process(&mut self, unit: &mut PairUnit) -> Result<()> {
        self.process_batch(std::slice::from_mut(unit))
    }

    fn batch(&self) -> usize {
        self.inpainter.batch()
    }

    fn process_batch(&mut self, units: &mut [PairUnit]) -> Result<()> {
        // The scene's pixels join the known ones: the fallback fills around them and keeps them bit for bit.
        let mut pasted = Vec::new();
        for u in units.iter_mut() {
            pasted.push(match (self.scene, &u.scene_depth) {
                (true, Some(scene)) => {
                    let p = paste_scene(u.condition.as_ref().expect("reproject sets the condition"), &u.known, scene);
                    u.scene_filled = p.from_scene.clone();
                    Some(p)
                }
                _ => None,
            });
        }
        let contexts: Vec<InpaintContext> = units
            .iter()
            .map(|u| InpaintContext {
                intrinsics: u.k.expect("ingest sets the intrinsics"),
                seed: noise_seed(u.seed, 0),
                t_target_from_source: u.t_target_from_source,
            })
            .collect();
        let views: Vec<_> = units
            .iter()
            .zip(&contexts)
            .zip(&pasted)
            .map(|((u, ctx), p)| match p {
                Some(p) => (&p.depth, p.known.as_slice(), ctx),
                None => (u.condition.as_ref().expect("reproject sets the condition"), u.known.as_slice(), ctx),
            })
            .collect();
        let filled = self.inpainter.inpaint_batch(&views);
        for (unit, depth) in units.iter_mut().zip(filled) {
            unit.target_depth = Some(depth);
        }
        Ok(())
    }
}

/// The inpainting noise seed of target view `view` (0 = the pair's first view) of a unit: a sub-stream of
/// the unit's seed, apart from the pose sampler's.
pub fn noise_seed(unit_seed: u64, view: u32) -> u64 {
    let stream = Rng::new(unit_seed).fork(streams::INPAINT);
    match view {
        0 => stream,
        v => stream.fork(v as u64),
    }
    .next_u64()
}
