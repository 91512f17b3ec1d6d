//! `atlas.toml`: the description of an atlas directory (format in `docs/atlas.md`).
//!
//! Parsing is strict (unknown keys are errors) so a typo cannot silently drop a parameter. The
//! scenario part (heuristic labels, label table, property tree, difficulty presets) can also live in
//! a file of its own, shared by several atlases: see [`ScenarioFile`].

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use stylet_physics::{
    ComplicationKind, HeuristicLabels, Label, LabelId, LabelTable, Param, ParamValue, PropertyTree, Role, Thresholds,
    TissueSpec,
};

/// The atlas format version this code reads and writes.
pub const FORMAT_VERSION: u32 = 1;

/// The manifest's file name inside an atlas directory.
pub const MANIFEST_FILE: &str = "atlas.toml";

/// Why an `atlas.toml`, a scenario file or a recipe's labels fail their checks: the section and
/// the value that is wrong, so the atlas author knows what to fix. The message is the one shown
/// after the file's path.
#[derive(Debug, thiserror::Error)]
pub enum ManifestError {
    /// Not TOML of the format: syntax, an unknown key, a wrong type or a `[render]` the parser
    /// refused (the parser's message).
    #[error("{0}")]
    Syntax(String),
    #[error("format_version {found} is not supported (this Stylet reads version {FORMAT_VERSION})")]
    UnsupportedVersion { found: u32 },
    #[error("name must not be empty")]
    EmptyName,
    /// `volumes.ct` or `volumes.labels` (`key`) names a file the loader must not open.
    #[error("{key} = {file:?}: {problem}")]
    VolumeFile {
        key: &'static str,
        file: String,
        problem: PathProblem,
    },
    #[error("volumes.ct and volumes.labels name the same file")]
    SameVolumeFile,
    /// A measured breathing file (`breathing.a1` …) that would leave the atlas folder.
    #[error("breathing.{key}: {problem}")]
    BreathingFile { key: &'static str, problem: PathProblem },
    /// A label whose consequence is not one line of 1–200 characters.
    #[error("label '{label}': a consequence is one line of 1–200 characters")]
    Consequence { label: String },
    #[error("label '{label}' has role '{role}'; expected one of target, risk, bone, organ, neutral")]
    UnknownRole { label: String, role: String },
    /// The labels do not form a valid label table (ids, heuristic labels, names).
    #[error(transparent)]
    LabelTable(stylet_physics::PhysicsError),
    /// `[tissues]` does not form a valid property tree (parents, cycles, parameters).
    #[error(transparent)]
    PropertyTree(stylet_physics::PhysicsError),
    /// A label's tissue lacks a material parameter the physics needs.
    #[error(transparent)]
    Materials(stylet_physics::PhysicsError),
    #[error("heuristic.risk_depth_mm must be a finite number ≥ 0, got {value}")]
    RiskDepth { value: f64 },
    /// `[thresholds]` out of order or not finite.
    #[error(transparent)]
    Thresholds(stylet_physics::PhysicsError),
    #[error("an insertion path has an empty name")]
    UnnamedPath,
    #[error("insertion path '{name}' is defined twice")]
    DuplicatePath { name: String },
    #[error("insertion path '{name}' has non-finite coordinates")]
    NonFinitePath { name: String },
    #[error("insertion path '{name}': entry and target are less than 1 mm apart")]
    ShortPath { name: String },
    /// A difficulty level (`level`) guided along a path the atlas does not plan.
    #[error("difficulty.{level}.guided_path = {path:?} names no insertion path")]
    UnknownGuidedPath { level: &'static str, path: String },
    #[error("scenario '{name}': a scenario name is 1–64 letters, digits or . _ - @")]
    ScenarioName { name: String },
    #[error("scenario '{name}' is declared twice")]
    DuplicateScenario { name: String },
    /// A scenario's C-arm set to what a C-arm cannot do.
    #[error("scenario '{scenario}': {error}")]
    ScenarioCArm { scenario: String, error: CArmError },
    /// A render preset (`preset`: skin, soft or bone) that cannot be drawn.
    #[error("render preset '{preset}': {error}")]
    RenderPreset { preset: &'static str, error: PresetError },
    #[error(
        "render.window: level_hu must be finite and width_hu a finite number > 0, got level {level_hu} width {width_hu}"
    )]
    RenderWindow { level_hu: f64, width_hu: f64 },
}

/// Why a file the manifest names may not be opened: the loader reads nothing outside the atlas
/// folder and only NIfTI volumes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum PathProblem {
    #[error("must be a plain file name inside the atlas directory")]
    NotPlainName,
    #[error("must be a NIfTI file (.nii or .nii.gz)")]
    NotNifti,
    #[error("must be a path inside the atlas directory (relative, without '..')")]
    OutsideAtlas,
}

/// A C-arm value outside what a C-arm can be set to: `field` is the key under `c_arm`
/// ("lao_deg", "window", …), `detail` the value and its allowed range.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("c_arm.{field} {detail}")]
pub struct CArmError {
    pub field: &'static str,
    pub detail: String,
}

/// Why a transfer-function preset cannot be drawn (`trapezoid` counts from 1).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PresetError {
    #[error("needs 1 … {MAX_PRESET_TRAPEZOIDS} trapezoids, has {count}")]
    TrapezoidCount { count: usize },
    #[error("trapezoid {trapezoid}: tissue must be a name of 1–64 characters")]
    TissueName { trapezoid: usize },
    /// A trapezoid's `field` (hu, rgb, opacity, weight) out of range; `detail` says how.
    #[error("trapezoid {trapezoid} ('{tissue}'): {field} {detail}")]
    Trapezoid {
        trapezoid: usize,
        tissue: String,
        field: &'static str,
        detail: String,
    },
    #[error("every trapezoid has weight or opacity 0: the preset would draw nothing")]
    DrawsNothing,
}

/// The whole `atlas.toml`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    pub format_version: u32,
    pub name: String,
    #[serde(default)]
    pub description: String,
    pub provenance: Provenance,
    pub volumes: Volumes,
    /// Heuristic thresholds; estimated from the CT histogram when absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub thresholds: Option<ThresholdsToml>,
    pub heuristic: HeuristicToml,
    pub labels: Vec<LabelToml>,
    pub tissues: BTreeMap<String, TissueToml>,
    pub difficulty: DifficultyPresets,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub paths: Vec<InsertionPath>,
    /// The exercises sessions on this atlas may be recorded for; the scoring service refuses
    /// uploads naming another. An atlas that declares none (written before scenarios were
    /// declared) accepts any well-formed name.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub scenarios: Vec<ScenarioToml>,
    /// Transfer-function presets and the slice window of the views (`stylet render`). An atlas
    /// written before presets existed has none; renderers then use the shipped PTCD presets.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub render: Option<RenderToml>,
    /// The breathing motion attached to the patient (docs/breathing.md "Atlases"). An atlas
    /// written before it existed has none and breathes with the default synthetic motion.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub breathing: Option<BreathingToml>,
}

/// What moves the patient when a session breathes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MotionKind {
    /// The synthetic motion built from the atlas' own maps (`stylet_physics::motion::synthetic`).
    Synthetic,
    /// Displacement fields measured on a 4D CT (`a1`, optionally `a2`, `a3`, and the surrogate
    /// `signal`), files beside `atlas.toml` (`stylet atlas attach-motion`).
    Measured,
    /// None: the patient does not breathe (built with `--no-breathing`, or no organ to place
    /// the diaphragm).
    None,
}

/// `[breathing]`: the attached motion; for the synthetic one its parameters (defaults and ranges
/// in docs/breathing.md), for measured fields their files (paths relative to the atlas
/// directory).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BreathingToml {
    pub motion: MotionKind,
    pub amplitude_mm: f64,
    pub anterior_ratio: f64,
    pub wall_mm: f64,
    pub bone_margin_mm: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub a1: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub a2: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub a3: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub signal: Option<String>,
}

impl Default for BreathingToml {
    fn default() -> Self {
        let m = stylet_physics::motion::SyntheticMotion::default();
        BreathingToml {
            motion: MotionKind::Synthetic,
            amplitude_mm: m.amplitude_mm,
            anterior_ratio: m.anterior_ratio,
            wall_mm: m.wall_mm,
            bone_margin_mm: m.bone_margin_mm,
            a1: None,
            a2: None,
            a3: None,
            signal: None,
        }
    }
}

impl BreathingToml {
    /// The default synthetic motion when `attached`, else none.
    pub fn attached(attached: bool) -> Self {
        BreathingToml {
            motion: if attached {
                MotionKind::Synthetic
            } else {
                MotionKind::None
            },
            ..Default::default()
        }
    }

    /// The measured motion's files, `a1` first (none for another motion).
    pub fn measured_files(&self) -> Vec<&str> {
        if self.motion != MotionKind::Measured {
            return Vec::new();
        }
        [&self.a1, &self.a2, &self.a3, &self.signal]
            .into_iter()
            .flatten()
            .map(String::as_str)
            .collect()
    }

    /// The synthetic motion's parameters; `None` for another motion.
    pub fn synthetic(&self) -> Option<stylet_physics::motion::SyntheticMotion> {
        (self.motion == MotionKind::Synthetic).then_some(stylet_physics::motion::SyntheticMotion {
            amplitude_mm: self.amplitude_mm,
            anterior_ratio: self.anterior_ratio,
            wall_mm: self.wall_mm,
            bone_margin_mm: self.bone_margin_mm,
        })
    }
}

/// A scenario (exercise) of an atlas: its name, as sessions record it, and what it asks for.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScenarioToml {
    pub name: String,
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub description: String,
    /// What the trainee practises, which decides the metrics and the rubric a session is graded
    /// with (a palpation is not a failed puncture). Absent: puncture.
    #[serde(default)]
    pub exercise: Exercise,
    /// Where the C-arm stands for this scenario's X-ray (docs/xray.md "Geometry"); absent: a
    /// posterior-anterior beam centred on the first planned path's target.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub c_arm: Option<CArmToml>,
    /// The breath hold the puncture should be made in when the patient breathes
    /// (docs/breathing.md "Scoring"); absent: end-expiration, the CT's phase.
    #[serde(default, skip_serializing_if = "HoldPhase::is_end_expiration")]
    pub hold_phase: HoldPhase,
    /// The patient breathes in this scenario's sessions on the desktop simulator, with the
    /// atlas' motion (docs/breathing.md "Sessions"); absent: still.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub breathes: bool,
    /// Who the scenario is for, when the file says (see [`ScenarioToml::kind`]). Read, never
    /// written: an atlas.toml, and with it the atlas' content hash that recorded sessions pin,
    /// stays as it was.
    #[serde(default, skip_serializing)]
    pub kind: Option<ScenarioKind>,
}

/// Who a scenario is for.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ScenarioKind {
    /// An exercise offered to trainees.
    #[default]
    Training,
    /// A scripted example or grading fixture (a risk hit, a second attempt, a survey done
    /// wrong): scripts, demos, tests and uploads may name it; the simulator's picker does not
    /// offer it to trainees.
    Example,
}

impl ScenarioToml {
    /// Who the scenario is for: as its file says, else as the shipped PTCD scenario file
    /// (atlases/ptcd.toml) says for a scenario of this name (atlases keep no kind, see `kind`),
    /// else training.
    pub fn kind(&self) -> ScenarioKind {
        static SHIPPED: std::sync::OnceLock<Vec<ScenarioToml>> = std::sync::OnceLock::new();
        self.kind
            .or_else(|| {
                SHIPPED
                    .get_or_init(|| ScenarioFile::ptcd().scenarios)
                    .iter()
                    .find(|s| s.name == self.name)
                    .and_then(|s| s.kind)
            })
            .unwrap_or_default()
    }
}

/// The correct breath hold of a scenario.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum HoldPhase {
    /// The CT's phase, where the plan holds: the usual hold for PTCD.
    #[default]
    EndExpiration,
    /// A deep breath in: lowers the liver below the lung's base for a high target.
    EndInspiration,
}

impl HoldPhase {
    fn is_end_expiration(&self) -> bool {
        *self == HoldPhase::EndExpiration
    }
}

/// `[scenarios.c_arm]`: the C-arm's cone-beam geometry and the X-ray display window. Every
/// field has a default (a typical interventional C-arm, posterior-anterior).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CArmToml {
    /// > 0 LAO (detector toward the patient's left), < 0 RAO, degrees.
    pub lao_deg: f64,
    /// > 0 cranial (detector toward the head), < 0 caudal, degrees.
    pub cranial_deg: f64,
    /// Focal spot to detector (SID), mm.
    pub source_to_detector_mm: f64,
    /// Focal spot to isocentre, mm.
    pub source_to_isocenter_mm: f64,
    /// Detector width and height, mm.
    pub detector_mm: [f64; 2],
    /// The point the central ray passes through (world mm); absent: the first planned path's
    /// target, else the CT's centre.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub isocenter_mm: Option<[f64; 3]>,
    /// The attenuation shown white and black (the log display's window).
    pub window: XrayWindowToml,
    /// Air kerma rate at the isocentre under fluoroscopy (mGy/min): with the beam's area there it
    /// gives the dose-area product estimate (docs/metrics.md).
    pub kerma_rate_mgy_per_min: f64,
}

/// The range of the line integral a = −ln(I/I₀) from white (`low`) to black (`high`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct XrayWindowToml {
    pub low: f64,
    pub high: f64,
}

/// Limits of [`CArmToml::check`] (what a C-arm can do, with margin).
pub const C_ARM_SID_RANGE_MM: (f64, f64) = (500.0, 2000.0);
pub const C_ARM_DETECTOR_SIDE_RANGE_MM: (f64, f64) = (50.0, 600.0);
pub const C_ARM_MAX_LAO_DEG: f64 = 135.0;
pub const C_ARM_MAX_CRANIAL_DEG: f64 = 60.0;

impl Default for CArmToml {
    fn default() -> Self {
        CArmToml {
            lao_deg: 0.0,
            cranial_deg: 0.0,
            source_to_detector_mm: 1000.0,
            source_to_isocenter_mm: 750.0,
            detector_mm: [300.0, 300.0],
            isocenter_mm: None,
            window: XrayWindowToml { low: 1.0, high: 5.0 },
            kerma_rate_mgy_per_min: 5.0,
        }
    }
}

impl CArmToml {
    /// Area of the beam at the isocentre (cm²): the detector's area scaled by (SOD/SID)².
    pub fn field_area_at_isocenter_cm2(&self) -> f64 {
        let m = self.source_to_isocenter_mm / self.source_to_detector_mm;
        self.detector_mm[0] * self.detector_mm[1] / 100.0 * m * m
    }

    /// Dose-area product per second of fluoroscopy (Gy·cm²/s): kerma rate × field area, both at
    /// the isocentre (the product is the same in every plane across the beam).
    pub fn dose_area_rate_gy_cm2_per_s(&self) -> f64 {
        self.kerma_rate_mgy_per_min / 1000.0 / 60.0 * self.field_area_at_isocenter_cm2()
    }

    /// Names the first value outside what a C-arm can be set to.
    pub fn check(&self) -> Result<(), CArmError> {
        let bad = |field: &'static str, detail: String| Err(CArmError { field, detail });
        if let Some(p) = self.isocenter_mm
            && !p.iter().all(|v| v.is_finite())
        {
            return bad("isocenter_mm", format!("{p:?} must be finite"));
        }
        let sid = self.source_to_detector_mm;
        let (lo, hi) = C_ARM_SID_RANGE_MM;
        if !(sid.is_finite() && (lo..=hi).contains(&sid)) {
            return bad("source_to_detector_mm", format!("{sid} must be {lo} … {hi} mm"));
        }
        let sod = self.source_to_isocenter_mm;
        if !(sod.is_finite() && sod >= 0.2 * sid && sod <= sid - 100.0) {
            return bad(
                "source_to_isocenter_mm",
                format!(
                    "{sod} must be between 20 % of the source-to-detector distance and 100 mm short of it ({} … {} mm)",
                    0.2 * sid,
                    sid - 100.0
                ),
            );
        }
        let (lo, hi) = C_ARM_DETECTOR_SIDE_RANGE_MM;
        for (name, side) in [("width", self.detector_mm[0]), ("height", self.detector_mm[1])] {
            if !(side.is_finite() && (lo..=hi).contains(&side)) {
                return bad("detector_mm", format!("{name} {side} must be {lo} … {hi} mm"));
            }
        }
        let m = C_ARM_MAX_LAO_DEG;
        if !(self.lao_deg.is_finite() && self.lao_deg.abs() <= m) {
            return bad(
                "lao_deg",
                format!("{} must be −{m} (RAO) … {m} (LAO) degrees", self.lao_deg),
            );
        }
        let m = C_ARM_MAX_CRANIAL_DEG;
        if !(self.cranial_deg.is_finite() && self.cranial_deg.abs() <= m) {
            return bad(
                "cranial_deg",
                format!("{} must be −{m} (caudal) … {m} (cranial) degrees", self.cranial_deg),
            );
        }
        let k = self.kerma_rate_mgy_per_min;
        if !(k.is_finite() && (0.1..=200.0).contains(&k)) {
            return bad("kerma_rate_mgy_per_min", format!("{k} must be 0.1 … 200 mGy/min"));
        }
        let w = self.window;
        if !(w.low.is_finite() && w.high.is_finite() && w.low >= 0.0 && w.high > w.low) {
            return bad(
                "window",
                format!("low {} / high {} must be finite with 0 ≤ low < high", w.low, w.high),
            );
        }
        Ok(())
    }
}

/// The kind of exercise a scenario is (docs/metrics.md "Exercises").
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Exercise {
    /// A needle puncture into the target (PTCD).
    #[default]
    Puncture,
    /// Palpating the intercostal spaces with the finger.
    Palpation,
    /// Finding the target with the ultrasound probe.
    UltrasoundSurvey,
    /// The whole PTCD: the puncture, then the drainage catheter placed over a guide wire by the
    /// Seldinger technique.
    Drainage,
}

impl Exercise {
    pub const ALL: [Exercise; 4] = [
        Exercise::Puncture,
        Exercise::Palpation,
        Exercise::UltrasoundSurvey,
        Exercise::Drainage,
    ];

    /// The identifier as stored and serialised ("puncture", "palpation", "ultrasound_survey",
    /// "drainage").
    pub fn as_str(self) -> &'static str {
        match self {
            Exercise::Puncture => "puncture",
            Exercise::Palpation => "palpation",
            Exercise::UltrasoundSurvey => "ultrasound_survey",
            Exercise::Drainage => "drainage",
        }
    }

    /// Parses the identifier; `None` for anything else.
    pub fn parse(s: &str) -> Option<Exercise> {
        Exercise::ALL.into_iter().find(|e| e.as_str() == s)
    }

    /// The name for people ("ultrasound survey").
    pub fn label(self) -> &'static str {
        match self {
            Exercise::Puncture => "puncture",
            Exercise::Palpation => "palpation",
            Exercise::UltrasoundSurvey => "ultrasound survey",
            Exercise::Drainage => "drainage",
        }
    }
}

impl std::fmt::Display for Exercise {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.label())
    }
}

/// Where the data came from and under which terms.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct Provenance {
    /// What the CT is: "procedural phantom", "TotalSegmentator example CT", …
    pub source: String,
    /// The program (and version) that wrote the atlas.
    pub generator: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seed: Option<u64>,
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub license: String,
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub citation: String,
    /// Free-form notes on how the atlas was derived (recipe steps, synthetic structures).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub notes: Vec<String>,
}

/// File names of the volumes, relative to the atlas directory.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Volumes {
    /// CT in Hounsfield units.
    pub ct: String,
    /// Partial label map (0 = not segmented).
    pub labels: String,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ThresholdsToml {
    pub air_skin: f64,
    pub skin_fat: f64,
    pub fat_bone: f64,
}

/// Which labels the heuristic h(x, d) produces, and its risk depth δ.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HeuristicToml {
    pub air: LabelId,
    pub skin: LabelId,
    pub fat: LabelId,
    pub bone: LabelId,
    pub risk: LabelId,
    /// δ of eq. 6.1.1 in mm.
    pub risk_depth_mm: f64,
    /// Skin thickness the needle feels under the surface (mm), see `needle_label_at`.
    #[serde(default = "default_skin_layer")]
    pub skin_layer_mm: f64,
}

fn default_skin_layer() -> f64 {
    stylet_physics::atlas::DEFAULT_SKIN_LAYER_MM
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LabelToml {
    pub id: LabelId,
    pub name: String,
    /// target / risk / bone / organ / neutral
    pub role: String,
    /// Property-tree node holding the material parameters.
    pub tissue: String,
    /// Risk structures: the clinical consequence of hitting it, one line for people
    /// ("pneumothorax", "haemorrhage"); shown with every hit in reviews and reports.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub consequence: Option<String>,
}

/// A parameter value in TOML: a number, or `{ hu = [...], value = [...] }`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum ParamToml {
    Scalar(f64),
    Piecewise(PiecewiseToml),
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PiecewiseToml {
    pub hu: Vec<f64>,
    pub value: Vec<f64>,
}

/// One property-tree node. Every parameter is optional (inherited when absent).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct TissueToml {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub parent: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stiffness_n_per_mm: Option<ParamToml>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cut_spring_n_per_mm: Option<ParamToml>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cut_spring_n_per_mm2: Option<ParamToml>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cut_threshold_n: Option<ParamToml>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub friction_max_n_per_mm: Option<ParamToml>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub color_rgba: Option<[u8; 4]>,
    /// How the tissue looks in ultrasound (inherited like the parameters; default `tissue`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub echo: Option<EchoClass>,
    /// What a needle through the tissue does to the patient (inherited like the parameters;
    /// docs/complications.md).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub complication: Option<ComplicationToml>,
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub note: String,
}

/// A tissue's complication as written in a manifest (`venous_bleed`, `arterial_bleed`,
/// `pneumothorax`, `bile_leak`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ComplicationToml {
    VenousBleed,
    ArterialBleed,
    Pneumothorax,
    BileLeak,
}

impl ComplicationToml {
    pub fn kind(self) -> ComplicationKind {
        match self {
            ComplicationToml::VenousBleed => ComplicationKind::VenousBleed,
            ComplicationToml::ArterialBleed => ComplicationKind::ArterialBleed,
            ComplicationToml::Pneumothorax => ComplicationKind::Pneumothorax,
            ComplicationToml::BileLeak => ComplicationKind::BileLeak,
        }
    }
}

/// How a tissue appears in simulated ultrasound (docs/ultrasound.md): solid tissue scatters
/// (speckle) by its CT value; fluid (bile, the gallbladder) is anechoic; veins and arteries are
/// anechoic and carry blood flow for the Doppler view (veins blue→cyan, arteries red→yellow).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum EchoClass {
    #[default]
    Tissue,
    Fluid,
    Vein,
    Artery,
}

/// Each label's [`EchoClass`]: its tissue node's `echo`, else the nearest ancestor's, else
/// `tissue`. Labels whose tissue is not in the tree (a manifest the loader would refuse) get
/// `tissue`.
pub fn echo_classes(labels: &[LabelToml], tissues: &BTreeMap<String, TissueToml>) -> Vec<(LabelId, EchoClass)> {
    labels
        .iter()
        .map(|l| {
            let mut node = Some(l.tissue.as_str());
            // The tree is acyclic once loaded; the bound keeps an unchecked manifest finite.
            for _ in 0..=tissues.len() {
                let Some(t) = node.and_then(|n| tissues.get(n)) else {
                    break;
                };
                if let Some(e) = t.echo {
                    return (l.id, e);
                }
                node = t.parent.as_deref();
            }
            (l.id, EchoClass::Tissue)
        })
        .collect()
}

/// Visual aids and rules per difficulty (thesis §6.3: the level changes the available aids).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DifficultyPresets {
    pub beginner: DifficultyPreset,
    pub advanced: DifficultyPreset,
    pub expert: DifficultyPreset,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DifficultyPreset {
    /// Target structure highlighted on clipping planes and in ultrasound (eq. 3.2.4).
    pub target_overlay: bool,
    /// Risk structures highlighted (eq. 3.2.4).
    pub risk_overlay: bool,
    /// Needle-guide line drawn in the ultrasound image.
    pub needle_guide: bool,
    /// Name of a predefined insertion path to follow (the thesis' guided mode), if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub guided_path: Option<String>,
}

/// A predefined insertion path: skin entry point and target point in world mm (RAS).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InsertionPath {
    pub name: String,
    pub entry_mm: [f64; 3],
    pub target_mm: [f64; 3],
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub description: String,
}

/// `[render]`: what the views draw unless told otherwise (docs/atlas.md "Render presets").
/// Checked when parsed (every error names the preset, the trapezoid and the field), so a loaded
/// atlas always has usable presets.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "RenderFields")]
pub struct RenderToml {
    pub presets: RenderPresets,
    /// The grey window of the slice views; the abdominal window (L 40, W 400) when absent.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub window: Option<WindowToml>,
}

/// `[render]` as written, before [`RenderToml::check`].
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RenderFields {
    presets: RenderPresets,
    #[serde(default)]
    window: Option<WindowToml>,
}

impl TryFrom<RenderFields> for RenderToml {
    type Error = ManifestError;
    fn try_from(f: RenderFields) -> Result<Self, ManifestError> {
        let r = RenderToml {
            presets: f.presets,
            window: f.window,
        };
        r.check()?;
        Ok(r)
    }
}

/// The three transfer-function presets of the 3D view (thesis §3.2.1, eq. 3.2.2).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RenderPresets {
    /// The body's surface, opaque.
    pub skin: PresetToml,
    /// Skin transparent, soft tissue faint, contrast-filled vessels and bone visible (Fig. 3.9).
    pub soft: PresetToml,
    /// Bone only.
    pub bone: PresetToml,
}

impl RenderPresets {
    /// The presets with their names, in the order skin, soft, bone.
    pub fn named(&self) -> [(&'static str, &PresetToml); 3] {
        [("skin", &self.skin), ("soft", &self.soft), ("bone", &self.bone)]
    }
}

/// One preset: c(v) = Σ α_i a_i(v) (r_i, g_i, b_i, 1) over its trapezoids.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PresetToml {
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub description: String,
    pub trapezoids: Vec<TrapezoidToml>,
}

/// One tissue's trapezoid a_i: opacity rises from `hu[0]` to `hu[1]`, stays at `opacity` to `hu[2]`,
/// falls to zero at `hu[3]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrapezoidToml {
    /// What it shows, for people ("skin", "contrast vessels").
    pub tissue: String,
    /// Corners in HU, a < b ≤ c < d.
    pub hu: [f64; 4],
    /// Linear RGB, 0 … 1.
    pub rgb: [f64; 3],
    /// Plateau opacity per millimetre of ray, 0 … 1.
    pub opacity: f64,
    /// α_i of eq. 3.2.2, 0 … 1 (0 hides the tissue).
    pub weight: f64,
}

/// A CT display window (level and width in HU).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WindowToml {
    pub level_hu: f64,
    pub width_hu: f64,
}

/// The most trapezoids a preset may hold (the GPU renderer keeps them in a fixed uniform array;
/// `stylet_render::transfer::MAX_TRAPEZOIDS`).
pub const MAX_PRESET_TRAPEZOIDS: usize = 8;

impl RenderToml {
    /// Checks every preset and the window; the error names the preset, trapezoid and field.
    pub fn check(&self) -> Result<(), ManifestError> {
        for (name, preset) in self.presets.named() {
            preset
                .check()
                .map_err(|error| ManifestError::RenderPreset { preset: name, error })?;
        }
        if let Some(w) = &self.window
            && (!w.level_hu.is_finite() || !w.width_hu.is_finite() || w.width_hu <= 0.0)
        {
            return Err(ManifestError::RenderWindow {
                level_hu: w.level_hu,
                width_hu: w.width_hu,
            });
        }
        Ok(())
    }
}

impl PresetToml {
    fn check(&self) -> Result<(), PresetError> {
        let n = self.trapezoids.len();
        if n == 0 || n > MAX_PRESET_TRAPEZOIDS {
            return Err(PresetError::TrapezoidCount { count: n });
        }
        let unit = |v: f64| v.is_finite() && (0.0..=1.0).contains(&v);
        for (i, t) in self.trapezoids.iter().enumerate() {
            let bad = |field: &'static str, detail: String| {
                Err(PresetError::Trapezoid {
                    trapezoid: i + 1,
                    tissue: t.tissue.clone(),
                    field,
                    detail,
                })
            };
            if t.tissue.trim().is_empty() || t.tissue.len() > 64 {
                return Err(PresetError::TissueName { trapezoid: i + 1 });
            }
            let [a, b, c, d] = t.hu;
            if !(t.hu.iter().all(|v| v.is_finite()) && a < b && b <= c && c < d) {
                return bad(
                    "hu",
                    format!("must be four finite corners a < b ≤ c < d, got {:?}", t.hu),
                );
            }
            if !t.rgb.iter().all(|&v| unit(v)) {
                return bad("rgb", format!("must be three values 0 … 1, got {:?}", t.rgb));
            }
            if !unit(t.opacity) {
                return bad("opacity", format!("(per mm) must be 0 … 1, got {}", t.opacity));
            }
            if !unit(t.weight) {
                return bad("weight", format!("must be 0 … 1, got {}", t.weight));
            }
        }
        if !self.trapezoids.iter().any(|t| t.weight > 0.0 && t.opacity > 0.0) {
            return Err(PresetError::DrawsNothing);
        }
        Ok(())
    }
}

/// The scenario part of a manifest, in a file of its own (e.g. `atlases/ptcd.toml`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScenarioFile {
    pub heuristic: HeuristicToml,
    pub labels: Vec<LabelToml>,
    pub tissues: BTreeMap<String, TissueToml>,
    pub difficulty: DifficultyPresets,
    #[serde(default)]
    pub scenarios: Vec<ScenarioToml>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub render: Option<RenderToml>,
}

/// Checks scenario names: 1–64 letters, digits or `. _ - @` (what a session header may name),
/// each once.
pub fn check_scenarios(scenarios: &[ScenarioToml]) -> Result<(), ManifestError> {
    let mut seen = std::collections::BTreeSet::new();
    for sc in scenarios {
        let ok = |c: char| c.is_ascii_alphanumeric() || "._-@".contains(c);
        if sc.name.is_empty() || sc.name.len() > 64 || !sc.name.chars().all(ok) {
            return Err(ManifestError::ScenarioName { name: sc.name.clone() });
        }
        if !seen.insert(sc.name.as_str()) {
            return Err(ManifestError::DuplicateScenario { name: sc.name.clone() });
        }
        if let Some(c) = &sc.c_arm {
            c.check().map_err(|error| ManifestError::ScenarioCArm {
                scenario: sc.name.clone(),
                error,
            })?;
        }
    }
    Ok(())
}

/// The clinical consequences the labels declare, by label id (risk structures).
pub fn consequences(labels: &[LabelToml]) -> BTreeMap<LabelId, String> {
    labels
        .iter()
        .filter_map(|l| l.consequence.as_ref().map(|c| (l.id, c.clone())))
        .collect()
}

/// The PTCD scenario shipped with Stylet: labels, property tree and presets (`atlases/ptcd.toml`).
pub const PTCD_SCENARIO_TOML: &str = include_str!("../../../atlases/ptcd.toml");

impl HeuristicToml {
    /// The labels the heuristic produces.
    pub fn ids(&self) -> [LabelId; 5] {
        [self.air, self.skin, self.fat, self.bone, self.risk]
    }
}

impl ScenarioFile {
    /// Keeps the heuristic labels and those `present` says a label map uses.
    pub fn keep_labels(&mut self, present: impl Fn(LabelId) -> bool) {
        let heuristic = self.heuristic.ids();
        self.labels.retain(|l| heuristic.contains(&l.id) || present(l.id));
    }

    pub fn parse(text: &str) -> Result<Self, ManifestError> {
        toml::from_str(text).map_err(|e| ManifestError::Syntax(e.to_string()))
    }

    /// The built-in PTCD scenario.
    pub fn ptcd() -> Self {
        Self::parse(PTCD_SCENARIO_TOML).expect("atlases/ptcd.toml is valid (checked by tests)")
    }
}

impl ParamToml {
    fn to_value(&self) -> ParamValue {
        match self {
            ParamToml::Scalar(v) => ParamValue::Scalar(*v),
            ParamToml::Piecewise(p) => ParamValue::PiecewiseLinear {
                hu: p.hu.clone(),
                value: p.value.clone(),
            },
        }
    }
}

impl TissueToml {
    fn param(&self, p: Param) -> Option<&ParamToml> {
        match p {
            Param::StiffnessNPerMm => self.stiffness_n_per_mm.as_ref(),
            Param::CutSpringNPerMm => self.cut_spring_n_per_mm.as_ref(),
            Param::CutSpringNPerMm2 => self.cut_spring_n_per_mm2.as_ref(),
            Param::CutThresholdN => self.cut_threshold_n.as_ref(),
            Param::FrictionMaxNPerMm => self.friction_max_n_per_mm.as_ref(),
        }
    }
}

/// The validated property tree of a `[tissues]` table.
pub fn property_tree(tissues: &BTreeMap<String, TissueToml>) -> Result<PropertyTree, ManifestError> {
    let specs = tissues
        .iter()
        .map(|(name, t)| TissueSpec {
            name: name.clone(),
            parent: t.parent.clone(),
            params: Param::ALL
                .into_iter()
                .filter_map(|p| t.param(p).map(|v| (p, v.to_value())))
                .collect(),
            color_rgba: t.color_rgba,
            complication: t.complication.map(ComplicationToml::kind),
        })
        .collect();
    PropertyTree::new(specs).map_err(ManifestError::PropertyTree)
}

/// The validated label table of `[[labels]]` and `[heuristic]`.
pub fn label_table(labels: &[LabelToml], heuristic: &HeuristicToml) -> Result<LabelTable, ManifestError> {
    let mut out = Vec::with_capacity(labels.len());
    for l in labels {
        if let Some(c) = &l.consequence
            && (c.trim().is_empty() || c.len() > 200 || c.contains(['\n', '\r']))
        {
            return Err(ManifestError::Consequence { label: l.name.clone() });
        }
        let role = Role::parse(&l.role).ok_or_else(|| ManifestError::UnknownRole {
            label: l.name.clone(),
            role: l.role.clone(),
        })?;
        out.push(Label {
            id: l.id,
            name: l.name.clone(),
            role,
            tissue: l.tissue.clone(),
        });
    }
    let h = HeuristicLabels {
        air: heuristic.air,
        skin: heuristic.skin,
        fat: heuristic.fat,
        bone: heuristic.bone,
        risk: heuristic.risk,
    };
    LabelTable::new(out, h).map_err(ManifestError::LabelTable)
}

impl ThresholdsToml {
    pub fn with_depth(&self, risk_depth_mm: f64) -> Thresholds {
        Thresholds {
            air_skin_hu: self.air_skin,
            skin_fat_hu: self.skin_fat,
            fat_bone_hu: self.fat_bone,
            risk_depth_mm,
        }
    }

    pub fn from_thresholds(t: &Thresholds) -> Self {
        ThresholdsToml {
            air_skin: t.air_skin_hu,
            skin_fat: t.skin_fat_hu,
            fat_bone: t.fat_bone_hu,
        }
    }
}

impl Manifest {
    /// A manifest for new volumes with the given scenario.
    pub fn new(name: &str, description: &str, provenance: Provenance, scenario: ScenarioFile) -> Self {
        Manifest {
            format_version: FORMAT_VERSION,
            name: name.into(),
            description: description.into(),
            provenance,
            volumes: Volumes {
                ct: "ct.nii.gz".into(),
                labels: "labels.nii.gz".into(),
            },
            thresholds: None,
            heuristic: scenario.heuristic,
            labels: scenario.labels,
            tissues: scenario.tissues,
            difficulty: scenario.difficulty,
            paths: Vec::new(),
            scenarios: scenario.scenarios,
            render: scenario.render,
            breathing: Some(BreathingToml::default()),
        }
    }

    /// `[breathing]`, or the default synthetic motion for an atlas written before the section
    /// existed.
    pub fn breathing_or_default(&self) -> BreathingToml {
        self.breathing.clone().unwrap_or_default()
    }

    pub fn to_toml(&self) -> String {
        toml::to_string_pretty(self).expect("manifest serialises")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn echo_classes_are_inherited_down_the_property_tree() {
        let s = ScenarioFile::ptcd();
        let classes = echo_classes(&s.labels, &s.tissues);
        let of = |name: &str| {
            let id = s
                .labels
                .iter()
                .find(|l| l.name == name)
                .unwrap_or_else(|| panic!("{name}"))
                .id;
            classes.iter().find(|c| c.0 == id).unwrap().1
        };
        // vessel → vein; aorta overrides → artery; bile_duct → fluid, its child target_duct too.
        assert_eq!(of("portal vein"), EchoClass::Vein);
        assert_eq!(of("aorta"), EchoClass::Artery);
        assert_eq!(of("bile duct"), EchoClass::Fluid);
        assert_eq!(of("right hepatic duct"), EchoClass::Fluid);
        assert_eq!(of("liver"), EchoClass::Tissue);
        let bad: Result<TissueToml, _> = toml::from_str("echo = \"blood\"");
        assert!(bad.unwrap_err().to_string().contains("unknown variant"));
    }

    #[test]
    fn the_shipped_ptcd_scenario_is_valid() {
        let s = ScenarioFile::parse(PTCD_SCENARIO_TOML).unwrap();
        let labels = label_table(&s.labels, &s.heuristic).unwrap();
        let tree = property_tree(&s.tissues).unwrap();
        stylet_physics::Materials::resolve(&labels, &tree).unwrap();
        assert_eq!(labels.with_role(Role::Target).count(), 1);
        check_scenarios(&s.scenarios).unwrap();
        assert!(s.scenarios.iter().any(|sc| sc.name == "success-intercostal"));
        let render = s.render.expect("ptcd.toml has [render] presets");
        for (name, preset) in render.presets.named() {
            assert!(!preset.trapezoids.is_empty(), "{name}");
        }
        // Fig. 3.9: the soft preset hides skin and shows bone fully.
        let weight = |tissue: &str| {
            render
                .presets
                .soft
                .trapezoids
                .iter()
                .find(|t| t.tissue == tissue)
                .unwrap()
                .weight
        };
        assert_eq!((weight("skin"), weight("bone")), (0.0, 1.0));
    }

    #[test]
    fn scenario_c_arms_parse_with_defaults_and_bad_ones_are_named() {
        let s = ScenarioFile::parse(PTCD_SCENARIO_TOML).unwrap();
        let success = s.scenarios.iter().find(|sc| sc.name == "success-intercostal").unwrap();
        // Trainees are offered the training scenarios; the scripted examples and grading
        // fixtures are marked so. The kind is not written into an atlas (its hash stays), and a
        // scenario read without one takes the shipped file's by name.
        let training: Vec<&str> = s
            .scenarios
            .iter()
            .filter(|sc| sc.kind() == ScenarioKind::Training)
            .map(|sc| sc.name.as_str())
            .collect();
        assert_eq!(
            training,
            [
                "success-intercostal",
                "breath-hold",
                "palpation-sweep",
                "probe-parallel",
                "probe-across",
                "full-ptcd"
            ]
        );
        let written = toml::to_string(&s.scenarios[1]).unwrap();
        assert_eq!(s.scenarios[1].kind, Some(ScenarioKind::Example));
        assert!(!written.contains("kind"), "{written}");
        let reread: ScenarioToml = toml::from_str(&toml::to_string(&s.scenarios[1]).unwrap()).unwrap();
        assert_eq!(
            (reread.name.as_str(), reread.kind, reread.kind()),
            ("two-attempts", None, ScenarioKind::Example)
        );
        let custom: ScenarioToml = toml::from_str("name = \"my-own\"\nkind = \"example\"\n").unwrap();
        assert_eq!(custom.kind(), ScenarioKind::Example);
        let unknown: ScenarioToml = toml::from_str("name = \"my-own\"\n").unwrap();
        assert_eq!(unknown.kind(), ScenarioKind::Training);
        assert_eq!(success.c_arm, Some(CArmToml::default()));
        let parsed: ScenarioToml = toml::from_str("name = \"x\"\n[c_arm]\nlao_deg = -30.0\n").unwrap();
        let c = parsed.c_arm.unwrap();
        assert_eq!((c.lao_deg, c.source_to_detector_mm), (-30.0, 1000.0));
        let check = |text: &str| {
            let sc: ScenarioToml = toml::from_str(&format!("name = \"x\"\n[c_arm]\n{text}\n")).unwrap();
            check_scenarios(&[sc]).unwrap_err().to_string()
        };
        let e = check("lao_deg = 150.0");
        assert!(e.contains("scenario 'x'") && e.contains("lao_deg 150"), "{e}");
        assert!(check("cranial_deg = -61.0").contains("cranial_deg"));
        assert!(check("source_to_isocenter_mm = 950.0").contains("source_to_isocenter_mm"));
        assert!(check("detector_mm = [300.0, 10.0]").contains("height"));
        assert!(check("window = { low = 3.0, high = 2.0 }").contains("window"));
        assert!(check("kerma_rate_mgy_per_min = 0.0").contains("kerma_rate"));
        // 300 × 300 mm at SID 1000, SOD 750: 900 cm² × 0.5625 at the isocentre; 5 mGy/min.
        let d = CArmToml::default();
        assert!((d.field_area_at_isocenter_cm2() - 506.25).abs() < 1e-9);
        assert!((d.dose_area_rate_gy_cm2_per_s() - 5e-3 / 60.0 * 506.25).abs() < 1e-12);
        assert!(toml::from_str::<ScenarioToml>("name = \"x\"\n[c_arm]\nkv = 70\n").is_err());
    }

    fn ptcd_with(edit: impl Fn(&mut toml::Table)) -> Result<ScenarioFile, ManifestError> {
        let mut t: toml::Table = toml::from_str(PTCD_SCENARIO_TOML).unwrap();
        edit(&mut t);
        ScenarioFile::parse(&toml::to_string(&t).unwrap())
    }

    fn soft_trapezoid(t: &mut toml::Table, i: usize) -> &mut toml::Table {
        t["render"]["presets"]["soft"]["trapezoids"].as_array_mut().unwrap()[i]
            .as_table_mut()
            .unwrap()
    }

    #[test]
    fn bad_render_presets_name_the_preset_the_trapezoid_and_the_field() {
        use toml::Value;
        let e = ptcd_with(|t| {
            soft_trapezoid(t, 3).insert("hu".into(), Value::try_from([200.0, 100.0, 300.0, 400.0]).unwrap());
        })
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("render preset 'soft'") && e.contains("'contrast vessels'") && e.contains("hu"),
            "{e}"
        );
        let e = ptcd_with(|t| {
            soft_trapezoid(t, 1).insert("opacity".into(), Value::Float(1.5));
        })
        .unwrap_err()
        .to_string();
        assert!(e.contains("'soft tissue'") && e.contains("opacity"), "{e}");
        let e = ptcd_with(|t| {
            soft_trapezoid(t, 0).insert("rgb".into(), Value::try_from([0.5, 2.0, 0.5]).unwrap());
        })
        .unwrap_err()
        .to_string();
        assert!(e.contains("rgb"), "{e}");
        let e = ptcd_with(|t| {
            soft_trapezoid(t, 4).insert("weight".into(), Value::Float(-0.1));
        })
        .unwrap_err()
        .to_string();
        assert!(e.contains("'bone'") && e.contains("weight"), "{e}");
        let e = ptcd_with(|t| {
            t["render"]["presets"]["bone"]["trapezoids"] = Value::Array(vec![]);
        })
        .unwrap_err()
        .to_string();
        assert!(e.contains("render preset 'bone'") && e.contains("trapezoids"), "{e}");
        let e = ptcd_with(|t| {
            t["render"]["presets"].as_table_mut().unwrap().remove("skin");
        })
        .unwrap_err()
        .to_string();
        assert!(e.contains("skin"), "{e}");
        let e = ptcd_with(|t| {
            t["render"]["window"]["width_hu"] = Value::Float(0.0);
        })
        .unwrap_err()
        .to_string();
        assert!(e.contains("render.window"), "{e}");
        let e = ptcd_with(|t| {
            soft_trapezoid(t, 1).insert("colour".into(), Value::Float(1.0));
        })
        .unwrap_err()
        .to_string();
        assert!(e.contains("colour"), "{e}");
    }
}
