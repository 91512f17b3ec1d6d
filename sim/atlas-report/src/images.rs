//! The report's pictures, drawn by the CPU reference renderers.

use std::path::Path;
use std::sync::Arc;

use stylet_physics::glam::DVec3;
use stylet_render::presets::Preset;
use stylet_render::scene::Tagging;
use stylet_render::tools::{NeedleShape, ToolState};
use stylet_render::views;
use stylet_render::volume::RenderVolume;

use crate::{ReportError, ReportInput, VIEW_PX};

/// A picture of the report: its file (in the report's folder) and caption.
pub(crate) struct Picture {
    pub file: String,
    pub caption: String,
}

/// Half the side of the box the 3D views frame, centred on the target (mm).
const FRAME_HALF_MM: f64 = 150.0;

/// Needle drawn along the guided path in the 3D views (a 18 G shaft, a 30 mm hub).
const NEEDLE_DIAMETER_MM: f32 = 1.27;

pub(crate) fn draw(dir: &Path, input: &ReportInput) -> Result<Vec<Picture>, ReportError> {
    let atlas = input.atlas;
    let mut out = Vec::new();
    let slices = dir.join("slices.png");
    let spec = stylet_render::figure::FigureSpec {
        planned: atlas
            .planned_paths()
            .into_iter()
            .map(|p| (p.name, p.entry_mm, p.target_mm))
            .collect(),
        ..stylet_render::figure::FigureSpec::new(
            &atlas.manifest.name,
            stylet_render::figure::default_center(&atlas.model),
        )
    };
    stylet_render::figure::figure(&atlas.model, &spec, &slices).map_err(|e| ReportError::Render {
        what: "the slices",
        message: e.to_string(),
    })?;
    out.push(Picture {
        file: "slices.png".into(),
        caption: "Axial, coronal and sagittal slices through the target's centre (radiological convention: \
                  the patient's right on the image's left), every structure in its own colour, the planned \
                  paths dashed in orange (projected onto each plane)."
            .into(),
    });
    let guided = atlas.manifest.difficulty.beginner.guided_path.as_deref();
    let path = atlas
        .planned_paths()
        .into_iter()
        .find(|p| Some(p.name.as_str()) == guided)
        .or_else(|| atlas.planned_paths().into_iter().next());
    let target = stylet_render::figure::default_center(&atlas.model);
    // Cut along the path (or vertically through the target without one), labels on the cut.
    let (cut_point, cut_axis) = match &path {
        Some(p) => (p.target_mm, (p.target_mm - p.entry_mm).normalize_or(DVec3::Y)),
        None => (target, DVec3::Y),
    };
    let step = views::default_step_mm(atlas);
    // Frame the body around the target, not the scan's whole box (its corners are air).
    let (lo, hi) = atlas.model.ct().grid().world_bounds();
    let bounds = (
        (target - DVec3::splat(FRAME_HALF_MM)).max(lo),
        (target + DVec3::splat(FRAME_HALF_MM)).min(hi),
    );
    let volume = RenderVolume::new(Arc::clone(&atlas.model));
    for (file, azimuth, side) in [
        ("3d-anterior.png", 0.0f32, "the front"),
        ("3d-right.png", -70.0, "the patient's right"),
    ] {
        let mut scene = views::scene_3d_orbit(
            atlas,
            Preset::Soft,
            Tagging::Labels,
            (cut_point, cut_axis),
            step,
            (azimuth, 15.0),
            bounds,
        )
        .map_err(|e| ReportError::Render {
            what: "the 3D views",
            message: e.to_string(),
        })?;
        if let Some(p) = &path {
            scene.tools = ToolState {
                needle: Some(NeedleShape {
                    nodes_mm: vec![p.entry_mm.as_vec3() - cut_axis.as_vec3() * 40.0, p.target_mm.as_vec3()],
                    diameter_mm: NEEDLE_DIAMETER_MM,
                    hub_length_mm: 30.0,
                    hub_diameter_mm: 8.0,
                }),
                ..ToolState::default()
            };
        }
        let image = stylet_render::raycast::render(&volume, &scene, VIEW_PX.0, VIEW_PX.1).image;
        let png = dir.join(file);
        image.write_png(&png).map_err(|e| ReportError::file(&png, e))?;
        out.push(Picture {
            file: file.into(),
            caption: format!(
                "Soft-tissue rendering from {side}, cut along {} with the structures coloured on the cut; \
                 the needle lies on the planned path.",
                path.as_ref()
                    .map(|p| format!("the path {}", p.name))
                    .unwrap_or_else(|| "a plane through the target".into())
            ),
        });
    }
    Ok(out)
}
