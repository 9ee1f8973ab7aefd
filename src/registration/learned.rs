//! A trained patch descriptor: its checkpoint format (safetensors, the configuration in the header's
//! metadata under [`META_KEY`]) and the describing of keypoints of a cloud.

use super::patch::{PatchCloud, PatchConfig};
use crate::error::{Error, Result};
use crate::geometry::Point;
use crate::nn::checkpoint::{read_header, read_tensors, write_safetensors};
use crate::nn::patch_net::{PatchNet, PatchNetConfig};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;
use tch::{nn, Device, Kind, Tensor};

/// Format tag stored in the metadata.
pub const FORMAT: &str = "pointreggpt.descriptor/1";
/// The `__metadata__` key holding [`DescriptorMeta`] as JSON.
pub const META_KEY: &str = "pointreggpt";
/// Prefix of the network's variables in a checkpoint (training state sits under other prefixes).
pub const NET_PREFIX: &str = "net.";
/// Patches per forward pass when describing.
const BATCH: usize = 256;

/// What a descriptor checkpoint says about itself besides the weights.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DescriptorMeta {
    pub format: String,
    pub net: PatchNetConfig,
    pub patch: PatchConfig,
    /// Completed optimiser steps.
    pub step: u64,
    /// Free-form provenance: training options, data sets, last loss.
    #[serde(default)]
    pub info: serde_json::Value,
}

/// Saves `net`'s variables (under [`NET_PREFIX`]) and `extra` tensors (e.g. optimiser moments) with `meta`.
pub fn save(path: &Path, vs: &nn::VarStore, extra: &[(String, Tensor)], meta: &DescriptorMeta) -> Result<()> {
    let mut tensors: Vec<(String, Tensor)> = vs.variables().into_iter().map(|(k, t)| (format!("{NET_PREFIX}{k}"), t)).collect();
    tensors.extend(extra.iter().map(|(k, t)| (k.clone(), t.shallow_clone())));
    let metadata = BTreeMap::from([(META_KEY.to_string(), serde_json::to_string(meta).expect("json"))]);
    write_safetensors(path, &tensors, &metadata)
}

/// The metadata of a descriptor checkpoint.
pub fn read_meta(path: &Path) -> Result<DescriptorMeta> {
    let (metadata, _) = read_header(path)?;
    let text = metadata.get(META_KEY).ok_or_else(|| Error::input(path, "not a pointreggpt descriptor checkpoint (no metadata)"))?;
    let meta: DescriptorMeta = serde_json::from_str(text).map_err(|e| Error::input(path, format!("descriptor metadata: {e}")))?;
    if meta.format != FORMAT {
        return Err(Error::input(path, format!("format `{}`, expected `{FORMAT}`", meta.format)));
    }
    Ok(meta)
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

/// A trained patch network with its patch geometry.
pub struct LearnedDescriptor {
    pub meta: DescriptorMeta,
    net: PatchNet,
    _vs: nn::VarStore,
}

impl LearnedDescriptor {
    /// Loads a checkpoint written by `pointreggpt train descriptor`.
    pub fn load(path: &Path) -> Result<Self> {
        let meta = read_meta(path)?;
        meta.patch.validate("descriptor.patch")?;
        let mut vs = nn::VarStore::new(Device::Cpu);
        let net = PatchNet::new(&vs.root(), &meta.net)?;
        load_into(path, &mut vs)?;
        Ok(LearnedDescriptor { meta, net, _vs: vs })
    }

    /// Descriptor length.
    pub fn dim(&self) -> usize {
        self.meta.net.dim as usize
    }

    /// Descriptors of `keypoints` in `cloud`: `keypoints.len() × dim` values, row after row.
    pub fn describe(&self, cloud: &[Point], keypoints: &[Point]) -> Vec<f32> {
        describe_with(&self.net, &self.meta.patch, cloud, keypoints)
    }
}

/// Descriptors of `keypoints` in `cloud` by `net` on patches made with `patch` (no gradients; the
/// cloud's radius indexes are built once).
pub fn describe_with(net: &PatchNet, patch: &PatchConfig, cloud: &[Point], keypoints: &[Point]) -> Vec<f32> {
    let n = patch.voxels as i64;
    let indexed = PatchCloud::new(cloud, patch);
    let mut out = Vec::with_capacity(keypoints.len() * net.config.dim as usize);
    for chunk in keypoints.chunks(BATCH) {
        let x = Tensor::from_slice(&indexed.patches(chunk)).view([chunk.len() as i64, 1, n, n, n]);
        let d = tch::no_grad(|| net.forward(&x));
        out.extend(Vec::<f32>::try_from(d.flatten(0, -1)).expect("float descriptors"));
    }
    out
}
