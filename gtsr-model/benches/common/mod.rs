//! Timing helpers shared by the benches.

use std::time::Duration;

/// Repetitions at the start of a series that only warm the allocator and the thread pool.
pub const WARM_UP: usize = 2;

/// The median of `times` after the first [`WARM_UP`] repetitions.
pub fn median_after_warm_up(times: &[Duration]) -> Duration {
    let mut t = times[WARM_UP.min(times.len().saturating_sub(1))..].to_vec();
    t.sort();
    t[t.len() / 2]
}
