//! A trained descriptor: which network it is ([`DescriptorModel`]: a patch network or an MLP on
//! multi-scale FPFH), its checkpoint format (safetensors, the configuration in the header's metadata
//! under [`META_KEY`]) and the describing of keypoints of a cloud.

use super::fpfh::{fpfh_features, FPFH_DIM};
use super::patch::{PatchCloud, PatchConfig};
use crate::error::{Error, Result};
use crate::geometry::Point;
use crate::nn::checkpoint::{read_header, read_tensors, write_safetensors};
use crate::nn::fpfh_mlp::{FpfhMlp, FpfhMlpConfig};
use crate::nn::patch_net::{PatchNet, PatchNetConfig};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;
use tch::{nn, Device, Kind, Tensor};

/// Format tag stored in the metadata (`/1`: patch networks only, without `model`; still read).
pub const FORMAT: &str = "pointreggpt.descriptor/2";
const FORMAT_V1: &str = "pointreggpt.descriptor/1";
/// The `__metadata__` key holding [`DescriptorMeta`] as JSON.
pub const META_KEY: &str = "pointreggpt";
/// Prefix of the network's variables in a checkpoint (training state sits under other prefixes).
pub const NET_PREFIX: &str = "net.";
/// Keypoints per forward pass when describing.
const BATCH: usize = 256;

/// Which network a descriptor is, with everything that shapes its input.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum DescriptorModel {
    /// A 3D ConvNet on a truncated-distance patch around each keypoint.
    Patch { net: PatchNetConfig, patch: PatchConfig },
    /// An MLP on the keypoint's FPFH at `radii` (metres), concatenated.
    FpfhMlp { mlp: FpfhMlpConfig, radii: Vec<f32> },
}

impl Default for DescriptorModel {
    fn default() -> Self {
        DescriptorModel::Patch { net: PatchNetConfig::default(), patch: PatchConfig::default() }
    }
}

impl DescriptorModel {
    /// The MLP on FPFH at `radii` with the default widths.
    pub fn fpfh_mlp(radii: Vec<f32>, hidden: i64, dim: i64) -> Self {
        let input = (FPFH_DIM * radii.len()) as i64;
        DescriptorModel::FpfhMlp { mlp: FpfhMlpConfig { input, hidden, dim }, radii }
    }

    /// Descriptor length.
    pub fn dim(&self) -> usize {
        match self {
            DescriptorModel::Patch { net, .. } => net.dim as usize,
            DescriptorModel::FpfhMlp { mlp, .. } => mlp.dim as usize,
        }
    }

    /// Checks that the network fits its input; `field` names the config in errors.
    pub fn validate(&self, field: &str) -> Result<()> {
        match self {
            DescriptorModel::Patch { net, patch } => {
                patch.validate(&format!("{field}.patch"))?;
                if net.voxels != patch.voxels as i64 {
                    return Err(Error::config(field, format!("the network takes {}³ patches, the patches have {}³ voxels", net.voxels, patch.voxels)));
                }
            }
            DescriptorModel::FpfhMlp { mlp, radii } => {
                if radii.is_empty() || !radii.iter().all(|r| r.is_finite() && *r > 0.0) {
                    return Err(Error::config(field, format!("FPFH radii must be positive metres, got {radii:?}")));
                }
                if mlp.input != (FPFH_DIM * radii.len()) as i64 {
                    return Err(Error::config(field, format!("the MLP takes {} values, {} FPFH radii give {}", mlp.input, radii.len(), FPFH_DIM * radii.len())));
                }
            }
        }
        Ok(())
    }
}

/// What a descriptor checkpoint says about itself besides the weights.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DescriptorMeta {
    pub format: String,
    pub model: DescriptorModel,
    /// Completed optimiser steps.
    pub step: u64,
    /// Free-form provenance: training options, data sets, last loss.
    #[serde(default)]
    pub info: serde_json::Value,
}

/// The metadata of a `/1` checkpoint (a patch network).
#[derive(Deserialize)]
struct MetaV1 {
    net: PatchNetConfig,
    patch: PatchConfig,
    step: u64,
    #[serde(default)]
    info: serde_json::Value,
}

/// Saves `vs`'s variables (under [`NET_PREFIX`]) and `extra` tensors (e.g. optimiser moments) with `meta`.
pub fn save(path: &Path, vs: &nn::VarStore, extra: &[(String, Tensor)], meta: &DescriptorMeta) -> Result<()> {
    let mut tensors: Vec<(String, Tensor)> = vs.variables().into_iter().map(|(k, t)| (format!("{NET_PREFIX}{k}"), t)).collect();
    tensors.extend(extra.iter().map(|(k, t)| (k.clone(), t.shallow_clone())));
    let metadata = BTreeMap::from([(META_KEY.to_string(), serde_json::to_string(meta).expect("json"))]);
    write_safetensors(path, &tensors, &metadata)
}

/// The metadata of a descriptor checkpoint (a `/1` one converted to the current layout).
pub fn read_meta(path: &Path) -> Result<DescriptorMeta> {
    let (metadata, _) = read_header(path)?;
    let text = metadata.get(META_KEY).ok_or_else(|| Error::input(path, "not a pointreggpt descriptor checkpoint (no metadata)"))?;
    let bad = |e: serde_json::Error| Error::input(path, format!("descriptor metadata: {e}"));
    let value: serde_json::Value = serde_json::from_str(text).map_err(bad)?;
    match value.get("format").and_then(|f| f.as_str()) {
        Some(FORMAT) => serde_json::from_value(value).map_err(bad),
        Some(FORMAT_V1) => {
            let v1: MetaV1 = serde_json::from_value(value).map_err(bad)?;
            Ok(DescriptorMeta { format: FORMAT.into(), model: DescriptorModel::Patch { net: v1.net, patch: v1.patch }, step: v1.step, info: v1.info })
        }
        other => Err(Error::input(path, format!("format {other:?}, expected `{FORMAT}`"))),
    }
}

/// Copies the checkpoint's tensors into `vs` (network variables) and returns the other tensors by name.
pub fn load_into(path: &Path, vs: &mut nn::VarStore) -> Result<BTreeMap<String, Tensor>> {
    let mut rest: BTreeMap<String, Tensor> = read_tensors(path)?.into_iter().collect();
    let mut vars = vs.variables();
    tch::no_grad(|| -> Result<()> {
        for (name, var) in vars.iter_mut() {
            let t = rest.remove(&format!("{NET_PREFIX}{name}")).ok_or_else(|| Error::input(path, format!("missing tensor `{NET_PREFIX}{name}`")))?;
            if t.size() != var.size() {
                return Err(Error::input(path, format!("tensor `{name}` has shape {:?}, the network wants {:?}", t.size(), var.size())));
            }
            var.copy_(&t.to_kind(Kind::Float));
        }
        Ok(())
    })?;
    if let Some(k) = rest.keys().find(|k| k.starts_with(NET_PREFIX)) {
        return Err(Error::input(path, format!("tensor `{k}` is not a variable of the network")));
    }
    Ok(rest)
}

/// A descriptor network of either kind, with what turns a cloud into its input.
#[derive(Debug)]
pub enum DescriptorNet {
    Patch { net: PatchNet, patch: PatchConfig },
    FpfhMlp { net: FpfhMlp, radii: Vec<f32> },
}

/// What a network needs of a whole cloud before it describes keypoints of it: the patch indexes, or
/// every point's FPFH (each FPFH mixes its neighbours' histograms).
pub enum Prepared<'a> {
    Patch(PatchCloud<'a>),
    Fpfh(Vec<f32>),
}

impl DescriptorNet {
    /// Creates the variables of `model`'s network under `p`.
    pub fn new(p: &nn::Path, model: &DescriptorModel) -> Result<Self> {
        model.validate("descriptor")?;
        Ok(match model {
            DescriptorModel::Patch { net, patch } => DescriptorNet::Patch { net: PatchNet::new(p, net)?, patch: *patch },
            DescriptorModel::FpfhMlp { mlp, radii } => DescriptorNet::FpfhMlp { net: FpfhMlp::new(p, mlp)?, radii: radii.clone() },
        })
    }

    /// Whether [`DescriptorNet::prepare`] is worth keeping per cloud when the same clouds come back (FPFH
    /// takes ~0.1 s per cloud; the patch indexes are cheap to rebuild and large to keep).
    pub fn worth_caching(&self) -> bool {
        matches!(self, DescriptorNet::FpfhMlp { .. })
    }

    pub fn prepare<'a>(&self, cloud: &'a [Point]) -> Prepared<'a> {
        match self {
            DescriptorNet::Patch { patch, .. } => Prepared::Patch(PatchCloud::new(cloud, patch)),
            DescriptorNet::FpfhMlp { radii, .. } => Prepared::Fpfh(fpfh_features(cloud, radii)),
        }
    }

    /// The network input for `keypoints` (indices into the prepared cloud).
    pub fn input(&self, prepared: &Prepared, cloud: &[Point], keypoints: &[usize]) -> Tensor {
        let m = keypoints.len() as i64;
        match (self, prepared) {
            (DescriptorNet::Patch { patch, .. }, Prepared::Patch(indexed)) => {
                let keys: Vec<Point> = keypoints.iter().map(|&k| cloud[k]).collect();
                let n = patch.voxels as i64;
                Tensor::from_slice(&indexed.patches(&keys)).view([m, 1, n, n, n])
            }
            (DescriptorNet::FpfhMlp { net, .. }, Prepared::Fpfh(rows)) => {
                let d = net.config.input as usize;
                let x: Vec<f32> = keypoints.iter().flat_map(|&k| rows[k * d..(k + 1) * d].iter().copied()).collect();
                Tensor::from_slice(&x).view([m, d as i64])
            }
            _ => unreachable!("a cloud prepared for another network"),
        }
    }

    /// Unit descriptors of a batch of inputs.
    pub fn forward(&self, x: &Tensor) -> Tensor {
        match self {
            DescriptorNet::Patch { net, .. } => net.forward(x),
            DescriptorNet::FpfhMlp { net, .. } => net.forward(x),
        }
    }

    /// Descriptors of `keypoints` (indices into `cloud`): `keypoints.len() × dim` values, row after row
    /// (no gradients; the cloud is prepared once).
    pub fn describe(&self, cloud: &[Point], keypoints: &[usize]) -> Vec<f32> {
        let prepared = self.prepare(cloud);
        let mut out = Vec::new();
        for chunk in keypoints.chunks(BATCH) {
            let d = tch::no_grad(|| self.forward(&self.input(&prepared, cloud, chunk)));
            out.extend(Vec::<f32>::try_from(d.flatten(0, -1)).expect("float descriptors"));
        }
        out
    }
}

/// A trained descriptor loaded from its checkpoint.
pub struct LearnedDescriptor {
    pub meta: DescriptorMeta,
    net: DescriptorNet,
    _vs: nn::VarStore,
}

impl LearnedDescriptor {
    /// Loads a checkpoint written by `pointreggpt train descriptor`.
    pub fn load(path: &Path) -> Result<Self> {
        let meta = read_meta(path)?;
        let mut vs = nn::VarStore::new(Device::Cpu);
        let net = DescriptorNet::new(&vs.root(), &meta.model).map_err(|e| Error::input(path, e.to_string()))?;
        load_into(path, &mut vs)?;
        Ok(LearnedDescriptor { meta, net, _vs: vs })
    }

    /// Descriptor length.
    pub fn dim(&self) -> usize {
        self.meta.model.dim()
    }

    /// Descriptors of `keypoints` (indices into `cloud`), row after row.
    pub fn describe(&self, cloud: &[Point], keypoints: &[usize]) -> Vec<f32> {
        self.net.describe(cloud, keypoints)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_first_format_checkpoint_reads_as_a_patch_model() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("v1.safetensors");
        let (net, patch) = (PatchNetConfig { voxels: 8, width: 4, dim: 16 }, PatchConfig { voxels: 8, ..Default::default() });
        let v1 = serde_json::json!({"format": FORMAT_V1, "net": net, "patch": patch, "step": 7, "info": {"pairs": 3}});
        let metadata = BTreeMap::from([(META_KEY.to_string(), v1.to_string())]);
        write_safetensors(&path, &[("net.x".to_string(), Tensor::zeros([1], (Kind::Float, Device::Cpu)))], &metadata).unwrap();
        let meta = read_meta(&path).unwrap();
        assert_eq!(meta.model, DescriptorModel::Patch { net, patch });
        assert_eq!((meta.step, meta.format.as_str(), meta.info["pairs"].as_i64()), (7, FORMAT, Some(3)));

        // A checkpoint of the current format round-trips; an unknown format is named.
        let model = DescriptorModel::fpfh_mlp(vec![0.1, 0.2], 64, 16);
        let current = DescriptorMeta { format: FORMAT.into(), model, step: 3, info: serde_json::Value::Null };
        let vs = nn::VarStore::new(Device::Cpu);
        let _x = vs.root().zeros("x", &[2]);
        let path2 = dir.path().join("v2.safetensors");
        save(&path2, &vs, &[], &current).unwrap();
        assert_eq!(read_meta(&path2).unwrap(), current);
        let other = BTreeMap::from([(META_KEY.to_string(), r#"{"format":"pointreggpt.descriptor/9"}"#.to_string())]);
        write_safetensors(&path, &[("x".to_string(), Tensor::zeros([1], (Kind::Float, Device::Cpu)))], &other).unwrap();
        assert!(read_meta(&path).unwrap_err().to_string().contains("descriptor/9"));
    }

    #[test]
    fn the_mlp_input_must_match_its_radii() {
        assert!(DescriptorModel::fpfh_mlp(vec![0.075, 0.125, 0.2], 128, 32).validate("d").is_ok());
        let bad = DescriptorModel::FpfhMlp { mlp: FpfhMlpConfig { input: 99, hidden: 8, dim: 4 }, radii: vec![0.1] };
        assert!(bad.validate("d").unwrap_err().to_string().contains("99"));
        assert_eq!(DescriptorModel::default().dim(), 32);
    }
}
