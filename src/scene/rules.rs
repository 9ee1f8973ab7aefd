//! What a scene decides about a target view, as pure functions: which re-projected pixels penetrate a
//! surface (the correction labels' rule), and which unknown pixels it fills.

use crate::geometry::DepthMap;
use crate::correction::{keep_label, SceneRule};

/// The keep mask of `depth` against the scene's depth `scene` seen from the same camera: where the scene
/// has a surface, the rule that makes the correction labels (keep when `|depth − scene| < margin`: a pixel
/// behind the fused surface by the margin or more penetrates it, one in front of it floats in space the
/// scene saw empty; with `behind_only` only the first is dropped), and with `fallback_everywhere` also
/// `fallback`'s decision; where it has none (never observed), `fallback`'s decision; pixels without depth
/// are kept (nothing to drop).
pub fn scene_keep_mask(depth: &DepthMap, scene: &DepthMap, rule: SceneRule, fallback: &[bool]) -> Vec<bool> {
    let label = keep_label(depth, scene, rule.margin);
    let (d, s) = (depth.data(), scene.data());
    let agrees = |i: usize| if rule.behind_only { d[i] - s[i] < rule.margin } else { label[i] };
    let seen = |i: usize| agrees(i) && (fallback[i] || !rule.fallback_everywhere);
    (0..d.len()).map(|i| if d[i] <= 0.0 { true } else if s[i] > 0.0 { seen(i) } else { fallback[i] }).collect()
}

/// A view with the scene's depth pasted into its unknown pixels ([`paste_scene`]).
pub struct Pasted {
    pub depth: DepthMap,
    /// The pixels the scene filled.
    pub from_scene: Vec<bool>,
    /// The pixels known now: re-projected or from the scene (what a fallback fill must keep).
    pub known: Vec<bool>,
}

/// The scene fill of a view: every unknown pixel where the scene has a surface gets the scene's depth;
/// known pixels stay bit for bit.
pub fn paste_scene(depth: &DepthMap, known: &[bool], scene: &DepthMap) -> Pasted {
    let mut out = depth.clone();
    let mut from_scene = vec![false; known.len()];
    for (i, (z, s)) in out.data_mut().iter_mut().zip(scene.data()).enumerate() {
        if !known[i] && *s > 0.0 {
            *z = *s;
            from_scene[i] = true;
        }
    }
    let known = known.iter().zip(&from_scene).map(|(k, s)| *k || *s).collect();
    Pasted { depth: out, from_scene, known }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_label_rule_where_the_scene_is_seen_and_the_fallback_elsewhere() {
        // Pixels: no depth; on the surface; 10 cm behind it; 10 cm in front; no scene (fallback keeps);
        // no scene (fallback drops).
        let depth = DepthMap::new(6, 1, vec![0.0, 2.01, 2.1, 1.9, 3.0, 3.0]).unwrap();
        let scene = DepthMap::new(6, 1, vec![2.0, 2.0, 2.0, 2.0, 0.0, 0.0]).unwrap();
        let fallback = [false, false, true, true, true, false];
        let rule = SceneRule { margin: 0.05, fallback_everywhere: false, behind_only: false };
        assert_eq!(scene_keep_mask(&depth, &scene, rule, &fallback), vec![true, true, false, false, true, false]);
        // The fallback everywhere: pixel 1 (on the surface) is dropped too, by the fallback.
        let rule = SceneRule { fallback_everywhere: true, ..rule };
        assert_eq!(scene_keep_mask(&depth, &scene, rule, &fallback), vec![true, false, false, false, true, false]);
        // Behind only: pixel 3 (10 cm in front of the surface) is kept.
        let rule = SceneRule { fallback_everywhere: false, behind_only: true, ..rule };
        assert_eq!(scene_keep_mask(&depth, &scene, rule, &fallback), vec![true, true, false, true, true, false]);
    }

    #[test]
    fn the_fill_takes_the_scene_at_unknown_pixels_only() {
        let depth = DepthMap::new(4, 1, vec![1.5, 0.0, 0.0, f32::from_bits(0x3fc0_0001)]).unwrap();
        let scene = DepthMap::new(4, 1, vec![9.0, 2.0, 0.0, 9.0]).unwrap();
        let known = [true, false, false, true];
        let p = paste_scene(&depth, &known, &scene);
        assert_eq!(p.from_scene, vec![false, true, false, false]);
        assert_eq!(p.known, vec![true, true, false, true]);
        assert_eq!(p.depth.data()[..3], [1.5, 2.0, 0.0]);
        assert_eq!(p.depth.data()[3].to_bits(), 0x3fc0_0001, "known pixels stay bit for bit");
    }
}
