//! The component presets: the paper's model, its ablations, a PGSR-like baseline, and `auto`,
//! which leaves out what the scene shows it does not need.

use serde::{Deserialize, Serialize};

use super::Components;

/// Named component sets: the paper's model, its ablations, a PGSR-like baseline, and `auto`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Preset {
    /// Everything on (the paper's method).
    Full,
    /// Ablation: no C_PBR (and hence no material smoothness).
    NoPbr,
    /// Ablation: surface opacity not weighted by the Fresnel term.
    NoFresnel,
    /// Ablation: no interior set (the scattering map is then absent from C_PBR).
    NoInterior,
    /// PGSR-like baseline: surface set only, no PBR, no Fresnel, PGSR's geometric terms.
    Pgsr,
    /// The full model less what the scene shows it does not need ([`auto_components`]).
    Auto,
}

impl Preset {
    /// All presets, for listings and benchmarks.
    pub const ALL: [Preset; 6] = [
        Preset::Full,
        Preset::NoPbr,
        Preset::NoFresnel,
        Preset::NoInterior,
        Preset::Pgsr,
        Preset::Auto,
    ];

    /// The kebab-case name used on the command line.
    pub fn name(&self) -> &'static str {
        match self {
            Preset::Full => "full",
            Preset::NoPbr => "no-pbr",
            Preset::NoFresnel => "no-fresnel",
            Preset::NoInterior => "no-interior",
            Preset::Pgsr => "pgsr",
            Preset::Auto => "auto",
        }
    }

    /// Parses a name as printed by [`Preset::name`].
    pub fn from_name(s: &str) -> Option<Preset> {
        Preset::ALL.into_iter().find(|p| p.name() == s)
    }

    /// The components of a fixed preset (`None` for [`Preset::Auto`], which needs the scene).
    pub fn components(&self) -> Option<Components> {
        let full = Components::FULL;
        Some(match self {
            Preset::Full => full,
            Preset::NoPbr => Components {
                pbr: false,
                smoothness: false,
                ..full
            },
            Preset::NoFresnel => Components {
                fresnel: false,
                ..full
            },
            Preset::NoInterior => Components {
                interior: false,
                ..full
            },
            Preset::Pgsr => Components {
                interior: false,
                fresnel: false,
                pbr: false,
                smoothness: false,
                ..full
            },
            Preset::Auto => return None,
        })
    }
}

/// What the scene tells `auto` (gathered by the caller from metadata and images).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SceneEvidence {
    /// `Some(true)` when metadata says the only light is a point light at the camera,
    /// `Some(false)` when it says otherwise, `None` when there is no such metadata.
    pub colocated_light: Option<bool>,
    /// `Some(true)` when metadata says the material is opaque (no subsurface scattering).
    pub opaque: Option<bool>,
    /// Whether the images' shading follows the camera ([`gtsr_data::light::light_evidence`]),
    /// when every training view has a mask and enough of the masks' hull is seen.
    pub light: Option<gtsr_data::light::LightEvidence>,
    /// Number of training views (the multi-view term needs neighbours).
    pub train_views: usize,
    /// Views that have at least one neighbour within the multi-view angle.
    pub views_with_neighbours: usize,
}

/// One decision of `auto`: a component, whether it is on, and why.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Decision {
    /// Component name.
    pub component: String,
    /// Whether it is kept.
    pub enabled: bool,
    /// Why, in words.
    pub reason: String,
}

/// Resolves [`Preset::Auto`]: starts from the full model and leaves out what the evidence says
/// the scene does not need. Every decision is returned with its reason.
pub fn auto_components(e: &SceneEvidence) -> (Components, Vec<Decision>) {
    let mut c = Components::FULL;
    let mut d = Vec::new();
    let mut say = |component: &str, enabled: bool, reason: String| {
        d.push(Decision {
            component: component.into(),
            enabled,
            reason,
        })
    };
    match (e.colocated_light, &e.light) {
        (Some(true), _) => say("pbr", true, "metadata: point light at the camera".into()),
        (Some(false), _) => {
            c.pbr = false;
            say(
                "pbr",
                false,
                "metadata: the light is not co-located with the camera, so the PBR model does not apply".into(),
            )
        }
        (None, Some(light)) if light.follows_camera() => say(
            "pbr",
            true,
            format!(
                "the images' shading follows the camera, as a light at the camera makes it: {}",
                light.describe()
            ),
        ),
        (None, Some(light)) => {
            c.pbr = false;
            say(
                "pbr",
                false,
                format!(
                    "the images' shading does not follow the camera, so the light is not at the camera and the PBR model does not apply: {}",
                    light.describe()
                ),
            )
        }
        (None, None) => {
            c.pbr = false;
            say(
                "pbr",
                false,
                "no light metadata, and the images cannot tell where the light is (it needs a mask on every training view and enough of the masks' hull seen)".into(),
            )
        }
    }
    if !c.pbr {
        c.smoothness = false;
        say(
            "smoothness",
            false,
            "regularises PBR material maps only".into(),
        );
    }
    match e.opaque {
        Some(true) => {
            c.interior = false;
            c.fresnel = false;
            say(
                "interior",
                false,
                "metadata: opaque material, nothing scatters inside".into(),
            );
            say(
                "fresnel",
                false,
                "opaque surface: nothing to see through".into(),
            );
        }
        Some(false) => say("interior", true, "metadata: translucent material".into()),
        None => say(
            "interior",
            true,
            "opacity cannot be told from images alone; kept (the safe choice for translucent data)"
                .into(),
        ),
    }
    if e.views_with_neighbours * 2 < e.train_views {
        c.multi_view = false;
        say(
            "multi_view",
            false,
            format!(
                "only {} of {} training views have a neighbour within the angle limit",
                e.views_with_neighbours, e.train_views
            ),
        );
    }
    (c, d)
}
