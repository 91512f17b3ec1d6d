//! The query of the routes that list, summarise and export sessions (the API's and the
//! dashboard's): the filters a caller may send and the store filter they become.

use axum::http::StatusCode;
use stylet_scoring::Difficulty;

use super::AppState;
use super::error::{ApiError, err};
use super::store::SessionFilter;

/// The query of list, summary and export routes: `?from=YYYY-MM-DD&to=YYYY-MM-DD&scenario=…&
/// difficulty=…&cohort=…&trainee=…&page=N` (all optional; `to` inclusive).
#[derive(Debug, Default, serde::Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
pub struct ListQuery {
    pub from: Option<String>,
    pub to: Option<String>,
    pub scenario: Option<String>,
    pub difficulty: Option<String>,
    pub cohort: Option<String>,
    pub trainee: Option<String>,
    pub page: Option<i64>,
}

impl ListQuery {
    /// The store filter, or 400 with what is wrong. Unknown cohorts and trainees match nothing.
    pub async fn filter(&self, s: &AppState) -> Result<SessionFilter, ApiError> {
        let blank = |v: &Option<String>| {
            v.as_deref()
                .map(str::trim)
                .filter(|v| !v.is_empty())
                .map(str::to_string)
        };
        let mut f = SessionFilter {
            scenario: blank(&self.scenario),
            difficulty: None,
            uploaded_from: blank(&self.from).map(|d| day_start(&d, 0)).transpose()?,
            uploaded_before: blank(&self.to).map(|d| day_start(&d, 1)).transpose()?,
            offset: (self.page.unwrap_or(1).max(1) - 1).saturating_mul(PAGE_SIZE),
            limit: PAGE_SIZE,
            ..Default::default()
        };
        f.difficulty = blank(&self.difficulty)
            .map(|d| d.parse::<Difficulty>())
            .transpose()
            .map_err(|e| ApiError::Invalid(e.to_string()))?;
        // A cohort or trainee that does not exist filters out everything, exactly like one the
        // caller may not see (the lists are narrowed to what the caller may see): the answer
        // does not tell which names exist.
        if let Some(c) = blank(&self.cohort) {
            f.cohort_id = Some(s.store.cohort_id(&c).await?.unwrap_or_default());
        }
        if let Some(t) = blank(&self.trainee) {
            f.trainee_id = Some(s.store.user_by_name(&t).await?.map(|u| u.id).unwrap_or_default());
        }
        Ok(f)
    }
}

/// Sessions per page of a list.
pub const PAGE_SIZE: i64 = 100;

/// `YYYY-MM-DD` (+ `days`) as the RFC 3339 start of that UTC day, or 400.
fn day_start(date: &str, days: u64) -> Result<String, ApiError> {
    let bad = || err(StatusCode::BAD_REQUEST, format!("'{date}' is not a date (YYYY-MM-DD)"));
    if date.len() != 10 {
        return Err(bad());
    }
    let t = humantime::parse_rfc3339(&format!("{date}T00:00:00Z")).map_err(|_| bad())?;
    let day = t + std::time::Duration::from_secs(86_400 * days);
    // humantime cannot write years past 9999 (the day after 9999-12-31).
    let mut out = String::new();
    std::fmt::write(&mut out, format_args!("{}", humantime::format_rfc3339_micros(day)))
        .map_err(|_| err(StatusCode::BAD_REQUEST, format!("'{date}' is out of range")))?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dates_in_filters_are_days_or_400() {
        assert_eq!(day_start("2026-11-23", 0).unwrap(), "2026-11-23T00:00:00.000000Z");
        assert_eq!(day_start("2026-12-31", 1).unwrap(), "2027-01-01T00:00:00.000000Z");
        for bad in ["2026-13-01", "23.11.2026", "2026-11-23T00", ""] {
            assert_eq!(
                day_start(bad, 0).unwrap_err().status(),
                StatusCode::BAD_REQUEST,
                "{bad}"
            );
        }
        // The day after the last day humantime can write: a 400, not a panic.
        let e = day_start("9999-12-31", 1).unwrap_err();
        assert_eq!(e.status(), StatusCode::BAD_REQUEST);
        assert!(e.message().contains("out of range"), "{e}");
    }
}
