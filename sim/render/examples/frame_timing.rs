//! Times CPU reference frames of an atlas (for profiling with `perf`; the measured comparison is
//! `cargo bench --bench render` and scripts/vtk-compare.py).
//!
//! `cargo run --release -p stylet-render --example frame_timing -- ATLAS_DIR [WxH] [frames] [preset]`

use std::sync::Arc;
use std::time::Instant;

use stylet_physics::glam::Vec3;
use stylet_render::presets::{Preset, render_settings};
use stylet_render::raycast::render;
use stylet_render::scene::{Camera, Light, Quality, Scene, Tagging};
use stylet_render::tools::ToolState;
use stylet_render::transfer::TransferFunction;
use stylet_render::volume::RenderVolume;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let Some(dir) = args.get(1) else {
        eprintln!("usage: frame_timing ATLAS_DIR [WxH] [frames] [skin|soft|bone] [out.png]");
        std::process::exit(2);
    };
    let (w, h) = args
        .get(2)
        .and_then(|s| s.split_once('x'))
        .and_then(|(a, b)| Some((a.parse().ok()?, b.parse().ok()?)))
        .unwrap_or((512u32, 512u32));
    let frames: usize = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(3);
    let preset = args.get(4).and_then(|s| Preset::parse(s)).unwrap_or(Preset::Soft);
    let atlas = match stylet_atlas::load(std::path::Path::new(dir)) {
        Ok(a) => a,
        Err(e) => {
            eprintln!("{dir}: {e}");
            std::process::exit(1);
        }
    };
    let volume = RenderVolume::new(Arc::clone(&atlas.model));
    let g = volume.atlas.ct().grid();
    let [nx, ny, nz] = g.dims();
    let (a, b) = (g.voxel_to_world(0, 0, 0), g.voxel_to_world(nx - 1, ny - 1, nz - 1));
    let camera = Camera::framing(a.min(b).as_vec3(), a.max(b).as_vec3(), 25.0, 15.0);
    let scene = Scene {
        camera,
        transfer: TransferFunction::from_preset(preset.of(&render_settings(&atlas.manifest))).unwrap(),
        light: Light::over_shoulder(&camera),
        clip: None,
        tagging: Tagging::Off,
        quality: Quality::fast(0.5),
        tools: ToolState::default(),
        background: Vec3::new(0.05, 0.05, 0.07),
        deformed: None,
        motion: None,
    };
    let _ = volume.cell_ranges(scene.quality.occupancy_cells);
    let mut last = None;
    for _ in 0..frames {
        let t = Instant::now();
        let out = render(&volume, &scene, w, h);
        println!(
            "{w}x{h} {}: {:.1} ms, {} samples",
            preset.as_str(),
            t.elapsed().as_secs_f64() * 1e3,
            out.samples
        );
        last = Some(out);
    }
    if let (Some(path), Some(out)) = (args.get(5), last) {
        out.image.write_png(std::path::Path::new(path)).unwrap();
    }
}
