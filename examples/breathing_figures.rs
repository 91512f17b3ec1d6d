//! The pictures of docs/breathing.md, from one scripted session on an atlas: a needle inserted
//! along the atlas' first planned path during a breath hold, then left in place while the patient
//! breathes (the default synthetic motion, seed 1).
//!
//! - `breathing-coronal.png`, `breathing-sagittal.png`: the slice through the target at
//!   end-expiration, at end-inspiration, and the two blended (end-expiration in magenta,
//!   end-inspiration in green: what moved shows in colour, what stayed in grey);
//! - `breathing-3d.png`: the soft-tissue ray cast cut along the planned path, labels on the cut,
//!   at both moments and their blend;
//! - `breathing-displacement.png`: the liver's displacement at the target over time, with the
//!   breath hold, beside a rib's (which stays).
//!
//! It also prints the ray-casting time of the end-inspiration frame with warped rays against the
//! same frame without motion.
//!
//! `cargo run --release --example breathing_figures -- ATLAS_DIR OUT_DIR`

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use plotters::prelude::*;
use stylet_atlas::Atlas;
use stylet_dashboard::plot::{ChartColor, LineChart, Series, write_chart};
use stylet_devices::run_headless;
use stylet_devices::script::{parse, scripted_simulation};
use stylet_physics::glam::DVec3;
use stylet_physics::motion::{BreathingSettings, BreathingSignal};
use stylet_render::image::Image;
use stylet_render::mpr::{Plane, SliceSpec, Window};
use stylet_render::presets::Preset;
use stylet_render::scene::{ClipPlane, Tagging};
use stylet_render::views::{self, Moment, SessionLabels};
use stylet_render::volume::RenderVolume;

/// The needle goes in during a hold of this long (s), then the patient breathes.
const HOLD_S: f64 = 7.0;
const END_S: f64 = 30.0;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    anyhow::ensure!(args.len() == 3, "usage: breathing_figures ATLAS_DIR OUT_DIR");
    let atlas = stylet_atlas::load(Path::new(&args[1]))?;
    let out = PathBuf::from(&args[2]);
    std::fs::create_dir_all(&out)?;
    let path = atlas
        .planned_paths()
        .into_iter()
        .next()
        .ok_or_else(|| anyhow::anyhow!("the atlas has no planned path"))?;
    let depth = (path.target_mm - path.entry_mm).length() - 15.0;
    let script = format!(
        "stylet-script 1\nbreathing on\nend {END_S}\nat 0 event breath-hold\nat 0 along {p} -15\nat 1 along {p} -15\n\
         at 6 along {p} {depth:.1}\nat {HOLD_S} event breath-release\nat {END_S} along {p} {depth:.1}\n",
        p = path.name
    );
    let signal = BreathingSignal::new(BreathingSettings::on().signal).map_err(anyhow::Error::msg)?;
    // After the hold the breathing clock starts at 0: the first cycle's end-inspiration, and the
    // end-expiration pause after it (three quarters into the second cycle, g ≈ 0).
    let c0 = signal.phase(0.0);
    let ei_tick = ((HOLD_S + 0.5 * c0.period_s) * 1000.0).round() as u64;
    let c1 = signal.phase(c0.period_s + 1e-6);
    let ee_tick = ((HOLD_S + c0.period_s + 0.92 * c1.period_s) * 1000.0).round() as u64;
    let labels = SessionLabels {
        scenario: atlas
            .manifest
            .scenarios
            .first()
            .map_or("ptcd".into(), |s| s.name.clone()),
        difficulty: stylet_scoring::Difficulty::Beginner,
        seed: 1,
    };
    let parsed = parse(&script)?;
    let (mut sim, mut device) = scripted_simulation(Arc::clone(&atlas.model), &atlas.planned_paths(), &parsed)?;
    let rib = rib_point(&atlas);
    let (mut ee, mut ei) = (None, None);
    let mut trace = Vec::new();
    run_headless(&mut sim, &mut device, |input, o, sim| {
        if o.tick == ee_tick {
            ee = Some(Moment::of_simulation(sim, input, o, &labels));
        }
        if o.tick == ei_tick {
            ei = Some(Moment::of_simulation(sim, input, o, &labels));
        }
        if o.tick % 20 == 0 {
            let (m, t) = (sim.motion(), sim.motion_time_s());
            trace.push((
                o.tick as f64 / 1000.0,
                m.displacement(path.target_mm, t),
                m.displacement(rib, t),
            ));
        }
    });
    let (ee, ei) = (ee.expect("end-expiration tick"), ei.expect("end-inspiration tick"));
    println!(
        "end-expiration at {:.2} s (g = {:.3}), end-inspiration at {:.2} s (g = {:.3})",
        ee_tick as f64 / 1000.0,
        signal.g(ee.breathing.as_ref().unwrap().t_s),
        ei_tick as f64 / 1000.0,
        signal.g(ei.breathing.as_ref().unwrap().t_s)
    );

    for (plane, name) in [(Plane::Coronal, "coronal"), (Plane::Sagittal, "sagittal")] {
        let spec = SliceSpec::plane(&atlas.model, plane, path.target_mm, Window::ABDOMEN, 520);
        let a = views::slice_image(&atlas, Some(&ee), &spec)?;
        let b = views::slice_image(&atlas, Some(&ei), &spec)?;
        let title = format!("{} — {name} slice through the target", atlas.manifest.name);
        panels(&title, &a, &b, &out.join(format!("breathing-{name}.png")))?;
    }

    let volume = RenderVolume::new(Arc::clone(&atlas.model));
    let step = views::default_step_mm(&atlas);
    let (w, h) = (560, 470);
    // Cut along the planned path through the target (the same plane at both moments), with the
    // labels on the cut: the liver, the lung and the vessels show where they are.
    let axis = (path.target_mm - path.entry_mm).normalize().as_vec3();
    let scene = |m: &Moment| -> anyhow::Result<stylet_render::scene::Scene> {
        let mut s = views::scene_3d(&atlas, Some(m), Preset::Soft, Tagging::Labels, step)?;
        s.clip = Some(ClipPlane::through_tool(path.target_mm.as_vec3(), axis, &s.camera));
        Ok(s)
    };
    let a = stylet_render::raycast::render(&volume, &scene(&ee)?, w, h).image;
    let t = Instant::now();
    let b = stylet_render::raycast::render(&volume, &scene(&ei)?, w, h).image;
    let warped_s = t.elapsed().as_secs_f64();
    let mut still = scene(&ei)?;
    still.motion = None;
    let t = Instant::now();
    let _ = stylet_render::raycast::render(&volume, &still, w, h);
    let static_s = t.elapsed().as_secs_f64();
    println!(
        "ray casting {w} × {h}, soft: warped rays {:.0} ms, static {:.0} ms, ratio {:.2}",
        warped_s * 1e3,
        static_s * 1e3,
        warped_s / static_s
    );
    let title = format!(
        "{} — soft tissue cut along the planned path, labels on the cut, needle left in the liver",
        atlas.manifest.name
    );
    panels(&title, &a, &b, &out.join("breathing-3d.png"))?;

    let series = |name: &str, color: ChartColor, f: &dyn Fn(&(f64, DVec3, DVec3)) -> f64| Series {
        name: name.into(),
        color,
        points: trace.iter().map(|r| (r.0, f(r))).collect(),
        ..Default::default()
    };
    let chart = LineChart {
        title: format!("Breathing motion — {} (synthetic, 12 mm, seed 1)", atlas.manifest.name),
        x_label: "time (s)".into(),
        y_label: "displacement (mm)".into(),
        series: vec![
            series("target, cranio-caudal (z)", ChartColor(214, 39, 40), &|r| r.1.z),
            series("target, anterior (y)", ChartColor(31, 119, 180), &|r| r.1.y),
            series("rib, |u|", ChartColor(127, 127, 127), &|r| r.2.length()),
        ],
        markers: vec![
            (0.0, "breath hold".into()),
            (HOLD_S, "release".into()),
            (ei_tick as f64 / 1000.0, "EI picture".into()),
            (ee_tick as f64 / 1000.0, "EE picture".into()),
        ],
        ..Default::default()
    };
    write_chart(&chart, &out.join("breathing-displacement.png"), (1200, 520))?;
    println!("pictures written to {}", out.display());
    Ok(())
}

/// A point inside a rib: the bone voxel (D_bone > 1 mm) nearest the first path's entry.
fn rib_point(atlas: &Atlas) -> DVec3 {
    let entry = atlas.planned_paths()[0].entry_mm;
    let d = atlas.model.bone_distance();
    d.data()
        .iter()
        .enumerate()
        .filter(|&(_, &v)| v > 1.0)
        .map(|(i, _)| d.grid().linear_to_world(i))
        .min_by(|a, b| (*a - entry).length().total_cmp(&(*b - entry).length()))
        .unwrap_or(entry)
}

/// End-expiration | end-inspiration | both blended (EE magenta, EI green), titled.
fn panels(title: &str, ee: &Image, ei: &Image, png: &Path) -> anyhow::Result<()> {
    stylet_render::fonts::ensure_fonts();
    let (w, h) = (ee.width, ee.height);
    let (gap, top) = (12u32, 70u32);
    let width = 3 * w + 4 * gap;
    let height = h + top + gap;
    let mut buf = vec![255u8; (width * height * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (width, height)).into_drawing_area();
        root.fill(&WHITE)?;
        let font = (stylet_render::fonts::SANS, 22).into_font();
        root.draw(&Text::new(title.to_string(), (gap as i32, 8), font.clone()))?;
        let small = (stylet_render::fonts::SANS, 18).into_font();
        for (k, label) in [
            "end-expiration (the CT)",
            "end-inspiration",
            "blend: EE magenta, EI green",
        ]
        .iter()
        .enumerate()
        {
            let x = (gap + k as u32 * (w + gap)) as i32;
            root.draw(&Text::new(label.to_string(), (x, 40), small.clone()))?;
        }
        for y in 0..h {
            for x in 0..w {
                let i = (y * w + x) as usize;
                let (p, q) = (ee.rgba[i], ei.rgba[i]);
                let grey = |c: [u8; 4]| ((c[0] as u32 + c[1] as u32 + c[2] as u32) / 3) as u8;
                let blend = [grey(p), grey(q), grey(p)];
                for (k, c) in [[p[0], p[1], p[2]], [q[0], q[1], q[2]], blend].iter().enumerate() {
                    let px = (gap + k as u32 * (w + gap) + x) as i32;
                    root.draw_pixel((px, (top + y) as i32), &RGBColor(c[0], c[1], c[2]))?;
                }
            }
        }
        root.present()?;
    }
    image_png(&buf, width, height, png)
}

fn image_png(rgb: &[u8], width: u32, height: u32, png: &Path) -> anyhow::Result<()> {
    let mut img = Image::new(width, height);
    for (o, c) in img.rgba.iter_mut().zip(rgb.chunks_exact(3)) {
        *o = [c[0], c[1], c[2], 255];
    }
    img.write_png(png)?;
    Ok(())
}
