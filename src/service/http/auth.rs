//! Optional bearer-token authentication (RFC 6750) and the CORS allow-list.
//!
//! With tokens configured, every route but `/healthz` and `/readyz` (probes) needs
//! `Authorization: Bearer <token>`. Tokens are compared in constant time ([`subtle`]) against
//! every configured token, so neither the match nor its position leaks through timing.
//!
//! A configured token may name its scope as a prefix: `read:<token>` may only read (GET),
//! `submit:<token>` may also submit and cancel jobs (POST), `admin:<token>` or a token without
//! a prefix may do everything, including deleting jobs. A token short of the scope a request
//! needs gets 403 `insufficient-scope` (RFC 6750 §3.1), so a read-only dashboard or a
//! submitting client cannot delete other clients' jobs; a submit token cancels only the jobs it
//! submitted (job ownership: `caller`). CORS
//! preflights are answered by the CORS layer, outside authentication, and expose `Location`,
//! `ETag` and `Retry-After` to the dashboard.

use std::time::Duration;

use axum::extract::{Request, State};
use axum::http::{header, HeaderName, HeaderValue, Method, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use subtle::{ConditionallySelectable, ConstantTimeEq};
use tower_http::cors::{AllowOrigin, CorsLayer};

use super::caller::{owner_id, Caller};
use super::linger::drain_unread;
use super::problem::ApiError;
use super::AppState;

/// Paths reachable without a token.
const OPEN_PATHS: [&str; 2] = ["/healthz", "/readyz"];

/// What a token may do; each scope includes the ones before it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
#[repr(u8)]
pub enum Scope {
    /// Read jobs, results, events, metrics and the OpenAPI document (GET).
    Read = 1,
    /// Also submit and cancel jobs (POST).
    Submit = 2,
    /// Also delete jobs (DELETE).
    Admin = 3,
}

impl Scope {
    fn name(self) -> &'static str {
        match self {
            Scope::Read => "read",
            Scope::Submit => "submit",
            Scope::Admin => "admin",
        }
    }

    /// The scope a request needs, by its method.
    pub fn needed(method: &Method) -> Scope {
        if *method == Method::GET || *method == Method::HEAD {
            Scope::Read
        } else if *method == Method::POST {
            Scope::Submit
        } else {
            Scope::Admin
        }
    }
}

/// Splits a configured token into its scope and the secret: `read:`, `submit:` and `admin:`
/// prefixes name the scope; any other token is an admin token.
pub fn scoped(token: &str) -> (Scope, &str) {
    for scope in [Scope::Read, Scope::Submit, Scope::Admin] {
        if let Some(secret) = token
            .strip_prefix(scope.name())
            .and_then(|t| t.strip_prefix(':'))
        {
            return (scope, secret);
        }
    }
    (Scope::Admin, token)
}

/// The scope of the configured token equal to `given`, if any, in time independent of where
/// they differ.
pub fn token_scope(tokens: &[String], given: &[u8]) -> Option<Scope> {
    let mut found = 0u8;
    for t in tokens {
        let (scope, secret) = scoped(t);
        // ct_eq on slices of different lengths is false without comparing contents; the
        // length of a token is not secret enough to pad for.
        let eq = secret.as_bytes().ct_eq(given);
        found = u8::conditional_select(&found, &(scope as u8), eq);
    }
    [Scope::Read, Scope::Submit, Scope::Admin]
        .into_iter()
        .find(|s| *s as u8 == found)
}

/// Whether `given` equals one of `tokens` (whatever its scope).
pub fn token_matches(tokens: &[String], given: &[u8]) -> bool {
    token_scope(tokens, given).is_some()
}

/// Middleware: refuses requests without a valid bearer token (when tokens are configured).
/// With a valid token, records the [`Caller`] (scope and owner id) for the handlers.
pub async fn require_token(
    State(state): State<AppState>,
    mut req: Request,
    next: Next,
) -> Response {
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
    let needed = Scope::needed(req.method());
    let given = given.map(|t| t.as_bytes().to_vec());
    let resp = match given
        .as_deref()
        .and_then(|t| token_scope(&state.config.tokens, t))
    {
        Some(scope) if scope >= needed => {
            let owner = given.as_deref().map(owner_id);
            req.extensions_mut().insert(Caller { scope, owner });
            return next.run(req).await;
        }
        Some(scope) => insufficient_scope(scope, needed, &req),
        None => unauthorized(),
    };
    // The client may still be sending its body (an upload with a wrong token): read it so it
    // gets this answer rather than a reset connection (see `linger`).
    let (parts, body) = req.into_parts();
    drain_unread(&parts.headers, body).await;
    resp
}

fn insufficient_scope(scope: Scope, needed: Scope, req: &Request) -> Response {
    let mut resp = ApiError::new(
        StatusCode::FORBIDDEN,
        "insufficient-scope",
        "Insufficient scope",
        format!(
            "this token's scope is {}; {} {} needs {}",
            scope.name(),
            req.method(),
            req.uri().path(),
            needed.name()
        ),
    )
    .field("Authorization")
    .into_response();
    let challenge = format!(
        "Bearer realm=\"retex\", error=\"insufficient_scope\", scope=\"{}\"",
        needed.name()
    );
    if let Ok(v) = HeaderValue::from_str(&challenge) {
        resp.headers_mut().insert(header::WWW_AUTHENTICATE, v);
    }
    resp
}

fn unauthorized() -> Response {
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

    #[test]
    fn scopes_come_from_prefixes() {
        use super::{scoped, token_scope, Scope};
        assert_eq!(scoped("read:abcdefgh"), (Scope::Read, "abcdefgh"));
        assert_eq!(scoped("submit:abcdefgh"), (Scope::Submit, "abcdefgh"));
        assert_eq!(scoped("admin:abcdefgh"), (Scope::Admin, "abcdefgh"));
        assert_eq!(scoped("reader:abcdefgh"), (Scope::Admin, "reader:abcdefgh"));
        let tokens = vec!["read:r-secret".to_string(), "a-secret".to_string()];
        assert_eq!(token_scope(&tokens, b"r-secret"), Some(Scope::Read));
        assert_eq!(token_scope(&tokens, b"a-secret"), Some(Scope::Admin));
        assert_eq!(token_scope(&tokens, b"read:r-secret"), None);
    }
}
