//! sRGB transfer functions (IEC 61966-2-1:1999, the piecewise curve with the linear toe).
//!
//! glTF stores base-color images sRGB-encoded and everything else (factors, COLOR_0, alpha) in
//! linear space; all blending in retex happens in linear space and only the final 8-bit encode
//! goes back to sRGB.
//!
//! * decode: `c <= 0.04045 ? c / 12.92 : ((c + 0.055) / 1.055)^2.4`
//! * encode: `l <= 0.0031308 ? 12.92 l : 1.055 l^(1/2.4) - 0.055`
//!
//! The scalar functions evaluate in f64 and round once to f32 (so 1 maps to exactly 1).
//! The 8-bit paths are table driven: [`srgb8_to_linear`] reads a 256-entry table built once, and
//! [`linear_to_srgb8`] rounds to the nearest code by comparing against the 255 decision thresholds
//! (the linear values of the code midpoints, computed in f64), located through a 4096-bucket
//! index so it costs one multiply, one lookup and at most a couple of comparisons. Because the
//! thresholds lie strictly between adjacent decoded codes, `linear_to_srgb8(srgb8_to_linear(v))
//! == v` for every code. Written by hand: it is a few lines and the crates that offer it do not
//! give this exact-inverse guarantee.

use std::sync::LazyLock;

/// Number of buckets of the index into the decision thresholds of [`linear_to_srgb8`]. The
/// steepest part of the curve (the linear toe, 12.92 × 255 codes per unit) crosses less than one
/// threshold per bucket, so the search from a bucket's start code is at most a few steps.
const ENCODE_BUCKETS: usize = 4096;

/// Decodes one sRGB-encoded channel value (nominally in [0, 1]) to linear.
///
/// Values below the toe (including negative ones) follow the linear segment; values above 1
/// follow the power segment. NaN stays NaN.
#[inline]
pub fn srgb_to_linear(c: f32) -> f32 {
    srgb_to_linear_f64(c as f64) as f32
}

/// Encodes one linear channel value to sRGB. The input is clamped to [0, 1] first (NaN → 0).
#[inline]
pub fn linear_to_srgb(c: f32) -> f32 {
    let c = if c.is_nan() {
        0.0
    } else {
        c.clamp(0.0, 1.0) as f64
    };
    let s = if c <= 0.003_130_8 {
        12.92 * c
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    };
    s as f32
}

/// f64 version of the decode curve, used to build the tables.
fn srgb_to_linear_f64(c: f64) -> f64 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// Linear value of every 8-bit sRGB code.
static DECODE: LazyLock<[f32; 256]> = LazyLock::new(|| {
    let mut t = [0.0f32; 256];
    for (v, slot) in t.iter_mut().enumerate() {
        *slot = srgb_to_linear_f64(v as f64 / 255.0) as f32;
    }
    t
});

/// Tables of the encoder: `thresholds[k]` is the linear value of the sRGB midpoint between codes
/// `k` and `k + 1`; `start[b]` is the code of the linear value `b / ENCODE_BUCKETS`.
struct EncodeTables {
    thresholds: [f64; 255],
    start: Vec<u8>,
}

static ENCODE: LazyLock<EncodeTables> = LazyLock::new(|| {
    let mut thresholds = [0.0f64; 255];
    for (k, t) in thresholds.iter_mut().enumerate() {
        *t = srgb_to_linear_f64((k as f64 + 0.5) / 255.0);
    }
    let start = (0..ENCODE_BUCKETS)
        .map(|b| {
            let x = b as f64 / ENCODE_BUCKETS as f64;
            thresholds.partition_point(|&t| t <= x) as u8
        })
        .collect();
    EncodeTables { thresholds, start }
});

/// Decodes an 8-bit sRGB code to linear (table lookup).
#[inline]
pub fn srgb8_to_linear(v: u8) -> f32 {
    DECODE[v as usize]
}

/// The 256-entry decode table itself, for hot loops that want to hoist the lazy-init check.
#[inline]
pub(crate) fn srgb8_table() -> &'static [f32; 256] {
    &DECODE
}

/// Encodes a linear value to the nearest 8-bit sRGB code (input clamped to [0, 1], NaN → 0).
///
/// "Nearest" is measured in sRGB space: the result is the code whose sRGB value is closest to
/// `linear_to_srgb(c)` (ties round up), decided exactly against f64 thresholds. It is the exact
/// inverse of [`srgb8_to_linear`] on all 256 codes.
#[inline]
pub fn linear_to_srgb8(c: f32) -> u8 {
    if c.is_nan() || c <= 0.0 {
        return 0;
    }
    if c >= 1.0 {
        return 255;
    }
    let tables = &*ENCODE;
    let bucket = ((c * ENCODE_BUCKETS as f32) as usize).min(ENCODE_BUCKETS - 1);
    let mut code = tables.start[bucket] as usize;
    let x = c as f64;
    while code < 255 && x >= tables.thresholds[code] {
        code += 1;
    }
    code as u8
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn all_256_codes_round_trip_exactly() {
        for v in 0..=255u8 {
            let l = srgb8_to_linear(v);
            assert_eq!(linear_to_srgb8(l), v, "code {v} → {l}");
        }
    }

    #[test]
    fn table_matches_formula() {
        for v in 0..=255u8 {
            let a = srgb8_to_linear(v);
            let b = srgb_to_linear(v as f32 / 255.0);
            assert!((a - b).abs() < 1e-6, "code {v}: {a} vs {b}");
        }
    }

    #[test]
    fn known_values() {
        assert!(
            (linear_to_srgb(0.5) - 0.735_356_9).abs() < 1e-5,
            "{}",
            linear_to_srgb(0.5)
        );
        assert!((srgb_to_linear(0.735_356_9) - 0.5).abs() < 1e-5);
        assert!(
            (srgb_to_linear(0.5) - 0.214_041_14).abs() < 1e-5,
            "{}",
            srgb_to_linear(0.5)
        );
        assert_eq!(srgb_to_linear(0.0), 0.0);
        assert!((srgb_to_linear(1.0) - 1.0).abs() < 1e-6);
        assert!((linear_to_srgb(1.0) - 1.0).abs() < 1e-6);
        assert_eq!(srgb8_to_linear(0), 0.0);
        assert_eq!(srgb8_to_linear(255), 1.0);
        assert_eq!(linear_to_srgb8(0.5), 188); // 0.7353569 * 255 = 187.52
    }

    #[test]
    fn piecewise_boundaries_are_continuous() {
        let c = 0.04045f32;
        let linear_side = c / 12.92;
        let power_side = ((c + 0.055) / 1.055).powf(2.4);
        assert!(
            (linear_side - power_side).abs() < 1e-6,
            "{linear_side} vs {power_side}"
        );
        assert!((srgb_to_linear(c) - srgb_to_linear(c + 1e-6)).abs() < 1e-6);
        let l = 0.003_130_8f32;
        let lin = 12.92 * l;
        let pow = 1.055 * l.powf(1.0 / 2.4) - 0.055;
        assert!((lin - pow).abs() < 1e-6, "{lin} vs {pow}");
        assert!((linear_to_srgb(l) - linear_to_srgb(l + 1e-7)).abs() < 1e-5);
    }

    #[test]
    fn encode_clamps_and_is_monotone() {
        assert_eq!(linear_to_srgb(-1.0), 0.0);
        assert_eq!(linear_to_srgb(2.0), 1.0);
        assert_eq!(linear_to_srgb(f32::NAN), 0.0);
        assert_eq!(linear_to_srgb8(-0.5), 0);
        assert_eq!(linear_to_srgb8(7.0), 255);
        assert_eq!(linear_to_srgb8(f32::NAN), 0);
        let mut prev = 0u8;
        for i in 0..=100_000 {
            let c = i as f32 / 100_000.0;
            let code = linear_to_srgb8(c);
            assert!(code >= prev);
            // Nearest in sRGB space, up to float noise at the exact midpoints.
            let ideal = linear_to_srgb(c) * 255.0;
            assert!(
                (code as f32 - ideal).abs() <= 0.5 + 1e-3,
                "c {c}: {code} vs {ideal}"
            );
            prev = code;
        }
    }
}
