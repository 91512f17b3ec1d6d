//! Import recipes: how to turn a CT plus label maps (e.g. a TotalSegmentator output folder) into a
//! puncture atlas (docs/atlas.md "Import recipes").

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use serde::Deserialize;
use stylet_physics::LabelId;

use crate::AtlasError;
use crate::manifest::{LabelToml, Provenance, ScenarioFile, TissueToml};

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Recipe {
    pub name: String,
    #[serde(default)]
    pub description: String,
    /// Scenario file (labels, property tree, presets), relative to the recipe.
    pub scenario: String,
    /// Resample to this isotropic spacing (mm); keep the source grid when absent.
    #[serde(default)]
    pub resample_mm: Option<f64>,
    pub source: Source,
    #[serde(default)]
    pub provenance: RecipeProvenance,
    #[serde(default)]
    pub map: Vec<LabelMap>,
    /// Labels added to the scenario's table.
    #[serde(default)]
    pub labels: Vec<LabelToml>,
    /// Tissues added to the scenario's property tree, by name (a child of one of its tissues
    /// inherits every parameter it does not set: a structure's own colour, say).
    #[serde(default)]
    pub tissues: std::collections::BTreeMap<String, TissueToml>,
    #[serde(default)]
    pub biliary: Option<Biliary>,
    #[serde(default)]
    pub window: Option<Window>,
    /// The breathing motion to attach (docs/breathing.md "Atlases"); absent: the default
    /// synthetic motion.
    #[serde(default)]
    pub breathing: Option<crate::manifest::BreathingToml>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Source {
    /// CT volume in HU (NIfTI), relative to the data directory.
    pub ct: String,
    #[serde(default)]
    pub labels: Vec<LabelSource>,
    /// The label maps' class table (CSV with `id` and `structure` columns, docs/atlas.md
    /// "Class tables"), relative to the data directory; TotalSegmentator's "total" classes when
    /// absent.
    #[serde(default)]
    pub classes: Option<String>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LabelSource {
    pub file: String,
    /// Label voxel (i, j, k) is CT voxel (i, j, k) + offset. Needed when a label map covers part
    /// of the CT but kept the CT's header (TotalSegmentator crops do).
    #[serde(default)]
    pub offset_voxels: [i64; 3],
}

#[derive(Debug, Clone, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct RecipeProvenance {
    #[serde(default)]
    pub source: String,
    #[serde(default)]
    pub license: String,
    #[serde(default)]
    pub citation: String,
}

/// Source label numbers that become one atlas label.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LabelMap {
    pub from: Vec<LabelId>,
    pub to: LabelId,
}

/// Synthesis of a dilated biliary tree inside the liver label (thesis §5.6).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Biliary {
    /// Atlas label of the liver (after mapping).
    pub liver_label: LabelId,
    /// Source labels whose entry into the liver marks the hilum (the portal vein).
    #[serde(default)]
    pub hilum_from: Vec<LabelId>,
    pub duct_label: LabelId,
    pub target_label: LabelId,
    pub target_length_mm: f64,
    pub target_radius_mm: f64,
    pub duct_radius_mm: f64,
    pub branch_radius_mm: f64,
    #[serde(default)]
    pub branches: u32,
    pub bile_hu: f64,
    #[serde(default)]
    pub seed: u64,
}

/// Where to look for the straight intercostal path to the target.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Window {
    pub upper_rib: LabelId,
    pub lower_rib: LabelId,
    #[serde(default)]
    pub bone_labels: Vec<LabelId>,
    /// Adapt the difficulty presets to the windows found (`import::presets`; `atlas new` does).
    #[serde(default)]
    pub adapt_presets: bool,
}

/// A parsed recipe with its scenario, checked for consistency.
#[derive(Debug, Clone)]
pub struct LoadedRecipe {
    pub path: PathBuf,
    pub recipe: Recipe,
    pub scenario: ScenarioFile,
}

impl LoadedRecipe {
    pub fn provenance(&self, generator: &str) -> Provenance {
        let p = &self.recipe.provenance;
        Provenance {
            source: p.source.clone(),
            generator: generator.into(),
            seed: self.recipe.biliary.as_ref().map(|b| b.seed),
            license: p.license.clone(),
            citation: p.citation.clone(),
            notes: Vec::new(),
        }
    }
}

/// Reads a recipe and its scenario; every error names the recipe (or scenario) file.
pub fn load_recipe(path: &Path) -> Result<LoadedRecipe, AtlasError> {
    crate::check_regular_file(path)?;
    let text = std::fs::read_to_string(path).map_err(|e| AtlasError::file(path, format!("cannot read: {e}")))?;
    let recipe: Recipe =
        toml::from_str(&text).map_err(|e| AtlasError::file(path, e.to_string().trim_end().to_string()))?;
    let scenario_path = path.parent().unwrap_or(Path::new(".")).join(&recipe.scenario);
    crate::check_regular_file(&scenario_path)?;
    let scenario_text = std::fs::read_to_string(&scenario_path)
        .map_err(|e| AtlasError::file(&scenario_path, format!("cannot read scenario: {e}")))?;
    let scenario = ScenarioFile::parse(&scenario_text).map_err(|error| AtlasError::Manifest {
        path: scenario_path.clone(),
        error,
    })?;
    LoadedRecipe::new(path, recipe, scenario)
}

impl LoadedRecipe {
    /// A recipe and its scenario (before the recipe's own labels are added), checked for
    /// consistency; errors name `path` (the recipe file, or what made the recipe).
    pub fn new(path: &Path, recipe: Recipe, mut scenario: ScenarioFile) -> Result<LoadedRecipe, AtlasError> {
        let bad = |m: String| AtlasError::file(path, m);
        if recipe.name.trim().is_empty() {
            return Err(bad("name must not be empty".into()));
        }
        if let Some(r) = recipe.resample_mm
            && !(r.is_finite() && (0.2..=10.0).contains(&r))
        {
            return Err(bad(format!("resample_mm = {r} must be 0.2 … 10")));
        }
        for (name, tissue) in &recipe.tissues {
            if scenario.tissues.contains_key(name) {
                return Err(bad(format!("[tissues.{name}] is already a tissue of the scenario")));
            }
            scenario.tissues.insert(name.clone(), tissue.clone());
        }
        scenario.labels.extend(recipe.labels.iter().cloned());
        let table = crate::manifest::label_table(&scenario.labels, &scenario.heuristic).map_err(|error| {
            AtlasError::Manifest {
                path: path.to_path_buf(),
                error,
            }
        })?;
        let mut seen = BTreeSet::new();
        for m in &recipe.map {
            if table.get(m.to).is_none() {
                return Err(bad(format!(
                    "[[map]] to = {} is not a label of the scenario or the recipe",
                    m.to
                )));
            }
            for &f in &m.from {
                if f == 0 {
                    return Err(bad("[[map]] from = 0: source label 0 means unlabelled".into()));
                }
                if !seen.insert(f) {
                    return Err(bad(format!("source label {f} is mapped twice")));
                }
            }
        }
        if let Some(b) = &recipe.biliary {
            for (what, id) in [
                ("liver_label", b.liver_label),
                ("duct_label", b.duct_label),
                ("target_label", b.target_label),
            ] {
                if table.get(id).is_none() {
                    return Err(bad(format!(
                        "[biliary] {what} = {id} is not a label of the scenario or the recipe"
                    )));
                }
            }
            let lengths = [
                b.target_length_mm,
                b.target_radius_mm,
                b.duct_radius_mm,
                b.branch_radius_mm,
            ];
            if lengths.iter().any(|v| !(v.is_finite() && *v > 0.0 && *v < 500.0)) {
                return Err(bad("[biliary] lengths and radii must be positive numbers of mm".into()));
            }
            if !b.bile_hu.is_finite() {
                return Err(bad("[biliary] bile_hu must be a number".into()));
            }
            if b.branches > 32 {
                return Err(bad("[biliary] branches must be ≤ 32".into()));
            }
        }
        if recipe.source.ct.contains("..")
            || recipe.source.labels.iter().any(|l| l.file.contains(".."))
            || recipe.source.classes.as_ref().is_some_and(|c| c.contains(".."))
        {
            return Err(bad("source files must lie inside the data directory (no '..')".into()));
        }
        Ok(LoadedRecipe {
            path: path.to_path_buf(),
            recipe,
            scenario,
        })
    }
}
