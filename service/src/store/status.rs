//! A session's scoring status, stored as text in `sessions.status` (checked by the schema).

/// Where a session is on its way to a score.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum SessionStatus {
    /// Uploaded, waiting for a worker.
    Queued,
    /// A worker is replaying it.
    Scoring,
    /// Replayed and graded (the grade may still be "not gradeable").
    Scored,
    /// The replay could not be done (`sessions.error` says why).
    Failed,
}

impl SessionStatus {
    pub const ALL: [SessionStatus; 4] = [
        SessionStatus::Queued,
        SessionStatus::Scoring,
        SessionStatus::Scored,
        SessionStatus::Failed,
    ];

    pub const fn as_str(self) -> &'static str {
        match self {
            SessionStatus::Queued => "queued",
            SessionStatus::Scoring => "scoring",
            SessionStatus::Scored => "scored",
            SessionStatus::Failed => "failed",
        }
    }

    pub fn parse(name: &str) -> Option<SessionStatus> {
        SessionStatus::ALL.into_iter().find(|s| s.as_str() == name)
    }

    /// Whether it will not change any more (scored or failed).
    pub fn is_final(self) -> bool {
        matches!(self, SessionStatus::Scored | SessionStatus::Failed)
    }
}

impl std::fmt::Display for SessionStatus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl sqlx::Type<sqlx::Any> for SessionStatus {
    fn type_info() -> sqlx::any::AnyTypeInfo {
        <String as sqlx::Type<sqlx::Any>>::type_info()
    }
}

impl<'r> sqlx::Decode<'r, sqlx::Any> for SessionStatus {
    fn decode(value: sqlx::any::AnyValueRef<'r>) -> Result<Self, sqlx::error::BoxDynError> {
        let name = <String as sqlx::Decode<sqlx::Any>>::decode(value)?;
        SessionStatus::parse(&name).ok_or_else(|| format!("unknown session status '{name}'").into())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn statuses_by_name() {
        for s in SessionStatus::ALL {
            assert_eq!(SessionStatus::parse(s.as_str()), Some(s));
            assert_eq!(serde_json::to_value(s).unwrap(), s.as_str());
        }
        assert_eq!(SessionStatus::parse("done"), None);
        assert!(SessionStatus::Scored.is_final() && !SessionStatus::Queued.is_final());
    }
}
