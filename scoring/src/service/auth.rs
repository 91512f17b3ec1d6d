//! Passwords (argon2id), login and API tokens (random, stored only as SHA-256), cookies.

use argon2::Argon2;
use argon2::password_hash::{PasswordHash, PasswordHasher, PasswordVerifier, SaltString, rand_core::OsRng};
use sha2::{Digest, Sha256};

/// A valid hash of a random password: checked against when the username does not exist, so that
/// the answer takes as long either way.
pub const DUMMY_HASH: &str =
    "$argon2id$v=19$m=19456,t=2,p=1$c3R5bGV0ZHVtbXlzYWx0$hGfBqV7k3m7KdbNn1qM4bCkz2m9s2nBg4d6CrUuVDTs";

pub fn hash_password(password: &str) -> Result<String, String> {
    let salt = SaltString::generate(&mut OsRng);
    Argon2::default()
        .hash_password(password.as_bytes(), &salt)
        .map(|h| h.to_string())
        .map_err(|e| e.to_string())
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

/// Whether the browser says this request was sent by a page of another site (`Sec-Fetch-Site:
/// cross-site` or `same-site`). Logins check it: they have no CSRF token to check yet, and a
/// cross-site login would put the browser into an account of the other site's choosing (login
/// CSRF). Clients that send no such header (scripts, the desktop app) are not browsers being
/// abused and are let through.
pub fn from_other_site(headers: &axum::http::HeaderMap) -> bool {
    matches!(
        headers.get("sec-fetch-site").and_then(|h| h.to_str().ok()),
        Some("cross-site") | Some("same-site")
    )
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
}
