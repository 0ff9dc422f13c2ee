//! The web dashboard (issue 16, part 2): static files embedded in the binary with
//! `include_bytes!` and served at `/` (the page) and `/dashboard/{path}` (its script, style
//! sheet and vendored `<model-viewer>`), plus the two API routes the page needs beside the job
//! routes ([`api`]): `GET /v1/methods` and `GET /v1/jobs/{id}/constraints`.
//!
//! The static routes sit outside bearer authentication (a browser cannot send a token before
//! the page that asks for it has loaded); the page's script sends `Authorization: Bearer` on
//! every API call itself. Every file has a strong ETag (SHA-256 of its bytes, computed once) and
//! answers `If-None-Match` with 304; `Cache-Control: no-cache` (revalidate each time, so a new
//! binary's page is picked up at once), except the vendored library, which is cacheable for a
//! day. The vendored file is stored gzip-compressed and sent as it is with
//! `Content-Encoding: gzip` to clients that accept it (every browser); others get 406.

use std::sync::OnceLock;

use axum::extract::Path;
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use sha2::{Digest, Sha256};

use super::jobs::if_none_match;
use super::problem::{self, ApiError};

pub mod api;
pub use api::{constraints, methods, InputUseDoc, InputsDoc, MethodDoc, MethodList};

/// One embedded file.
struct Asset {
    path: &'static str,
    media_type: &'static str,
    bytes: &'static [u8],
    /// Stored gzip-compressed.
    gzip: bool,
    cache: &'static str,
}

const NO_CACHE: &str = "no-cache";
const DAY: &str = "public, max-age=86400";

const ASSETS: &[Asset] = &[
    Asset {
        path: "index.html",
        media_type: "text/html; charset=utf-8",
        bytes: include_bytes!("static/index.html"),
        gzip: false,
        cache: NO_CACHE,
    },
    Asset {
        path: "app.js",
        media_type: "text/javascript; charset=utf-8",
        bytes: include_bytes!("static/app.js"),
        gzip: false,
        cache: NO_CACHE,
    },
    Asset {
        path: "app.css",
        media_type: "text/css; charset=utf-8",
        bytes: include_bytes!("static/app.css"),
        gzip: false,
        cache: NO_CACHE,
    },
    Asset {
        path: "vendor/model-viewer.min.js",
        media_type: "text/javascript; charset=utf-8",
        bytes: include_bytes!("static/vendor/model-viewer.min.js.gz"),
        gzip: true,
        cache: DAY,
    },
    Asset {
        path: "vendor/model-viewer.LICENSE",
        media_type: "text/plain; charset=utf-8",
        bytes: include_bytes!("static/vendor/model-viewer.LICENSE"),
        gzip: false,
        cache: NO_CACHE,
    },
    Asset {
        path: "vendor/THIRD-PARTY.md",
        media_type: "text/markdown; charset=utf-8",
        bytes: include_bytes!("static/vendor/THIRD-PARTY.md"),
        gzip: false,
        cache: NO_CACHE,
    },
];

/// The strong ETag of each asset, in [`ASSETS`] order.
fn etags() -> &'static [String] {
    static TAGS: OnceLock<Vec<String>> = OnceLock::new();
    TAGS.get_or_init(|| {
        ASSETS
            .iter()
            .map(|a| format!("\"{}\"", hex::encode(&Sha256::digest(a.bytes)[..16])))
            .collect()
    })
}

fn accepts_gzip(headers: &HeaderMap) -> bool {
    headers
        .get_all(header::ACCEPT_ENCODING)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(','))
        .any(|c| {
            let mut it = c.split(';');
            let name = it.next().unwrap_or("").trim();
            let q_zero = it.any(|p| {
                p.trim()
                    .strip_prefix("q=")
                    .is_some_and(|q| q.trim().parse::<f32>().is_ok_and(|q| q == 0.0))
            });
            (name.eq_ignore_ascii_case("gzip") || name == "*") && !q_zero
        })
}

fn serve(path: &str, headers: &HeaderMap) -> Response {
    let Some(i) = ASSETS.iter().position(|a| a.path == path) else {
        return problem::from_status(
            StatusCode::NOT_FOUND,
            format!(
                "no dashboard file {:?}",
                problem::clip(path, problem::ECHO_CHARS)
            ),
        )
        .into_response();
    };
    let asset = &ASSETS[i];
    let tag = &etags()[i];
    if asset.gzip && !accepts_gzip(headers) {
        return ApiError::new(
            StatusCode::NOT_ACCEPTABLE,
            "gzip-required",
            "The file is only available gzip-compressed",
            format!("{path} is stored gzip-compressed; send Accept-Encoding: gzip"),
        )
        .field("Accept-Encoding")
        .into_response();
    }
    let mut out = if if_none_match(headers, tag) {
        StatusCode::NOT_MODIFIED.into_response()
    } else {
        (StatusCode::OK, asset.bytes).into_response()
    };
    let h = out.headers_mut();
    let mut set = |name: header::HeaderName, value: &str| {
        if let Ok(v) = HeaderValue::from_str(value) {
            h.insert(name, v);
        }
    };
    set(header::CONTENT_TYPE, asset.media_type);
    set(header::ETAG, tag);
    set(header::CACHE_CONTROL, asset.cache);
    set(header::X_CONTENT_TYPE_OPTIONS, "nosniff");
    if asset.gzip {
        set(header::CONTENT_ENCODING, "gzip");
        set(header::VARY, "Accept-Encoding");
    }
    if asset.path == "index.html" {
        set(header::REFERRER_POLICY, "no-referrer");
        set(header::X_FRAME_OPTIONS, "DENY");
    }
    out
}

/// `GET /`: the dashboard page.
pub async fn index(headers: HeaderMap) -> Response {
    serve("index.html", &headers)
}

/// `GET /dashboard/{*path}`: the page's script, style sheet and vendored files.
pub async fn file(Path(path): Path<String>, headers: HeaderMap) -> Response {
    serve(&path, &headers)
}
