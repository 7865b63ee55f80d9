//! Runs the hot per-pixel loops compiled for AVX2 when the CPU has it (checked at run time,
//! cached by std), else as compiled for the baseline target (SSE2 on x86_64).
//!
//! Only the instruction set changes: the loops are written with explicit four-lane partial
//! sums and no fused multiply-add is requested (Rust never contracts `a * b + c`), so both
//! versions perform the same operations in the same order and give bit-identical results.

/// `avx2_or_baseline!(kernel(args...))`: calls the `#[inline(always)]` function `kernel`
/// inside an AVX2-enabled wrapper when available, directly otherwise. Exported for the other
/// crates' hot loops (the calibration's Gram products), so the dispatch is written once.
#[macro_export]
macro_rules! avx2_or_baseline {
    ($f:ident($($a:expr),* $(,)?)) => {{
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx2") {
                #[target_feature(enable = "avx2")]
                #[allow(clippy::too_many_arguments)]
                unsafe fn wide<A, R>(f: impl FnOnce() -> R, _: A) -> R {
                    f()
                }
                // SAFETY: AVX2 is available on this CPU (checked just above).
                return unsafe { wide(|| $f($($a),*), ()) };
            }
        }
        $f($($a),*)
    }};
}
