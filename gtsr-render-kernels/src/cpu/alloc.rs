//! Keeping freed memory in the process between renders (glibc).
//!
//! One forward and backward pass allocates tens of megabytes of short-lived buffers
//! (projected splats, tile lists, gradient rows). glibc serves blocks over its mmap threshold
//! (128 KiB at first) with fresh mappings and gives them back to the kernel when they are
//! freed, and it trims the top of each heap, so every call faults its buffers in again, page
//! by page, zeroed by the kernel. [`keep_freed_memory`] raises those thresholds once for the
//! process.

/// Largest value glibc accepts for `M_MMAP_THRESHOLD` on 64-bit targets (32 MiB).
#[cfg(all(target_os = "linux", target_env = "gnu"))]
const MMAP_THRESHOLD_MAX: i32 = 32 << 20;

/// Tells glibc's allocator to keep freed memory for reuse instead of returning it to the
/// kernel: blocks up to 32 MiB come from the heap rather than from fresh mappings, and heaps
/// are not trimmed below 1 GiB of free space at their top, with 64 MiB of slack taken at each
/// growth. Process-wide: meant to be called once, early, by a binary (gtsr-train and the
/// kernel benchmark call it), not by a library. Returns whether every setting was accepted.
/// It does nothing and returns `false` where the environment sets `GTSR_MALLOC=default` (to
/// measure the difference) and elsewhere than Linux with glibc.
///
/// The cost is resident memory: what a render freed stays mapped until the process ends,
/// about one render's working set per thread arena.
pub fn keep_freed_memory() -> bool {
    if std::env::var("GTSR_MALLOC").as_deref() == Ok("default") {
        return false;
    }
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // SAFETY: mallopt only changes allocator parameters; it is safe to call at any time.
        unsafe {
            libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_THRESHOLD_MAX) == 1
                && libc::mallopt(libc::M_TRIM_THRESHOLD, 1 << 30) == 1
                && libc::mallopt(libc::M_TOP_PAD, 64 << 20) == 1
        }
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    {
        false
    }
}
