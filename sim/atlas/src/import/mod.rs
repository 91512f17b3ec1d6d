//! Importers for real CT: a generic recipe-driven importer for a CT plus label maps (a
//! TotalSegmentator output folder imports as is) and, behind the `dicom` feature, a DICOM series
//! importer. Recipes are documented in docs/atlas.md "Import recipes".

pub mod auto;
pub mod biliary;
pub mod checks;
pub mod classes;
#[cfg(feature = "dicom")]
pub mod dicom;
#[cfg(feature = "dicom")]
pub mod dicom_seg;
pub mod mapping;
pub mod new;
pub mod presets;
pub mod recipe;
pub mod resample;
pub mod scripts;
pub mod steps;
pub mod window;

use std::path::Path;

use stylet_physics::thresholds::estimate_thresholds;
use stylet_physics::{LabelId, PunctureAtlas, Volume};

use crate::manifest::{self, Manifest};
use crate::{AtlasError, nifti_io};
use biliary::BiliaryReport;
use classes::ClassTable;
use recipe::{LoadedRecipe, load_recipe};
use steps::{Step, StepTimer};
use window::WindowReport;

/// What an import did, for the command's output and the tests.
#[derive(Debug, Clone)]
pub struct ImportReport {
    pub manifest: Manifest,
    pub biliary: Option<BiliaryReport>,
    pub window: Option<WindowReport>,
    /// The source label maps' class names (ribs by side and number in the window's text).
    pub classes: ClassTable,
    pub notes: Vec<String>,
    /// The source CT and label map as they came (grid, HU range, label coverage).
    pub source: checks::SourceSummary,
    /// What a clinician should check before approving the patient.
    pub warnings: Vec<checks::Warning>,
    /// The time each step took (reading, tree, window, writing; `atlas new` adds its own).
    pub timings: Vec<(Step, std::time::Duration)>,
    /// The difficulty presets adapted to this patient (`atlas new`), level by level.
    pub presets: Option<presets::PresetNotes>,
}

impl ImportReport {
    pub fn to_text(&self) -> String {
        let mut out = self.to_text_without_time();
        if !self.timings.is_empty() {
            out += &format!("- time: {}\n", steps::describe_timings(&self.timings));
        }
        out
    }

    /// [`Self::to_text`] without the timings line (what does not change from run to run).
    pub fn to_text_without_time(&self) -> String {
        let mut out = String::new();
        for n in &self.notes {
            out += &format!("- {n}\n");
        }
        if let Some(b) = &self.biliary {
            out += &format!(
                "- biliary tree: hilum at ({:.1}, {:.1}, {:.1}) mm from the {}, target centre ({:.1}, {:.1}, {:.1}) mm, \
                 {} target and {} duct voxels, {} connected component(s), bile with {:.1} HU liver noise\n",
                b.hilum_mm.x,
                b.hilum_mm.y,
                b.hilum_mm.z,
                b.hilum_source,
                b.target_center_mm.x,
                b.target_center_mm.y,
                b.target_center_mm.z,
                b.target_voxels,
                b.duct_voxels,
                b.components,
                b.liver_noise_hu
            );
        }
        if let Some(w) = &self.window {
            out += &window_text(w, &self.classes);
        }
        if let Some(p) = &self.presets {
            for (level, note) in p.lines() {
                out += &format!("- difficulty {level}: {note}\n");
            }
        }
        for w in &self.warnings {
            out += &format!("- WARNING ({}): {}\n", w.kind.title(), w.text);
        }
        out
    }
}

/// The window search in words: the chosen window and why, then every window in rank order.
fn window_text(w: &WindowReport, c: &ClassTable) -> String {
    use window::Choice;
    let mut out = String::new();
    let asked = format!(
        "{} ({} / {})",
        window::space_name(c, w.requested.0, w.requested.1),
        c.describe(w.requested.0),
        c.describe(w.requested.1)
    );
    match (&w.found, w.choice()) {
        (Some(f), choice) => {
            let why = match choice {
                Choice::Requested => String::new(),
                Choice::RequestedTranspleural => format!(
                    " — the {asked} asked for passes through the pleural recess, so the best-ranked window instead"
                ),
                Choice::RequestedMissing | Choice::None => format!(
                    " — NO straight path through the {asked} asked for, within {:.0} mm of both ribs, reaches \
                     the target without bone or risk, so the best-ranked window instead",
                    window::BOUND_NEAR_MM
                ),
            };
            out += &format!(
                "- intercostal window: {} ({} / {}){why}: entry ({:.1}, {:.1}, {:.1}) mm → target \
                 ({:.1}, {:.1}, {:.1}) mm, {:.0} mm long, {:.1} mm clear of bone, {:.1} mm of vessels, \
                 {:.0} mm from the lung at the wall\n",
                window::space_name(c, f.upper, f.lower),
                c.describe(f.upper),
                c.describe(f.lower),
                f.entry_mm.x,
                f.entry_mm.y,
                f.entry_mm.z,
                f.target_mm.x,
                f.target_mm.y,
                f.target_mm.z,
                f.length_mm,
                f.bone_clearance_mm,
                f.vessel_clearance_mm,
                f.lung_clearance_mm
            );
        }
        (None, _) => {
            out += &format!(
                "- NO intercostal window found: no straight path from the skin between two ribs \
                 (requested: the {asked}) reaches the target without crossing bone or a risk structure\n"
            );
        }
    }
    if !w.ranked.is_empty() {
        let list: Vec<String> = w
            .ranked
            .iter()
            .enumerate()
            .map(|(k, f)| {
                format!(
                    "{}. {} {:.1}{}",
                    k + 1,
                    window::space_name(c, f.upper, f.lower),
                    f.penalty(),
                    if f.transpleural() { " (transpleural)" } else { "" }
                )
            })
            .collect();
        out += &format!(
            "- windows ranked by clinical score (clear of the pleura first, then penalty points for vessels and \
             bone nearby, length and tilt): {}\n",
            list.join(", ")
        );
    }
    out
}

/// Places a label map into the CT's grid: by index with the recipe's offset, or by identical
/// geometry when no offset is given.
fn place_labels(
    ct_grid: &stylet_physics::Grid,
    labels: &Volume<LabelId>,
    offset: [i64; 3],
    path: &Path,
    into: &mut Volume<LabelId>,
    notes: &mut Vec<String>,
) -> Result<(), AtlasError> {
    let (cd, ld) = (ct_grid.dims(), labels.grid().dims());
    if offset == [0, 0, 0] {
        if cd != ld {
            return Err(AtlasError::file(
                path,
                format!(
                    "label map has dimensions {ld:?} but the CT has {cd:?}; if it covers part of the CT, give its offset in voxels (recipe: offset_voxels; atlas new: --offset-voxels)"
                ),
            ));
        }
        let diff = ct_grid.affine().max_abs_diff(labels.grid().affine());
        if diff > 1e-3 {
            return Err(AtlasError::file(
                path,
                format!("label map affine differs from the CT's by up to {diff:.4} mm"),
            ));
        }
    } else {
        for a in 0..3 {
            if offset[a] < 0 || offset[a] as usize + ld[a] > cd[a] {
                return Err(AtlasError::file(
                    path,
                    format!("with offset_voxels {offset:?} the label map ({ld:?}) does not fit inside the CT ({cd:?})"),
                ));
            }
        }
        let spacing_diff = (0..3)
            .map(|a| (ct_grid.spacing_mm()[a] - labels.grid().spacing_mm()[a]).abs())
            .fold(0.0, f64::max);
        if spacing_diff > 1e-3 {
            return Err(AtlasError::file(
                path,
                "label map voxel size differs from the CT's; index alignment needs equal voxels",
            ));
        }
        notes.push(format!(
            "{} aligned to the CT by index with offset {offset:?} (its header origin is ignored)",
            path.display()
        ));
    }
    for k in 0..ld[2] {
        for j in 0..ld[1] {
            for i in 0..ld[0] {
                let v = labels.get(i, j, k);
                if v != 0 {
                    into.set(
                        i + offset[0] as usize,
                        j + offset[1] as usize,
                        k + offset[2] as usize,
                        v,
                    );
                }
            }
        }
    }
    Ok(())
}

/// The recipe's CT and source label map (label maps placed into the CT grid, resampled as the
/// recipe asks), before mapping: what the importer starts from.
pub struct Sources {
    pub ct: Volume<f32>,
    /// Source label numbers (e.g. TotalSegmentator classes) on the CT's grid.
    pub labels: Volume<LabelId>,
    pub notes: Vec<String>,
}

/// Reads the recipe's CT and label maps from `data_dir`.
pub fn read_sources(r: &LoadedRecipe, data_dir: &Path) -> Result<Sources, AtlasError> {
    let rec = &r.recipe;
    let mut notes = Vec::new();
    let ct_path = data_dir.join(&rec.source.ct);
    let mut ct = nifti_io::read_ct(&ct_path)?;
    let mut source = Volume::filled(*ct.grid(), 0 as LabelId);
    for ls in &rec.source.labels {
        let p = data_dir.join(&ls.file);
        let l = nifti_io::read_labels(&p)?;
        place_labels(ct.grid(), &l, ls.offset_voxels, &p, &mut source, &mut notes)?;
    }
    if let Some(mm) = rec.resample_mm {
        let g = resample::isotropic_grid(ct.grid(), mm);
        notes.push(format!(
            "resampled from {:?} voxels of {:?} mm to {:?} voxels of {mm} mm",
            ct.grid().dims(),
            ct.grid().spacing_mm(),
            g.dims()
        ));
        ct = resample::resample_ct(&ct, &g);
        source = resample::resample_labels(&source, &g);
    }
    Ok(Sources {
        ct,
        labels: source,
        notes,
    })
}

/// Imports a CT and label maps from `data_dir` following the recipe, writes the atlas to `out`.
pub fn import(recipe_path: &Path, data_dir: &Path, out: &Path) -> Result<ImportReport, AtlasError> {
    import_with(recipe_path, data_dir, out, true)
}

/// [`import`], attaching the synthetic breathing motion or not (`--no-breathing`).
pub fn import_with(
    recipe_path: &Path,
    data_dir: &Path,
    out: &Path,
    breathing: bool,
) -> Result<ImportReport, AtlasError> {
    let mut r: LoadedRecipe = load_recipe(recipe_path)?;
    if !breathing {
        r.recipe.breathing = Some(crate::manifest::BreathingToml::attached(false));
    }
    let rec = &r.recipe;
    // The small file first: a bad class table is refused before the CT is read.
    let classes = match &rec.source.classes {
        Some(file) => ClassTable::read_csv(&data_dir.join(file))?,
        None => ClassTable::totalsegmentator(),
    };
    let mut quiet = |_| {};
    let mut timer = StepTimer::new(&mut quiet);
    let sources = timer.run(Step::ReadCt, || read_sources(&r, data_dir))?;
    build(&r, sources, classes, out, &mut timer)
}

/// The importer's work on sources already read (a recipe's, or `atlas new`'s): maps the source
/// classes to atlas labels, synthesises the biliary tree, finds the intercostal window and writes
/// the atlas to `out`. Errors name `r.path` (the recipe, or what made it).
pub fn build(
    r: &LoadedRecipe,
    sources: Sources,
    classes: ClassTable,
    out: &Path,
    timer: &mut StepTimer,
) -> Result<ImportReport, AtlasError> {
    let rec = &r.recipe;
    let recipe_path = r.path.as_path();
    let Sources {
        mut ct,
        labels: source,
        mut notes,
    } = sources;
    let source_summary = checks::SourceSummary::of(&ct, &source);
    let mut lut = vec![0 as LabelId; LabelId::MAX as usize + 1];
    for m in &rec.map {
        for &f in &m.from {
            lut[f as usize] = m.to;
        }
    }
    let mut labels = source.map(|s| lut[s as usize]);
    let mut unmapped: Vec<LabelId> = source
        .data()
        .iter()
        .copied()
        .filter(|&s| s != 0 && lut[s as usize] == 0)
        .collect();
    unmapped.sort_unstable();
    unmapped.dedup();
    if !unmapped.is_empty() {
        let named: Vec<String> = unmapped.iter().map(|&s| classes.describe(s)).collect();
        notes.push(format!(
            "source labels left to the heuristic (not mapped; names from {}): {}",
            classes.source,
            named.join(", ")
        ));
    }

    let biliary = match &rec.biliary {
        Some(b) => Some(
            timer
                .run(Step::Biliary, || biliary::synthesize(b, &mut ct, &mut labels, &source))
                .map_err(|error| AtlasError::Biliary {
                    path: recipe_path.to_path_buf(),
                    error,
                })?,
        ),
        None => None,
    };
    if let Some(b) = &biliary
        && b.components != 1
    {
        return Err(AtlasError::file(
            recipe_path,
            format!(
                "[biliary]: the synthetic tree falls into {} pieces; adjust radii or branches",
                b.components
            ),
        ));
    }

    let mut scenario = r.scenario.clone();
    let mut present = vec![false; LabelId::MAX as usize + 1];
    labels.data().iter().for_each(|&l| present[l as usize] = true);
    scenario.keep_labels(|id| present[id as usize]);
    let mut provenance = r.provenance(&format!(
        "stylet {} (atlas import, recipe {})",
        env!("CARGO_PKG_VERSION"),
        recipe_path.display()
    ));
    provenance.notes = notes.clone();
    if let Some(b) = &rec.biliary {
        provenance.notes.push(format!(
            "synthetic dilated biliary tree (seed {}): target label {}, ducts label {}, bile {} HU",
            b.seed, b.target_label, b.duct_label, b.bile_hu
        ));
    }
    let mut manifest = Manifest::new(&rec.name, &rec.description, provenance, scenario);
    let breathing = rec.breathing.clone().unwrap_or_default();
    if breathing.motion == crate::manifest::MotionKind::Measured {
        return Err(AtlasError::file(
            &r.path,
            "[breathing] motion = \"measured\" cannot come with a recipe: attach measured fields to the imported atlas with `stylet atlas attach-motion`",
        ));
    }
    manifest.breathing = Some(breathing);

    let mut presets = None;
    let window = match &rec.window {
        Some(w) => {
            // The atlas the search walks through (its distance maps included) is part of the step.
            let report = timer.run(Step::Window, || -> Result<WindowReport, AtlasError> {
                let bad = |error| AtlasError::Manifest {
                    path: recipe_path.to_path_buf(),
                    error,
                };
                let table = manifest::label_table(&manifest.labels, &manifest.heuristic).map_err(bad)?;
                let tree = manifest::property_tree(&manifest.tissues).map_err(bad)?;
                let t = estimate_thresholds(&ct, manifest.heuristic.risk_depth_mm)
                    .map_err(|e| AtlasError::file(recipe_path, format!("CT thresholds: {e}")))?;
                let atlas = PunctureAtlas::new(ct.clone(), labels.clone(), table, tree, t)
                    .map_err(|e| AtlasError::file(recipe_path, e.to_string()))?;
                Ok(window::find_window(
                    &atlas,
                    &source,
                    &classes,
                    (w.upper_rib, w.lower_rib),
                    &w.bone_labels,
                ))
            })?;
            // The chosen window guides beginners; the others are planned paths too (scoring
            // measures a trainee against the path whose entry is nearest).
            let paths = report.paths(&classes);
            if w.adapt_presets {
                presets = presets::adapt(&mut manifest.difficulty, &report, &classes);
            } else if let Some(p) = paths.first() {
                manifest.difficulty.beginner.guided_path = Some(p.name.clone());
            }
            manifest.paths.extend(paths);
            Some(report)
        }
        None => None,
    };
    timer.run(Step::Write, || crate::write(out, &manifest, &ct, &labels))?;
    let window_found = window.as_ref().is_some_and(|w| w.found.is_some());
    let warnings = checks::warnings(&source_summary, &manifest, window_found);
    Ok(ImportReport {
        manifest,
        biliary,
        window,
        classes,
        notes,
        source: source_summary,
        warnings,
        timings: timer.timings.clone(),
        presets,
    })
}
