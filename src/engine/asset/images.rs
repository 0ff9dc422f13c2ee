//! Images (glTF 2.0 §3.8.1 "Images", §3.8.2 "Image Data"): format detection, header-only size
//! checks, and bounded decoding of base-color images to RGBA8.
//!
//! Every image's width, height and pixel layout are read from its header alone (no pixel
//! allocation) and checked against `max_image_side` and `max_image_pixels`, so a small file that
//! claims to be 100000x100000 (a decompression bomb) is refused before decoding; its decoded
//! size counts against the job's budget ([`super::budget`]). Only the base-color images a drawn
//! primitive samples are decoded, straight into the one RGBA8 buffer that is kept, with
//! `image::Limits` (max width, height and allocation) as a second guard.
//! glTF 2.0 core allows PNG and JPEG; the format is sniffed from the bytes (the JSON `mimeType`
//! is only a hint, §3.8.2 says the bytes must match it).
//!
//! Textures (§3.8.3, sampler wrap modes §3.8.4) and the base-color part of materials (§3.9.2,
//! with `KHR_texture_transform` and its texCoord override, and the archived
//! `KHR_materials_pbrSpecularGlossiness` diffuse factor/texture) are read here too, since they
//! decide which images get decoded.

use std::io::Cursor;

use image::{ImageFormat, ImageReader};

use gltf::json::validation::Checked;
use gltf::json::Root;
use serde_json::Value;

use super::model::{DecodedImage, Material, Sampler, Texture, TextureRef, UvTransform, Wrap};
use super::{IngestError, IngestLimits};

/// The format of encoded image bytes, by magic number: PNG or JPEG, else `None`.
pub fn sniff(bytes: &[u8]) -> Option<ImageFormat> {
    if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
        Some(ImageFormat::Png)
    } else if bytes.starts_with(&[0xFF, 0xD8, 0xFF]) {
        Some(ImageFormat::Jpeg)
    } else {
        None
    }
}

/// The MIME type of a format retex reads.
pub fn mime_of(format: ImageFormat) -> &'static str {
    match format {
        ImageFormat::Png => "image/png",
        _ => "image/jpeg",
    }
}

/// What the header of an image says, read without decoding pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ImageHeader {
    /// PNG or JPEG.
    pub format: ImageFormat,
    /// Width in pixels (> 0).
    pub width: u32,
    /// Height in pixels (> 0).
    pub height: u32,
    /// Bytes per pixel the decoder writes (1 for 8-bit grey ... 8 for 16-bit RGBA).
    pub bytes_per_pixel: u8,
}

impl ImageHeader {
    /// Bytes of the one buffer [`decode_rgba8`] allocates for this image: width × height ×
    /// max(4, bytes per pixel). The RGBA8 result takes 4 bytes a pixel; a 16-bit RGB or RGBA PNG
    /// is decoded at 6 or 8 bytes a pixel into the same buffer and packed to RGBA8 in place.
    pub fn decoded_bytes(&self) -> u64 {
        u64::from(self.width) * u64::from(self.height) * u64::from(self.bytes_per_pixel.max(4))
    }
}

fn decoder_for<'a>(
    image: usize,
    bytes: &'a [u8],
    format: ImageFormat,
    limits: &IngestLimits,
) -> Result<impl image::ImageDecoder + 'a, IngestError> {
    let mut reader = ImageReader::with_format(Cursor::new(bytes), format);
    let mut lim = image::Limits::default();
    lim.max_image_width = Some(limits.max_image_side);
    lim.max_image_height = Some(limits.max_image_side);
    lim.max_alloc = Some(limits.max_image_alloc_bytes);
    reader.limits(lim);
    reader.into_decoder().map_err(|e| {
        let too_large = matches!(e, image::ImageError::Limits(_));
        IngestError::ImageDecode {
            image,
            message: if too_large {
                format!("cannot decode: {e}")
            } else {
                format!("cannot read the image header: {e}")
            },
        }
    })
}

/// Reads the header of image `image` (format, size, pixel layout) and checks the size against
/// `max_image_side` and `max_image_pixels`. No pixel is decoded.
///
/// # Errors
/// [`IngestError::UnrecognizedImage`], [`IngestError::ImageDecode`] (corrupt header) or
/// [`IngestError::ImageTooLarge`].
pub fn read_header(
    image: usize,
    bytes: &[u8],
    limits: &IngestLimits,
) -> Result<ImageHeader, IngestError> {
    use image::ImageDecoder;
    let format = sniff(bytes).ok_or(IngestError::UnrecognizedImage { image })?;
    // The side limit is checked below, with the error that names it.
    let unbounded = IngestLimits {
        max_image_side: u32::MAX,
        ..limits.clone()
    };
    let decoder = decoder_for(image, bytes, format, &unbounded)?;
    let (width, height) = decoder.dimensions();
    let bytes_per_pixel = decoder.color_type().bytes_per_pixel();
    if width == 0 || height == 0 {
        return Err(IngestError::ImageDecode {
            image,
            message: format!("image is {width}x{height}"),
        });
    }
    let side = limits.max_image_side;
    if width > side || height > side {
        return Err(IngestError::ImageTooLarge {
            image,
            width,
            height,
            max: side as u64,
        });
    }
    if width as u64 * height as u64 > limits.max_image_pixels {
        return Err(IngestError::ImageTooLarge {
            image,
            width,
            height,
            max: limits.max_image_pixels,
        });
    }
    Ok(ImageHeader {
        format,
        width,
        height,
        bytes_per_pixel,
    })
}

/// [`read_header`], returning the format and size.
///
/// # Errors
/// As [`read_header`].
pub fn checked_dimensions(
    image: usize,
    bytes: &[u8],
    limits: &IngestLimits,
) -> Result<(ImageFormat, u32, u32), IngestError> {
    read_header(image, bytes, limits).map(|h| (h.format, h.width, h.height))
}

/// Decodes image `image` (already checked by [`read_header`]) to RGBA8 under `image::Limits`,
/// straight into the one buffer the [`DecodedImage`] keeps (width × height × max(4, bytes per
/// pixel) bytes, see [`ImageHeader::decoded_bytes`]); grey, grey-alpha, RGB and 16-bit pixels are
/// expanded or packed to RGBA8 in place, exactly as `image`'s `into_rgba8` converts them (16-bit
/// channels rounded to `(c + 128) / 257`). Colors stay sRGB-encoded.
///
/// # Errors
/// [`IngestError::ImageDecode`] when the data is corrupt, a decoder limit is hit or the buffer
/// cannot be allocated.
pub fn decode_rgba8(
    image: usize,
    bytes: &[u8],
    format: ImageFormat,
    limits: &IngestLimits,
) -> Result<DecodedImage, IngestError> {
    use image::{ColorType, ImageDecoder};
    let fail = |message: String| IngestError::ImageDecode { image, message };
    let decoder = decoder_for(image, bytes, format, limits)?;
    let (width, height) = decoder.dimensions();
    let color = decoder.color_type();
    let total = decoder.total_bytes();
    if total > limits.max_image_alloc_bytes {
        return Err(fail(format!(
            "cannot decode: {total} bytes of pixels exceed max_image_alloc_bytes = {}",
            limits.max_image_alloc_bytes
        )));
    }
    let n = width as usize * height as usize;
    // One [u8; 4] cell per pixel, two for 16-bit RGB(A) (6 or 8 bytes a pixel while decoding).
    let cells = n * (color.bytes_per_pixel() as usize).max(4).div_ceil(4);
    let mut pixels: Vec<[u8; 4]> = Vec::new();
    pixels
        .try_reserve_exact(cells)
        .map_err(|e| fail(format!("cannot allocate {} bytes: {e}", cells * 4)))?;
    pixels.resize(cells, [0; 4]);
    let buf = pixels.as_flattened_mut();
    let used = usize::try_from(total).map_err(|e| fail(e.to_string()))?;
    decoder
        .read_image(&mut buf[..used])
        .map_err(|e| fail(format!("cannot decode: {e}")))?;
    match color {
        ColorType::Rgba8 => {}
        ColorType::Rgb8 => expand_back(buf, n, 3, |s| [s[0], s[1], s[2], 255]),
        ColorType::L8 => expand_back(buf, n, 1, |s| [s[0], s[0], s[0], 255]),
        ColorType::La8 => expand_back(buf, n, 2, |s| [s[0], s[0], s[0], s[1]]),
        ColorType::L16 => expand_back(buf, n, 2, |s| {
            let l = narrow(s, 0);
            [l, l, l, 255]
        }),
        ColorType::La16 => expand_back(buf, n, 4, |s| {
            let l = narrow(s, 0);
            [l, l, l, narrow(s, 1)]
        }),
        ColorType::Rgb16 => pack_forward(buf, n, 6, |s| {
            [narrow(s, 0), narrow(s, 1), narrow(s, 2), 255]
        }),
        ColorType::Rgba16 => pack_forward(buf, n, 8, |s| {
            [narrow(s, 0), narrow(s, 1), narrow(s, 2), narrow(s, 3)]
        }),
        other => return Err(fail(format!("cannot decode: unsupported pixels {other:?}"))),
    }
    if pixels.len() != n {
        pixels.truncate(n);
        // Shrinking a large block gives its tail back in place (no copy).
        pixels.shrink_to_fit();
    }
    Ok(DecodedImage {
        width,
        height,
        pixels,
    })
}

/// Channel `k` of native-endian 16-bit samples, rounded to 8 bits as `image` does.
fn narrow(s: &[u8], k: usize) -> u8 {
    let c = u16::from_ne_bytes([s[2 * k], s[2 * k + 1]]);
    ((u32::from(c) + 128) / 257) as u8
}

/// Widens `n` pixels of `from` bytes (< 4, or 4 in place) at the front of `buf` to RGBA8, last
/// pixel first so that no source byte is overwritten before it is read.
fn expand_back(buf: &mut [u8], n: usize, from: usize, px: impl Fn(&[u8]) -> [u8; 4]) {
    for i in (0..n).rev() {
        let rgba = px(&buf[i * from..i * from + from]);
        buf[i * 4..i * 4 + 4].copy_from_slice(&rgba);
    }
}

/// Packs `n` pixels of `from` bytes (> 4) to RGBA8 at the front of `buf`, first pixel first.
fn pack_forward(buf: &mut [u8], n: usize, from: usize, px: impl Fn(&[u8]) -> [u8; 4]) {
    for i in 0..n {
        let rgba = px(&buf[i * from..i * from + from]);
        buf[i * 4..i * 4 + 4].copy_from_slice(&rgba);
    }
}

fn wrap(mode: &Checked<gltf::json::texture::WrappingMode>) -> Wrap {
    use gltf::json::texture::WrappingMode as W;
    match mode {
        Checked::Valid(W::ClampToEdge) => Wrap::ClampToEdge,
        Checked::Valid(W::MirroredRepeat) => Wrap::MirroredRepeat,
        _ => Wrap::Repeat,
    }
}

/// Reads `textures` from the raw JSON (gltf-json would require `source`, which glTF does
/// not), validating `source` and `sampler` references (§3.8.3, §3.8.4).
pub(super) fn read_textures(json: &Value, root: &Root) -> Result<Vec<Texture>, IngestError> {
    let Some(items) = json.get("textures") else {
        return Ok(Vec::new());
    };
    let items = items
        .as_array()
        .ok_or_else(|| IngestError::InvalidDocument {
            path: "textures".into(),
            message: "is not an array".into(),
        })?;
    let mut out = Vec::with_capacity(items.len());
    for (i, t) in items.iter().enumerate() {
        let index =
            |key: &str, target: &'static str, count: usize| -> Result<Option<usize>, IngestError> {
                let Some(v) = t.get(key) else { return Ok(None) };
                let idx = v.as_u64().ok_or_else(|| IngestError::InvalidDocument {
                    path: format!("textures[{i}].{key}"),
                    message: "is not a non-negative integer".into(),
                })?;
                if idx >= count as u64 {
                    return Err(IngestError::UnresolvedReference {
                        path: format!("textures[{i}].{key}"),
                        target,
                        index: usize::try_from(idx).unwrap_or(usize::MAX),
                        count,
                    });
                }
                Ok(Some(idx as usize))
            };
        let image = index("source", "images", root.images.len())?;
        let sampler = match index("sampler", "samplers", root.samplers.len())? {
            Some(s) => {
                let s = &root.samplers[s];
                Sampler {
                    wrap_s: wrap(&s.wrap_s),
                    wrap_t: wrap(&s.wrap_t),
                    nearest: matches!(
                        s.mag_filter,
                        Some(Checked::Valid(gltf::json::texture::MagFilter::Nearest))
                    ),
                }
            }
            None => Sampler::default(),
        };
        out.push(Texture { image, sampler });
    }
    Ok(out)
}

fn texture_ref(
    info: &gltf::json::texture::Info,
    path: String,
    textures: usize,
) -> Result<TextureRef, IngestError> {
    let texture = info.index.value();
    if texture >= textures {
        return Err(IngestError::UnresolvedReference {
            path,
            target: "textures",
            index: texture,
            count: textures,
        });
    }
    let tt = info
        .extensions
        .as_ref()
        .and_then(|e| e.texture_transform.as_ref());
    let transform = tt.map(|t| UvTransform {
        offset: t.offset.0,
        rotation: t.rotation.0,
        scale: t.scale.0,
    });
    let tex_coord = tt.and_then(|t| t.tex_coord).unwrap_or(info.tex_coord);
    Ok(TextureRef {
        texture,
        tex_coord,
        transform,
    })
}

/// Reads each material's base color (§3.9.2), from `KHR_materials_pbrSpecularGlossiness`
/// (diffuse factor and texture) when present, else `pbrMetallicRoughness`.
pub(super) fn read_materials(root: &Root, textures: usize) -> Result<Vec<Material>, IngestError> {
    let mut out = Vec::with_capacity(root.materials.len());
    for (i, m) in root.materials.iter().enumerate() {
        let pbr = &m.pbr_metallic_roughness;
        let spec_gloss = m
            .extensions
            .as_ref()
            .and_then(|e| e.pbr_specular_glossiness.as_ref());
        let (factor, texture) = match spec_gloss {
            Some(sg) => (
                sg.diffuse_factor.0,
                sg.diffuse_texture
                    .as_ref()
                    .map(|t| {
                        let path = format!("materials[{i}].extensions.KHR_materials_pbrSpecularGlossiness.diffuseTexture.index");
                        texture_ref(t, path, textures)
                    })
                    .transpose()?,
            ),
            None => (
                pbr.base_color_factor.0,
                pbr.base_color_texture
                    .as_ref()
                    .map(|t| texture_ref(t, format!("materials[{i}].pbrMetallicRoughness.baseColorTexture.index"), textures))
                    .transpose()?,
            ),
        };
        out.push(Material {
            name: m.name.clone(),
            base_color_factor: factor,
            base_color_texture: texture,
            double_sided: m.double_sided,
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A PNG signature and IHDR chunk claiming `w` x `h` RGBA8, with no pixel data.
    fn png_header(w: u32, h: u32) -> Vec<u8> {
        let mut v = b"\x89PNG\r\n\x1a\n".to_vec();
        v.extend_from_slice(&13u32.to_be_bytes());
        let mut chunk = b"IHDR".to_vec();
        chunk.extend_from_slice(&w.to_be_bytes());
        chunk.extend_from_slice(&h.to_be_bytes());
        chunk.extend_from_slice(&[8, 6, 0, 0, 0]);
        // The png crate checks the CRC, so compute it.
        push_chunk(&mut v, &chunk);
        // A short zlib stream of zeros: decoding it fully would need width*height*4 bytes.
        push_chunk(&mut v, b"IDAT\x78\x9c\x63\x00\x00\x00\x01\x00\x01");
        push_chunk(&mut v, b"IEND");
        v
    }

    fn push_chunk(v: &mut Vec<u8>, type_and_data: &[u8]) {
        if !type_and_data.starts_with(b"IHDR") {
            v.extend_from_slice(&(type_and_data.len() as u32 - 4).to_be_bytes());
        }
        v.extend_from_slice(type_and_data);
        v.extend_from_slice(&crc32(type_and_data).to_be_bytes());
    }

    fn crc32(data: &[u8]) -> u32 {
        let mut crc = 0xFFFF_FFFFu32;
        for &b in data {
            crc ^= b as u32;
            for _ in 0..8 {
                crc = if crc & 1 != 0 {
                    (crc >> 1) ^ 0xEDB8_8320
                } else {
                    crc >> 1
                };
            }
        }
        !crc
    }

    #[test]
    fn bomb_header_is_refused_without_decoding() {
        let bytes = png_header(100_000, 100_000);
        let err = checked_dimensions(3, &bytes, &IngestLimits::default()).unwrap_err();
        assert!(
            matches!(
                err,
                IngestError::ImageTooLarge {
                    image: 3,
                    width: 100_000,
                    height: 100_000,
                    ..
                }
            ),
            "{err}"
        );
        let limits = IngestLimits {
            max_image_pixels: 100,
            ..IngestLimits::default()
        };
        let err = checked_dimensions(0, &png_header(11, 10), &limits).unwrap_err();
        assert!(matches!(err, IngestError::ImageTooLarge { max: 100, .. }));
    }

    #[test]
    fn garbage_is_unrecognized_and_truncated_is_corrupt() {
        assert!(matches!(
            checked_dimensions(1, b"GIF89a", &IngestLimits::default()),
            Err(IngestError::UnrecognizedImage { image: 1 })
        ));
        assert!(matches!(
            checked_dimensions(2, b"\x89PNG\r\n\x1a\n\0", &IngestLimits::default()),
            Err(IngestError::ImageDecode { image: 2, .. })
        ));
    }

    #[test]
    fn small_png_decodes() {
        let mut buf = Vec::new();
        let img = image::RgbaImage::from_fn(3, 2, |x, y| image::Rgba([x as u8, y as u8, 7, 255]));
        img.write_to(&mut Cursor::new(&mut buf), ImageFormat::Png)
            .unwrap();
        let (f, w, h) = checked_dimensions(0, &buf, &IngestLimits::default()).unwrap();
        assert_eq!((f, w, h), (ImageFormat::Png, 3, 2));
        let d = decode_rgba8(0, &buf, f, &IngestLimits::default()).unwrap();
        assert_eq!(d.pixels[4], [1, 1, 7, 255]);
    }
}
