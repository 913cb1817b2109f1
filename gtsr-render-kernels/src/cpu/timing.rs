//! Wall time spent in each phase of the CPU kernels, summed over the process, so that a
//! training loop can say where a step's time goes ([`kernel_times`]; subtract two snapshots).

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// The phases timed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Phase {
    Project = 0,
    SortBin = 1,
    BlendForward = 2,
    BlendBackward = 3,
    Gather = 4,
    HostCopies = 5,
}

const PHASES: usize = 6;
static NANOS: [AtomicU64; PHASES] = [const { AtomicU64::new(0) }; PHASES];
static CALLS: [AtomicU64; 2] = [const { AtomicU64::new(0) }; 2];

/// Adds the time since `start` to `phase`; returns now (the next phase's start).
pub(crate) fn lap(phase: Phase, start: Instant) -> Instant {
    let now = Instant::now();
    let ns = now.duration_since(start).as_nanos() as u64;
    NANOS[phase as usize].fetch_add(ns, Ordering::Relaxed);
    now
}

pub(crate) fn count_call(backward: bool) {
    CALLS[usize::from(backward)].fetch_add(1, Ordering::Relaxed);
}

/// Time spent in the CPU kernels since the process started (all threads, wall time of the
/// calling thread around each parallel phase).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct KernelTimes {
    /// Projection of the Gaussians to screen space (forward).
    pub project: Duration,
    /// Depth sort, tile binning and the packed per-tile copies.
    pub sort_bin: Duration,
    /// The front-to-back blend.
    pub blend_forward: Duration,
    /// The blend's backward pass (one gradient row per tile-splat pair).
    pub blend_backward: Duration,
    /// Summing each splat's rows, the projection's backward pass and the scatter to the
    /// input layout.
    pub gather: Duration,
    /// Copies between Burn tensors and the kernels' host buffers (NdArray glue).
    pub host_copies: Duration,
    /// Forward calls.
    pub forward_calls: u64,
    /// Backward calls.
    pub backward_calls: u64,
}

impl KernelTimes {
    /// The sum of the phases.
    pub fn total(&self) -> Duration {
        self.project
            + self.sort_bin
            + self.blend_forward
            + self.blend_backward
            + self.gather
            + self.host_copies
    }

    /// `self - earlier`, phase by phase (saturating).
    pub fn since(&self, earlier: &KernelTimes) -> KernelTimes {
        KernelTimes {
            project: self.project.saturating_sub(earlier.project),
            sort_bin: self.sort_bin.saturating_sub(earlier.sort_bin),
            blend_forward: self.blend_forward.saturating_sub(earlier.blend_forward),
            blend_backward: self.blend_backward.saturating_sub(earlier.blend_backward),
            gather: self.gather.saturating_sub(earlier.gather),
            host_copies: self.host_copies.saturating_sub(earlier.host_copies),
            forward_calls: self.forward_calls.saturating_sub(earlier.forward_calls),
            backward_calls: self.backward_calls.saturating_sub(earlier.backward_calls),
        }
    }
}

impl std::ops::AddAssign<&KernelTimes> for KernelTimes {
    fn add_assign(&mut self, o: &KernelTimes) {
        self.project += o.project;
        self.sort_bin += o.sort_bin;
        self.blend_forward += o.blend_forward;
        self.blend_backward += o.blend_backward;
        self.gather += o.gather;
        self.host_copies += o.host_copies;
        self.forward_calls += o.forward_calls;
        self.backward_calls += o.backward_calls;
    }
}

/// A snapshot of the process-wide kernel timers.
pub fn kernel_times() -> KernelTimes {
    let d = |p: Phase| Duration::from_nanos(NANOS[p as usize].load(Ordering::Relaxed));
    KernelTimes {
        project: d(Phase::Project),
        sort_bin: d(Phase::SortBin),
        blend_forward: d(Phase::BlendForward),
        blend_backward: d(Phase::BlendBackward),
        gather: d(Phase::Gather),
        host_copies: d(Phase::HostCopies),
        forward_calls: CALLS[0].load(Ordering::Relaxed),
        backward_calls: CALLS[1].load(Ordering::Relaxed),
    }
}
