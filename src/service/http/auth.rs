//! Optional bearer-token authentication (RFC 6750) and the CORS allow-list.
//!
//! With tokens configured, every route but `/healthz` and `/readyz` (probes) needs
//! `Authorization: Bearer <token>`. Tokens are compared in constant time ([`subtle`]) against
//! every configured token, so neither the match nor its position leaks through timing. CORS
//! preflights are answered by the CORS layer, outside authentication, and expose `Location`,
//! `ETag` and `Retry-After` to the dashboard.

use std::time::Duration;

use axum::extract::{Request, State};
use axum::http::{header, HeaderName, HeaderValue, Method, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use subtle::ConstantTimeEq;
use tower_http::cors::{AllowOrigin, CorsLayer};

use super::problem::ApiError;
use super::AppState;

/// Paths reachable without a token.
const OPEN_PATHS: [&str; 2] = ["/healthz", "/readyz"];

/// Whether `given` equals one of `tokens`, in time independent of where they differ.
pub fn token_matches(tokens: &[String], given: &[u8]) -> bool {
    let mut ok = subtle::Choice::from(0u8);
    for t in tokens {
        // ct_eq on slices of different lengths is false without comparing contents; the
        // length of a token is not secret enough to pad for.
        ok |= t.as_bytes().ct_eq(given);
    }
    ok.into()
}

/// Middleware: refuses requests without a valid bearer token (when tokens are configured).
pub async fn require_token(State(state): State<AppState>, req: Request, next: Next) -> Response {
    if state.config.tokens.is_empty()
        || OPEN_PATHS.contains(&req.uri().path())
        || req.method() == Method::OPTIONS
    {
        return next.run(req).await;
    }
    let given = req
        .headers()
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| {
            let (scheme, token) = v.trim().split_once(' ')?;
            scheme.eq_ignore_ascii_case("bearer").then(|| token.trim())
        });
    match given {
        Some(t) if token_matches(&state.config.tokens, t.as_bytes()) => next.run(req).await,
        _ => {
            let mut resp = ApiError::new(
                StatusCode::UNAUTHORIZED,
                "unauthorized",
                "Unauthorized",
                "a valid `Authorization: Bearer <token>` header is required",
            )
            .field("Authorization")
            .into_response();
            resp.headers_mut().insert(
                header::WWW_AUTHENTICATE,
                HeaderValue::from_static("Bearer realm=\"retex\""),
            );
            resp
        }
    }
}

/// The CORS layer for the configured origins (`*` allows any; none configured allows none).
pub fn cors(origins: &[String]) -> CorsLayer {
    let allow = if origins.iter().any(|o| o == "*") {
        AllowOrigin::any()
    } else {
        AllowOrigin::list(
            origins
                .iter()
                .filter_map(|o| HeaderValue::from_str(o.trim_end_matches('/')).ok()),
        )
    };
    CorsLayer::new()
        .allow_origin(allow)
        .allow_methods([Method::GET, Method::POST, Method::DELETE, Method::OPTIONS])
        .allow_headers([
            header::AUTHORIZATION,
            header::CONTENT_TYPE,
            header::IF_NONE_MATCH,
            header::IF_RANGE,
            header::RANGE,
            HeaderName::from_static("idempotency-key"),
            HeaderName::from_static("last-event-id"),
        ])
        .expose_headers([
            header::LOCATION,
            header::ETAG,
            header::RETRY_AFTER,
            header::CONTENT_RANGE,
            header::CONTENT_DISPOSITION,
        ])
        .max_age(Duration::from_secs(600))
}

#[cfg(test)]
mod tests {
    use super::token_matches;

    #[test]
    fn tokens_match_exactly() {
        let tokens = vec!["secret-one".to_string(), "secret-two".to_string()];
        assert!(token_matches(&tokens, b"secret-two"));
        assert!(!token_matches(&tokens, b"secret-tw"));
        assert!(!token_matches(&tokens, b"secret-twoo"));
        assert!(!token_matches(&tokens, b""));
        assert!(!token_matches(&[], b"x"));
    }
}
