//! `stylet demo`: the main job on the embedded default. For now: build the phantom atlas, load it
//! back through the validating loader and print its summary (later issues add sessions, scores and
//! the dashboard).

use std::path::PathBuf;
use std::time::Instant;

use clap::Args;

#[derive(Debug, Args)]
pub struct DemoArgs {
    /// Where to write the demo's files.
    #[arg(long, default_value = "target/stylet-demo")]
    pub out: PathBuf,
    /// Phantom seed.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

pub fn run(args: DemoArgs) -> anyhow::Result<()> {
    let atlas_dir = args.out.join("atlases/phantom");
    let t0 = Instant::now();
    super::atlas::build_phantom(
        &atlas_dir,
        &stylet_atlas::phantom::PhantomConfig {
            seed: args.seed,
            ..Default::default()
        },
    )?;
    let built = t0.elapsed();
    let t1 = Instant::now();
    let atlas = stylet_atlas::load(&atlas_dir)?;
    let loaded = t1.elapsed();
    sayf!("{}", stylet_atlas::summary::Summary::of(&atlas).to_text());
    sayf!(
        "phantom generated and written in {:.2} s, loaded and validated in {:.2} s",
        built.as_secs_f64(),
        loaded.as_secs_f64()
    );
    let png = args.out.join("phantom.png");
    stylet_render::figure::atlas_figure(
        &atlas.model,
        &atlas.manifest.name,
        &super::atlas::insertion_paths(&atlas),
        &png,
    )?;
    sayf!("three orthogonal slices with the label overlay: {}", png.display());
    Ok(())
}
