//! The difficulty levels a session is recorded and graded at. The atlas' `[difficulty.*]` presets
//! give each level its aids, the rubrics give each level its rules; session headers, the API, the
//! store and rubric files write a level as its lowercase name.

use serde::{Deserialize, Serialize};

use crate::manifest::{DifficultyPreset, DifficultyPresets};

/// A difficulty level, easiest first (the order sorts and lists them).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Difficulty {
    Beginner,
    Advanced,
    Expert,
}

impl Difficulty {
    /// Every level, easiest first.
    pub const ALL: [Difficulty; 3] = [Difficulty::Beginner, Difficulty::Advanced, Difficulty::Expert];

    /// The level's name as files and the API write it.
    pub const fn as_str(self) -> &'static str {
        match self {
            Difficulty::Beginner => "beginner",
            Difficulty::Advanced => "advanced",
            Difficulty::Expert => "expert",
        }
    }

    /// The names of every level, easiest first, for messages: "beginner, advanced, expert".
    pub fn names() -> String {
        Difficulty::ALL.map(Difficulty::as_str).join(", ")
    }
}

impl std::fmt::Display for Difficulty {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.pad(self.as_str())
    }
}

/// A name that is not a difficulty level (the names are case-sensitive).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown difficulty '{name}' ({})", Difficulty::names())]
pub struct UnknownDifficulty {
    pub name: String,
}

impl std::str::FromStr for Difficulty {
    type Err = UnknownDifficulty;

    fn from_str(s: &str) -> Result<Difficulty, UnknownDifficulty> {
        Difficulty::ALL
            .into_iter()
            .find(|d| d.as_str() == s)
            .ok_or_else(|| UnknownDifficulty { name: s.to_string() })
    }
}

impl DifficultyPresets {
    /// The aids of `level`.
    pub fn of(&self, level: Difficulty) -> &DifficultyPreset {
        match level {
            Difficulty::Beginner => &self.beginner,
            Difficulty::Advanced => &self.advanced,
            Difficulty::Expert => &self.expert,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn levels_by_name() {
        for d in Difficulty::ALL {
            assert_eq!(d.as_str().parse::<Difficulty>(), Ok(d));
            assert_eq!(serde_json::to_value(d).unwrap(), d.as_str());
            assert_eq!(d.to_string(), d.as_str());
            assert_eq!(format!("{d:<9}|"), format!("{:<9}|", d.as_str()));
        }
        let e = "Expert".parse::<Difficulty>().unwrap_err();
        assert_eq!(
            e.to_string(),
            "unknown difficulty 'Expert' (beginner, advanced, expert)"
        );
        assert!(Difficulty::Beginner < Difficulty::Advanced && Difficulty::Advanced < Difficulty::Expert);
    }
}
