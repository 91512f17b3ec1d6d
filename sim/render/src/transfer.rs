//! Transfer functions c: HU → RGBA (thesis eq. 3.2.2): a weighted sum of per-tissue trapezoids,
//! or the windowing ramp of the MPR views. Evaluated analytically (no lookup table) by both
//! renderers, so the CPU reference and the GPU shader agree exactly on every sample's colour.

/// One tissue's trapezoid: opacity rises from `hu[0]` to `hu[1]`, stays at `opacity` to `hu[2]`
/// and falls to zero at `hu[3]`.
#[derive(Debug, Clone, PartialEq)]
pub struct Trapezoid {
    pub tissue: String,
    pub hu: [f32; 4],
    /// Linear RGB, 0 … 1.
    pub rgb: [f32; 3],
    /// a_i on the plateau: opacity per millimetre of ray (corrected for the step length).
    pub opacity: f32,
    /// α_i of eq. 3.2.2 (0 … 1).
    pub weight: f32,
}

impl Trapezoid {
    /// a_i(v): 0 outside (`hu[0]`, `hu[3]`), linear ramps, `opacity` on the plateau.
    #[inline]
    pub fn opacity_at(&self, hu: f32) -> f32 {
        let [a, b, c, d] = self.hu;
        let shape = if hu <= a || hu >= d {
            0.0
        } else if hu < b {
            (hu - a) / (b - a)
        } else if hu <= c {
            1.0
        } else {
            (d - hu) / (d - c)
        };
        shape * self.opacity
    }
}

/// The most trapezoids one transfer function may sum (the GPU keeps them in a uniform array).
pub const MAX_TRAPEZOIDS: usize = 8;

/// c(v) of eq. 3.2.2, or a windowing ramp.
#[derive(Debug, Clone, PartialEq)]
pub enum TransferFunction {
    /// Σ α_i a_i(v) (r_i, g_i, b_i, 1): colour is the opacity-weighted mean of the trapezoids'
    /// colours, opacity their weighted sum clamped to 1.
    Trapezoids(Vec<Trapezoid>),
    /// Grey ramp g = clamp((v − (level − width/2)) / width, 0, 1); RGBA = (g, g, g, g·opacity).
    Window { level_hu: f32, width_hu: f32, opacity: f32 },
}

/// Why a transfer function cannot be used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TransferError {
    #[error("a transfer function needs 1 … {MAX_TRAPEZOIDS} trapezoids, not {0}")]
    Count(usize),
    #[error("trapezoid {tissue:?}: {message}")]
    Trapezoid { tissue: String, message: String },
    #[error("window: {0}")]
    Window(String),
}

impl TransferFunction {
    /// Checks every number is finite and in range (corners ascending, opacities and weights and
    /// colours 0 … 1, window width > 0).
    pub fn validate(&self) -> Result<(), TransferError> {
        let unit = |v: f32| v.is_finite() && (0.0..=1.0).contains(&v);
        match self {
            TransferFunction::Trapezoids(ts) => {
                if ts.is_empty() || ts.len() > MAX_TRAPEZOIDS {
                    return Err(TransferError::Count(ts.len()));
                }
                for t in ts {
                    let bad = |message: &str| TransferError::Trapezoid {
                        tissue: t.tissue.clone(),
                        message: message.into(),
                    };
                    if !(t.hu.iter().all(|v| v.is_finite())
                        && t.hu[0] < t.hu[1]
                        && t.hu[1] <= t.hu[2]
                        && t.hu[2] < t.hu[3])
                    {
                        return Err(bad("HU corners must be finite with a < b ≤ c < d"));
                    }
                    if !t.rgb.iter().all(|&v| unit(v)) || !unit(t.opacity) || !unit(t.weight) {
                        return Err(bad("colour, opacity and weight must be 0 … 1"));
                    }
                }
                Ok(())
            }
            TransferFunction::Window {
                level_hu,
                width_hu,
                opacity,
            } => {
                if !(level_hu.is_finite() && width_hu.is_finite() && *width_hu > 0.0 && unit(*opacity)) {
                    return Err(TransferError::Window(
                        "level must be finite, width > 0 and opacity 0 … 1".into(),
                    ));
                }
                Ok(())
            }
        }
    }

    /// RGBA at CT value `hu`: straight (not premultiplied) colour and opacity per millimetre.
    #[inline]
    pub fn eval(&self, hu: f32) -> [f32; 4] {
        match self {
            TransferFunction::Trapezoids(ts) => {
                let (mut r, mut g, mut b, mut a) = (0.0f32, 0.0f32, 0.0f32, 0.0f32);
                for t in ts {
                    let w = t.weight * t.opacity_at(hu);
                    r += w * t.rgb[0];
                    g += w * t.rgb[1];
                    b += w * t.rgb[2];
                    a += w;
                }
                if a <= 0.0 {
                    return [0.0; 4];
                }
                [r / a, g / a, b / a, a.min(1.0)]
            }
            TransferFunction::Window {
                level_hu,
                width_hu,
                opacity,
            } => {
                let g = ((hu - (level_hu - width_hu * 0.5)) / width_hu).clamp(0.0, 1.0);
                [g, g, g, g * opacity]
            }
        }
    }

    /// Whether any CT value in [`lo_hu`, `hi_hu`] has opacity > 0: cells of the occupancy grid
    /// whose value range fails this are skipped by empty-space leaping without changing the image.
    pub fn visible_in(&self, lo_hu: f32, hi_hu: f32) -> bool {
        match self {
            TransferFunction::Trapezoids(ts) => ts
                .iter()
                .any(|t| t.weight > 0.0 && t.opacity > 0.0 && hi_hu > t.hu[0] && lo_hu < t.hu[3]),
            TransferFunction::Window {
                level_hu,
                width_hu,
                opacity,
            } => *opacity > 0.0 && hi_hu > level_hu - width_hu * 0.5,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn skin() -> Trapezoid {
        Trapezoid {
            tissue: "skin".into(),
            hu: [-500.0, -300.0, -100.0, 100.0],
            rgb: [0.9, 0.7, 0.6],
            opacity: 0.8,
            weight: 1.0,
        }
    }

    #[test]
    fn a_trapezoid_ramps_plateaus_and_falls() {
        let t = skin();
        assert_eq!(t.opacity_at(-600.0), 0.0);
        assert!((t.opacity_at(-400.0) - 0.4).abs() < 1e-6);
        assert_eq!(t.opacity_at(-200.0), 0.8);
        assert!((t.opacity_at(0.0) - 0.4).abs() < 1e-6);
        assert_eq!(t.opacity_at(100.0), 0.0);
    }

    #[test]
    fn weights_mix_colours_by_opacity_and_visibility_follows_the_corners() {
        let mut bone = skin();
        bone.tissue = "bone".into();
        bone.hu = [-250.0, -200.0, 0.0, 50.0];
        bone.rgb = [1.0, 1.0, 1.0];
        bone.opacity = 0.8;
        let tf = TransferFunction::Trapezoids(vec![skin(), bone]);
        tf.validate().unwrap();
        let c = tf.eval(-150.0);
        assert!((c[0] - 0.95).abs() < 1e-6 && (c[3] - 1.0).abs() < 1e-6, "{c:?}");
        assert!(tf.visible_in(-1000.0, -450.0));
        assert!(!tf.visible_in(-1000.0, -500.0));
        assert!(!tf.visible_in(100.0, 3000.0));
        let zero = TransferFunction::Trapezoids(vec![Trapezoid { weight: 0.0, ..skin() }]);
        assert!(!zero.visible_in(-1000.0, 3000.0));
        assert_eq!(zero.eval(-200.0), [0.0; 4]);
    }

    #[test]
    fn bad_transfer_functions_are_named() {
        let t = TransferFunction::Trapezoids(vec![Trapezoid {
            hu: [0.0, -1.0, 2.0, 3.0],
            ..skin()
        }]);
        assert!(matches!(t.validate(), Err(TransferError::Trapezoid { .. })));
        assert_eq!(
            TransferFunction::Trapezoids(vec![]).validate(),
            Err(TransferError::Count(0))
        );
        let w = TransferFunction::Window {
            level_hu: 40.0,
            width_hu: 0.0,
            opacity: 1.0,
        };
        assert!(w.validate().is_err());
    }
}
