//! Export of both sets as one 3DGS-compatible PLY (binary little-endian): the standard
//! `x y z nx ny nz f_dc_* f_rest_* opacity scale_* rot_*` layout that splat viewers read, plus
//! a `gtsr_set` property (0 surface, 1 interior). Values are the raw parameters as 3DGS stores
//! them (logit opacity, log scale, unnormalised quaternion `w x y z`, SH with `f_rest`
//! channel-major). A surface set trained with an opacity floor is written with the plain
//! logits of its opacities, so that a viewer's logistic gives them back.
//!
//! The splats are written in the dataset's own frame: a scene normalised at load time
//! ([`gtsr_data::Normalisation`], a uniform scale and a shift) is mapped back, so the file
//! lines up with the input cameras and points.

use std::path::Path;

use gtsr_data::Normalisation;

use crate::checkpoint::write_atomic;
use crate::error::ModelError;
use crate::gaussians::{HostSet, ParamKind};
use crate::model::Model;

/// Writes `model`'s sets to `path` (atomically), mapped from the model's frame to the dataset's
/// by `to_world` ([`Normalisation::IDENTITY`] when the model was trained in the dataset's frame).
/// Returns the number of splats written.
pub fn write_splat_ply(
    model: &Model,
    path: &Path,
    to_world: &Normalisation,
) -> Result<usize, ModelError> {
    if !(to_world.radius.is_finite() && to_world.radius > 0.0 && to_world.centre.is_finite()) {
        return Err(ModelError::Data(format!(
            "{}: the scene normalisation (centre {}, radius {}) cannot be inverted",
            path.display(),
            to_world.centre,
            to_world.radius
        )));
    }
    let mut surface = model.surface.to_host();
    surface.unfloor_opacity(model.surface_opacity_floor);
    let mut sets = vec![(0.0f32, surface)];
    if let Some(int) = &model.interior {
        sets.push((1.0, int.to_host()));
    }
    let k = model.components.sh_coeffs();
    let n: usize = sets.iter().map(|(_, s)| s.n).sum();
    let mut header = String::from(
        "ply\nformat binary_little_endian 1.0\ncomment gtsr-rs: surface and interior Gaussians (gtsr_set 0 / 1)\n",
    );
    header += &format!("element vertex {n}\n");
    let mut props: Vec<String> = ["x", "y", "z", "nx", "ny", "nz"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    props.extend((0..3).map(|i| format!("f_dc_{i}")));
    props.extend((0..(k - 1) * 3).map(|i| format!("f_rest_{i}")));
    props.push("opacity".into());
    props.extend((0..3).map(|i| format!("scale_{i}")));
    props.extend((0..4).map(|i| format!("rot_{i}")));
    props.push("gtsr_set".into());
    for p in &props {
        header += &format!("property float {p}\n");
    }
    header += "end_header\n";
    let mut out = header.into_bytes();
    for (flag, set) in &sets {
        write_rows(&mut out, set, k, *flag, to_world)?;
    }
    write_atomic(path, &out)?;
    Ok(n)
}

fn write_rows(
    out: &mut Vec<u8>,
    set: &HostSet,
    k: usize,
    flag: f32,
    to_world: &Normalisation,
) -> Result<(), ModelError> {
    // A similarity scales every axis alike: log-scales shift by ln(radius), rotations stay.
    let log_radius = to_world.radius.ln();
    let col = |kind: ParamKind| set.column(kind);
    let (means, _) =
        col(ParamKind::Means).ok_or_else(|| ModelError::Data("set without means".into()))?;
    let (rot, _) = col(ParamKind::Rotations)
        .ok_or_else(|| ModelError::Data("set without rotations".into()))?;
    let (ls, _) =
        col(ParamKind::LogScales).ok_or_else(|| ModelError::Data("set without scales".into()))?;
    let (op, _) =
        col(ParamKind::Opacity).ok_or_else(|| ModelError::Data("set without opacity".into()))?;
    let (dc, _) = col(ParamKind::ShDc).ok_or_else(|| ModelError::Data("set without SH".into()))?;
    let rest = col(ParamKind::ShRest);
    let mut push = |v: f32| out.extend_from_slice(&v.to_le_bytes());
    for i in 0..set.n {
        let world = to_world.to_world(glam::Vec3::from_slice(&means[3 * i..3 * i + 3]));
        for a in 0..3 {
            push(world[a]);
        }
        for _ in 0..3 {
            push(0.0);
        }
        for c in 0..3 {
            push(dc[3 * i + c]);
        }
        // 3DGS orders f_rest channel-major: index c * (K - 1) + j.
        for c in 0..3 {
            for j in 0..k - 1 {
                push(rest.map_or(0.0, |(r, w)| r[i * w + j * 3 + c]));
            }
        }
        push(op[i]);
        for a in 0..3 {
            push(ls[3 * i + a] + log_radius);
        }
        for a in 0..4 {
            push(rot[4 * i + a]);
        }
        push(flag);
    }
    Ok(())
}
