//! Whether the mesh still changes along a run: each mesh the evaluations extract, against the
//! one before it, so that a run says when training on no longer moves its mesh.

use anyhow::Result;
use gtsr_data::ply::TriMesh;

/// A mesh has settled when it moved less than this many training-pixel footprints (the chamfer
/// distance between two consecutive evaluations' meshes) and [`SETTLED_SHARE`] of each mesh
/// lies within half a footprint of the other (a mean would hide a pit carved in one place).
pub const SETTLED_FOOTPRINTS: f64 = 0.1;

/// See [`SETTLED_FOOTPRINTS`].
pub const SETTLED_SHARE: f64 = 0.99;

/// Samples per mesh for the comparison (area-uniform, seeded).
const SAMPLES: usize = 20_000;

/// How far one in-run mesh lies from the one before it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MeshChange {
    /// The step of the later mesh.
    pub step: usize,
    /// The step of the earlier one.
    pub since: usize,
    /// Their chamfer distance (scene units).
    pub distance: f64,
    /// The same in training-pixel footprints.
    pub footprints: f64,
    /// The smaller of the shares of each mesh within half a footprint of the other.
    pub within_half: f64,
}

impl MeshChange {
    /// Whether the mesh has settled ([`SETTLED_FOOTPRINTS`], [`SETTLED_SHARE`]).
    pub fn settled(&self) -> bool {
        self.footprints < SETTLED_FOOTPRINTS && self.within_half >= SETTLED_SHARE
    }
}

/// The meshes of a run's evaluations, one after another.
#[derive(Debug)]
pub struct Settle {
    footprint: f64,
    previous: Option<(usize, TriMesh)>,
    settled_at: Option<usize>,
}

impl Settle {
    /// A run whose training pixels cover `footprint` scene units at the object.
    pub fn new(footprint: f64) -> Self {
        Settle {
            footprint,
            previous: None,
            settled_at: None,
        }
    }

    /// Compares `mesh`, extracted at `step`, with the mesh before it (`None` for the first
    /// mesh, or when either is empty), and keeps it for the next comparison.
    pub fn compare(&mut self, step: usize, mesh: &TriMesh) -> Result<Option<MeshChange>> {
        let change = match &self.previous {
            Some((since, prev)) if !prev.triangles.is_empty() && !mesh.triangles.is_empty() => {
                let half = 0.5 * self.footprint as f32;
                let m = gtsr_eval::chamfer(prev, mesh, SAMPLES, half, 0)?;
                Some(MeshChange {
                    step,
                    since: *since,
                    distance: m.chamfer,
                    footprints: m.chamfer / self.footprint,
                    within_half: m.precision.min(m.recall),
                })
            }
            _ => None,
        };
        self.previous = Some((step, mesh.clone()));
        Ok(change)
    }

    /// The line a run prints for `change`; the first time the mesh has settled
    /// ([`SETTLED_FOOTPRINTS`]) it says so, and how to stop a run there.
    pub fn note(&mut self, change: &MeshChange) -> String {
        let moved = format!(
            "mesh: moved {:.3} footprints since step {} (chamfer between the two meshes; {:.1} % \
             of each within half a footprint of the other)",
            change.footprints,
            change.since,
            100.0 * change.within_half
        );
        if !change.settled() {
            self.settled_at = None;
            return moved;
        }
        if self.settled_at.is_some() {
            return moved;
        }
        self.settled_at = Some(change.since);
        format!(
            "{moved}: it has settled (less than {SETTLED_FOOTPRINTS} footprints, {} % within \
             half of one); training on may not change it, and `--stop-at {}` stops a run of this \
             schedule there",
            100.0 * SETTLED_SHARE,
            change.step
        )
    }

    /// The step since which the mesh has settled ([`MeshChange::settled`]), if it has.
    pub fn settled_since(&self) -> Option<usize> {
        self.settled_at
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    /// A closed tetrahedron scaled by `s`.
    fn tetra(s: f32) -> TriMesh {
        TriMesh {
            positions: vec![
                Vec3::new(0.0, 0.0, 0.0),
                Vec3::new(s, 0.0, 0.0),
                Vec3::new(0.0, s, 0.0),
                Vec3::new(0.0, 0.0, s),
            ],
            triangles: vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
        }
    }

    #[test]
    fn a_mesh_that_stops_moving_is_said_to_have_settled_once() {
        let mut settle = Settle::new(0.01);
        assert_eq!(settle.compare(100, &tetra(1.0)).unwrap(), None);
        // Moved: 5 % larger, far more than a tenth of a footprint.
        let c = settle.compare(200, &tetra(1.05)).unwrap().unwrap();
        assert_eq!((c.step, c.since), (200, 100));
        assert!(c.footprints > 1.0, "{c:?}");
        assert!(!settle.note(&c).contains("settled"));
        assert_eq!(settle.settled_since(), None);
        // The same mesh again: settled since step 200, said once.
        let c = settle.compare(300, &tetra(1.05)).unwrap().unwrap();
        assert!(c.footprints < 1e-4, "{c:?}");
        let line = settle.note(&c);
        assert!(
            line.contains("settled") && line.contains("--stop-at 300"),
            "{line}"
        );
        assert_eq!(settle.settled_since(), Some(200));
        let c = settle.compare(400, &tetra(1.05)).unwrap().unwrap();
        assert!(!settle.note(&c).contains("settled"));
        assert_eq!(settle.settled_since(), Some(200));
        // It moves again: no longer settled.
        let c = settle.compare(500, &tetra(1.2)).unwrap().unwrap();
        settle.note(&c);
        assert_eq!(settle.settled_since(), None);
        // An empty mesh is not compared.
        let empty = TriMesh {
            positions: Vec::new(),
            triangles: Vec::new(),
        };
        assert_eq!(settle.compare(600, &empty).unwrap(), None);
    }
}
