//! PNG encoding of baked textures and decoding back to linear, via the `image` crate.
//!
//! Encode: color channels are linear → sRGB 8-bit with [`linear_to_srgb8`] (exact round trip of
//! every code), alpha is linear, `round(clamp(a, 0, 1) · 255)`. When every alpha quantizes to 255
//! the alpha channel is dropped and an RGB8 PNG is written. The encoder settings are fixed
//! (default zlib level, adaptive filtering) and no metadata (time, gamma, ICC) is written, so the
//! same pixels always give the same bytes for a given `image`/`png` version.
//!
//! Decode: any PNG the `image` crate reads (8/16-bit, gray, palette, RGB, RGBA) is converted to
//! RGBA8 and back to linear with [`srgb8_to_linear`]; alpha is `a / 255`.

use image::codecs::png::{CompressionType, FilterType, PngEncoder};
use image::{ExtendedColorType, ImageEncoder, ImageFormat};
use rayon::prelude::*;

use super::color::{linear_to_srgb8, srgb8_to_linear};

/// Why [`try_encode_png_srgb`] failed.
#[derive(Debug, thiserror::Error)]
pub enum EncodeError {
    /// The image has no texels.
    #[error("png of {width}x{height} has no pixels")]
    Empty {
        /// Width in pixels.
        width: u32,
        /// Height in pixels.
        height: u32,
    },
    /// The pixel slice does not hold `width × height` pixels.
    #[error("png of {width}x{height} needs {expected} pixels, got {got}")]
    SizeMismatch {
        /// Width in pixels.
        width: u32,
        /// Height in pixels.
        height: u32,
        /// `width × height`.
        expected: u64,
        /// The slice length.
        got: u64,
    },
    /// The PNG encoder failed.
    #[error("png encoding failed: {0}")]
    Image(#[from] image::ImageError),
}

/// Quantizes linear alpha to 8 bits (NaN → 0).
#[inline]
fn alpha8(a: f32) -> u8 {
    if a.is_nan() {
        0
    } else {
        // Round half up (non-negative input, so the truncating cast after + 0.5 is `round`).
        (a.clamp(0.0, 1.0) * 255.0 + 0.5) as u8
    }
}

/// Linear RGBA → PNG bytes (see the module docs), checking the dimensions.
///
/// # Errors
/// [`EncodeError::Empty`] for a zero width or height, [`EncodeError::SizeMismatch`] when
/// `pixels.len() != width × height`, [`EncodeError::Image`] if the encoder fails.
pub fn try_encode_png_srgb(
    pixels: &[[f32; 4]],
    width: u32,
    height: u32,
) -> Result<Vec<u8>, EncodeError> {
    if width == 0 || height == 0 {
        return Err(EncodeError::Empty { width, height });
    }
    let expected = width as u64 * height as u64;
    if pixels.len() as u64 != expected {
        return Err(EncodeError::SizeMismatch {
            width,
            height,
            expected,
            got: pixels.len() as u64,
        });
    }
    let opaque = pixels.par_iter().all(|p| alpha8(p[3]) == 255);
    let channels = if opaque { 3 } else { 4 };
    // Converted in parallel by rows (the same bytes in the same order for any thread count).
    let mut raw = vec![0u8; pixels.len() * channels];
    let row = width as usize;
    raw.par_chunks_mut(row * channels)
        .zip(pixels.par_chunks(row))
        .for_each(|(out, texels)| {
            for (o, p) in out.chunks_exact_mut(channels).zip(texels) {
                o[0] = linear_to_srgb8(p[0]);
                o[1] = linear_to_srgb8(p[1]);
                o[2] = linear_to_srgb8(p[2]);
                if !opaque {
                    o[3] = alpha8(p[3]);
                }
            }
        });
    let color = if opaque {
        ExtendedColorType::Rgb8
    } else {
        ExtendedColorType::Rgba8
    };
    let mut out = Vec::new();
    PngEncoder::new_with_quality(&mut out, CompressionType::Fast, FilterType::Adaptive)
        .write_image(&raw, width, height, color)?;
    Ok(out)
}

/// Linear RGBA f32 → PNG bytes: color sRGB-encoded with [`linear_to_srgb8`], alpha
/// linear-quantized; an RGB8 PNG when every alpha quantizes to 255. Deterministic bytes.
///
/// `pixels` must hold `width × height` pixels and both sizes must be non-zero; otherwise this
/// returns an empty `Vec` (use [`try_encode_png_srgb`] to get the reason).
pub fn encode_png_srgb(pixels: &[[f32; 4]], width: u32, height: u32) -> Vec<u8> {
    try_encode_png_srgb(pixels, width, height).unwrap_or_default()
}

/// Linear values in [0, 1] → 8-bit PNG with `channels` (1 gray, 2 gray+alpha, 3 RGB, 4 RGBA)
/// per texel, no transfer function (normal maps, occlusion, data). Values are clamped and
/// rounded; NaN is 0. Returns an empty `Vec` when the sizes do not fit (`texels.len()` must be
/// `width × height × channels`, all non-zero).
pub fn encode_png_linear8(width: u32, height: u32, channels: u8, texels: &[f32]) -> Vec<u8> {
    let color = match channels {
        1 => ExtendedColorType::L8,
        2 => ExtendedColorType::La8,
        3 => ExtendedColorType::Rgb8,
        4 => ExtendedColorType::Rgba8,
        _ => return Vec::new(),
    };
    let n = width as u64 * height as u64 * channels as u64;
    if width == 0 || height == 0 || texels.len() as u64 != n {
        return Vec::new();
    }
    let raw: Vec<u8> = texels.iter().map(|&v| alpha8(v)).collect();
    let mut out = Vec::new();
    match PngEncoder::new_with_quality(&mut out, CompressionType::Fast, FilterType::Adaptive)
        .write_image(&raw, width, height, color)
    {
        Ok(()) => out,
        Err(_) => Vec::new(),
    }
}

/// Values in [0, 1] → 16-bit grayscale PNG (clamped, rounded to 1/65535; NaN is 0), e.g. a
/// displacement map. Returns an empty `Vec` when `texels.len() != width × height` or a size is 0.
pub fn encode_png_gray16(width: u32, height: u32, texels: &[f32]) -> Vec<u8> {
    if width == 0 || height == 0 || texels.len() as u64 != width as u64 * height as u64 {
        return Vec::new();
    }
    let mut raw = Vec::with_capacity(texels.len() * 2);
    for &v in texels {
        let q = if v.is_nan() {
            0u16
        } else {
            (v.clamp(0.0, 1.0) * 65535.0 + 0.5) as u16
        };
        // The PNG encoder takes 16-bit samples in native byte order.
        raw.extend_from_slice(&q.to_ne_bytes());
    }
    let mut out = Vec::new();
    match PngEncoder::new_with_quality(&mut out, CompressionType::Fast, FilterType::Adaptive)
        .write_image(&raw, width, height, ExtendedColorType::L16)
    {
        Ok(()) => out,
        Err(_) => Vec::new(),
    }
}

/// Decodes PNG bytes to `(width, height, linear RGBA)`, row-major from the top-left.
///
/// # Errors
/// The `image` crate's error when the bytes are not a PNG it can decode (or exceed its default
/// memory limits).
pub fn decode_png_linear(bytes: &[u8]) -> Result<(u32, u32, Vec<[f32; 4]>), image::ImageError> {
    let img = image::load_from_memory_with_format(bytes, ImageFormat::Png)?.to_rgba8();
    let (w, h) = img.dimensions();
    let pixels = img
        .pixels()
        .map(|p| {
            let [r, g, b, a] = p.0;
            [
                srgb8_to_linear(r),
                srgb8_to_linear(g),
                srgb8_to_linear(b),
                a as f32 / 255.0,
            ]
        })
        .collect();
    Ok((w, h, pixels))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn test_pixels(w: u32, h: u32, alpha: bool) -> Vec<[f32; 4]> {
        (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as f32 / w as f32, (i / w) as f32 / h as f32);
                let a = if alpha { 1.0 - 0.7 * x } else { 1.0 };
                [x * x, y, (x * 7.3 + y * 3.1).fract(), a]
            })
            .collect()
    }

    fn srgb_step_error(a: f32, b: f32) -> f32 {
        // Distance in 8-bit sRGB steps.
        (crate::engine::texture::color::linear_to_srgb(a)
            - crate::engine::texture::color::linear_to_srgb(b))
        .abs()
            * 255.0
    }

    #[test]
    fn round_trip_is_within_one_srgb_step() {
        for alpha in [false, true] {
            let (w, h) = (33, 17);
            let px = test_pixels(w, h, alpha);
            let bytes = encode_png_srgb(&px, w, h);
            assert_eq!(&bytes[1..4], b"PNG");
            let (dw, dh, back) = decode_png_linear(&bytes).unwrap();
            assert_eq!((dw, dh), (w, h));
            for (p, q) in px.iter().zip(&back) {
                for k in 0..3 {
                    assert!(srgb_step_error(p[k], q[k]) <= 0.5 + 1e-3, "{p:?} vs {q:?}");
                }
                assert!((p[3] - q[3]).abs() <= 0.5 / 255.0 + 1e-6, "{p:?} vs {q:?}");
            }
        }
    }

    #[test]
    fn opaque_images_are_rgb_and_translucent_ones_rgba() {
        let opaque = encode_png_srgb(&test_pixels(8, 8, false), 8, 8);
        let translucent = encode_png_srgb(&test_pixels(8, 8, true), 8, 8);
        let color_type = |b: &[u8]| image::load_from_memory(b).unwrap().color();
        assert_eq!(color_type(&opaque), image::ColorType::Rgb8);
        assert_eq!(color_type(&translucent), image::ColorType::Rgba8);
    }

    #[test]
    fn exact_codes_survive_and_bytes_are_deterministic() {
        let px: Vec<[f32; 4]> = (0..256u32)
            .map(|v| {
                let l = srgb8_to_linear(v as u8);
                [l, srgb8_to_linear(255 - v as u8), l, v as f32 / 255.0]
            })
            .collect();
        let a = encode_png_srgb(&px, 16, 16);
        let b = encode_png_srgb(&px, 16, 16);
        assert_eq!(a, b);
        let (_, _, back) = decode_png_linear(&a).unwrap();
        assert_eq!(back, px);
    }

    #[test]
    fn bad_input_is_an_error_not_a_panic() {
        assert!(matches!(
            try_encode_png_srgb(&[], 0, 4),
            Err(EncodeError::Empty { .. })
        ));
        assert!(matches!(
            try_encode_png_srgb(&[[0.0; 4]; 3], 2, 2),
            Err(EncodeError::SizeMismatch {
                expected: 4,
                got: 3,
                ..
            })
        ));
        assert!(encode_png_srgb(&[[0.0; 4]; 3], 2, 2).is_empty());
        assert!(decode_png_linear(b"not a png").is_err());
        // Out-of-range and NaN values clamp.
        let bytes = encode_png_srgb(&[[f32::NAN, -1.0, 7.0, 2.0]], 1, 1);
        let (_, _, back) = decode_png_linear(&bytes).unwrap();
        assert_eq!(back[0], [0.0, 0.0, 1.0, 1.0]);
    }
}
