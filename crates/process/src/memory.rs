//! Keeping freed memory for reuse.
//!
//! The forward model allocates and frees map-sized arrays (a few hundred kB each: removal maps,
//! analysis columns, kernel spectra) thousands of times per calibration. glibc's malloc hands
//! blocks that size back to the operating system when they are freed (above its mmap threshold,
//! or when the top of a heap exceeds its trim threshold), and the next allocation faults them
//! back in page by page, each page zeroed by the kernel (10 % of the samples of a calibration
//! profile were page faults and zeroing). Measured on the synthetic suite (2026-11-25, the 12
//! calibrations' CPU, alternately twice, load about 1.7): 5.06-5.61 s with the defaults,
//! 4.74-5.21 s with the thresholds below.
//!
//! [`retain_freed_memory`] raises both thresholds once for the process; the command line and
//! the benches call it at start. The cost is that up to [`TRIM_THRESHOLD`] bytes of freed
//! memory stay with the process instead of returning to the system. Elsewhere than Linux with
//! glibc it does nothing.

/// Blocks up to this size come from malloc's heaps instead of fresh mappings (bytes; glibc
/// takes at most 32 MiB on 64-bit); larger ones (a 4096^2 map is 128 MiB) are still mapped
/// and unmapped on their own.
pub const MMAP_THRESHOLD: usize = 32 << 20;
/// Free memory at the top of a heap kept before it is returned to the system (bytes).
pub const TRIM_THRESHOLD: usize = 256 << 20;

/// Raises malloc's mmap and trim thresholds for this process (see the module docs); returns
/// whether the allocator took them.
pub fn retain_freed_memory() -> bool {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // SAFETY: mallopt only sets allocator parameters (it takes malloc's lock); both values
        // fit an int and are within glibc's limits (it refuses an mmap threshold above 32 MiB
        // on 64-bit, returning 0).
        let (a, b) = unsafe {
            (
                libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_THRESHOLD as libc::c_int),
                libc::mallopt(libc::M_TRIM_THRESHOLD, TRIM_THRESHOLD as libc::c_int),
            )
        };
        a == 1 && b == 1
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    {
        false
    }
}

#[cfg(test)]
mod tests {
    /// glibc takes both thresholds (it silently refused an mmap threshold of 64 MiB).
    #[test]
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    fn glibc_takes_the_thresholds() {
        assert!(super::retain_freed_memory());
    }
}
