//! Stylet scoring: the grade comes from physics, not from what a client claims. [`replay`](mod@replay) re-runs
//! a session file's recorded inputs through `stylet_physics` and checks every recorded output and
//! state digest bit for bit; [`metrics`] measures the replayed session (docs/metrics.md);
//! [`rubric`] turns metrics into a grade per difficulty; [`score`] ties them together for one file
//! or a batch; [`trace`] keeps what the dashboard draws of a replay. The HTTP service is the crate
//! `stylet-service`.

pub mod benchmark;
pub mod consequences;
pub mod drainage;
pub mod live_guidance;
pub mod metric_words;
pub mod metrics;
pub mod needle_motion;
pub mod probe_view;
pub mod reasons;
pub mod replay;
pub mod rubric;
pub mod rubric_metrics;
pub mod score;
pub mod smoke;
pub mod target;
pub mod tip_path;
pub mod trace;

pub use benchmark::Benchmark;
pub use metric_words::{MetricInfo, metric_label};
pub use metrics::{MetricParams, Metrics, PalpationMetrics, RiskHit, UltrasoundMetrics};
pub use reasons::{Outcome, reasons};
pub use replay::{Divergence, ReplayError, ReplayReport, Replayer, StepToError, replay};
pub use rubric::{Difficulty, Grade, GradeError, Rubric, RubricError, UnknownDifficulty, Unmet};
pub use score::{ScoreError, ScoreReport, Scorer, ScorerError};
pub use stylet_atlas::Exercise;
pub use trace::{ReviewTrace, TraceEvent};
