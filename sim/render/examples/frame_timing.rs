//! Times CPU reference frames of an atlas (for profiling with `perf`; the measured comparison is
//! `cargo bench --bench render` and scripts/vtk-compare.py).
//!
//! `cargo run --release -p stylet-render --example frame_timing -- ATLAS_DIR [WxH] [frames] [preset]`
//!
//! The frames are drawn in two runs, back to back as scripts/vtk-compare.py times VTK's (each
//! after an untimed first frame): first with the samples evaluated on SIMD lanes, then one at a
//! time; the last images of the two runs must be equal. The runs are not interleaved frame by
//! frame, so neither kind starts from caches the other filled.

use std::sync::Arc;
use std::time::Instant;

use stylet_physics::glam::Vec3;
use stylet_render::presets::{Preset, render_settings};
use stylet_render::raycast::{Lanes, render_with};
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
    let mut last = Vec::new();
    let (mut lanes_ms, mut one_ms) = (Vec::new(), Vec::new());
    for lanes in [Lanes::Auto, Lanes::OneAtATime] {
        // An untimed first frame (it builds the cube mask), as VTK's first is left out.
        let mut out = (frames > 0).then(|| render_with(&volume, &scene, w, h, lanes));
        for _ in 0..frames {
            let t = Instant::now();
            let o = render_with(&volume, &scene, w, h, lanes);
            let ms = t.elapsed().as_secs_f64() * 1e3;
            println!(
                "{w}x{h} {} {lanes:?}: {ms:.1} ms, {} samples",
                preset.as_str(),
                o.samples
            );
            if lanes == Lanes::Auto {
                lanes_ms.push(ms);
            } else {
                one_ms.push(ms);
            }
            out = Some(o);
        }
        last.extend(out);
    }
    if let [a, b] = &last[..] {
        assert_eq!(a, b, "the lanes changed the picture");
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    if frames > 0 {
        let (a, b) = (median(&mut lanes_ms), median(&mut one_ms));
        println!("median: lanes {a:.1} ms, one at a time {b:.1} ms, ratio {:.2}", b / a);
    }
    if let (Some(path), Some(out)) = (args.get(5), last.first()) {
        out.image.write_png(std::path::Path::new(path)).unwrap();
    }
}
