//! Who is calling, and which jobs they may manage (issue 9, item 9: per-token job ownership on
//! top of the scopes of `auth`).
//!
//! With tokens configured, the authentication middleware records a [`Caller`]: the token's
//! scope and its owner id, the first 16 hex digits of the token's SHA-256 (stable across
//! restarts, not the secret). A job records the owner id of the token that submitted it. A
//! `submit` token cancels only its own jobs (403 `not-job-owner` otherwise); an admin token
//! cancels and deletes any job (deletion needs admin, see `auth`). Idempotency-Keys are kept per
//! owner, so one client's key never replays another client's job. Without tokens everything is
//! open and jobs have no owner.

use axum::extract::FromRequestParts;
use axum::http::request::Parts;
use axum::http::{Extensions, StatusCode};
use sha2::{Digest, Sha256};

use super::auth::Scope;
use super::problem::ApiError;
use super::AppState;

/// The owner id of a token secret: the first 16 hex digits of its SHA-256.
pub fn owner_id(secret: &[u8]) -> String {
    hex::encode(&Sha256::digest(secret)[..8])
}

/// The authenticated caller: scope and owner id (`None` when authentication is off).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Caller {
    /// What the caller may do.
    pub scope: Scope,
    /// The caller's owner id.
    pub owner: Option<String>,
}

impl Caller {
    /// Whether the caller may cancel or delete a job submitted by `job_owner`.
    pub fn may_manage(&self, job_owner: Option<&str>) -> bool {
        self.owner.is_none()
            || self.scope == Scope::Admin
            || (job_owner.is_some() && job_owner == self.owner.as_deref())
    }

    /// The 403 for a job this caller may not manage.
    pub fn not_owner(&self) -> ApiError {
        ApiError::new(
            StatusCode::FORBIDDEN,
            "not-job-owner",
            "Not the job's owner",
            "this job was submitted with another token; a submit token manages only its own jobs (an admin token manages all)",
        )
        .field("Authorization")
    }

    /// The stored form of a client's Idempotency-Key: `<owner>/<key>` with authentication on.
    pub fn idempotency_key(&self, key: String) -> String {
        match &self.owner {
            Some(owner) => format!("{owner}/{key}"),
            None => key,
        }
    }
}

/// The caller recorded in `extensions` by the middleware; without one, the caller is open when
/// authentication is off and may only read when it is on (a route the middleware skipped).
pub fn caller_of(extensions: &Extensions, state: &AppState) -> Caller {
    extensions.get::<Caller>().cloned().unwrap_or(Caller {
        scope: if state.config.tokens.is_empty() {
            Scope::Admin
        } else {
            Scope::Read
        },
        owner: None,
    })
}

impl FromRequestParts<AppState> for Caller {
    type Rejection = std::convert::Infallible;

    async fn from_request_parts(
        parts: &mut Parts,
        state: &AppState,
    ) -> Result<Self, Self::Rejection> {
        Ok(caller_of(&parts.extensions, state))
    }
}

#[cfg(test)]
mod tests {
    use super::{owner_id, Caller, Scope};

    #[test]
    fn owners_manage_their_own_jobs_and_admins_all() {
        let a = owner_id(b"farm-a-secret");
        assert_eq!(a.len(), 16);
        assert_ne!(a, owner_id(b"farm-b-secret"));
        let farm_a = Caller {
            scope: Scope::Submit,
            owner: Some(a.clone()),
        };
        assert!(farm_a.may_manage(Some(&a)));
        assert!(!farm_a.may_manage(Some(&owner_id(b"farm-b-secret"))));
        assert!(!farm_a.may_manage(None));
        let admin = Caller {
            scope: Scope::Admin,
            owner: Some(owner_id(b"ops")),
        };
        assert!(admin.may_manage(Some(&a)) && admin.may_manage(None));
        let open = Caller {
            scope: Scope::Admin,
            owner: None,
        };
        assert!(open.may_manage(Some(&a)));
        assert_eq!(farm_a.idempotency_key("k".into()), format!("{a}/k"));
        assert_eq!(open.idempotency_key("k".into()), "k");
    }
}
