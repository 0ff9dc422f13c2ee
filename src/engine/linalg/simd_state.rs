//! Clears the upper halves of the vector registers (`vzeroupper`, and the AVX-512 registers 16-31
//! which `vzeroupper` leaves alone) on every thread of the rayon pool and on the calling thread.
//!
//! Why: faer's kernels use 256/512-bit AVX. A thread that leaves the upper register halves
//! dirty runs all later SSE code (the rest of the engine, compiled for baseline x86-64) with a
//! false dependency on them, and on AVX-512 parts it can stay at the lower AVX frequency
//! licence. Measured on this 2-core AVX-512 machine: MeshMatch's 64K transfer took 39-43 s
//! instead of 18 s when its HKS spectra ran on the pool's threads, and every later stage (fans,
//! E-step, vote: plain SSE code) was 2-4× slower. Call this after a faer-heavy step that other
//! work follows on the same threads. The linalg module does so wherever faer returns
//! (Cholesky factor and solves, the dense eigensolver, the Lanczos products, the Laplace
//! spectrum), so its callers need not.

/// `vzeroupper` on the calling thread and on every rayon worker (a no-op without AVX): after
/// faer ran with `Par::rayon`.
pub fn clear_upper_vector_state() {
    clear_upper_vector_state_here();
    rayon::broadcast(|_| clear_upper_vector_state_here());
}

/// `vzeroupper` (and zmm16-31) on the calling thread only: after faer ran with `Par::Seq`, on
/// the thread that called it (a few cycles).
#[inline]
pub fn clear_upper_vector_state_here() {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx") {
            // SAFETY: AVX is available (checked just above).
            unsafe { zero_upper() }
        }
        if std::arch::is_x86_feature_detected!("avx512f") {
            // SAFETY: AVX-512F is available (checked just above).
            unsafe { zero_high_registers() }
        }
    }
}

/// Zeroes zmm16-31 (an EVEX 128-bit xor zeroes the whole register).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn zero_high_registers() {
    std::arch::asm!(
        "vpxord xmm16, xmm16, xmm16",
        "vpxord xmm17, xmm17, xmm17",
        "vpxord xmm18, xmm18, xmm18",
        "vpxord xmm19, xmm19, xmm19",
        "vpxord xmm20, xmm20, xmm20",
        "vpxord xmm21, xmm21, xmm21",
        "vpxord xmm22, xmm22, xmm22",
        "vpxord xmm23, xmm23, xmm23",
        "vpxord xmm24, xmm24, xmm24",
        "vpxord xmm25, xmm25, xmm25",
        "vpxord xmm26, xmm26, xmm26",
        "vpxord xmm27, xmm27, xmm27",
        "vpxord xmm28, xmm28, xmm28",
        "vpxord xmm29, xmm29, xmm29",
        "vpxord xmm30, xmm30, xmm30",
        "vpxord xmm31, xmm31, xmm31",
        out("zmm16") _, out("zmm17") _, out("zmm18") _, out("zmm19") _,
        out("zmm20") _, out("zmm21") _, out("zmm22") _, out("zmm23") _,
        out("zmm24") _, out("zmm25") _, out("zmm26") _, out("zmm27") _,
        out("zmm28") _, out("zmm29") _, out("zmm30") _, out("zmm31") _,
        options(nomem, nostack, preserves_flags)
    );
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx")]
unsafe fn zero_upper() {
    std::arch::x86_64::_mm256_zeroupper();
}
