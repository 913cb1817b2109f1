//! Checkpoints: every parameter, every Adam state, the densification statistics, counters,
//! the step and the configuration, in one safetensors file written atomically. Loading it and
//! stepping gives exactly the step an uninterrupted run would have taken.

use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use burn::tensor::Device;
use safetensors::{Dtype, SafeTensors, tensor::TensorView};
use serde::{Deserialize, Serialize};

use crate::config::TrainConfig;
use crate::densify::DensifyStats;
use crate::error::ModelError;
use crate::gaussians::{HostSet, ParamKind, SetKind, host_vec};
use crate::model::Model;
use crate::optim::SetOptimizer;
use crate::trainer::{Counters, Trainer};
use crate::views::ViewTensors;

#[derive(Serialize, Deserialize)]
struct Meta {
    format: u32,
    step: usize,
    extent: f64,
    sh_degree: u32,
    counters: Counters,
    config: TrainConfig,
    /// Per set: `(param, width)` in order.
    layouts: BTreeMap<String, Vec<(ParamKind, usize)>>,
    /// Per set and parameter: Adam `(width, time)`.
    adam: BTreeMap<String, Vec<(ParamKind, usize, usize)>>,
}

const FORMAT: u32 = 1;

fn bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

fn floats(b: &[u8]) -> Vec<f32> {
    b.chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

/// Writes `trainer` to `path` (temporary file + rename).
pub fn save(trainer: &Trainer, path: &Path) -> Result<(), ModelError> {
    let mut tensors: Vec<(String, Vec<usize>, Vec<u8>)> = Vec::new();
    let mut layouts = BTreeMap::new();
    let mut adam = BTreeMap::new();
    let mut sets: Vec<(&str, HostSet, &SetOptimizer, Option<&DensifyStats>)> = vec![(
        "surface",
        trainer.model.surface.to_host(),
        &trainer.opt_surface,
        Some(&trainer.stats_surface),
    )];
    if let Some(int) = &trainer.model.interior {
        sets.push((
            "interior",
            int.to_host(),
            &trainer.opt_interior,
            Some(&trainer.stats_interior),
        ));
    }
    if let Some(l) = &trainer.model.log_light {
        let v = host_vec(l.clone().detach());
        let host = HostSet {
            kind: SetKind::Surface,
            n: 1,
            columns: vec![(ParamKind::Opacity, 1, v)],
        };
        sets.push(("light", host, &trainer.opt_light, None));
    }
    for (name, host, opt, stats) in sets {
        layouts.insert(
            name.to_string(),
            host.columns.iter().map(|(k, w, _)| (*k, *w)).collect(),
        );
        for (k, w, v) in &host.columns {
            tensors.push((format!("{name}.{}", k.name()), vec![host.n, *w], bytes(v)));
        }
        let mut a = Vec::new();
        for (k, w, (time, m1, m2)) in opt.to_host() {
            let rows = m1.len() / w.max(1);
            tensors.push((
                format!("{name}.adam1.{}", k.name()),
                vec![rows, w],
                bytes(&m1),
            ));
            tensors.push((
                format!("{name}.adam2.{}", k.name()),
                vec![rows, w],
                bytes(&m2),
            ));
            a.push((k, w, time));
        }
        adam.insert(name.to_string(), a);
        if let Some(s) = stats {
            for (field, v) in [
                ("grad_sum", &s.grad_sum),
                ("count", &s.count),
                ("max_radius", &s.max_radius),
            ] {
                tensors.push((format!("{name}.stats.{field}"), vec![v.len()], bytes(v)));
            }
        }
    }
    let meta = Meta {
        format: FORMAT,
        step: trainer.step,
        extent: trainer.extent,
        sh_degree: trainer.model.sh_degree,
        counters: trainer.counters.clone(),
        config: trainer.config.clone(),
        layouts,
        adam,
    };
    let meta_json = serde_json::to_string(&meta).map_err(|e| ModelError::Checkpoint {
        path: path.to_path_buf(),
        reason: e.to_string(),
    })?;
    let views: Vec<(String, TensorView<'_>)> = tensors
        .iter()
        .map(|(n, shape, b)| {
            TensorView::new(Dtype::F32, shape.clone(), b)
                .map(|v| (n.clone(), v))
                .map_err(|e| ModelError::Checkpoint {
                    path: path.to_path_buf(),
                    reason: format!("{n}: {e}"),
                })
        })
        .collect::<Result<_, _>>()?;
    let data = safetensors::serialize(
        views,
        Some(HashMap::from([("gtsr".to_string(), meta_json)])),
    )
    .map_err(|e| ModelError::Checkpoint {
        path: path.to_path_buf(),
        reason: e.to_string(),
    })?;
    write_atomic(path, &data)
}

/// Writes `data` to `path` through a temporary file in the same folder and a rename.
pub fn write_atomic(path: &Path, data: &[u8]) -> Result<(), ModelError> {
    let tmp = path.with_extension(format!(
        "{}.tmp{}",
        path.extension().and_then(|e| e.to_str()).unwrap_or(""),
        std::process::id()
    ));
    std::fs::write(&tmp, data).map_err(|e| ModelError::io(&tmp, e))?;
    std::fs::rename(&tmp, path).map_err(|e| ModelError::io(path, e))
}

/// Restores a trainer saved by [`save`], on `device` (autodiff), with `views` (the same
/// training views, in the same order, as the saved run).
pub fn load(path: &Path, views: Vec<ViewTensors>, device: &Device) -> Result<Trainer, ModelError> {
    let bad = |reason: String| ModelError::Checkpoint {
        path: path.to_path_buf(),
        reason,
    };
    let data = std::fs::read(path).map_err(|e| ModelError::io(path, e))?;
    let st =
        SafeTensors::deserialize(&data).map_err(|e| bad(format!("not a safetensors file: {e}")))?;
    let (_, md) = SafeTensors::read_metadata(&data).map_err(|e| bad(e.to_string()))?;
    let meta_json = md
        .metadata()
        .as_ref()
        .and_then(|m| m.get("gtsr"))
        .ok_or_else(|| bad("no gtsr metadata".into()))?;
    let meta: Meta = serde_json::from_str(meta_json).map_err(|e| bad(format!("metadata: {e}")))?;
    if meta.format != FORMAT {
        return Err(bad(format!(
            "format {} (this build reads {FORMAT})",
            meta.format
        )));
    }
    let get = |name: &str| -> Result<(Vec<usize>, Vec<f32>), ModelError> {
        let t = st.tensor(name).map_err(|e| bad(format!("{name}: {e}")))?;
        if t.dtype() != Dtype::F32 {
            return Err(bad(format!("{name}: dtype {:?}, expected F32", t.dtype())));
        }
        Ok((t.shape().to_vec(), floats(t.data())))
    };
    let inner = device.clone().without_autodiff();
    let load_set =
        |name: &str,
         kind: SetKind|
         -> Result<Option<(HostSet, SetOptimizer, Option<DensifyStats>)>, ModelError> {
            let Some(layout) = meta.layouts.get(name) else {
                return Ok(None);
            };
            let mut columns = Vec::new();
            let mut n = None;
            for (k, w) in layout {
                let (shape, v) = get(&format!("{name}.{}", k.name()))?;
                if shape.len() != 2 || shape[1] != *w || n.is_some_and(|n| n != shape[0]) {
                    return Err(bad(format!(
                        "{name}.{}: shape {shape:?} does not fit the layout",
                        k.name()
                    )));
                }
                if let Some(i) = v.iter().position(|x| !x.is_finite()) {
                    return Err(bad(format!("{name}.{}: value {i} is not finite", k.name())));
                }
                n = Some(shape[0]);
                columns.push((*k, *w, v));
            }
            let host = HostSet {
                kind,
                n: n.unwrap_or(0),
                columns,
            };
            let mut states = Vec::new();
            for (k, w, time) in meta.adam.get(name).cloned().unwrap_or_default() {
                let (_, m1) = get(&format!("{name}.adam1.{}", k.name()))?;
                let (_, m2) = get(&format!("{name}.adam2.{}", k.name()))?;
                states.push((k, w, (time, m1, m2)));
            }
            let opt = SetOptimizer::from_host(states, &inner);
            let stats = if name == "light" {
                None
            } else {
                Some(DensifyStats {
                    grad_sum: get(&format!("{name}.stats.grad_sum"))?.1,
                    count: get(&format!("{name}.stats.count"))?.1,
                    max_radius: get(&format!("{name}.stats.max_radius"))?.1,
                })
            };
            Ok(Some((host, opt, stats)))
        };
    let (surface, opt_surface, stats_surface) =
        load_set("surface", SetKind::Surface)?.ok_or_else(|| bad("no surface set".into()))?;
    let interior = load_set("interior", SetKind::Interior)?;
    let light = load_set("light", SetKind::Surface)?;
    let mut trainer = Trainer::new(meta.config.clone(), views, meta.extent, &[[0.0; 3]], device)?;
    trainer.model = Model {
        components: meta.config.components,
        surface: surface.to_device(device),
        interior: interior.as_ref().map(|(h, _, _)| h.to_device(device)),
        log_light: light.as_ref().map(|(h, _, _)| {
            h.to_device(device)
                .params
                .into_iter()
                .next()
                .map(|(_, t)| t)
                .expect("light tensor")
        }),
        sh_degree: meta.sh_degree,
        blur_px2: meta.config.blur_px2,
        compensate_blur: meta.config.compensate_blur,
        surface_opacity_floor: meta.config.surface_opacity_floor,
        plane_blur_px2: 0.0,
    };
    trainer.step = meta.step;
    trainer.counters = meta.counters;
    trainer.opt_surface = opt_surface;
    trainer.stats_surface = stats_surface.unwrap_or_default();
    if let Some((_, opt, stats)) = interior {
        trainer.opt_interior = opt;
        trainer.stats_interior = stats.unwrap_or_default();
    }
    if let Some((_, opt, _)) = light {
        trainer.opt_light = opt;
    }
    Ok(trainer)
}
