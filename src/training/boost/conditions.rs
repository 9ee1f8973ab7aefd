//! The training conditions of `eval boost` and the pipeline settings of the generators.
//!
//! A condition is a list of components joined by `+`, each a source of training pairs with an optional
//! factor `:f`:
//! - `fpfh`: raw FPFH, no training (alone);
//! - real pairs: `single` (real single-frame pairs of the training frames, their source-side overlap
//!   histogram matched to the reference generator's pairs), `frag` (pairs of fused fragments of the
//!   training frames, up to `--pairs` of them), `fragN` (N of the fragment pairs: the scarce-real case);
//! - generated pairs: `reproj` (re-projection only: no correction, no fill), `classical` (min-pool +
//!   the fill of the classical config), `nofill` (min-pool, holes left empty), `neural` (U-Net correction
//!   + the hole-aware diffusion refiner), `scene` (for posed sequences: corrected and filled from the
//!   scene fused from the training frames around each source frame, min-pool and no fill where the scene
//!   saw nothing), each optionally `-lo` (poses drawn for a 3DLoMatch + 3DMatch overlap mix through
//!   `[pose.target]`).
//!
//! Counts: when the first component is real, it is the base: n of its pairs are drawn, the base keeps
//! ⌈f·n⌉ of them and every other component ⌊f·n⌋ (its pool permitting). Without a real component, each
//! generated component takes ⌊f·--pairs⌋. So `frag+nofill:8` is the paper's 8:1 mix, `frag+single:8` its
//! control with real single frames in place of the generated ones.
//!
//! The conditions of the single-frame protocol keep their names: C0 = `fpfh`, C1 = `single`, C2 =
//! `reproj`, C3 = `classical`, C4 = `neural`, C5 = `single:0.5+classical:0.5`, C5x2 = `single+classical`,
//! C6 = `single:0.5+neural:0.5`, C6x2 = `single+neural`.

use crate::error::{Error, Result};
use std::path::Path;

/// Where a generator's pairs come from: its correction and fill.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum GeneratorKind {
    Reprojection,
    Classical,
    NoFill,
    Neural,
    Scene,
}

/// A generator pipeline a condition draws pairs from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Generator {
    pub kind: GeneratorKind,
    /// Poses steered to the 3DLoMatch + 3DMatch overlap bins.
    pub lo: bool,
}

/// The `[pose.target]` of the `-lo` generators: half the pairs at 10–30 % overlap, half above.
const LO_TARGET: &str = "{ bin_edges = [0.1, 0.3, 1.0], weights = [1.0, 1.0] }";

impl Generator {
    pub const CLASSICAL: Generator = Generator { kind: GeneratorKind::Classical, lo: false };

    pub fn name(self) -> String {
        let base = match self.kind {
            GeneratorKind::Reprojection => "reproj",
            GeneratorKind::Classical => "classical",
            GeneratorKind::NoFill => "nofill",
            GeneratorKind::Neural => "neural",
            GeneratorKind::Scene => "scene",
        };
        if self.lo {
            format!("{base}-lo")
        } else {
            base.to_string()
        }
    }

    fn parse(s: &str) -> Option<Generator> {
        let (base, lo) = match s.strip_suffix("-lo") {
            Some(b) => (b, true),
            None => (s, false),
        };
        let kind = match base {
            "reproj" => GeneratorKind::Reprojection,
            "classical" => GeneratorKind::Classical,
            "nofill" => GeneratorKind::NoFill,
            "neural" => GeneratorKind::Neural,
            "scene" => GeneratorKind::Scene,
            _ => return None,
        };
        Some(Generator { kind, lo })
    }

    /// Overrides (TOML key, TOML value) applied on top of the classical pipeline config; `models` is the
    /// folder holding the neural generator's checkpoints.
    pub fn overrides(self, models: &Path) -> Vec<(String, String)> {
        let q = |p: &Path| toml::Value::String(p.display().to_string()).to_string();
        let none = r#"{ method = "none" }"#.to_string();
        let mut out: Vec<(String, String)> = match self.kind {
            GeneratorKind::Classical => Vec::new(),
            GeneratorKind::NoFill => vec![("inpaint".into(), none)],
            GeneratorKind::Reprojection => {
                vec![("correct.condition".into(), none.clone()), ("correct.output".into(), none.clone()), ("inpaint".into(), none)]
            }
            GeneratorKind::Neural => {
                let unet = format!(r#"{{ method = "unet", checkpoint = {}, threshold = 0.5 }}"#, q(&models.join("correction-tiny.safetensors")));
                let diffusion = format!(
                    r#"{{ method = "diffusion", checkpoint = {}, steps = 1, eta = 0.0, start = "push_pull", start_step = 0 }}"#,
                    q(&models.join("diffusion-tiny-holes.safetensors"))
                );
                vec![("correct.condition".into(), unet.clone()), ("correct.output".into(), unet), ("inpaint".into(), diffusion)]
            }
            GeneratorKind::Scene => {
                let correct = r#"{ method = "scene", margin = 0.05, fallback = { method = "min_pool", threshold = 0.0375 } }"#.to_string();
                let fill = r#"{ method = "scene", fallback = { method = "none" } }"#.to_string();
                vec![("correct.condition".into(), correct.clone()), ("correct.output".into(), correct), ("inpaint".into(), fill)]
            }
        };
        if self.lo {
            out.push(("pose.target".into(), LO_TARGET.into()));
        }
        out
    }
}

/// The real pairs of a component.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Real {
    /// Real single-frame pairs of the training frames.
    Single,
    /// Pairs of fused fragments of the training frames; `Some(n)`: n of them.
    Fragments(Option<usize>),
}

/// One source of a condition's training pairs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Source {
    Real(Real),
    Generated(Generator),
}

/// A source and its factor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Part {
    pub source: Source,
    pub factor: f64,
}

/// One training condition: its name (as written, or the alias) and what it trains on (no part: raw FPFH).
#[derive(Clone, Debug, PartialEq)]
pub struct Condition {
    pub name: String,
    pub parts: Vec<Part>,
}

/// The single-frame protocol's names and what they stand for.
const ALIASES: [(&str, &str); 9] = [
    ("C0", "fpfh"),
    ("C1", "single"),
    ("C2", "reproj"),
    ("C3", "classical"),
    ("C4", "neural"),
    ("C5", "single:0.5+classical:0.5"),
    ("C5x2", "single+classical"),
    ("C6", "single:0.5+neural:0.5"),
    ("C6x2", "single+neural"),
];

/// What an alias stands for (`C5x2` → `single+classical`).
pub fn alias_spec(name: &str) -> Option<&'static str> {
    ALIASES.iter().find(|(a, _)| *a == name).map(|(_, s)| *s)
}

/// Every alias, in order (the default condition list).
pub fn aliases() -> Vec<&'static str> {
    ALIASES.iter().map(|(a, _)| *a).collect()
}

/// The paired differences the single-frame protocol reports between its aliases (first − second).
const ALIAS_COMPARISONS: [(&str, &str); 8] =
    [("C1", "C0"), ("C3", "C0"), ("C3", "C2"), ("C4", "C3"), ("C5", "C1"), ("C5x2", "C1"), ("C6", "C1"), ("C6x2", "C1")];

impl Condition {
    /// Parses an alias (`C5x2`, any case) or a component list (`frag+nofill:8`).
    pub fn parse(text: &str) -> Result<Condition> {
        let text = text.trim();
        let bad = |m: String| Error::config("--conditions", format!("`{text}`: {m}"));
        let (name, spec) = match ALIASES.iter().find(|(a, _)| a.eq_ignore_ascii_case(text)) {
            Some((a, s)) => (a.to_string(), *s),
            None => (text.to_string(), text),
        };
        if spec == "fpfh" {
            return Ok(Condition { name, parts: Vec::new() });
        }
        let mut parts = Vec::new();
        for item in spec.split('+') {
            let (source, factor) = match item.split_once(':') {
                Some((s, f)) => (s, f.parse::<f64>().map_err(|_| bad(format!("factor `{f}` is not a number")))?),
                None => (item, 1.0),
            };
            if !(factor.is_finite() && factor > 0.0) {
                return Err(bad(format!("factor {factor} must be positive")));
            }
            let source = match source {
                "single" => Source::Real(Real::Single),
                "frag" => Source::Real(Real::Fragments(None)),
                s if s.starts_with("frag") && s[4..].parse::<usize>().is_ok_and(|n| n > 0) => Source::Real(Real::Fragments(Some(s[4..].parse().unwrap()))),
                s => Source::Generated(Generator::parse(s).ok_or_else(|| {
                    bad(format!(
                        "unknown component `{s}` (fpfh alone; single, frag, fragN; reproj, classical, nofill, neural, scene, each with -lo; \
                         or an alias {})",
                        aliases().join(", ")
                    ))
                })?),
            };
            parts.push(Part { source, factor });
        }
        let any_real = parts.iter().any(|p| matches!(p.source, Source::Real(_)));
        if any_real && !matches!(parts[0].source, Source::Real(_)) {
            return Err(bad("put the real component first: it is the base the others are counted by".into()));
        }
        Ok(Condition { name, parts })
    }

    /// Whether the condition trains a descriptor (all but `fpfh`).
    pub fn trains(&self) -> bool {
        !self.parts.is_empty()
    }

    /// The real pairs the condition counts by, if its first component is real.
    pub fn base(&self) -> Option<Real> {
        match self.parts.first()?.source {
            Source::Real(r) => Some(r),
            Source::Generated(_) => None,
        }
    }

    /// The real and generated sources the condition uses.
    pub fn reals(&self) -> impl Iterator<Item = Real> + '_ {
        self.parts.iter().filter_map(|p| match p.source {
            Source::Real(r) => Some(r),
            Source::Generated(_) => None,
        })
    }

    pub fn generators(&self) -> impl Iterator<Item = Generator> + '_ {
        self.parts.iter().filter_map(|p| match p.source {
            Source::Generated(g) => Some(g),
            Source::Real(_) => None,
        })
    }

    /// How many pairs each part takes: `base` pairs drawn for the real base (if any), `pairs` (--pairs)
    /// otherwise; a pool's size caps its part (`available`).
    pub fn counts(&self, base: usize, pairs: usize, available: impl Fn(&Source) -> usize) -> Vec<usize> {
        let based = self.base().is_some();
        self.parts
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let want = match (based, i) {
                    (true, 0) => (p.factor * base as f64).ceil() as usize,
                    (true, _) => (p.factor * base as f64).floor() as usize,
                    (false, _) => (p.factor * pairs as f64).floor() as usize,
                };
                want.min(available(&p.source))
            })
            .collect()
    }
}

/// Parses `--conditions` (empty: the nine aliases of the single-frame protocol). Names must be unique.
pub fn parse_list(items: &[String]) -> Result<Vec<Condition>> {
    let items: Vec<String> = if items.is_empty() { aliases().iter().map(|s| s.to_string()).collect() } else { items.to_vec() };
    let mut out: Vec<Condition> = Vec::new();
    for s in &items {
        let c = Condition::parse(s)?;
        if !out.iter().any(|o| o.name == c.name) {
            out.push(c);
        }
    }
    Ok(out)
}

/// The paired differences to report among `conditions` (first − second): the single-frame protocol's
/// between its aliases; for a mix, against its base alone (`frag+nofill:8` − `frag`); for one component
/// alone, against raw FPFH; plus the `extra` pairs asked for (`A-B` by name). Only pairs of conditions run.
pub fn comparisons(conditions: &[Condition], extra: &[(String, String)]) -> Vec<(String, String)> {
    let has = |n: &str| conditions.iter().any(|c| c.name == n);
    let mut out: Vec<(String, String)> = Vec::new();
    let mut push = |a: &str, b: &str| {
        if has(a) && has(b) && a != b && !out.iter().any(|(x, y)| x == a && y == b) {
            out.push((a.to_string(), b.to_string()));
        }
    };
    for (a, b) in ALIAS_COMPARISONS {
        push(a, b);
    }
    let alias = |c: &Condition| ALIASES.iter().any(|(a, _)| *a == c.name);
    let fpfh = conditions.iter().find(|c| !c.trains()).map(|c| c.name.clone());
    for c in conditions.iter().filter(|c| c.trains() && !alias(c)) {
        if c.parts.len() > 1 {
            // The base alone, under any name that means it.
            let base = Condition { name: String::new(), parts: vec![Part { factor: 1.0, ..c.parts[0] }] };
            if let Some(b) = conditions.iter().find(|o| o.parts == base.parts) {
                push(&c.name, &b.name);
            }
        } else if let Some(f) = &fpfh {
            push(&c.name, f);
        }
    }
    for (a, b) in extra {
        push(a, b);
    }
    out
}

/// Parses `--compare A-B,...` (names as in --conditions; the last `-` splits, so names may contain `-`).
pub fn parse_comparisons(items: &[String]) -> Result<Vec<(String, String)>> {
    items
        .iter()
        .map(|s| {
            // Names never end in `-`, and `-lo` is a suffix: split at a `-` followed by a condition name.
            s.match_indices('-')
                .map(|(i, _)| (&s[..i], &s[i + 1..]))
                .find(|(a, b)| Condition::parse(a).is_ok() && Condition::parse(b).is_ok())
                .map(|(a, b)| (a.trim().to_string(), b.trim().to_string()))
                .ok_or_else(|| Error::config("--compare", format!("`{s}` is not A-B with A and B conditions")))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn aliases_and_component_lists_parse() {
        let c = Condition::parse("c5x2").unwrap();
        assert_eq!(c.name, "C5x2");
        assert_eq!(c.parts, vec![Part { source: Source::Real(Real::Single), factor: 1.0 }, Part { source: Source::Generated(Generator::CLASSICAL), factor: 1.0 }]);
        let c = Condition::parse("frag24+nofill-lo:8").unwrap();
        assert_eq!(c.base(), Some(Real::Fragments(Some(24))));
        assert_eq!(c.generators().collect::<Vec<_>>(), vec![Generator { kind: GeneratorKind::NoFill, lo: true }]);
        assert!(!Condition::parse("C0").unwrap().trains());
        for bad in ["C7", "frag+", "nofill+frag", "frag:0", "frag:x", "frag0"] {
            assert!(Condition::parse(bad).is_err(), "{bad} parsed");
        }
    }

    #[test]
    fn counts_follow_the_base() {
        let avail = |_: &Source| 10_000;
        // The single-frame protocol's mixes at 301 real pairs: C5 151 + 150, C5x2 301 + 301.
        assert_eq!(Condition::parse("C5").unwrap().counts(301, 2000, avail), vec![151, 150]);
        assert_eq!(Condition::parse("C5x2").unwrap().counts(301, 2000, avail), vec![301, 301]);
        assert_eq!(Condition::parse("C3").unwrap().counts(301, 500, avail), vec![500]);
        assert_eq!(Condition::parse("frag+nofill:8").unwrap().counts(37, 2000, avail), vec![37, 296]);
        // A small pool caps its part.
        assert_eq!(Condition::parse("frag+nofill:8").unwrap().counts(37, 2000, |s| if matches!(s, Source::Generated(_)) { 100 } else { 37 }), vec![37, 100]);
    }

    #[test]
    fn comparisons_by_rule() {
        let cs = parse_list(&["C0", "frag", "frag+nofill:8", "frag+single:8", "nofill"].map(String::from)).unwrap();
        let got = comparisons(&cs, &[("frag+nofill:8".into(), "frag+single:8".into())]);
        let want: Vec<(String, String)> = [("frag", "C0"), ("frag+nofill:8", "frag"), ("frag+single:8", "frag"), ("nofill", "C0"), ("frag+nofill:8", "frag+single:8")]
            .iter()
            .map(|(a, b)| (a.to_string(), b.to_string()))
            .collect();
        assert_eq!(got, want);
        assert_eq!(comparisons(&parse_list(&[]).unwrap(), &[]).len(), 8, "the single-frame protocol's eight");
        assert_eq!(parse_comparisons(&["frag+nofill-lo:8-frag".into()]).unwrap(), vec![("frag+nofill-lo:8".to_string(), "frag".to_string())]);
    }
}
