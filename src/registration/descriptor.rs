//! The descriptors `eval registration` compares, behind one `--descriptor` value: FPFH at one or
//! several radii (`fpfh`, `fpfh:0.1`, `fpfh:0.075+0.125+0.2`) or a network trained by
//! `pointreggpt train descriptor` (the path of its checkpoint: a patch network or an FPFH MLP).

use super::fpfh::{fpfh_features, FPFH_DIM};
use super::learned::LearnedDescriptor;
use super::matching::Features;
use crate::error::{Error, Result};
use crate::geometry::Point;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// FPFH radius for `fpfh` alone, metres (5 × the 2.5 cm evaluation voxel, Open3D's usual choice).
pub const DEFAULT_FPFH_RADIUS: f32 = 0.125;

/// A way of describing every point of a cloud.
#[derive(Clone)]
pub enum Descriptor {
    /// FPFH at these radii (metres), concatenated ([`fpfh_features`]).
    Fpfh { radii: Vec<f32> },
    /// A trained network, loaded from `path`.
    Learned { path: PathBuf, model: Arc<LearnedDescriptor> },
}

impl PartialEq for Descriptor {
    fn eq(&self, other: &Self) -> bool {
        match (self, other) {
            (Descriptor::Fpfh { radii: a }, Descriptor::Fpfh { radii: b }) => a == b,
            (Descriptor::Learned { path: a, .. }, Descriptor::Learned { path: b, .. }) => a == b,
            _ => false,
        }
    }
}

impl std::fmt::Debug for Descriptor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.name())
    }
}

impl Descriptor {
    /// Parses `fpfh`, `fpfh:R` or `fpfh:R1+R2+…` (radii in metres); errors name the flag.
    pub fn parse(s: &str, flag: &str) -> Result<Descriptor> {
        let bad = |m: String| Error::config(flag, m);
        let (kind, arg) = s.split_once(':').unwrap_or((s, ""));
        match kind {
            "fpfh" => {
                if arg.is_empty() {
                    return Ok(Descriptor::Fpfh { radii: vec![DEFAULT_FPFH_RADIUS] });
                }
                let radii = arg
                    .split('+')
                    .map(|r| r.trim().parse::<f32>().ok().filter(|r| r.is_finite() && *r > 0.0 && *r <= 2.0))
                    .collect::<Option<Vec<_>>>()
                    .ok_or_else(|| {
                        bad(format!(
                            "`{s}`: FPFH radii must be numbers in (0, 2] metres joined by `+`, e.g. fpfh:0.075+0.125"
                        ))
                    })?;
                Ok(Descriptor::Fpfh { radii })
            }
            _ if Path::new(s).is_file() => {
                let model = LearnedDescriptor::load(Path::new(s))?;
                Ok(Descriptor::Learned { path: PathBuf::from(s), model: Arc::new(model) })
            }
            _ => Err(bad(format!("unknown descriptor `{s}` (known: fpfh, fpfh:RADIUS, fpfh:R1+R2+..., or the path of a checkpoint of `train descriptor`)"))),
        }
    }

    /// The name tables print.
    pub fn name(&self) -> String {
        match self {
            Descriptor::Fpfh { radii } => {
                format!("fpfh:{}", radii.iter().map(|r| r.to_string()).collect::<Vec<_>>().join("+"))
            }
            Descriptor::Learned { path, .. } => path.display().to_string(),
        }
    }

    /// One descriptor row per point of `points` (a cloud in its own camera frame, metres).
    pub fn describe(&self, points: &[Point]) -> Features {
        match self {
            Descriptor::Fpfh { radii } => Features { dim: FPFH_DIM * radii.len(), data: fpfh_features(points, radii) },
            Descriptor::Learned { .. } => self.describe_at(points, &(0..points.len()).collect::<Vec<_>>()),
        }
    }

    /// The rows of [`Descriptor::describe`] at `keypoints` (indices into `points`), in that order. FPFH
    /// (and the FPFH MLP) still need every point's histogram (each FPFH mixes its neighbours'); a patch
    /// network describes only the keypoints.
    pub fn describe_at(&self, points: &[Point], keypoints: &[usize]) -> Features {
        match self {
            Descriptor::Fpfh { .. } => self.describe(points).select(keypoints),
            Descriptor::Learned { model, .. } => Features { dim: model.dim(), data: model.describe(points, keypoints) },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_rejects() {
        assert_eq!(Descriptor::parse("fpfh", "--descriptor").unwrap(), Descriptor::Fpfh { radii: vec![0.125] });
        assert_eq!(
            Descriptor::parse("fpfh:0.1+0.2", "--descriptor").unwrap(),
            Descriptor::Fpfh { radii: vec![0.1, 0.2] }
        );
        let e = Descriptor::parse("fpfh:abc", "--compare").unwrap_err().to_string();
        assert!(e.contains("--compare") && e.contains("radii"), "{e}");
        assert!(Descriptor::parse("shot", "--descriptor").unwrap_err().to_string().contains("unknown descriptor"));
    }
}
