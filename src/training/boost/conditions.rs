//! The training conditions of the boost protocol and the pipeline settings of the generated ones.

use crate::error::{Error, Result};
use std::path::Path;

/// One training condition.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Condition {
    /// Raw FPFH, no training.
    C0,
    /// Real single-frame pairs of the training frames with their captured poses.
    C1,
    /// Re-projection only: no correction, no fill (the paper's ablation).
    C2,
    /// The classical generator: min-pool correction + background fill.
    C3,
    /// The neural generator: U-Net correction + the hole-aware diffusion refiner (1 step from push–pull).
    C4,
    /// Real + C3 at C1's pair count (half each) and at double (all of C1 + as many C3 pairs).
    C5,
    C5x2,
    /// Real + C4, likewise.
    C6,
    C6x2,
}

pub const ALL: [Condition; 9] =
    [Condition::C0, Condition::C1, Condition::C2, Condition::C3, Condition::C4, Condition::C5, Condition::C5x2, Condition::C6, Condition::C6x2];

/// The paired IR differences the table reports (first − second), when both were run.
pub const COMPARISONS: [(Condition, Condition); 8] = [
    (Condition::C1, Condition::C0),
    (Condition::C3, Condition::C0),
    (Condition::C3, Condition::C2),
    (Condition::C4, Condition::C3),
    (Condition::C5, Condition::C1),
    (Condition::C5x2, Condition::C1),
    (Condition::C6, Condition::C1),
    (Condition::C6x2, Condition::C1),
];

/// A generator pipeline a condition draws pairs from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Generator {
    Reprojection,
    Classical,
    Neural,
}

impl Generator {
    pub fn name(self) -> &'static str {
        match self {
            Generator::Reprojection => "reprojection",
            Generator::Classical => "classical",
            Generator::Neural => "neural",
        }
    }

    /// Overrides (TOML key, TOML value) applied on top of the classical pipeline config; `models` is the
    /// folder holding the neural generator's checkpoints.
    pub fn overrides(self, models: &Path) -> Vec<(String, String)> {
        let q = |p: &Path| toml::Value::String(p.display().to_string()).to_string();
        match self {
            Generator::Classical => Vec::new(),
            Generator::Reprojection => vec![
                ("correct.condition".into(), r#"{ method = "none" }"#.into()),
                ("correct.output".into(), r#"{ method = "none" }"#.into()),
                ("inpaint".into(), r#"{ method = "none" }"#.into()),
            ],
            Generator::Neural => {
                let unet = format!(r#"{{ method = "unet", checkpoint = {}, threshold = 0.5 }}"#, q(&models.join("correction-tiny.safetensors")));
                let diffusion = format!(
                    r#"{{ method = "diffusion", checkpoint = {}, steps = 1, eta = 0.0, start = "push_pull", start_step = 0 }}"#,
                    q(&models.join("diffusion-tiny-holes.safetensors"))
                );
                vec![("correct.condition".into(), unet.clone()), ("correct.output".into(), unet), ("inpaint".into(), diffusion)]
            }
        }
    }
}

impl Condition {
    pub fn parse(s: &str) -> Result<Condition> {
        ALL.into_iter().find(|c| c.name().eq_ignore_ascii_case(s.trim())).ok_or_else(|| {
            Error::config("--conditions", format!("unknown condition `{s}` (known: {})", ALL.map(|c| c.name()).join(", ")))
        })
    }

    pub fn name(self) -> &'static str {
        match self {
            Condition::C0 => "C0",
            Condition::C1 => "C1",
            Condition::C2 => "C2",
            Condition::C3 => "C3",
            Condition::C4 => "C4",
            Condition::C5 => "C5",
            Condition::C5x2 => "C5x2",
            Condition::C6 => "C6",
            Condition::C6x2 => "C6x2",
        }
    }

    /// What the table prints beside the name.
    pub fn label(self) -> &'static str {
        match self {
            Condition::C0 => "raw FPFH",
            Condition::C1 => "real pairs",
            Condition::C2 => "re-projection only",
            Condition::C3 => "classical generator",
            Condition::C4 => "neural generator",
            Condition::C5 => "real + classical",
            Condition::C5x2 => "real + classical, 2x",
            Condition::C6 => "real + neural",
            Condition::C6x2 => "real + neural, 2x",
        }
    }

    /// Whether the condition trains a descriptor (all but C0).
    pub fn trains(self) -> bool {
        self != Condition::C0
    }

    /// Whether the condition uses the real pairs.
    pub fn uses_real(self) -> bool {
        matches!(self, Condition::C1 | Condition::C5 | Condition::C5x2 | Condition::C6 | Condition::C6x2)
    }

    /// The generator whose pairs the condition uses, if any.
    pub fn generator(self) -> Option<Generator> {
        match self {
            Condition::C2 => Some(Generator::Reprojection),
            Condition::C3 | Condition::C5 | Condition::C5x2 => Some(Generator::Classical),
            Condition::C4 | Condition::C6 | Condition::C6x2 => Some(Generator::Neural),
            Condition::C0 | Condition::C1 => None,
        }
    }

    /// (real pairs, generated pairs) the condition trains on, given `real` real pairs and `generated`
    /// generated ones available.
    pub fn mix(self, real: usize, generated: usize) -> (usize, usize) {
        match self {
            Condition::C0 => (0, 0),
            Condition::C1 => (real, 0),
            Condition::C2 | Condition::C3 | Condition::C4 => (0, generated),
            Condition::C5 | Condition::C6 => (real.div_ceil(2), (real / 2).min(generated)),
            Condition::C5x2 | Condition::C6x2 => (real, real.min(generated)),
        }
    }
}

/// Parses `C0,C1,...` (empty: all).
pub fn parse_list(items: &[String]) -> Result<Vec<Condition>> {
    if items.is_empty() {
        return Ok(ALL.to_vec());
    }
    let mut out: Vec<Condition> = items.iter().map(|s| Condition::parse(s)).collect::<Result<_>>()?;
    out.sort();
    out.dedup();
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_parse_back_and_mixes_keep_the_counts() {
        for c in ALL {
            assert_eq!(Condition::parse(&c.name().to_lowercase()).unwrap(), c);
        }
        assert!(Condition::parse("C7").unwrap_err().to_string().contains("C6x2"));
        assert_eq!(Condition::C5.mix(301, 500), (151, 150));
        assert_eq!(Condition::C5x2.mix(301, 500), (301, 301));
        assert_eq!(Condition::C3.mix(301, 500), (0, 500));
        assert_eq!(parse_list(&["c3".into(), "C0".into(), "C3".into()]).unwrap(), vec![Condition::C0, Condition::C3]);
    }
}
