//! `stylet atlas …`: build the phantom, import real CT, inspect atlases.

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::{Args, Subcommand};

use super::say;
use stylet_atlas::phantom::{self, PhantomConfig};
use stylet_atlas::summary::Summary;

#[derive(Debug, Subcommand)]
pub enum AtlasCommand {
    /// Generate the procedural phantom atlas (the embedded default).
    Phantom(PhantomArgs),
    /// Import a CT and label maps (e.g. a TotalSegmentator output folder) following a recipe.
    Import(ImportArgs),
    /// Import a DICOM CT series as a heuristic-only atlas.
    ImportDicom(ImportDicomArgs),
    /// Make a PTCD atlas from a CT and an automatic segmentation, no recipe needed (labels by
    /// structure name: TotalSegmentator's classes built in).
    New(NewArgs),
    /// Print an atlas' summary; optionally write JSON or a PNG of three orthogonal slices.
    Inspect(InspectArgs),
    /// Attach measured breathing motion to an atlas: displacement fields of the surrogate model
    /// (NIfTI vector images as ITK and ANTs write them) and the surrogate signal (CSV
    /// `time_s,g`); checked, copied into the atlas' `motion/` folder (docs/breathing.md
    /// "Measured motion").
    AttachMotion(AttachMotionArgs),
    /// Smoke-test an atlas' guided path with generated example scripts and write its validation
    /// record (`validation.toml`), which publishing requires.
    Validate(ValidateArgs),
    /// Upload a validated atlas to a scoring service (an admin's or instructor's `full` API
    /// token in STYLET_TOKEN), which checks it again and lists it in its scenario catalogue.
    Publish(PublishArgs),
    /// Withdraw an atlas from a scoring service's catalogue (an admin's `full` API token in
    /// STYLET_TOKEN): it takes no new sessions; the sessions recorded on it stay readable,
    /// replayable and scored.
    Unpublish(UnpublishArgs),
}

#[derive(Debug, Args)]
pub struct UnpublishArgs {
    /// The atlas' content hash (the catalogue lists it; `stylet atlas inspect` prints it).
    pub content_hash: String,
    /// The service, e.g. https://stylet.example.org (plain http only to this computer).
    #[arg(long)]
    pub server: String,
    /// Environment variable holding the API token.
    #[arg(long, default_value = "STYLET_TOKEN")]
    pub token_env: String,
}

#[derive(Debug, Args)]
pub struct ValidateArgs {
    /// Atlas directory.
    pub dir: PathBuf,
}

#[derive(Debug, Args)]
pub struct PublishArgs {
    /// Atlas directory (validated: `stylet atlas new` or `stylet atlas validate`).
    pub dir: PathBuf,
    /// The service, e.g. https://stylet.example.org (plain http only to this computer).
    #[arg(long)]
    pub server: String,
    /// Environment variable holding the API token (never a command-line argument: other users
    /// can read those).
    #[arg(long, default_value = "STYLET_TOKEN")]
    pub token_env: String,
}

#[derive(Debug, Args)]
pub struct ImportArgs {
    /// Import recipe (e.g. atlases/ts-abdomen/recipe.toml).
    #[arg(long)]
    pub recipe: PathBuf,
    /// Directory holding the recipe's source files.
    #[arg(long)]
    pub data: PathBuf,
    /// Output atlas directory.
    #[arg(long)]
    pub out: PathBuf,
    /// Leave out the breathing motion the atlas gets by default (docs/breathing.md "Atlases"):
    /// its sessions cannot breathe.
    #[arg(long)]
    pub no_breathing: bool,
}

#[derive(Debug, Args)]
pub struct NewArgs {
    /// The CT: a NIfTI file in HU, or a folder holding one DICOM series.
    #[arg(long)]
    pub ct: PathBuf,
    /// The labels: one multi-label NIfTI, a TotalSegmentator output folder of per-structure
    /// masks (<structure>.nii.gz), or a binary DICOM SEG on the CT's grid.
    #[arg(long)]
    pub labels: PathBuf,
    /// Output atlas directory.
    #[arg(long)]
    pub out: PathBuf,
    /// Atlas name (default: the output folder's name).
    #[arg(long)]
    pub name: Option<String>,
    /// Class table of a multi-label file: CSV with `id` and `structure` columns (default:
    /// TotalSegmentator's "total" classes).
    #[arg(long)]
    pub classes: Option<PathBuf>,
    /// Corrections to the default PTCD mapping: CSV with `structure` and `label` columns, the
    /// label an atlas label's id or name, `heuristic` or `heuristic-bone`.
    #[arg(long)]
    pub map: Option<PathBuf>,
    /// A label map that covers part of the CT and kept its header: label voxel (i,j,k) is CT
    /// voxel (i,j,k) + offset, e.g. 0,0,82.
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true)]
    pub offset_voxels: Option<Vec<i64>>,
    /// Leave out the breathing motion the atlas gets by default (docs/breathing.md "Atlases"):
    /// its sessions cannot breathe.
    #[arg(long)]
    pub no_breathing: bool,
}

#[derive(Debug, Args)]
pub struct ImportDicomArgs {
    /// Directory with the series' DICOM files (one slice per file).
    #[arg(long)]
    pub series: PathBuf,
    /// Output atlas directory.
    #[arg(long)]
    pub out: PathBuf,
    /// Atlas name.
    #[arg(long, default_value = "dicom")]
    pub name: String,
}

#[derive(Debug, Args)]
pub struct PhantomArgs {
    /// Output atlas directory.
    #[arg(long)]
    pub out: PathBuf,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Grid size in voxels, e.g. 256,256,200.
    #[arg(long, value_delimiter = ',', default_values_t = [256usize, 256, 200])]
    pub dims: Vec<usize>,
    /// Voxel spacing in mm, one value or three (x,y,z).
    #[arg(long, value_delimiter = ',', default_values_t = [1.5f64])]
    pub spacing: Vec<f64>,
    /// Image noise (standard deviation, HU).
    #[arg(long, default_value_t = 10.0)]
    pub noise: f64,
    /// Standard deviation of the scanner's point-spread function (mm).
    #[arg(long, default_value_t = 0.7)]
    pub psf: f64,
    /// Leave out the breathing motion the atlas gets by default (docs/breathing.md "Atlases"):
    /// its sessions cannot breathe.
    #[arg(long)]
    pub no_breathing: bool,
}

#[derive(Debug, Args)]
pub struct AttachMotionArgs {
    /// Atlas directory.
    pub dir: PathBuf,
    /// a₁: the displacement at an average end-inspiration (u = a₁g + a₂g′ + a₃).
    #[arg(long)]
    pub a1: PathBuf,
    /// a₂: the displacement per unit of g′ (hysteresis).
    #[arg(long)]
    pub a2: Option<PathBuf>,
    /// a₃: a constant offset.
    #[arg(long)]
    pub a3: Option<PathBuf>,
    /// The surrogate signal recorded with the fields; without it sessions use the seeded Lujan
    /// signal.
    #[arg(long)]
    pub signal: Option<PathBuf>,
}

#[derive(Debug, Args)]
pub struct InspectArgs {
    /// Atlas directory.
    pub dir: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
    /// Write three orthogonal slices with the label overlay to this PNG.
    #[arg(long)]
    pub png: Option<PathBuf>,
}

pub fn run(cmd: AtlasCommand) -> anyhow::Result<()> {
    match cmd {
        AtlasCommand::Phantom(a) => {
            let spacing = match a.spacing.as_slice() {
                [s] => [*s; 3],
                [x, y, z] => [*x, *y, *z],
                other => anyhow::bail!("--spacing takes one or three values, got {}", other.len()),
            };
            let [x, y, z] = a.dims[..] else {
                anyhow::bail!("--dims takes three values (x,y,z), got {}", a.dims.len());
            };
            let config = PhantomConfig {
                dims: [x, y, z],
                spacing_mm: spacing,
                seed: a.seed,
                noise_hu: a.noise,
                psf_mm: a.psf,
            };
            build_phantom(&a.out, &config, !a.no_breathing)?;
            sayf!("phantom atlas written to {}", a.out.display());
            say(breathing_line(!a.no_breathing));
            Ok(())
        }
        AtlasCommand::Import(a) => {
            let report = stylet_atlas::import::import_with(&a.recipe, &a.data, &a.out, !a.no_breathing)?;
            sayf!("atlas '{}' written to {}", report.manifest.name, a.out.display());
            say(report.to_text().trim_end());
            say(breathing_line(
                report.manifest.breathing_or_default().motion != stylet_atlas::manifest::MotionKind::None,
            ));
            Ok(())
        }
        AtlasCommand::New(a) => {
            let name = match &a.name {
                Some(n) => n.clone(),
                None => a
                    .out
                    .file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .context("--out has no folder name; give --name")?,
            };
            let offset = match a.offset_voxels.as_deref() {
                None => [0, 0, 0],
                Some(&[i, j, k]) => [i, j, k],
                Some(other) => anyhow::bail!("--offset-voxels takes three numbers, got {}", other.len()),
            };
            let args = stylet_atlas::import::new::NewAtlas {
                ct: a.ct,
                labels: a.labels,
                classes: a.classes,
                map: a.map,
                offset_voxels: offset,
                name,
                breathing: !a.no_breathing,
            };
            let (ct_source, labels_source) = (args.ct.display().to_string(), args.labels.display().to_string());
            let mut on_step = progress();
            let made = stylet_atlas::import::new::new_atlas(&args, &a.out, &mut on_step)?;
            let report = &made.import;
            sayf!("atlas '{}' written to {}", report.manifest.name, a.out.display());
            say(report.to_text().trim_end());
            let outcomes = smoke_test(&made.atlas, &a.out, &made.scripts)?;
            let smoke = report_rows(&outcomes);
            // The report shows a failed smoke test too: it is what the clinician must see.
            let mut timer = stylet_atlas::import::steps::StepTimer::new(&mut on_step);
            let files = timer.run(stylet_atlas::import::steps::Step::Report, || {
                stylet_atlas_report::write_report(
                    &a.out.join("report"),
                    &stylet_atlas_report::ReportInput {
                        atlas: &made.atlas,
                        import: report,
                        smoke: &smoke,
                        ct_source: &ct_source,
                        labels_source: &labels_source,
                    },
                )
            })?;
            sayf!("- validation report: {}", files.html.display());
            let failures: Vec<String> = outcomes.iter().filter_map(|o| o.failure()).collect();
            if !failures.is_empty() {
                anyhow::bail!(
                    "the new scenario in {} failed its smoke test (the atlas is kept for a look): {}",
                    a.out.display(),
                    failures.join("; ")
                );
            }
            Ok(())
        }
        AtlasCommand::Validate(a) => validate(&a.dir),
        AtlasCommand::AttachMotion(a) => {
            let atlas = stylet_atlas::attach_motion::attach_measured(
                &a.dir,
                &a.a1,
                a.a2.as_deref(),
                a.a3.as_deref(),
                a.signal.as_deref(),
            )?;
            sayf!("measured breathing motion attached to {}", a.dir.display());
            say(stylet_atlas::summary::BreathingSummary::of(&atlas).to_text().trim_end());
            Ok(())
        }
        AtlasCommand::Publish(a) => publish(&a),
        AtlasCommand::Unpublish(a) => unpublish(&a),
        AtlasCommand::ImportDicom(a) => {
            let series = stylet_atlas::import::dicom::import_series(&a.series, &a.out, &a.name)?;
            let g = series.ct.grid();
            let s = g.spacing_mm();
            let d = g.dims();
            say(&format!(
                "atlas '{}' written to {}: {}×{}×{} voxels of {:.3}×{:.3}×{:.3} mm (slice thickness {}), {} HU … {} HU",
                a.name,
                a.out.display(),
                d[0],
                d[1],
                d[2],
                s[0],
                s[1],
                s[2],
                series
                    .slice_thickness_mm
                    .map(|t| format!("{t:.1} mm"))
                    .unwrap_or_else(|| "not given".into()),
                series.ct.data().iter().copied().fold(f32::INFINITY, f32::min),
                series.ct.data().iter().copied().fold(f32::NEG_INFINITY, f32::max),
            ));
            say(
                "breathing: none attached (no organ is labelled to place the diaphragm); this patient does not breathe",
            );
            Ok(())
        }
        AtlasCommand::Inspect(a) => {
            let atlas = stylet_atlas::load(&a.dir)?;
            let summary = Summary::of(&atlas);
            if a.json {
                sayf!("{}", serde_json::to_string_pretty(&summary)?);
            } else {
                say(summary.to_text().trim_end());
            }
            if let Some(png) = a.png {
                stylet_render::figure::atlas_figure(&atlas.model, &atlas.manifest.name, &insertion_paths(&atlas), &png)
                    .with_context(|| format!("writing {}", png.display()))?;
                if !a.json {
                    sayf!("slices written to {}", png.display());
                }
            }
            Ok(())
        }
    }
}

/// What an atlas-writing command says about the breathing motion it attached.
fn breathing_line(attached: bool) -> &'static str {
    if attached {
        "breathing: the synthetic motion is attached (`stylet atlas inspect` reports its inversion error; --no-breathing leaves it out)"
    } else {
        "breathing: none attached; this patient does not breathe"
    }
}

/// Generates the phantom and writes it as an atlas directory, with the synthetic breathing
/// motion attached when `breathing`.
pub fn build_phantom(out: &Path, config: &PhantomConfig, breathing: bool) -> anyhow::Result<()> {
    let mut p = phantom::generate(config)?;
    p.manifest.breathing = Some(stylet_atlas::manifest::BreathingToml::attached(breathing));
    stylet_atlas::write(out, &p.manifest, &p.ct, &p.partial)?;
    Ok(())
}

/// The atlas' predefined insertion paths as (entry, target) pairs for drawing.
pub fn insertion_paths(atlas: &stylet_atlas::Atlas) -> Vec<(stylet_physics::glam::DVec3, stylet_physics::glam::DVec3)> {
    atlas
        .planned_paths()
        .iter()
        .map(|p| (p.entry_mm, p.target_mm))
        .collect()
}

/// Runs the scenario's example scripts through the physics, the recorder and the scorer (the
/// pipeline a trainee's session takes; `stylet_scoring::smoke`), prints each outcome and keeps
/// the validation record in `dir` only when every script passed (an old record is removed
/// otherwise). Returns the outcomes for the report; an error is a script that could not be run or
/// scored at all.
fn smoke_test(
    atlas: &stylet_atlas::Atlas,
    dir: &Path,
    generated: &[stylet_atlas::import::scripts::GeneratedScript],
) -> anyhow::Result<Vec<stylet_scoring::smoke::SmokeOutcome>> {
    use stylet_atlas::validation;
    use stylet_scoring::smoke;
    if generated.is_empty() {
        say("- smoke test: no planned path, so no example scripts");
        validation::remove_record(dir)?;
        return Ok(Vec::new());
    }
    let tmp = tempfile::tempdir().context("cannot make a temporary folder for the smoke test")?;
    let bar = spinner("smoke test: recording and scoring the example scripts");
    let outcomes = smoke::run(atlas, &smoke::smoke_scripts(generated), tmp.path());
    bar.finish_and_clear();
    let outcomes = outcomes.context("smoke test")?;
    for o in &outcomes {
        say(&format!(
            "- smoke test scripts/{}: {} — {} ({}; {:.1} s)",
            o.script,
            if o.passed { "ok" } else { "FAILED" },
            o.expect.describe(),
            o.got,
            o.seconds,
        ));
    }
    if smoke::first_failure(&outcomes).is_none() {
        validation::write_record(dir, &smoke::record(atlas, &outcomes))?;
        sayf!(
            "- validation record: {}",
            dir.join(validation::VALIDATION_FILE).display()
        );
    } else {
        validation::remove_record(dir)?;
    }
    Ok(outcomes)
}

/// The smoke test's outcomes as the report shows them.
fn report_rows(outcomes: &[stylet_scoring::smoke::SmokeOutcome]) -> Vec<stylet_atlas_report::SmokeResult> {
    outcomes
        .iter()
        .map(|o| stylet_atlas_report::SmokeResult {
            script: o.script.clone(),
            expected: o.expect.describe(),
            got: o.got.clone(),
            passed: o.passed,
            seconds: o.seconds,
        })
        .collect()
}

/// The API token in the environment variable `name`.
fn token_from(name: &str, whose: &str) -> anyhow::Result<String> {
    std::env::var(name)
        .ok()
        .filter(|t| !t.trim().is_empty())
        .map(|t| t.trim().to_string())
        .with_context(|| format!("set {name} to {whose} `full` API token (dashboard: API tokens)"))
}

/// `stylet atlas unpublish HASH --server URL`: the token from the environment.
fn unpublish(a: &UnpublishArgs) -> anyhow::Result<()> {
    let token = token_from(&a.token_env, "an admin's")?;
    let client = stylet_app::service_client::ServiceClient::new(&a.server)?;
    let withdrawn = client.unpublish_atlas(&token, a.content_hash.trim())?;
    sayf!(
        "atlas '{}' ({}) withdrawn from {}: it takes no new sessions; the sessions recorded on it stay readable and replayable",
        withdrawn.name,
        withdrawn.content_hash,
        client.base()
    );
    Ok(())
}

/// `stylet atlas publish DIR --server URL`: the token from the environment, never an argument.
fn publish(a: &PublishArgs) -> anyhow::Result<()> {
    let token = token_from(&a.token_env, "an admin's or instructor's")?;
    let client = stylet_app::service_client::ServiceClient::new(&a.server)?;
    let started = std::time::Instant::now();
    let bar = spinner("checking and packing the atlas");
    let show = |p: stylet_app::publish_client::PublishProgress| {
        use stylet_app::publish_client::PublishProgress as P;
        match p {
            P::Packed { bytes } => {
                bar.set_length(bytes);
                bar.set_style(
                    indicatif::ProgressStyle::with_template("{msg} {bar:30} {bytes}/{total_bytes} ({elapsed})")
                        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
                );
                bar.set_message("uploading");
            }
            P::Sent { bytes, .. } => bar.set_position(bytes),
            P::Checking => {
                bar.set_style(spinner_style());
                bar.set_message("the service checks the atlas and runs its smoke test");
            }
        }
    };
    let published = client.publish_atlas_with(&token, &a.dir, &show);
    bar.finish_and_clear();
    let published = published?;
    sayf!(
        "atlas '{}' ({}) {} on {} ({:.1} s)",
        published.name,
        published.content_hash,
        if published.new {
            "published"
        } else {
            "was already published"
        },
        client.base(),
        started.elapsed().as_secs_f64()
    );
    for line in &published.smoke {
        sayf!("- the service's smoke test: {line}");
    }
    Ok(())
}

/// `stylet atlas validate DIR`: loads the atlas, writes the example scripts of its guided path to
/// `DIR/scripts/`, smoke-tests them and writes `DIR/validation.toml` when every one passed.
fn validate(dir: &Path) -> anyhow::Result<()> {
    let bar = spinner("loading the atlas (validation, distance maps)");
    let atlas = stylet_atlas::load(dir);
    bar.finish_and_clear();
    let atlas = atlas?;
    let generated = stylet_scoring::smoke::example_scripts(&atlas);
    if generated.is_empty() {
        anyhow::bail!(
            "{}: the atlas has no planned insertion path, so there is nothing to smoke-test (an atlas without one cannot be published)",
            dir.display()
        );
    }
    stylet_atlas::import::new::write_scripts(dir, &generated)?;
    let outcomes = smoke_test(&atlas, dir, &generated)?;
    if let Some(failure) = stylet_scoring::smoke::first_failure(&outcomes) {
        anyhow::bail!("{}: the smoke test failed: {failure}", dir.display());
    }
    sayf!("atlas '{}' ({}) is validated", atlas.manifest.name, atlas.content_hash);
    Ok(())
}

fn spinner_style() -> indicatif::ProgressStyle {
    indicatif::ProgressStyle::with_template("{spinner} {msg} ({elapsed})")
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_spinner())
}

/// A spinner on standard error while `message` runs (hidden when standard error is not a
/// terminal); the caller clears it.
fn spinner(message: &str) -> indicatif::ProgressBar {
    let b = indicatif::ProgressBar::new_spinner().with_style(spinner_style());
    b.set_message(message.to_string());
    b.enable_steady_tick(std::time::Duration::from_millis(120));
    b
}

/// A spinner on standard error for each step of `atlas new` (hidden when standard error is not a
/// terminal), and a line with its time when it ends.
fn progress() -> impl FnMut(stylet_atlas::import::steps::StepEvent) {
    use stylet_atlas::import::steps::StepEvent;
    let mut bar: Option<indicatif::ProgressBar> = None;
    move |e| match e {
        StepEvent::Started(step) => {
            bar = Some(spinner(step.describe()));
        }
        StepEvent::Finished(step, took) => {
            if let Some(b) = bar.take() {
                b.finish_and_clear();
                if !b.is_hidden() {
                    eprintln!("✓ {} ({:.1} s)", step.describe(), took.as_secs_f64());
                }
            }
        }
    }
}
