//! The tool's signing key: RSA 2048, made on first use and kept in the database (so every replica
//! signs with it), published at `/lti/jwks` under its key id. Platforms check deep linking
//! responses and grade-service token requests with it (IMS Security Framework 1.0 §6).

use jsonwebtoken::jwk::{Jwk, JwkSet, KeyAlgorithm, PublicKeyUse};
use jsonwebtoken::{Algorithm, EncodingKey, Header};

use crate::store::{Store, StoreError};

/// The tool's key: to sign with, and its public half as a JWK.
pub struct ToolKey {
    pub kid: String,
    encoding: EncodingKey,
    pub jwk: Jwk,
}

/// Why the tool's key could not be had.
#[derive(Debug, thiserror::Error)]
pub enum ToolKeyError {
    #[error(transparent)]
    Store(#[from] StoreError),
    #[error("the tool's LTI key: {0}")]
    Key(String),
}

impl ToolKey {
    /// The key of a PKCS#8 PEM.
    pub fn from_pem(kid: &str, pem: &str) -> Result<ToolKey, ToolKeyError> {
        let encoding = EncodingKey::from_rsa_pem(pem.as_bytes()).map_err(|e| ToolKeyError::Key(e.to_string()))?;
        let mut jwk =
            Jwk::from_encoding_key(&encoding, Algorithm::RS256).map_err(|e| ToolKeyError::Key(e.to_string()))?;
        jwk.common.key_id = Some(kid.to_string());
        jwk.common.public_key_use = Some(PublicKeyUse::Signature);
        jwk.common.key_algorithm = Some(KeyAlgorithm::RS256);
        Ok(ToolKey {
            kid: kid.to_string(),
            encoding,
            jwk,
        })
    }

    /// `claims` signed (RS256, this key's `kid` in the header).
    pub fn sign(&self, claims: &serde_json::Value) -> Result<String, ToolKeyError> {
        let mut header = Header::new(Algorithm::RS256);
        header.kid = Some(self.kid.clone());
        jsonwebtoken::encode(&header, claims, &self.encoding).map_err(|e| ToolKeyError::Key(e.to_string()))
    }

    /// The key set `/lti/jwks` serves.
    pub fn key_set(&self) -> JwkSet {
        JwkSet {
            keys: vec![self.jwk.clone()],
        }
    }
}

/// A new RSA 2048 key as PKCS#8 PEM.
pub fn new_pem() -> Result<String, ToolKeyError> {
    use aws_lc_rs::encoding::AsDer as _;
    use base64::Engine as _;
    let pair = aws_lc_rs::rsa::KeyPair::generate(aws_lc_rs::rsa::KeySize::Rsa2048)
        .map_err(|e| ToolKeyError::Key(e.to_string()))?;
    let der = pair.as_der().map_err(|e| ToolKeyError::Key(e.to_string()))?;
    let b64 = base64::engine::general_purpose::STANDARD.encode(der.as_ref());
    let mut pem = String::from("-----BEGIN PRIVATE KEY-----\n");
    for chunk in b64.as_bytes().chunks(64) {
        pem.push_str(std::str::from_utf8(chunk).expect("base64 is ASCII"));
        pem.push('\n');
    }
    pem.push_str("-----END PRIVATE KEY-----\n");
    Ok(pem)
}

/// The tool's key, made and stored on first use. Two replicas making one at once both insert;
/// both then use the oldest.
pub async fn load_or_create(store: &Store) -> Result<ToolKey, ToolKeyError> {
    if let Some((kid, pem)) = store.lti_tool_key().await? {
        return ToolKey::from_pem(&kid, &pem);
    }
    let pem = tokio::task::spawn_blocking(new_pem)
        .await
        .map_err(|e| ToolKeyError::Key(e.to_string()))??;
    let kid = format!("stylet-{}", &crate::auth::sha256_hex(&pem)[..16]);
    store.insert_lti_tool_key(&kid, &pem).await?;
    let (kid, pem) = store
        .lti_tool_key()
        .await?
        .ok_or_else(|| ToolKeyError::Key("the key just stored is not there".into()))?;
    ToolKey::from_pem(&kid, &pem)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_new_key_signs_what_its_public_half_verifies() {
        let key = ToolKey::from_pem("k1", &new_pem().unwrap()).unwrap();
        let token = key
            .sign(&serde_json::json!({"iss": "stylet", "exp": 4_000_000_000u64}))
            .unwrap();
        let decoding = jsonwebtoken::DecodingKey::from_jwk(&key.key_set().keys[0]).unwrap();
        let mut v = jsonwebtoken::Validation::new(Algorithm::RS256);
        v.set_required_spec_claims(&["exp"]);
        let data = jsonwebtoken::decode::<serde_json::Value>(&token, &decoding, &v).unwrap();
        assert_eq!(data.header.kid.as_deref(), Some("k1"));
        assert_eq!(data.claims["iss"], "stylet");
        // Another key's public half does not verify it.
        let other = ToolKey::from_pem("k2", &new_pem().unwrap()).unwrap();
        let wrong = jsonwebtoken::DecodingKey::from_jwk(&other.key_set().keys[0]).unwrap();
        assert!(jsonwebtoken::decode::<serde_json::Value>(&token, &wrong, &v).is_err());
    }
}
