//! The step profile (`--profile`): mean step times per stage, printed and written to
//! `profile.md`.

use std::path::Path;

use anyhow::Result;
use gtsr_model::trainer::{StepTimes, Trainer};

use crate::outputs::write_text;

/// Prints the profile table of the steps run so far and writes it to `profile.md`.
pub(crate) fn write_profile(
    profile: &[(StepTimes, usize); 2],
    trainer: &Trainer,
    out: &Path,
) -> Result<()> {
    let table = profile_table(profile, trainer);
    println!("{table}");
    write_text(&out.join("profile.md"), &table)
}

/// Mean milliseconds per step of each phase, per stage, as a markdown table.
pub(crate) fn profile_table(profile: &[(StepTimes, usize); 2], trainer: &Trainer) -> String {
    let (w, h) = trainer.views()[0].size();
    let mut out = format!(
        "Step time by phase, mean ms per step ({w}x{h}, {} rayon threads, blend {:?}).\n\n\
         | phase | stage 1 | stage 2 |\n|---|---:|---:|\n",
        rayon::current_num_threads(),
        gtsr_render_kernels::cpu::BlendPath::default_path()
    );
    let ms = |d: std::time::Duration, n: usize| {
        if n == 0 {
            "-".to_string()
        } else {
            format!("{:.1}", d.as_secs_f64() * 1e3 / n as f64)
        }
    };
    type Get = fn(&StepTimes) -> std::time::Duration;
    let rows: [(&str, Get); 13] = [
        ("kernels: projection", |t| t.kernels.project),
        ("kernels: depth sort and tile binning", |t| {
            t.kernels.sort_bin
        }),
        ("kernels: blend forward", |t| t.kernels.blend_forward),
        ("kernels: blend backward", |t| t.kernels.blend_backward),
        ("kernels: gradient gather and projection backward", |t| {
            t.kernels.gather
        }),
        ("kernels: copies to and from Burn tensors", |t| {
            t.kernels.host_copies
        }),
        ("Burn ops, forward (SH, Fresnel, C_PBR, losses)", |t| {
            let k = &t.kernels;
            t.forward
                .saturating_sub(k.project + k.sort_bin + k.blend_forward + k.host_copies)
        }),
        ("Burn ops, backward (autodiff outside the kernels)", |t| {
            let k = &t.kernels;
            t.backward.saturating_sub(k.blend_backward + k.gather)
        }),
        ("gradient read-out, finiteness, densify statistics", |t| {
            t.gradients
        }),
        ("Adam", |t| t.adam),
        ("densification and pruning", |t| t.densify),
        ("step total", |t| t.total()),
        ("of which in the kernels", |t| t.kernels.total()),
    ];
    for (name, get) in rows {
        out += &format!(
            "| {name} | {} | {} |\n",
            ms(get(&profile[0].0), profile[0].1),
            ms(get(&profile[1].0), profile[1].1)
        );
    }
    out += &format!("| steps | {} | {} |\n", profile[0].1, profile[1].1);
    // The forward pass by part (renders include the kernels' forward phases).
    let mut names: Vec<&str> = Vec::new();
    for (t, _) in profile {
        for (n, _) in &t.forward_parts {
            if !names.contains(n) {
                names.push(n);
            }
        }
    }
    out += "\nForward pass by part, mean ms per step (the renders include the kernels' forward \
            phases; `multi_view` includes the neighbour view's render).\n\n\
            | part | stage 1 | stage 2 |\n|---|---:|---:|\n";
    for name in names {
        let part = |k: usize| {
            let d = profile[k]
                .0
                .forward_parts
                .iter()
                .find(|(n, _)| *n == name)
                .map_or(std::time::Duration::ZERO, |p| p.1);
            ms(d, profile[k].1)
        };
        out += &format!("| {name} | {} | {} |\n", part(0), part(1));
    }
    out
}
