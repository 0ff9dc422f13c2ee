//! Images (glTF 2.0 §3.8.1 "Images", §3.8.2 "Image Data"): format detection, header-only size
//! checks, and bounded decoding of base-color images to RGBA8.
//!
//! Every image's width and height are read from its header alone (no pixel allocation) and
//! checked against `max_image_side` and `max_image_pixels`, so a small file that claims to be
//! 100000x100000 (a decompression bomb) is refused before decoding. Only images used as a base
//! color are decoded, with `image::Limits` (max width, height and allocation) as a second guard.
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

/// Reads width and height from the header of image `image` and checks them against the limits.
///
/// # Errors
/// [`IngestError::UnrecognizedImage`], [`IngestError::ImageDecode`] (corrupt header) or
/// [`IngestError::ImageTooLarge`].
pub fn checked_dimensions(
    image: usize,
    bytes: &[u8],
    limits: &IngestLimits,
) -> Result<(ImageFormat, u32, u32), IngestError> {
    let format = sniff(bytes).ok_or(IngestError::UnrecognizedImage { image })?;
    let (width, height) = ImageReader::with_format(Cursor::new(bytes), format)
        .into_dimensions()
        .map_err(|e| IngestError::ImageDecode {
            image,
            message: format!("cannot read the image header: {e}"),
        })?;
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
    Ok((format, width, height))
}

/// Decodes image `image` (already checked by [`checked_dimensions`]) to RGBA8 under
/// `image::Limits`. 16-bit and grey images are converted; colors stay sRGB-encoded.
///
/// # Errors
/// [`IngestError::ImageDecode`] when the data is corrupt or a decoder limit is hit.
pub fn decode_rgba8(
    image: usize,
    bytes: &[u8],
    format: ImageFormat,
    limits: &IngestLimits,
) -> Result<DecodedImage, IngestError> {
    let mut reader = ImageReader::with_format(Cursor::new(bytes), format);
    let mut lim = image::Limits::default();
    lim.max_image_width = Some(limits.max_image_side);
    lim.max_image_height = Some(limits.max_image_side);
    lim.max_alloc = Some(limits.max_image_alloc_bytes);
    reader.limits(lim);
    let decoded = reader.decode().map_err(|e| IngestError::ImageDecode {
        image,
        message: format!("cannot decode: {e}"),
    })?;
    let rgba = decoded.into_rgba8();
    let (width, height) = rgba.dimensions();
    let pixels = rgba
        .into_raw()
        .chunks_exact(4)
        .map(|c| [c[0], c[1], c[2], c[3]])
        .collect();
    Ok(DecodedImage {
        width,
        height,
        pixels,
    })
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
