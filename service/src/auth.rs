//! Passwords (argon2id), login and API tokens (random, stored only as SHA-256), cookies.

use argon2::Argon2;
use argon2::password_hash::{PasswordHash, PasswordHasher, PasswordVerifier, SaltString, rand_core::OsRng};
use sha2::{Digest, Sha256};

/// A valid hash of a random password: checked against when the username does not exist, so that
/// the answer takes as long either way.
pub const DUMMY_HASH: &str =
    "$argon2id$v=19$m=19456,t=2,p=1$c3R5bGV0ZHVtbXlzYWx0$hGfBqV7k3m7KdbNn1qM4bCkz2m9s2nBg4d6CrUuVDTs";

/// The argon2id hash of `password` (PHC string) with a random salt; argon2's error if hashing
/// fails (a password longer than argon2 takes, or memory it cannot have).
pub fn hash_password(password: &str) -> Result<String, argon2::password_hash::Error> {
    let salt = SaltString::generate(&mut OsRng);
    Argon2::default()
        .hash_password(password.as_bytes(), &salt)
        .map(|h| h.to_string())
}

pub fn verify_password(password: &str, hash: &str) -> bool {
    PasswordHash::new(hash).is_ok_and(|h| Argon2::default().verify_password(password.as_bytes(), &h).is_ok())
}

/// 32 random bytes, hex.
pub fn random_token() -> String {
    use argon2::password_hash::rand_core::RngCore;
    let mut b = [0u8; 32];
    OsRng.fill_bytes(&mut b);
    b.iter().map(|x| format!("{x:02x}")).collect()
}

pub fn sha256_hex(data: impl AsRef<[u8]>) -> String {
    Sha256::digest(data.as_ref())
        .iter()
        .map(|x| format!("{x:02x}"))
        .collect()
}

/// The login cookie's name.
pub const COOKIE: &str = "stylet_session";

/// The `Set-Cookie` value of a login: HttpOnly, SameSite=Strict, Secure behind TLS.
pub fn login_cookie(token: &str, secure: bool, max_age_s: u64) -> String {
    format!(
        "{COOKIE}={token}; Path=/; HttpOnly; SameSite=Strict; Max-Age={max_age_s}{}",
        if secure { "; Secure" } else { "" }
    )
}

pub fn logout_cookie(secure: bool) -> String {
    login_cookie("", secure, 0)
}

/// Whether a login was sent by a page of another site. Logins check it: they have no CSRF token
/// to check yet, and a cross-site login would put the browser into an account of the other
/// site's choosing (login CSRF). Refused:
/// - `Sec-Fetch-Site: cross-site` or `same-site` (the browser says so);
/// - an `Origin` that is not this server: its host and port must be the `Host` header's (the
///   scheme is left out: behind a TLS proxy the browser's scheme is not this server's);
///   `Origin: null` (sandboxed frames, `file:` pages) is refused too. Browsers without
///   `Sec-Fetch-Site` still send `Origin` with a cross-site POST;
/// - no `Origin` but a `Referer` whose host and port are not the `Host` header's.
///
/// Clients that send none of these (scripts, the desktop app) are not browsers being abused and
/// are let through. A reverse proxy must pass the browser's `Host` on.
pub fn from_other_site(headers: &axum::http::HeaderMap) -> bool {
    use axum::http::header;
    if matches!(
        headers.get("sec-fetch-site").and_then(|h| h.to_str().ok()),
        Some("cross-site") | Some("same-site")
    ) {
        return true;
    }
    let host = headers.get(header::HOST).and_then(|h| h.to_str().ok());
    let this_server = |url: &axum::http::HeaderValue| {
        let url = url.to_str().ok().and_then(scheme_and_authority);
        matches!((url, host), (Some((scheme, authority)), Some(host)) if same_authority(scheme, authority, host))
    };
    match (headers.get(header::ORIGIN), headers.get(header::REFERER)) {
        (Some(origin), _) => !this_server(origin),
        (None, Some(referer)) => !this_server(referer),
        (None, None) => false,
    }
}

/// `scheme://[user@]host[:port][/…]` → (scheme, `host[:port]`); None for anything else (`null`,
/// a relative reference).
fn scheme_and_authority(url: &str) -> Option<(&str, &str)> {
    let (scheme, rest) = url.trim().split_once("://")?;
    let scheme_ok = scheme.starts_with(|c: char| c.is_ascii_alphabetic())
        && scheme.chars().all(|c| c.is_ascii_alphanumeric() || "+-.".contains(c));
    let authority = &rest[..rest.find(['/', '?', '#']).unwrap_or(rest.len())];
    let authority = authority.rsplit_once('@').map_or(authority, |(_, a)| a);
    (scheme_ok && !authority.is_empty()).then_some((scheme, authority))
}

/// Whether `authority` (of a URL with `scheme`) is `host` (a `Host` header): names compared
/// without case, the scheme's default port (http 80, https 443) written or not.
fn same_authority(scheme: &str, authority: &str, host: &str) -> bool {
    let default_port = match scheme.to_ascii_lowercase().as_str() {
        "http" => Some(":80"),
        "https" => Some(":443"),
        _ => None,
    };
    let normal = |a: &str| {
        let a = a.trim().to_ascii_lowercase();
        match default_port {
            Some(p) if a.ends_with(p) => a[..a.len() - p.len()].to_string(),
            _ => a,
        }
    };
    normal(authority) == normal(host)
}

/// The login token in a `Cookie` header.
pub fn token_from_cookie_header(header: &str) -> Option<&str> {
    header
        .split(';')
        .map(str::trim)
        .find_map(|kv| kv.strip_prefix(COOKIE)?.strip_prefix('='))
        .filter(|t| !t.is_empty())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn passwords_round_trip_and_cookies_parse() {
        let h = hash_password("correct horse").unwrap();
        assert!(h.starts_with("$argon2id$"));
        assert!(verify_password("correct horse", &h));
        assert!(!verify_password("wrong horse", &h));
        assert!(!verify_password("x", "not a hash"));
        assert!(PasswordHash::new(DUMMY_HASH).is_ok());
        assert_eq!(token_from_cookie_header("a=1; stylet_session=abc; b=2"), Some("abc"));
        assert_eq!(token_from_cookie_header("stylet_session="), None);
        assert!(login_cookie("t", true, 60).contains("HttpOnly; SameSite=Strict; Max-Age=60; Secure"));
        assert_ne!(random_token(), random_token());
    }

    fn headers(pairs: &[(&'static str, &str)]) -> axum::http::HeaderMap {
        let mut h = axum::http::HeaderMap::new();
        for (k, v) in pairs {
            h.insert(*k, v.parse().unwrap());
        }
        h
    }

    #[test]
    fn logins_from_other_origins_are_refused() {
        let host = ("host", "127.0.0.1:8080");
        // Scripts and the desktop app send none of the browser's headers.
        assert!(!from_other_site(&headers(&[host])));
        assert!(!from_other_site(&headers(&[])));
        // This server's own pages.
        for same in [
            "http://127.0.0.1:8080",
            "https://127.0.0.1:8080",
            "HTTP://127.0.0.1:8080",
        ] {
            assert!(!from_other_site(&headers(&[host, ("origin", same)])), "{same}");
        }
        assert!(!from_other_site(&headers(&[
            host,
            ("referer", "http://127.0.0.1:8080/login?next=%2F")
        ])));
        assert!(!from_other_site(&headers(&[
            ("host", "Stylet.Example"),
            ("origin", "https://stylet.example")
        ])));
        assert!(!from_other_site(&headers(&[
            ("host", "stylet.example:443"),
            ("origin", "https://stylet.example")
        ])));
        assert!(!from_other_site(&headers(&[
            ("host", "stylet.example"),
            ("origin", "http://stylet.example:80")
        ])));
        // Other sites, with no Sec-Fetch-Site (older browsers, or one that leaves it out).
        for other in [
            "http://evil.example",
            "null",
            "http://127.0.0.1:8081",
            "http://127.0.0.1",
            "http://127.0.0.1:8080.evil.example",
            "http://evil.example/http://127.0.0.1:8080",
            "127.0.0.1:8080",
            "",
        ] {
            assert!(from_other_site(&headers(&[host, ("origin", other)])), "origin {other}");
        }
        for other in [
            "http://evil.example/login",
            "https://evil.example/?u=http://127.0.0.1:8080/",
            "http://127.0.0.1:8080@evil.example/",
            "/login",
        ] {
            assert!(
                from_other_site(&headers(&[host, ("referer", other)])),
                "referer {other}"
            );
        }
        // Origin wins over Referer, both ways; without a Host nothing can match.
        assert!(from_other_site(&headers(&[
            host,
            ("origin", "http://evil.example"),
            ("referer", "http://127.0.0.1:8080/")
        ])));
        assert!(!from_other_site(&headers(&[
            host,
            ("origin", "http://127.0.0.1:8080"),
            ("referer", "http://evil.example/")
        ])));
        assert!(from_other_site(&headers(&[("origin", "http://127.0.0.1:8080")])));
        // What the browser says about itself still counts, also beside a matching Origin.
        assert!(from_other_site(&headers(&[
            host,
            ("origin", "http://127.0.0.1:8080"),
            ("sec-fetch-site", "cross-site")
        ])));
        assert!(from_other_site(&headers(&[
            host,
            ("origin", "http://evil.example"),
            ("sec-fetch-site", "same-origin")
        ])));
    }
}
