//! Tokens and roles from the daemon's auth file, and the check every API handler makes.
//!
//! ```toml
//! [[token]]
//! name = "ada"          # who: shown as the owner of the runs the token starts
//! token = "…"           # at least 8 characters; unique
//! role = "operator"     # viewer (read) | operator (run control) | admin (device control, calibration)
//! ```
//! Requests carry `Authorization: Bearer <token>`; GET requests may instead pass
//! `?access_token=<token>` because browsers' EventSource and `<img>` cannot set headers.

use std::collections::HashMap;
use std::fmt;

use axum::http::{header, HeaderMap, Method, StatusCode, Uri};
use serde::Deserialize;

use crate::problem::Problem;

/// What a token may do; each role includes the ones before it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Deserialize, serde::Serialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum Role {
    /// Read status, runs, events, previews, datasets.
    Viewer,
    /// Also start, pause, resume and abort runs.
    Operator,
    /// Also device control and calibrations, and control of anyone's run.
    Admin,
}

impl fmt::Display for Role {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Role::Viewer => "viewer",
            Role::Operator => "operator",
            Role::Admin => "admin",
        })
    }
}

/// Who made a request.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Caller {
    /// The token's name.
    pub name: String,
    /// The token's role.
    pub role: Role,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct AuthFile {
    token: Vec<TokenEntry>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct TokenEntry {
    name: String,
    token: String,
    role: Role,
}

/// Shortest token accepted.
pub const MIN_TOKEN_LEN: usize = 8;

/// The tokens the daemon accepts.
#[derive(Clone)]
pub struct Auth {
    tokens: HashMap<String, Caller>,
}

impl fmt::Debug for Auth {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        // Never print the secrets.
        f.debug_struct("Auth").field("tokens", &self.tokens.len()).finish()
    }
}

impl Auth {
    /// Parses an auth file; `origin` names it in errors.
    pub fn from_toml(text: &str, origin: &str) -> Result<Auth, String> {
        let file: AuthFile = toml::from_str(text).map_err(|e| {
            format!("{origin}: {}; expected [[token]] tables with name, token and role = \"viewer\" | \"operator\" | \"admin\"", e.message())
        })?;
        let mut tokens = HashMap::new();
        for (i, t) in file.token.into_iter().enumerate() {
            let what = format!("{origin}: token {} ({:?})", i + 1, t.name);
            if t.name.trim().is_empty() {
                return Err(format!("{what}: name is empty; give the person or script a name"));
            }
            if t.token.len() < MIN_TOKEN_LEN || t.token.chars().any(|c| c.is_whitespace() || c.is_control()) {
                return Err(format!(
                    "{what}: a token needs at least {MIN_TOKEN_LEN} characters and no spaces or control characters"
                ));
            }
            if tokens.insert(t.token, Caller { name: t.name, role: t.role }).is_some() {
                return Err(format!("{what}: the same token is given twice; every token must be unique"));
            }
        }
        if tokens.is_empty() {
            return Err(format!("{origin}: no [[token]]: nobody could use the daemon"));
        }
        Ok(Auth { tokens })
    }

    /// One admin token named `name`, random, for a daemon started without an auth file.
    pub fn generated(name: &str) -> (Auth, String) {
        use rand::Rng;
        let mut rng = rand::rngs::OsRng;
        let token: String = (0..32).map(|_| format!("{:x}", rng.gen_range(0..16u8))).collect();
        let mut tokens = HashMap::new();
        tokens.insert(token.clone(), Caller { name: name.into(), role: Role::Admin });
        (Auth { tokens }, token)
    }

    /// Who sent the request, if they may do what needs `needed`: 401 without a known token,
    /// 403 when the token's role is below `needed`.
    pub fn check(&self, method: &Method, uri: &Uri, headers: &HeaderMap, needed: Role) -> Result<Caller, Problem> {
        let token = bearer(headers).or_else(|| (method == Method::GET).then(|| query_token(uri)).flatten());
        let Some(token) = token else {
            return Err(Problem::new(
                StatusCode::UNAUTHORIZED,
                "no token: send Authorization: Bearer <token> (GET requests may use ?access_token=<token>)",
            ));
        };
        let caller = self.find(&token).ok_or_else(|| {
            Problem::new(StatusCode::UNAUTHORIZED, "unknown token: it is not in the daemon's auth file")
        })?;
        if caller.role < needed {
            return Err(Problem::new(
                StatusCode::FORBIDDEN,
                format!("{} has role {}; this needs role {needed} or above", caller.name, caller.role),
            ));
        }
        Ok(caller)
    }

    /// Compares against every token in constant time per token, so response times do not
    /// tell how much of a guess was right.
    fn find(&self, token: &str) -> Option<Caller> {
        let mut found = None;
        for (t, c) in &self.tokens {
            if constant_time_eq(t.as_bytes(), token.as_bytes()) {
                found = Some(c.clone());
            }
        }
        found
    }
}

fn constant_time_eq(a: &[u8], b: &[u8]) -> bool {
    if a.len() != b.len() {
        return false;
    }
    a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

fn bearer(headers: &HeaderMap) -> Option<String> {
    let v = headers.get(header::AUTHORIZATION)?.to_str().ok()?;
    let (scheme, token) = v.split_once(' ')?;
    scheme.eq_ignore_ascii_case("bearer").then(|| token.trim().to_string())
}

fn query_token(uri: &Uri) -> Option<String> {
    uri.query()?.split('&').find_map(|kv| {
        let (k, v) = kv.split_once('=')?;
        (k == "access_token").then(|| v.to_string())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const FILE: &str = r#"
[[token]]
name = "viewer"
token = "viewer-token"
role = "viewer"
[[token]]
name = "ada"
token = "operator-token"
role = "operator"
"#;

    fn headers(v: &str) -> HeaderMap {
        let mut h = HeaderMap::new();
        h.insert(header::AUTHORIZATION, v.parse().unwrap());
        h
    }

    #[test]
    fn roles_order_and_statuses() {
        let a = Auth::from_toml(FILE, "auth.toml").unwrap();
        let uri: Uri = "/api/v1/runs".parse().unwrap();
        let op = a.check(&Method::POST, &uri, &headers("Bearer operator-token"), Role::Operator).unwrap();
        assert_eq!(op.name, "ada");
        let e = a.check(&Method::POST, &uri, &headers("Bearer viewer-token"), Role::Operator).unwrap_err();
        assert_eq!(e.status, 403);
        assert!(e.detail.contains("viewer has role viewer"), "{}", e.detail);
        assert_eq!(a.check(&Method::POST, &uri, &HeaderMap::new(), Role::Viewer).unwrap_err().status, 401);
        assert_eq!(
            a.check(&Method::POST, &uri, &headers("Bearer nope-nope-nope"), Role::Viewer).unwrap_err().status,
            401
        );
        assert_eq!(
            a.check(&Method::POST, &uri, &headers("Basic operator-token"), Role::Viewer).unwrap_err().status,
            401
        );
        // The query token works for GET only.
        let q: Uri = "/api/v1/preview?access_token=viewer-token".parse().unwrap();
        assert!(a.check(&Method::GET, &q, &HeaderMap::new(), Role::Viewer).is_ok());
        assert_eq!(a.check(&Method::POST, &q, &HeaderMap::new(), Role::Viewer).unwrap_err().status, 401);
    }

    #[test]
    fn bad_files_say_what_is_wrong() {
        let short = "[[token]]\nname = \"a\"\ntoken = \"short\"\nrole = \"admin\"\n";
        assert!(Auth::from_toml(short, "f").unwrap_err().contains("at least 8 characters"));
        let role = "[[token]]\nname = \"a\"\ntoken = \"long-enough\"\nrole = \"root\"\n";
        assert!(
            Auth::from_toml(role, "f").unwrap_err().contains("viewer"),
            "{}",
            Auth::from_toml(role, "f").unwrap_err()
        );
        let twice = short.replace("short", "same-token-1").repeat(2);
        assert!(Auth::from_toml(&twice, "f").unwrap_err().contains("unique"));
        assert!(Auth::from_toml("token = []", "f").unwrap_err().contains("no [[token]]"));
    }
}
