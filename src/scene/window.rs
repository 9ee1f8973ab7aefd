//! Which frames a scene fuses: the window of a source frame's block ([`super::SceneConfig`]), without the
//! frames a held-out view must not see ([`HeldOut`]).

use super::config::SceneConfig;

/// A captured view that scores a generated one: its frame, and `radius` frames on each side of it, must
/// never enter the scene that corrects or fills the generated view (a frame that saw the same pixels
/// would hand the scene the answer, its sensor noise and dropouts included).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HeldOut {
    /// The held-out frame's sequence position.
    pub position: usize,
    /// Frames on each side of it that are held out with it.
    pub radius: usize,
}

impl HeldOut {
    /// Whether the frame at `position` is held out.
    pub fn excludes(&self, position: usize) -> bool {
        position.abs_diff(self.position) <= self.radius
    }
}

/// The sequence positions one scene fuses, in increasing order. Made only by [`window_frames`], which
/// leaves out every held-out frame: a held-out frame cannot be in a scene.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SceneFrames {
    positions: Vec<usize>,
}

impl SceneFrames {
    pub fn positions(&self) -> &[usize] {
        &self.positions
    }
}

/// The block a source frame at sequence position `position` belongs to: its scene is the block's.
pub fn block_of(position: usize, config: &SceneConfig) -> usize {
    position / config.block
}

/// The frames of block `block`'s scene in a sequence whose selected frames span positions `span` (both
/// ends included): the positions `block·B − reach .. (block+1)·B + reach` (B = `config.block`) within
/// `span` that are multiples of `config.every` and have a pose, minus every frame `held_out` excludes.
pub fn window_frames(config: &SceneConfig, block: usize, span: (usize, usize), has_pose: impl Fn(usize) -> bool, held_out: &[HeldOut]) -> SceneFrames {
    let start = (block * config.block).saturating_sub(config.reach).max(span.0);
    let end = ((block + 1) * config.block + config.reach).min(span.1 + 1);
    let positions = (start..end)
        .filter(|p| p % config.every == 0 && has_pose(*p) && !held_out.iter().any(|h| h.excludes(*p)))
        .collect();
    SceneFrames { positions }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config(block: usize, reach: usize, every: usize) -> SceneConfig {
        SceneConfig { block, reach, every, ..SceneConfig::default() }
    }

    #[test]
    fn a_block_takes_every_nth_posed_frame_within_its_reach_and_the_span() {
        let c = config(10, 5, 2);
        assert_eq!(block_of(0, &c), 0);
        assert_eq!(block_of(19, &c), 1);
        // Block 1 spans 10..20, reach 5: 5..25, even positions only.
        let all = window_frames(&c, 1, (0, 100), |_| true, &[]);
        assert_eq!(all.positions(), &[6, 8, 10, 12, 14, 16, 18, 20, 22, 24]);
        // The span cuts it (a training split 8..=17), and unposed frames are left out.
        let cut = window_frames(&c, 1, (8, 17), |p| p != 12, &[]);
        assert_eq!(cut.positions(), &[8, 10, 14, 16]);
    }

    #[test]
    fn a_held_out_frame_and_its_neighbours_never_enter_a_scene() {
        let c = config(30, 60, 1);
        for target in [0usize, 29, 30, 45, 89, 200] {
            for radius in [0usize, 3, 15] {
                let h = HeldOut { position: target, radius };
                for block in 0..5 {
                    let frames = window_frames(&c, block, (0, 300), |_| true, &[h]);
                    assert!(frames.positions().iter().all(|p| p.abs_diff(target) > radius), "block {block}, target {target}, radius {radius}");
                    // Nothing else is left out: every other position of the window is there.
                    let all = window_frames(&c, block, (0, 300), |_| true, &[]);
                    let kept = all.positions().iter().filter(|p| p.abs_diff(target) > radius).count();
                    assert_eq!(frames.positions().len(), kept);
                }
            }
        }
    }
}
