//! The run's settings: a configuration file (a run's `config.json` or a bare training
//! configuration), overlaid by the flags given, resolved against the scene, and recorded.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use gtsr_data::Scene;
use gtsr_mesh::MeshConfig;
use gtsr_model::config::{Decision, Preset, TrainConfig, auto_components};
use gtsr_model::views::scene_evidence;
use serde::{Deserialize, Serialize};

use crate::args::Args;

/// What `config.json` holds: every setting, plus what was decided and why.
#[derive(Serialize, Deserialize)]
pub(crate) struct ResolvedConfig {
    pub(crate) data: PathBuf,
    pub(crate) resolution: u32,
    pub(crate) preset: Preset,
    pub(crate) decisions: Vec<Decision>,
    pub(crate) train: TrainConfig,
    /// Absent in the files of runs from before the mesh settings were recorded.
    #[serde(default)]
    pub(crate) mesh: MeshConfig,
}

/// Progress saved with each checkpoint (training time is not in the model checkpoint).
#[derive(Serialize, Deserialize, Default)]
pub(crate) struct RunState {
    pub(crate) train_seconds: f64,
}

/// What `--config` gives: a run's `config.json`, or a bare training configuration (then the
/// mesh settings are the defaults, and neither the dataset, the resolution nor the preset is
/// given).
pub(crate) struct FileConfig {
    pub(crate) data: Option<PathBuf>,
    pub(crate) train: TrainConfig,
    pub(crate) mesh: MeshConfig,
    pub(crate) resolution: Option<u32>,
    pub(crate) preset: Option<Preset>,
    pub(crate) decisions: Vec<Decision>,
}

pub(crate) fn read_config(path: &Path) -> Result<FileConfig> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    match serde_json::from_str::<ResolvedConfig>(&text) {
        Ok(r) => Ok(FileConfig {
            data: Some(r.data),
            train: r.train,
            mesh: r.mesh,
            resolution: Some(r.resolution),
            preset: Some(r.preset),
            decisions: r.decisions,
        }),
        Err(run_err) => match serde_json::from_str::<TrainConfig>(&text) {
            Ok(train) => Ok(FileConfig {
                data: None,
                train,
                mesh: MeshConfig::default(),
                resolution: None,
                preset: None,
                decisions: Vec::new(),
            }),
            Err(_) => Err(anyhow::anyhow!(
                "{}: not a gtsr-train configuration ({run_err})",
                path.display()
            )),
        },
    }
}

/// Overlays on `base` the settings that `args` gave on the command line: each given id is a
/// path in `config.json` (`train.weights.mask`), and the value at that path comes from the
/// parsed command line.
pub(crate) fn overlay_given(base: &mut serde_json::Value, args: &Args) -> Result<()> {
    let cli = serde_json::json!({ "train": args.train, "mesh": args.mesh });
    for id in &args.given {
        if !(id.starts_with("train.") || id.starts_with("mesh.")) {
            continue;
        }
        let pointer = format!("/{}", id.replace('.', "/"));
        let value = cli
            .pointer(&pointer)
            .with_context(|| format!("setting {id} is not in the configuration"))?;
        *base
            .pointer_mut(&pointer)
            .with_context(|| format!("setting {id} is not in the configuration"))? = value.clone();
    }
    Ok(())
}

/// The run's settings: the scene's defaults (or `--config`), the schedule laid out again when
/// `--iterations` changes the length, then the flags given on the command line.
pub(crate) fn resolve_config(
    args: &Args,
    scene: &Scene,
    file: Option<FileConfig>,
    iterations: usize,
) -> Result<(TrainConfig, MeshConfig, Vec<Decision>)> {
    let mut decisions = Vec::new();
    let (mut train, mesh) = match file {
        Some(f) => {
            let mut t = f.train;
            if args.iterations.is_some() && t.iterations != iterations {
                t.set_schedule(iterations);
            }
            decisions = f.decisions;
            (t, f.mesh)
        }
        None => {
            let components = match args.preset.components() {
                Some(c) => c,
                None => {
                    let (c, d) = auto_components(&scene_evidence(scene, 30.0)?);
                    decisions = d;
                    c
                }
            };
            let view = &scene.train[0];
            let pixels = view.width() as usize * view.height() as usize;
            let masked = scene.train.iter().all(|v| v.mask.is_some());
            (
                TrainConfig::for_views(components, iterations, pixels, masked),
                MeshConfig::default(),
            )
        }
    };
    let mut json = serde_json::json!({ "train": train, "mesh": mesh });
    overlay_given(&mut json, args)?;
    let (given_train, mesh): (TrainConfig, MeshConfig) = (
        serde_json::from_value(json["train"].take()).context("the training settings")?,
        serde_json::from_value(json["mesh"].take()).context("the mesh settings")?,
    );
    // A component switched on the command line is a decision too.
    for id in &args.given {
        if let Some(name) = id.strip_prefix("train.components.")
            && name != "sh_degree"
        {
            let on = serde_json::to_value(given_train.components)?[name] == true;
            decisions.retain(|d| d.component != name);
            decisions.push(Decision {
                component: name.into(),
                enabled: on,
                reason: format!("--{} {on} on the command line", name.replace('_', "-")),
            });
        }
    }
    train = given_train;
    if !train.components.pbr && train.components.smoothness {
        // Smoothness regularises the PBR maps only.
        train.components.smoothness = false;
    }
    train
        .validate()
        .map_err(|e| anyhow::anyhow!("invalid configuration: {e}"))?;
    mesh.validate()
        .map_err(|e| anyhow::anyhow!("invalid mesh settings: {e}"))?;
    Ok((train, mesh, decisions))
}

/// The paths (`weights.mask`) at which two JSON values differ, as `path: a -> b`; at most
/// eight.
pub(crate) fn differing_fields(a: &serde_json::Value, b: &serde_json::Value) -> Vec<String> {
    fn walk(a: &serde_json::Value, b: &serde_json::Value, path: &str, out: &mut Vec<String>) {
        use serde_json::Value;
        match (a, b) {
            (Value::Object(x), Value::Object(y)) => {
                let mut keys: Vec<&String> = x.keys().chain(y.keys()).collect();
                keys.sort();
                keys.dedup();
                for k in keys {
                    let p = if path.is_empty() {
                        k.clone()
                    } else {
                        format!("{path}.{k}")
                    };
                    walk(
                        x.get(k).unwrap_or(&Value::Null),
                        y.get(k).unwrap_or(&Value::Null),
                        &p,
                        out,
                    );
                }
            }
            _ if a != b && out.len() < 8 => out.push(format!("{path}: {a} -> {b}")),
            _ => {}
        }
    }
    let mut out = Vec::new();
    walk(a, b, "", &mut out);
    out
}
