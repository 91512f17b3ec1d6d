//! Acoustic properties from the CT (thesis §3.4 after Wein et al. 2008 and Reichl et al. 2009;
//! docs/ultrasound.md "Tissue model"): acoustic impedance Z, attenuation α and the strength of
//! diffuse backscatter (speckle) as piecewise-linear functions of HU for solid tissue, replaced by
//! constants inside labels whose tissue is fluid, vein or artery (the atlas' `echo` class: bile
//! and blood are anechoic whatever their CT value). Values (MRayl; dB/cm/MHz): air 0.0004,
//! lung and gas opaque, fat 1.38 / 0.6, water-like tissue 1.54 / 0.5, liver 1.65 / 0.6, bone 7.8 / 20
//! (Duck, *Physical Properties of Tissue*, 1990; Szabo, *Diagnostic Ultrasound Imaging*, 2014).

use stylet_atlas::EchoClass;
use stylet_physics::LabelId;

/// One tissue's acoustic properties.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Acoustic {
    pub impedance_mrayl: f32,
    pub attenuation_db_per_cm_mhz: f32,
    /// Diffuse backscatter relative to liver (1).
    pub scatter: f32,
}

/// Breakpoints for solid tissue: HU → (Z, α, scatter); constant beyond the ends. Soft tissue
/// extends to 180 HU (contrast-enhanced liver, kidney), bone starts above it.
const TISSUE_HU: [f32; 8] = [-1000.0, -400.0, -100.0, 0.0, 60.0, 180.0, 400.0, 1000.0];
const TISSUE_Z: [f32; 8] = [0.0004, 0.4, 1.38, 1.54, 1.65, 1.75, 3.5, 7.8];
const TISSUE_ALPHA: [f32; 8] = [40.0, 40.0, 0.6, 0.5, 0.6, 0.7, 20.0, 20.0];
const TISSUE_SCATTER: [f32; 8] = [0.0, 0.0, 0.5, 0.8, 1.0, 1.1, 1.5, 1.5];

/// Bile and other still fluids: hardly any attenuation, no scatterers.
pub const FLUID: Acoustic = Acoustic {
    impedance_mrayl: 1.52,
    attenuation_db_per_cm_mhz: 0.05,
    scatter: 0.0,
};
/// Blood: a little attenuation and very weak scatter (red cells).
pub const BLOOD: Acoustic = Acoustic {
    impedance_mrayl: 1.61,
    attenuation_db_per_cm_mhz: 0.15,
    scatter: 0.02,
};

/// A fresh haematoma: blood that has begun to clot, hypoechoic with faint internal echoes
/// (scatter an estimate: a quarter of liver's; clotted and days-old haematomas look otherwise).
pub const HAEMATOMA: Acoustic = Acoustic {
    impedance_mrayl: 1.61,
    attenuation_db_per_cm_mhz: 0.2,
    scatter: 0.25,
};

/// Scatter at an aerated lung's surface (relative to liver): the sub-pleural texture that moves
/// with the lung as it slides under the chest wall while the patient breathes ("lung sliding").
/// Only the first lung sample shows it (the sound is gone a fraction of a millimetre into air).
/// A pneumothorax separates the pleurae: the surface then is still air and shows none. An
/// estimate, chosen to give the pleural line a visible grain.
pub const PLEURA_SCATTER: f32 = 50.0;

/// Solid tissue at `hu`.
pub fn tissue(hu: f32) -> Acoustic {
    Acoustic {
        impedance_mrayl: piecewise(hu, &TISSUE_Z),
        attenuation_db_per_cm_mhz: piecewise(hu, &TISSUE_ALPHA),
        scatter: piecewise(hu, &TISSUE_SCATTER),
    }
}

/// The properties of a sample of class `class` at `hu`.
pub fn of(class: EchoClass, hu: f32) -> Acoustic {
    match class {
        EchoClass::Tissue => tissue(hu),
        EchoClass::Fluid => FLUID,
        EchoClass::Vein | EchoClass::Artery => BLOOD,
    }
}

fn piecewise(hu: f32, values: &[f32; 8]) -> f32 {
    if hu.is_nan() || hu <= TISSUE_HU[0] {
        return values[0];
    }
    for k in 1..TISSUE_HU.len() {
        if hu <= TISSUE_HU[k] {
            let f = (hu - TISSUE_HU[k - 1]) / (TISSUE_HU[k] - TISSUE_HU[k - 1]);
            return values[k - 1] + f * (values[k] - values[k - 1]);
        }
    }
    values[values.len() - 1]
}

/// Each label's echo class and whether it is the target, indexed by label id (ids beyond the
/// table are solid tissue and not the target).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct EchoTable {
    class: Vec<EchoClass>,
    target: Vec<bool>,
    /// Lungs: labels with a pleura that slides under the chest wall.
    pleural: Vec<LabelId>,
}

impl EchoTable {
    /// From (label, class) pairs (`stylet_atlas::manifest::echo_classes`) and the target labels.
    pub fn new(classes: &[(LabelId, EchoClass)], targets: &[LabelId]) -> EchoTable {
        let n = classes
            .iter()
            .map(|c| c.0)
            .chain(targets.iter().copied())
            .max()
            .map_or(0, |m| m as usize + 1);
        let mut t = EchoTable {
            class: vec![EchoClass::Tissue; n],
            target: vec![false; n],
            pleural: Vec::new(),
        };
        for &(id, c) in classes {
            t.class[id as usize] = c;
        }
        for &id in targets {
            t.target[id as usize] = true;
        }
        t
    }

    /// The table of a loaded atlas: its labels' `echo` classes (inherited in the property tree)
    /// and its target labels.
    pub fn of_atlas(atlas: &stylet_atlas::Atlas) -> EchoTable {
        let m = &atlas.manifest;
        let targets: Vec<LabelId> = atlas
            .model
            .label_table()
            .labels()
            .iter()
            .filter(|l| l.role == stylet_physics::Role::Target)
            .map(|l| l.id)
            .collect();
        let lungs: Vec<LabelId> = stylet_physics::complications::label_kinds(&atlas.model)
            .into_iter()
            .filter(|(_, k)| *k == stylet_physics::ComplicationKind::Pneumothorax)
            .map(|(l, _)| l)
            .collect();
        EchoTable::new(&stylet_atlas::manifest::echo_classes(&m.labels, &m.tissues), &targets).with_pleura(&lungs)
    }

    /// The table with `lungs` as the labels whose surface slides under the chest wall (the
    /// tissues whose puncture lets air into a pleural space).
    pub fn with_pleura(mut self, lungs: &[LabelId]) -> EchoTable {
        self.pleural = lungs.to_vec();
        self.pleural.sort_unstable();
        self.pleural.dedup();
        self
    }

    /// Whether `id` is a lung (a label with a pleura).
    #[inline]
    pub fn is_pleural(&self, id: LabelId) -> bool {
        self.pleural.binary_search(&id).is_ok()
    }

    #[inline]
    pub fn class(&self, id: LabelId) -> EchoClass {
        self.class.get(id as usize).copied().unwrap_or_default()
    }

    #[inline]
    pub fn is_target(&self, id: LabelId) -> bool {
        self.target.get(id as usize).copied().unwrap_or(false)
    }

    /// Per label id: the class's code (0 tissue, 1 fluid, 2 vein, 3 artery) | 256 when it is a
    /// target label | 512 when it is a lung whose surface slides (not in `air_in_pleura`): what
    /// the GPU reads.
    pub fn packed(&self, air_in_pleura: &[LabelId]) -> Vec<u32> {
        let code = |c: EchoClass| match c {
            EchoClass::Tissue => 0,
            EchoClass::Fluid => 1,
            EchoClass::Vein => 2,
            EchoClass::Artery => 3,
        };
        let n = self.class.len().max(self.pleural.last().map_or(0, |&l| l as usize + 1));
        (0..n)
            .map(|id| {
                let label = id as LabelId;
                let slides = self.is_pleural(label) && !air_in_pleura.contains(&label);
                code(self.class(label)) | if self.is_target(label) { 256 } else { 0 } | if slides { 512 } else { 0 }
            })
            .collect()
    }

    /// Whether any label carries blood flow (the Doppler view has something to show).
    pub fn has_flow(&self) -> bool {
        self.class
            .iter()
            .any(|c| matches!(c, EchoClass::Vein | EchoClass::Artery))
    }
}

/// Amplitude reflection coefficient between two impedances, (Z₂ − Z₁)/(Z₂ + Z₁).
#[inline]
pub fn reflection(z1: f32, z2: f32) -> f32 {
    (z2 - z1) / (z2 + z1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interfaces_reflect_as_the_textbooks_say() {
        // Soft tissue to bone: about 0.65 of the amplitude (≈ 43 % of the intensity).
        let r = reflection(tissue(60.0).impedance_mrayl, tissue(1000.0).impedance_mrayl);
        assert!((r - 0.65).abs() < 0.01, "{r}");
        // Soft tissue to air: total.
        let r = reflection(tissue(60.0).impedance_mrayl, tissue(-1000.0).impedance_mrayl);
        assert!(r < -0.999, "{r}");
        // Fat to liver: a weak echo of about 9 %.
        let r = reflection(tissue(-100.0).impedance_mrayl, tissue(60.0).impedance_mrayl);
        assert!((r - 0.089).abs() < 0.002, "{r}");
    }

    #[test]
    fn fluids_are_anechoic_whatever_their_ct_value() {
        for hu in [-50.0, 20.0, 180.0] {
            assert_eq!(of(EchoClass::Fluid, hu).scatter, 0.0);
            assert!(of(EchoClass::Vein, hu).scatter < 0.05 * tissue(60.0).scatter);
        }
        assert!(tissue(f32::NAN).impedance_mrayl > 0.0);
    }
}
