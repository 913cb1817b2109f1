//! The run's settings: a configuration file (a run's `config.json` or a bare training
//! configuration), overlaid by the flags given, resolved against the scene, and recorded.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use gtsr_data::Scene;
use gtsr_mesh::MeshConfig;
use gtsr_model::config::{Components, Decision, Preset, TrainConfig, auto_components};
use gtsr_model::views::scene_evidence;
use serde::{Deserialize, Serialize};

use crate::args::{Args, ExposureMode};

/// What `config.json` holds: every setting, plus what was decided and why.
#[derive(Serialize, Deserialize)]
pub(crate) struct ResolvedConfig {
    pub(crate) data: PathBuf,
    pub(crate) resolution: u32,
    /// Absent in the files of runs from before exposures were read (`auto`).
    #[serde(default)]
    pub(crate) exposure: ExposureMode,
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

/// A configuration that cannot be used: a field that is not a setting, a value of the wrong
/// type or out of range. `gtsr-train` exits with status 2 on it, as on a bad flag.
#[derive(Debug)]
pub struct ConfigError(pub String);

impl std::fmt::Display for ConfigError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for ConfigError {}

/// The top-level fields of a run's `config.json`.
const RUN_FIELDS: [&str; 7] = [
    "data",
    "resolution",
    "exposure",
    "preset",
    "decisions",
    "train",
    "mesh",
];

/// What `--config` gives: a run's `config.json` or any part of it, or a bare training
/// configuration (the `train` part alone) or any part of that. What a file leaves out comes
/// from the scene's defaults, as without `--config`.
pub(crate) struct FileConfig {
    /// The file, for messages.
    pub(crate) path: PathBuf,
    pub(crate) data: Option<PathBuf>,
    pub(crate) resolution: Option<u32>,
    pub(crate) exposure: Option<ExposureMode>,
    pub(crate) preset: Option<Preset>,
    pub(crate) decisions: Option<Vec<Decision>>,
    /// The `train` fields given.
    pub(crate) train: Option<serde_json::Value>,
    /// The `mesh` fields given.
    pub(crate) mesh: Option<serde_json::Value>,
}

pub(crate) fn read_config(path: &Path) -> Result<FileConfig> {
    use serde_json::Value;
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let bad = |what: String| ConfigError(format!("{}: {what}", path.display()));
    let value: Value = serde_json::from_str(&text).map_err(|e| bad(format!("not JSON ({e})")))?;
    let Value::Object(mut fields) = value else {
        return Err(
            bad("not a gtsr-train configuration (a JSON object is expected)".into()).into(),
        );
    };
    if !fields.keys().any(|k| RUN_FIELDS.contains(&k.as_str())) {
        // A bare training configuration.
        fields = serde_json::Map::from_iter([("train".to_string(), Value::Object(fields))]);
    }
    // Every field that is not a setting, named at once.
    let mut unknown: Vec<String> = fields
        .keys()
        .filter(|k| !RUN_FIELDS.contains(&k.as_str()))
        .cloned()
        .collect();
    if let Some(t) = fields.get("train") {
        let mut all = serde_json::to_value(TrainConfig::for_iterations(Components::FULL, 3000))?;
        unknown.extend(overlay_fields(&mut all, t, "train"));
    }
    if let Some(m) = fields.get("mesh") {
        let mut all = serde_json::to_value(MeshConfig::default())?;
        unknown.extend(overlay_fields(&mut all, m, "mesh"));
    }
    if !unknown.is_empty() {
        return Err(bad(format!("unknown setting(s) {}", unknown.join(", "))).into());
    }
    fn take<T: serde::de::DeserializeOwned>(
        fields: &mut serde_json::Map<String, Value>,
        name: &str,
        bad: &dyn Fn(String) -> ConfigError,
    ) -> Result<Option<T>> {
        match fields.remove(name) {
            None => Ok(None),
            Some(v) => Ok(Some(
                serde_json::from_value(v).map_err(|e| bad(format!("{name}: {e}")))?,
            )),
        }
    }
    Ok(FileConfig {
        path: path.to_path_buf(),
        data: take(&mut fields, "data", &bad)?,
        resolution: take(&mut fields, "resolution", &bad)?,
        exposure: take(&mut fields, "exposure", &bad)?,
        preset: take(&mut fields, "preset", &bad)?,
        decisions: take(&mut fields, "decisions", &bad)?,
        train: fields.remove("train"),
        mesh: fields.remove("mesh"),
    })
}

/// Overlays `given` on `base` field by field (objects merge, anything else replaces) and
/// returns the paths of the fields in `given` that `base` does not have, under `prefix`.
pub(crate) fn overlay_fields(
    base: &mut serde_json::Value,
    given: &serde_json::Value,
    prefix: &str,
) -> Vec<String> {
    use serde_json::Value;
    let mut unknown = Vec::new();
    match (base, given) {
        (Value::Object(b), Value::Object(g)) => {
            for (k, v) in g {
                let path = format!("{prefix}.{k}");
                match b.get_mut(k) {
                    Some(slot) => unknown.extend(overlay_fields(slot, v, &path)),
                    None => unknown.push(path),
                }
            }
        }
        (slot, v) => *slot = v.clone(),
    }
    unknown
}

/// `given` overlaid on `base` (whose fields [`read_config`] has already checked it against):
/// a [`ConfigError`] where a value does not fit.
fn overlaid<T: Serialize + serde::de::DeserializeOwned>(
    base: &T,
    given: &serde_json::Value,
    part: &str,
    file: &Path,
) -> Result<T> {
    let mut json = serde_json::to_value(base)?;
    overlay_fields(&mut json, given, part);
    serde_json::from_value(json)
        .map_err(|e| ConfigError(format!("{}: {part}: {e}", file.display())).into())
}

/// Records component `name` of `components` (a field of [`Components`]) as decided for
/// `why`, replacing what was decided before; `sh_degree` is a setting, not a decision.
fn decide(
    decisions: &mut Vec<Decision>,
    components: Components,
    name: &str,
    why: impl FnOnce(bool) -> String,
) -> Result<()> {
    if name == "sh_degree" {
        return Ok(());
    }
    let on = serde_json::to_value(components)?[name] == true;
    decisions.retain(|d| d.component != name);
    decisions.push(Decision {
        component: name.into(),
        enabled: on,
        reason: why(on),
    });
    Ok(())
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

/// The scene's default components: the preset's, or what `auto` decides from the scene.
fn default_components(preset: Preset, scene: &Scene) -> Result<(Components, Vec<Decision>)> {
    Ok(match preset.components() {
        Some(c) => (c, Vec::new()),
        None => auto_components(&scene_evidence(scene, 30.0)?),
    })
}

/// The training settings without a file: the scene's defaults for `components` and
/// `iterations`.
fn scene_defaults(scene: &Scene, components: Components, iterations: usize) -> TrainConfig {
    let view = &scene.train[0];
    let pixels = view.width() as usize * view.height() as usize;
    let masked = scene.train.iter().all(|v| v.mask.is_some());
    TrainConfig::for_views(components, iterations, pixels, masked)
}

/// The training settings of a file that gives some of them: the scene's defaults (for the
/// components and the length the file gives, else the preset's and the run's) overlaid with
/// them. Every component the file sets is a decision.
fn partial_train(
    args: &Args,
    scene: &Scene,
    f: &FileConfig,
    given: &serde_json::Value,
    iterations: usize,
) -> Result<(TrainConfig, Vec<Decision>)> {
    let preset = f.preset.unwrap_or(args.preset);
    let (components, mut decisions) = default_components(preset, scene)?;
    let components: Components = match given.get("components") {
        Some(c) => overlaid(&components, c, "train.components", &f.path)?,
        None => components,
    };
    let length = match (args.iterations, given.get("iterations")) {
        (None, Some(n)) => serde_json::from_value::<usize>(n.clone())
            .map_err(|e| ConfigError(format!("{}: train.iterations: {e}", f.path.display())))?,
        _ => iterations,
    };
    let mut given = given.clone();
    if args.iterations.is_some()
        && let Some(fields) = given.as_object_mut()
    {
        // The command line's length lays the schedule out again.
        fields.remove("iterations");
    }
    let train = overlaid(
        &scene_defaults(scene, components, length),
        &given,
        "train",
        &f.path,
    )?;
    if let Some(serde_json::Value::Object(set)) = given.get("components") {
        for name in set.keys() {
            decide(&mut decisions, train.components, name, |on| {
                format!("{name}: {on} in {}", f.path.display())
            })?;
        }
    }
    Ok((train, decisions))
}

/// The run's settings: the scene's defaults, overlaid with `--config` (a complete file is
/// taken as it is, its schedule laid out again when `--iterations` changes the length), then
/// with the flags given on the command line.
pub(crate) fn resolve_config(
    args: &Args,
    scene: &Scene,
    file: Option<FileConfig>,
    iterations: usize,
) -> Result<(TrainConfig, MeshConfig, Vec<Decision>)> {
    let (mut train, mesh, mut decisions) = match file {
        Some(f) => {
            let complete = f
                .train
                .as_ref()
                .and_then(|v| serde_json::from_value::<TrainConfig>(v.clone()).ok());
            let (train, decisions) = match (complete, &f.train) {
                (Some(mut t), _) => {
                    if args.iterations.is_some() && t.iterations != iterations {
                        t.set_schedule(iterations);
                    }
                    (t, f.decisions.clone().unwrap_or_default())
                }
                (None, given) => {
                    let empty = serde_json::json!({});
                    partial_train(
                        args,
                        scene,
                        &f,
                        given.as_ref().unwrap_or(&empty),
                        iterations,
                    )?
                }
            };
            let mesh = match &f.mesh {
                Some(m) => overlaid(&MeshConfig::default(), m, "mesh", &f.path)?,
                None => MeshConfig::default(),
            };
            (train, mesh, decisions)
        }
        None => {
            let (components, decisions) = default_components(args.preset, scene)?;
            (
                scene_defaults(scene, components, iterations),
                MeshConfig::default(),
                decisions,
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
        if let Some(name) = id.strip_prefix("train.components.") {
            decide(&mut decisions, given_train.components, name, |on| {
                format!("--{} {on} on the command line", name.replace('_', "-"))
            })?;
        }
    }
    train = given_train;
    if !train.components.pbr && train.components.smoothness {
        // Smoothness regularises the PBR maps only.
        train.components.smoothness = false;
    }
    train
        .validate()
        .map_err(|e| ConfigError(format!("invalid configuration: {e}")))?;
    mesh.validate()
        .map_err(|e| ConfigError(format!("invalid mesh settings: {e}")))?;
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
