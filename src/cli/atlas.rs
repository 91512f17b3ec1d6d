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
}

#[derive(Debug, Args)]
pub struct NewArgs {
    /// The CT: a NIfTI file in HU, or a folder holding one DICOM series.
    #[arg(long)]
    pub ct: PathBuf,
    /// The labels: one multi-label NIfTI, or a TotalSegmentator output folder of per-structure
    /// masks (<structure>.nii.gz).
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
            build_phantom(&a.out, &config)?;
            sayf!("phantom atlas written to {}", a.out.display());
            Ok(())
        }
        AtlasCommand::Import(a) => {
            let report = stylet_atlas::import::import(&a.recipe, &a.data, &a.out)?;
            sayf!("atlas '{}' written to {}", report.manifest.name, a.out.display());
            say(report.to_text().trim_end());
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
            };
            let (ct_source, labels_source) = (args.ct.display().to_string(), args.labels.display().to_string());
            let mut on_step = progress();
            let made = stylet_atlas::import::new::new_atlas(&args, &a.out, &mut on_step)?;
            let report = &made.import;
            sayf!("atlas '{}' written to {}", report.manifest.name, a.out.display());
            say(report.to_text().trim_end());
            let smoke = smoke_test(&made)?;
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
            let failures: Vec<String> = smoke
                .iter()
                .filter(|s| !s.passed)
                .map(|s| format!("scripts/{} should: {}; got: {}", s.script, s.expected, s.got))
                .collect();
            if !failures.is_empty() {
                anyhow::bail!(
                    "the new scenario in {} failed its smoke test (the atlas is kept for a look): {}",
                    a.out.display(),
                    failures.join("; ")
                );
            }
            Ok(())
        }
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

/// Generates the phantom and writes it as an atlas directory.
pub fn build_phantom(out: &Path, config: &PhantomConfig) -> anyhow::Result<()> {
    let p = phantom::generate(config)?;
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

/// Runs the new scenario's generated scripts through the physics, the recorder and the scorer
/// (the pipeline a trainee's session takes): the success script must reach and confirm the target
/// with no risk hit or bone contact, the risk script must hit the structure it names. Returns
/// each outcome (the caller reports them and fails on any failure, keeping the atlas for a look);
/// an error is a script that could not be run or scored at all.
fn smoke_test(
    made: &stylet_atlas::import::new::NewAtlasReport,
) -> anyhow::Result<Vec<stylet_atlas_report::SmokeResult>> {
    use stylet_atlas::import::scripts::Expectation;
    if made.scripts.is_empty() {
        say("- smoke test: no planned path, so no example scripts");
        return Ok(Vec::new());
    }
    let atlas = &made.atlas;
    let scorer = stylet_scoring::Scorer::new(atlas, stylet_scoring::Rubric::default_rubric(), None)
        .map_err(|e| anyhow::anyhow!(e))?;
    let tmp = tempfile::tempdir().context("cannot make a temporary folder for the smoke test")?;
    let mut results = Vec::new();
    for s in &made.scripts {
        let started = std::time::Instant::now();
        let scenario = s.file_name.trim_end_matches(".txt");
        let session = tmp.path().join(format!("{scenario}.mcap"));
        let info = stylet_recorder::SessionInfo {
            trainee: "smoke-test",
            scenario,
            difficulty: "beginner",
            seed: 0,
            atlas_id: &atlas.manifest.name,
            atlas_hash: &atlas.content_hash,
        };
        super::script::record_script_text(atlas, &s.text, &session, &info)
            .with_context(|| format!("smoke test: running scripts/{}", s.file_name))?;
        let r = scorer
            .score_file(&session)
            .map_err(|e| anyhow::anyhow!("smoke test: scoring scripts/{}: {e}", s.file_name))?;
        let m = &r.metrics;
        let hits: Vec<&str> = m.risk_hits.iter().map(|h| h.structure.as_str()).collect();
        let (ok, what) = match &s.expect {
            Expectation::Success => (
                r.replay_verified && m.target_reached && m.target_confirmed && hits.is_empty() && m.bone_contacts == 0,
                "reaches and confirms the target, no risk hit, no bone contact".to_string(),
            ),
            Expectation::Hit { name, .. } => (
                r.replay_verified && hits.first() == Some(&name.as_str()),
                format!("hits the {name} first"),
            ),
        };
        let got = format!(
            "target reached {}, confirmed {}, risk hits [{}], bone contacts {}, replay verified {}",
            m.target_reached,
            m.target_confirmed,
            hits.join(", "),
            m.bone_contacts,
            r.replay_verified
        );
        let seconds = started.elapsed().as_secs_f64();
        say(&format!(
            "- smoke test scripts/{}: {} — {} ({got}; {seconds:.1} s)",
            s.file_name,
            if ok { "ok" } else { "FAILED" },
            what,
        ));
        results.push(stylet_atlas_report::SmokeResult {
            script: s.file_name.clone(),
            expected: what,
            got,
            passed: ok,
            seconds,
        });
    }
    Ok(results)
}

/// A spinner on standard error for each step of `atlas new` (hidden when standard error is not a
/// terminal), and a line with its time when it ends.
fn progress() -> impl FnMut(stylet_atlas::import::steps::StepEvent) {
    use stylet_atlas::import::steps::StepEvent;
    let mut bar: Option<indicatif::ProgressBar> = None;
    move |e| match e {
        StepEvent::Started(step) => {
            let b = indicatif::ProgressBar::new_spinner().with_style(
                indicatif::ProgressStyle::with_template("{spinner} {msg} ({elapsed})")
                    .unwrap_or_else(|_| indicatif::ProgressStyle::default_spinner()),
            );
            b.set_message(step.describe());
            b.enable_steady_tick(std::time::Duration::from_millis(120));
            bar = Some(b);
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
