//! URI resolution for buffers and images (glTF 2.0 §2.8 "URIs", §3.6.1.1 buffer data,
//! §3.8.1 image data), restricted to the upload.
//!
//! A glTF URI is either a `data:` URI (RFC 2397; base64 or percent-encoded payload), which is
//! decoded under a size cap checked *before* decoding, or a relative reference, which is
//! percent-decoded and looked up by exact name in the [`BlobSet`], relative to the main file's
//! folder inside the set. Everything else is refused with [`IngestError::ForbiddenUri`]: any
//! scheme (`file:`, `http:`, `https:`, `ftp:`, ...), absolute paths (`/x`, `\x`, `C:`), `..`
//! segments, backslashes and NUL bytes. Nothing here touches the filesystem or the network.

use std::borrow::Cow;

use base64::engine::general_purpose::{GeneralPurpose, GeneralPurposeConfig};
use base64::engine::DecodePaddingMode;
use base64::Engine as _;

use super::{BlobSet, IngestError};

/// Base64 with the standard alphabet that accepts both padded and unpadded input.
const BASE64: GeneralPurpose = GeneralPurpose::new(
    &base64::alphabet::STANDARD,
    GeneralPurposeConfig::new().with_decode_padding_mode(DecodePaddingMode::Indifferent),
);

/// Resolved bytes of a URI.
#[derive(Debug)]
pub struct Resolved<'a> {
    /// The bytes: borrowed from a blob or decoded from a data: URI.
    pub bytes: Cow<'a, [u8]>,
    /// The media type of a data: URI, if it names one.
    pub mime: Option<String>,
}

/// Whether `uri` is a data: URI.
pub fn is_data_uri(uri: &str) -> bool {
    uri.len() >= 5 && uri[..5].eq_ignore_ascii_case("data:")
}

/// Whether `s` starts with a URI scheme (`ALPHA *( ALPHA / DIGIT / "+" / "-" / "." ) ":"`).
fn has_scheme(s: &str) -> bool {
    let Some(colon) = s.find(':') else {
        return false;
    };
    let scheme = &s[..colon];
    let mut chars = scheme.chars();
    matches!(chars.next(), Some(c) if c.is_ascii_alphabetic())
        && chars.all(|c| c.is_ascii_alphanumeric() || matches!(c, '+' | '-' | '.'))
}

/// The folder of `main` inside the blob set, with a trailing `/` (or empty).
pub fn base_dir(main: &str) -> &str {
    match main.rfind('/') {
        Some(i) => &main[..=i],
        None => "",
    }
}

/// Turns a relative URI into a blob name: percent-decodes it, refuses schemes, absolute paths
/// and `..`, drops `.` segments, and prefixes `base` (a folder ending in `/`, or empty).
///
/// # Errors
/// [`IngestError::ForbiddenUri`] or [`IngestError::InvalidUri`] (not UTF-8 after decoding).
pub fn relative_name(base: &str, uri: &str, what: &str) -> Result<String, IngestError> {
    let forbidden = || IngestError::ForbiddenUri {
        what: what.to_string(),
        uri: uri.to_string(),
    };
    if has_scheme(uri) {
        return Err(forbidden());
    }
    let decoded = percent_encoding::percent_decode_str(uri)
        .decode_utf8()
        .map_err(|_| IngestError::InvalidUri {
            what: what.to_string(),
            reason: "percent-decoded uri is not utf-8".to_string(),
        })?;
    if decoded.is_empty() {
        return Err(IngestError::InvalidUri {
            what: what.to_string(),
            reason: "uri is empty".to_string(),
        });
    }
    if has_scheme(&decoded)
        || decoded.starts_with('/')
        || decoded.contains('\\')
        || decoded.contains('\0')
        || decoded
            .split('/')
            .next()
            .is_some_and(|first| first.contains(':'))
    {
        return Err(forbidden());
    }
    let mut segments = Vec::new();
    for seg in decoded.split('/') {
        match seg {
            "" | "." => {}
            ".." => return Err(forbidden()),
            s => segments.push(s),
        }
    }
    if segments.is_empty() {
        return Err(IngestError::InvalidUri {
            what: what.to_string(),
            reason: "uri names no file".to_string(),
        });
    }
    Ok(format!("{base}{}", segments.join("/")))
}

/// Decodes a data: URI (`data:[<mediatype>][;base64],<data>`), refusing payloads whose decoded
/// size would exceed `max_bytes` before decoding them.
///
/// # Errors
/// [`IngestError::InvalidUri`] or [`IngestError::DataUriTooLarge`].
pub fn decode_data_uri(
    uri: &str,
    what: &str,
    max_bytes: u64,
) -> Result<(Option<String>, Vec<u8>), IngestError> {
    let invalid = |reason: &str| IngestError::InvalidUri {
        what: what.to_string(),
        reason: reason.to_string(),
    };
    if !is_data_uri(uri) {
        return Err(invalid("not a data: uri"));
    }
    let rest = &uri[5..];
    let comma = rest
        .find(',')
        .ok_or_else(|| invalid("data: uri has no ',' before its payload"))?;
    let (header, payload) = (&rest[..comma], &rest[comma + 1..]);
    let (media, is_base64) = match header.len().checked_sub(7) {
        Some(i) if header.is_char_boundary(i) && header[i..].eq_ignore_ascii_case(";base64") => {
            (&header[..i], true)
        }
        _ => (header, false),
    };
    let mut parts = media.split(';');
    let mime = parts
        .next()
        .filter(|m| !m.is_empty())
        .map(|m| m.to_ascii_lowercase());
    if parts.any(|p| !p.contains('=')) {
        return Err(invalid(
            "data: uri has a media type parameter that is not name=value",
        ));
    }
    let estimate = if is_base64 {
        payload.len() as u64 / 4 * 3 + 3
    } else {
        payload.len() as u64
    };
    if estimate > max_bytes {
        // An upper bound for plain payloads; for base64 within 3 bytes of the exact size.
        let exact_enough = if is_base64 {
            estimate.saturating_sub(3)
        } else {
            estimate
        };
        if exact_enough > max_bytes {
            return Err(IngestError::DataUriTooLarge {
                what: what.to_string(),
                bytes: exact_enough,
                max: max_bytes,
            });
        }
    }
    let bytes = if is_base64 {
        BASE64
            .decode(payload.trim_end())
            .map_err(|e| invalid(&format!("base64 payload is invalid: {e}")))?
    } else {
        percent_encoding::percent_decode_str(payload).collect::<Vec<u8>>()
    };
    if bytes.len() as u64 > max_bytes {
        return Err(IngestError::DataUriTooLarge {
            what: what.to_string(),
            bytes: bytes.len() as u64,
            max: max_bytes,
        });
    }
    Ok((mime, bytes))
}

/// Resolves `uri` (of `what`, e.g. `buffers[0]`) to bytes: a data: URI is decoded, a relative
/// reference is looked up in `blobs` relative to `base`.
///
/// # Errors
/// [`IngestError::ForbiddenUri`], [`IngestError::InvalidUri`], [`IngestError::DataUriTooLarge`]
/// or [`IngestError::MissingFile`].
pub fn resolve<'a>(
    uri: &str,
    base: &str,
    what: &str,
    blobs: &'a BlobSet,
    max_data_uri_bytes: u64,
) -> Result<Resolved<'a>, IngestError> {
    if is_data_uri(uri) {
        let (mime, bytes) = decode_data_uri(uri, what, max_data_uri_bytes)?;
        return Ok(Resolved {
            bytes: Cow::Owned(bytes),
            mime,
        });
    }
    let name = relative_name(base, uri, what)?;
    match blobs.get(&name) {
        Some(bytes) => Ok(Resolved {
            bytes: Cow::Borrowed(bytes),
            mime: None,
        }),
        None => Err(IngestError::MissingFile {
            what: what.to_string(),
            name,
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn forbidden(uri: &str) -> bool {
        matches!(
            relative_name("", uri, "buffers[0]"),
            Err(IngestError::ForbiddenUri { .. })
        )
    }

    #[test]
    fn relative_names_are_decoded_and_based() {
        assert_eq!(relative_name("", "Fox.bin", "x").unwrap(), "Fox.bin");
        assert_eq!(
            relative_name("sub/", "tex/a%20b.png", "x").unwrap(),
            "sub/tex/a b.png"
        );
        assert_eq!(relative_name("", "./a b.bin", "x").unwrap(), "a b.bin");
        assert_eq!(
            relative_name("", "Unicode%E2%9D%A4.bin", "x").unwrap(),
            "Unicode❤.bin"
        );
    }

    #[test]
    fn escapes_and_schemes_are_forbidden() {
        for uri in [
            "../secret.bin",
            "a/../../b",
            "%2e%2e/secret.bin",
            "file:///etc/passwd",
            "http://example.com/buffer.bin",
            "https://x/y",
            "ftp://x/y",
            "/etc/passwd",
            "%2Fetc/passwd",
            "C:/x.bin",
            "c:x",
            "a\\b",
            "http%3A//x",
        ] {
            assert!(forbidden(uri), "{uri}");
        }
    }

    #[test]
    fn data_uris_decode_with_cap() {
        assert!(matches!(
            decode_data_uri("data:a/b;;base64,AA==", "x", 5),
            Err(IngestError::InvalidUri { .. })
        ));
        assert!(decode_data_uri("data:a/b;charset=x;base64,AA==", "x", 5).is_ok());
        let (mime, b) =
            decode_data_uri("data:application/octet-stream;base64,AAECAw==", "x", 100).unwrap();
        assert_eq!(mime.as_deref(), Some("application/octet-stream"));
        assert_eq!(b, [0, 1, 2, 3]);
        assert_eq!(decode_data_uri("data:,a%20b", "x", 100).unwrap().1, b"a b");
        assert_eq!(
            decode_data_uri("data:;base64,AAECAw", "x", 100).unwrap().1,
            [0, 1, 2, 3]
        );
        assert!(matches!(
            decode_data_uri("data:;base64,AAAAAAAA", "x", 5),
            Err(IngestError::DataUriTooLarge { .. })
        ));
        assert!(matches!(
            decode_data_uri("data:;base64,A!A", "x", 5),
            Err(IngestError::InvalidUri { .. })
        ));
        assert!(matches!(
            decode_data_uri("data:abc", "x", 5),
            Err(IngestError::InvalidUri { .. })
        ));
    }
}
