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
//!
//! [`zeroed_dense`] allocates a large working buffer (a spectrum, a dwell map of a 1001^2 grid)
//! and asks the kernel to back it with transparent huge pages where the system leaves that to
//! the program (`/sys/kernel/mm/transparent_hugepage/enabled` = `madvise`, as on the project's
//! machines): a fresh buffer is then faulted in 2 MiB at a time instead of 4 KiB. Measured on
//! the vibration coupling bench (1001^2, ten dwell channels, seven kernel spectra) with glibc's
//! own switch for this (`GLIBC_TUNABLES=glibc.malloc.hugetlb=1`), alternately twice: 701, 703 ms
//! without, 640, 573 ms with.

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

/// Buffers smaller than this are left to the allocator as they are (bytes): a huge page is
/// 2 MiB, and only the 2 MiB-aligned interior of a buffer can be backed by them.
pub const HUGE_PAGE_MIN_BYTES: usize = 4 << 20;

/// Element types whose all-zero bit pattern is the value zero (so a zero-filled allocation is
/// a valid vector of zeros).
///
/// # Safety
/// Implement only for types for which every byte being 0 is a valid value.
pub unsafe trait Zeroable: Copy {}
// SAFETY: 0.0 is all zero bits; Complex<f64> is two f64 (repr(C)).
unsafe impl Zeroable for f64 {}
unsafe impl Zeroable for rustfft::num_complex::Complex<f64> {}

/// `n` zeros from zero-filled memory: above the allocator's mmap threshold these are fresh pages
/// the kernel maps on first touch, so parts never written (a dwell map away from the path)
/// cost nothing, and nothing is written twice.
pub fn zeroed<T: Zeroable>(n: usize) -> Vec<T> {
    let layout = match std::alloc::Layout::array::<T>(n) {
        Ok(l) if l.size() > 0 => l,
        Ok(_) => return Vec::new(),
        Err(_) => panic!("capacity overflow: {n} elements"),
    };
    // SAFETY: `layout` has a non-zero size; the block is zero-filled, which `T: Zeroable` makes
    // `n` valid values of T; it was allocated by the global allocator with T's layout for
    // exactly `n` elements, as `Vec::from_raw_parts` requires.
    unsafe {
        let ptr = std::alloc::alloc_zeroed(layout);
        if ptr.is_null() {
            std::alloc::handle_alloc_error(layout);
        }
        Vec::from_raw_parts(ptr as *mut T, n, n)
    }
}

/// [`zeroed`] for a buffer that will be written in full (a spectrum, a transform's input):
/// large ones are advised for transparent huge pages before first use (see the module docs).
pub fn zeroed_dense<T: Zeroable>(n: usize) -> Vec<T> {
    let mut v = zeroed::<T>(n);
    let bytes = std::mem::size_of_val(v.as_slice());
    if bytes >= HUGE_PAGE_MIN_BYTES {
        advise_huge_pages(v.as_mut_ptr() as usize, bytes);
    }
    v
}

/// Advises the 2 MiB-aligned pages inside `[start, start + len)` for transparent huge pages
/// (Linux with glibc's libc crate; advice only: the contents and the mapping are unchanged, and a refusal is ignored).
fn advise_huge_pages(start: usize, len: usize) {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        const HUGE: usize = 2 << 20;
        let lo = start.div_ceil(HUGE) * HUGE;
        let hi = (start + len) / HUGE * HUGE;
        if hi > lo {
            // SAFETY: [lo, hi) lies inside an allocation this process owns and has not handed
            // out yet; MADV_HUGEPAGE changes how the kernel backs the range, never its contents
            // or its validity, and its only failure (EINVAL where THP is absent) is harmless.
            unsafe {
                libc::madvise(lo as *mut libc::c_void, hi - lo, libc::MADV_HUGEPAGE);
            }
        }
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    {
        let _ = (start, len);
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn zeroed_vectors_are_zero_at_every_size() {
        use rustfft::num_complex::Complex;
        for n in [0, 1, 1000, (5 << 20) / 8 + 3] {
            let v = super::zeroed::<f64>(n);
            assert_eq!(v.len(), n);
            assert!(v.iter().all(|x| *x == 0.0));
            let mut c = super::zeroed_dense::<Complex<f64>>(n / 2);
            assert_eq!(c.len(), n / 2);
            assert!(c.iter().all(|x| *x == Complex::new(0.0, 0.0)));
            c.push(Complex::new(1.0, 2.0));
            assert_eq!(c[n / 2], Complex::new(1.0, 2.0));
        }
    }

    /// glibc takes both thresholds (it silently refused an mmap threshold of 64 MiB).
    #[test]
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    fn glibc_takes_the_thresholds() {
        assert!(super::retain_freed_memory());
    }
}
