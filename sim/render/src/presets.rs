//! The scenario's transfer-function presets (`[render.presets.*]` in the atlas TOML, docs/atlas.md
//! "Render presets") as transfer functions, and its slice window. An atlas written before presets
//! existed gets the shipped PTCD presets.

use stylet_atlas::manifest::{PresetToml, RenderToml};
use stylet_atlas::{Manifest, ScenarioFile};

use crate::mpr::Window;
use crate::transfer::{TransferError, TransferFunction, Trapezoid};

/// Which preset of the 3D view.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Preset {
    /// The body's surface, opaque.
    #[default]
    Skin,
    /// Faint soft tissue, contrast-filled vessels and bone (thesis Fig. 3.9).
    Soft,
    /// Bone only.
    Bone,
}

impl Preset {
    pub const ALL: [Preset; 3] = [Preset::Skin, Preset::Soft, Preset::Bone];

    /// The name in the TOML and on the command line.
    pub fn as_str(self) -> &'static str {
        match self {
            Preset::Skin => "skin",
            Preset::Soft => "soft",
            Preset::Bone => "bone",
        }
    }

    pub fn parse(s: &str) -> Option<Preset> {
        Preset::ALL.into_iter().find(|p| p.as_str() == s)
    }

    /// This preset's table in `[render.presets]`.
    pub fn of(self, render: &RenderToml) -> &PresetToml {
        match self {
            Preset::Skin => &render.presets.skin,
            Preset::Soft => &render.presets.soft,
            Preset::Bone => &render.presets.bone,
        }
    }
}

/// The `[render]` table of an atlas, or the shipped PTCD one when the atlas has none.
pub fn render_settings(manifest: &Manifest) -> RenderToml {
    manifest.render.clone().unwrap_or_else(|| {
        ScenarioFile::ptcd()
            .render
            .expect("atlases/ptcd.toml has [render] presets (checked by tests)")
    })
}

/// The slice views' window: `[render.window]`, else the abdominal window.
pub fn slice_window(render: &RenderToml) -> Window {
    render.window.map_or(Window::ABDOMEN, |w| Window {
        level_hu: w.level_hu,
        width_hu: w.width_hu,
    })
}

impl TransferFunction {
    /// The preset's trapezoids as a transfer function, checked ([`TransferFunction::validate`]).
    pub fn from_preset(preset: &PresetToml) -> Result<TransferFunction, TransferError> {
        let f = |v: f64| v as f32;
        let tf = TransferFunction::Trapezoids(
            preset
                .trapezoids
                .iter()
                .map(|t| Trapezoid {
                    tissue: t.tissue.clone(),
                    hu: t.hu.map(f),
                    rgb: t.rgb.map(f),
                    opacity: f(t.opacity),
                    weight: f(t.weight),
                })
                .collect(),
        );
        tf.validate()?;
        Ok(tf)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_shipped_presets_are_valid_transfer_functions_that_show_what_they_promise() {
        let render = ScenarioFile::ptcd().render.unwrap();
        let tf = |p: Preset| TransferFunction::from_preset(p.of(&render)).unwrap();
        let (skin, soft, bone) = (tf(Preset::Skin), tf(Preset::Soft), tf(Preset::Bone));
        // Air is transparent in every preset; the body's surface (skin ≈ 35 HU, fat ≈ −100 HU)
        // is opaque in the skin preset only.
        for t in [&skin, &soft, &bone] {
            assert_eq!(t.eval(-1000.0)[3], 0.0);
        }
        assert!(skin.eval(-100.0)[3] > 0.5 && skin.eval(35.0)[3] > 0.5);
        assert_eq!(soft.eval(-100.0)[3], 0.0);
        // Soft: liver (≈ 73 HU) faint; a contrast-filled vessel (portal vein ≈ 150 HU, 15 mm across)
        // gathers more than half the opacity, the 1.5 mm soft-tissue-to-rib edge at the same values
        // little; bone opaque.
        let liver = soft.eval(73.0)[3];
        assert!(liver > 0.0 && liver < 0.2, "{liver}");
        let across = |a: f32, mm: f32| 1.0 - (1.0 - a).powf(mm);
        let vessel = soft.eval(200.0);
        assert!(
            across(vessel[3], 15.0) > 0.5 && across(vessel[3], 1.5) < 0.15,
            "{vessel:?}"
        );
        assert!(vessel[0] > 2.0 * vessel[1], "vessels are red: {vessel:?}");
        assert!(soft.eval(1000.0)[3] > 0.9);
        // Bone: nothing below the contrast-enhanced kidneys (≈ 220 HU), cortical bone opaque.
        assert_eq!(bone.eval(73.0)[3], 0.0);
        assert_eq!(bone.eval(220.0)[3], 0.0);
        assert!(bone.eval(800.0)[3] > 0.9);
        assert_eq!(Preset::parse("soft"), Some(Preset::Soft));
        assert_eq!(Preset::parse("lung"), None);
        assert_eq!(slice_window(&render), Window::ABDOMEN);
    }
}
