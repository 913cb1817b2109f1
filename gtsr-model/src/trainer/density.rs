//! Density control on the trainer: densification and pruning on schedule, the trim of
//! surface Gaussians no view observes, and the demotion of hidden ones to the interior set.

use crate::densify::{DensifyReport, DensifyStats, densify_and_prune, reset_opacity};
use crate::error::ModelError;
use crate::gaussians::{HostSet, ParamKind};

use super::*;

impl Trainer {
    /// Per surface Gaussian, in how many training views it is observed
    /// ([`Model::observed_surface`] at the transmittance `threshold`).
    pub fn observation_counts(&self, threshold: f64) -> Result<Vec<usize>, ModelError> {
        let model = self.model.detached();
        let mut seen = vec![0usize; model.surface.len()];
        for view in &self.views {
            let observed = model.observed_surface(&view.camera, threshold)?;
            for (count, o) in seen.iter_mut().zip(observed) {
                *count += usize::from(o);
            }
        }
        Ok(seen)
    }

    /// PGSR's multi-view trim: prunes the surface Gaussians that fewer than `min_views` training
    /// views observe ([`Self::observation_counts`] at the transmittance `threshold`; PGSR: 2
    /// and 0.5). Returns how many it removed.
    pub fn trim_unobserved(
        &mut self,
        min_views: usize,
        threshold: f64,
    ) -> Result<usize, ModelError> {
        let (keep, hidden) = self.split_observed(min_views, threshold)?;
        if !hidden.is_empty() {
            let host = self.model.surface.to_host();
            self.keep_surface(&host, &keep);
        }
        Ok(hidden.len())
    }

    /// The surface Gaussians that at least `min_views` training views observe
    /// ([`Self::observation_counts`] at the transmittance `threshold`), and the rest.
    fn split_observed(
        &self,
        min_views: usize,
        threshold: f64,
    ) -> Result<(Vec<usize>, Vec<usize>), ModelError> {
        let seen = self.observation_counts(threshold)?;
        Ok((0..seen.len()).partition(|&i| seen[i] >= min_views))
    }

    /// Keeps the rows `keep` of the surface set (`host`, its host copy), with their
    /// optimiser state and densification statistics.
    fn keep_surface(&mut self, host: &HostSet, keep: &[usize]) {
        self.model.surface = host.reindex(keep, None).to_device(&self.device);
        self.opt_surface.reindex(keep, 0);
        self.stats_surface = self.stats_surface.select(keep);
    }

    /// Moves the surface Gaussians that fewer than `min_views` training views observe
    /// ([`Self::observation_counts`] at the transmittance `threshold`) into the interior set,
    /// with their position, shape, opacity and colour; their material parameters are
    /// dropped and their optimiser state starts afresh. Where the interior set would pass
    /// its cap ([`crate::config::DensifyConfig::max_interior`]), the most opaque of them
    /// move and the rest are pruned. Returns how many moved and how many were pruned; does
    /// nothing without an interior set.
    pub fn demote_hidden(
        &mut self,
        min_views: usize,
        threshold: f64,
    ) -> Result<(usize, usize), ModelError> {
        if self.model.interior.is_none() {
            return Ok((0, 0));
        }
        let (keep, mut moved) = self.split_observed(min_views, threshold)?;
        if moved.is_empty() {
            return Ok((0, 0));
        }
        let interior = self.model.interior.as_ref().expect("checked").to_host();
        let hidden = moved.len();
        let surface = self.model.surface.to_host();
        let room = self.config.densify.max_interior.saturating_sub(interior.n);
        if room < moved.len() {
            let (op, _) = surface.column(ParamKind::Opacity).expect("opacity");
            moved.sort_by(|a, b| op[*b].total_cmp(&op[*a]));
            moved.truncate(room);
            moved.sort_unstable();
        }
        // The moved rows, less the material columns the interior set does not have.
        let mut extra = surface.reindex(&moved, None);
        extra.kind = interior.kind;
        extra.unfloor_opacity(self.config.surface_opacity_floor);
        extra
            .columns
            .retain(|(k, _, _)| interior.column(*k).is_some());
        let all_interior: Vec<usize> = (0..interior.n).collect();
        self.model.interior = Some(
            interior
                .reindex(&all_interior, Some(&extra))
                .to_device(&self.device),
        );
        self.opt_interior.reindex(&all_interior, extra.n);
        self.stats_interior = self.stats_interior.with_new_rows(extra.n);
        self.keep_surface(&surface, &keep);
        let pruned = hidden - extra.n;
        self.counters.demoted += extra.n;
        self.counters.trimmed += pruned;
        Ok((extra.n, pruned))
    }

    pub(super) fn maybe_densify(
        &mut self,
        step: usize,
    ) -> Result<Option<(DensifyReport, DensifyReport)>, ModelError> {
        let d = self.config.densify.clone();
        let s1 = step + 1;
        let mut out = None;
        if s1 >= d.start && s1 <= d.end && s1.is_multiple_of(d.every) {
            let prune_big = d.opacity_reset_every > 0 && s1 > d.opacity_reset_every;
            let mut rng = step_rng(self.config.seed, step, RNG_DENSIFY);
            let host = self.model.surface.to_host();
            let ds = densify_and_prune(
                &host,
                &self.stats_surface,
                &d,
                self.extent,
                prune_big,
                d.max_surface,
                &mut rng,
            );
            self.opt_surface.reindex(&ds.keep, ds.added);
            self.model.surface = ds.set.to_device(&self.device);
            self.stats_surface = DensifyStats::new(self.model.surface.len());
            let mut rep_i = DensifyReport::default();
            if let Some(int) = &self.model.interior {
                let host = int.to_host();
                let di = densify_and_prune(
                    &host,
                    &self.stats_interior,
                    &d,
                    self.extent,
                    prune_big,
                    d.max_interior,
                    &mut rng,
                );
                self.opt_interior.reindex(&di.keep, di.added);
                rep_i = di.report;
                self.model.interior = Some(di.set.to_device(&self.device));
                self.stats_interior = DensifyStats::new(di.keep.len() + di.added);
            }
            self.counters.densifications += 1;
            out = Some((ds.report, rep_i));
        }
        if d.trims_after(s1) {
            self.counters.trimmed +=
                self.trim_unobserved(d.trim_min_views, d.trim_transmittance)?;
        }
        if d.demotes_after(s1, self.config.stage2_start) {
            self.demote_hidden(d.demote_min_views, d.demote_transmittance)?;
        }
        if d.resets_after(s1) {
            let mut host = self.model.surface.to_host();
            reset_opacity(&mut host, 0.01);
            self.model.surface = host.to_device(&self.device);
            self.opt_surface.reset(ParamKind::Opacity);
            if let Some(int) = &self.model.interior {
                let mut host = int.to_host();
                reset_opacity(&mut host, 0.01);
                self.model.interior = Some(host.to_device(&self.device));
                self.opt_interior.reset(ParamKind::Opacity);
            }
        }
        Ok(out)
    }
}
