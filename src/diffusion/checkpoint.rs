//! Denoiser checkpoints in safetensors, in the authors' key layout: the online network under `model.`,
//! the EMA network under `ema.ema_model.model.`, Adam's moments under `opt.m.` / `opt.v.`, and our
//! configuration and training state as JSON in the header's `__metadata__` (key `pointreggpt`).
//!
//! Loading for sampling takes the EMA weights when present, else the online ones, else root-level keys,
//! so the authors' checkpoint converted by `scripts/convert-official.py diffusion` and a bare exported
//! state dict load too; a file without our metadata has its widths inferred from the tensor shapes.

use crate::error::{Error, Result};
use crate::nn::checkpoint::{read_header, write_safetensors, META_KEY};
use crate::nn::denoiser::{Denoiser, DenoiserConfig};
use crate::nn::unet::{Preset, UnetConfig};
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, HashMap};
use std::path::Path;
use tch::{nn, Device, Tensor};

/// Format tag stored in the metadata.
pub const FORMAT: &str = "pointreggpt.diffusion/1";
/// Prefix of the online network's tensors.
pub const ONLINE: &str = "model.";
/// Prefix of the EMA network's tensors (the weights sampling uses).
pub const EMA: &str = "ema.ema_model.model.";
/// Prefixes tried, in order, when loading a network for sampling.
const LOAD_PREFIXES: [&str; 5] = [EMA, "ema_model.model.", "model.model.", ONLINE, ""];

/// What a checkpoint says about itself besides the weights.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct DiffusionMeta {
    pub format: String,
    pub net: DenoiserConfig,
    /// Completed optimiser steps.
    pub step: u64,
    /// Free-form provenance: training options, data, losses.
    #[serde(default)]
    pub info: serde_json::Value,
}

impl DiffusionMeta {
    /// The time-step cap the network was trained under (`train diffusion --max-t`, recorded with the
    /// training options), if any: such a network only knows the steps below it.
    pub fn trained_below_step(&self) -> Option<usize> {
        self.info.get("options")?.get("max_t")?.as_u64().map(|t| t as usize)
    }
}

/// Named tensors in a fixed (sorted) order.
pub type Named = Vec<(String, Tensor)>;

/// The variables of `vs`, sorted by name.
pub fn sorted_variables(vs: &nn::VarStore) -> Named {
    let mut v: Named = vs.variables().into_iter().collect();
    v.sort_by(|a, b| a.0.cmp(&b.0));
    v
}

fn prefixed<'a>(prefix: &str, tensors: &'a [(String, Tensor)]) -> impl Iterator<Item = (String, Tensor)> + 'a {
    let prefix = prefix.to_string();
    tensors.iter().map(move |(k, t)| (format!("{prefix}{k}"), t.shallow_clone()))
}

/// Writes a checkpoint: `online` under `model.`, `ema` under `ema.ema_model.model.`, and each extra group
/// under its own prefix (Adam's moments), atomically.
pub fn save(path: &Path, meta: &DiffusionMeta, online: &[(String, Tensor)], ema: &[(String, Tensor)], extra: &[(&str, &Named)]) -> Result<()> {
    let mut all: Named = prefixed(ONLINE, online).chain(prefixed(EMA, ema)).collect();
    for (prefix, group) in extra {
        all.extend(prefixed(prefix, group));
    }
    let metadata = BTreeMap::from([(META_KEY.to_string(), serde_json::to_string(meta).expect("json"))]);
    write_safetensors(path, &all, &metadata)
}

/// Reads the metadata, or infers the configuration of a file without ours (the authors' layout).
pub fn read_meta(path: &Path) -> Result<DiffusionMeta> {
    let (meta, shapes) = read_header(path)?;
    meta_from_header(path, &meta, &shapes)
}

/// [`read_meta`] from an already read header.
fn meta_from_header(path: &Path, meta: &BTreeMap<String, String>, shapes: &BTreeMap<String, Vec<i64>>) -> Result<DiffusionMeta> {
    match meta.get(META_KEY) {
        Some(json) => {
            let m: DiffusionMeta =
                serde_json::from_str(json).map_err(|e| Error::input(path, format!("bad checkpoint metadata: {e}")))?;
            if m.format != FORMAT {
                return Err(Error::input(path, format!("checkpoint format `{}`, expected `{FORMAT}` (a diffusion checkpoint)", m.format)));
            }
            Ok(m)
        }
        None => {
            let prefix = network_prefix(path, shapes)?;
            Ok(DiffusionMeta { format: FORMAT.into(), net: infer_config(path, shapes, prefix)?, step: 0, info: serde_json::Value::Null })
        }
    }
}

fn network_prefix(path: &Path, shapes: &BTreeMap<String, Vec<i64>>) -> Result<&'static str> {
    LOAD_PREFIXES
        .into_iter()
        .find(|p| shapes.contains_key(&format!("{p}init_conv.weight")))
        .ok_or_else(|| Error::input(path, "no `init_conv.weight` under `ema.ema_model.model.`, `model.` or the root: not a denoiser checkpoint"))
}

/// The configuration of an official denoiser state dict under `prefix`, from its tensor shapes (groups
/// and heads cannot be seen in the shapes: the official 8 and 4).
fn infer_config(path: &Path, shapes: &BTreeMap<String, Vec<i64>>, prefix: &str) -> Result<DenoiserConfig> {
    let bad = |m: &str| Error::input(path, format!("not a denoiser checkpoint of the official layout: {m}"));
    let get = |k: &str| shapes.get(&format!("{prefix}{k}"));
    let init = get("init_conv.weight").filter(|s| s.len() == 4).ok_or_else(|| bad("no 4-D `init_conv.weight`"))?;
    let dim = init[0];
    let mut dim_mults = Vec::new();
    while let Some(s) = get(&format!("downs.{}.3.weight", dim_mults.len())) {
        dim_mults.push(s[0] / dim.max(1));
    }
    let cond = get("downs.0.0.mlp.1.weight").ok_or_else(|| bad("its ResnetBlocks are not conditioned (a correction U-Net?)"))?;
    if get("param_mlp.0.weight").is_none() {
        return Err(bad("no intrinsics MLP `param_mlp.0.weight`"));
    }
    let hidden = get("downs.0.2.fn.fn.to_qkv.weight").map_or(3 * 4 * 32, |s| s[0]) / 3;
    let unet = UnetConfig {
        dim,
        dim_mults,
        in_channels: init[1],
        out_channels: get("final_conv.weight").map_or(1, |s| s[0]),
        resnet_groups: 8,
        cond_dim: Some(cond[1]),
        attention: get("downs.0.2.fn.norm.g").is_some(),
        attn_heads: 4,
        attn_dim_head: hidden / 4,
        final_conv_in_sequential: false,
    };
    let preset = [Preset::Paper, Preset::Tiny].into_iter().find(|p| p.diffusion_unet() == unet);
    // The authors feed raw pixel intrinsics.
    Ok(DenoiserConfig { preset, unet, intrinsics_scale: 1.0 })
}

/// Every tensor of the file, by name.
pub fn read_tensors(path: &Path) -> Result<HashMap<String, Tensor>> {
    Ok(crate::nn::checkpoint::read_tensors(path)?.into_iter().collect())
}

/// The tensors under `prefix` (prefix stripped).
pub fn group(tensors: &HashMap<String, Tensor>, prefix: &str) -> HashMap<String, Tensor> {
    tensors.iter().filter_map(|(k, t)| k.strip_prefix(prefix).map(|s| (s.to_string(), t.shallow_clone()))).collect()
}

/// Copies `group` into `vars` (every variable must be there with its shape; tensors the network does not
/// have, such as the authors' schedule buffers, are ignored).
pub fn copy_into(path: &Path, group: &HashMap<String, Tensor>, vars: &[(String, Tensor)], what: &str) -> Result<()> {
    tch::no_grad(|| {
        for (name, var) in vars {
            let src = group.get(name).ok_or_else(|| Error::input(path, format!("{what} tensor `{name}` is missing")))?;
            if src.size() != var.size() {
                return Err(Error::input(path, format!("{what} tensor `{name}` has shape {:?}, the network {:?}", src.size(), var.size())));
            }
            var.shallow_clone().copy_(&src.to_kind(var.kind()));
        }
        Ok(())
    })
}

/// The configuration and the weights sampling uses (EMA when present, else the first of
/// [`LOAD_PREFIXES`] the file has), their prefix stripped.
pub fn read_sampling_weights(path: &Path) -> Result<(DiffusionMeta, HashMap<String, Tensor>)> {
    let (header, shapes) = read_header(path)?;
    let meta = meta_from_header(path, &header, &shapes)?;
    let prefix = network_prefix(path, &shapes)?;
    Ok((meta, group(&read_tensors(path)?, prefix)))
}

/// Loads the network sampling uses (EMA weights when present) onto `device`.
pub fn load_denoiser(path: &Path, device: Device) -> Result<(nn::VarStore, Denoiser, DiffusionMeta)> {
    let (meta, weights) = read_sampling_weights(path)?;
    let mut vs = nn::VarStore::new(Device::Cpu);
    let net = Denoiser::new(&vs.root(), &meta.net)?;
    copy_into(path, &weights, &sorted_variables(&vs), "denoiser")?;
    if device != Device::Cpu {
        vs.set_device(device);
    }
    Ok((vs, net, meta))
}

/// Writes the EMA network of a training checkpoint alone (with its metadata) to `dst`: the small file
/// sampling needs.
pub fn export_ema(src: &Path, dst: &Path) -> Result<()> {
    let meta = read_meta(src)?;
    let mut ema: Named = group(&read_tensors(src)?, EMA).into_iter().collect();
    if ema.is_empty() {
        return Err(Error::input(src, "no EMA weights (`ema.ema_model.model.*`) to export"));
    }
    ema.sort_by(|a, b| a.0.cmp(&b.0));
    save(dst, &meta, &[], &ema, &[])
}
