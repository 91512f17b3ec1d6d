//! What a guide wire is made of (docs/seldinger.md "The wire"): its diameter, its tip and the
//! stiffness of its body and of its floppy tip.
//!
//! Body: flexural rigidity EI = E·π d⁴ / 64 of a solid core of the wire's diameter, with the
//! flexural modulus E Harrison et al. measured by three-point bending for 0.035″ wires (J Endovasc
//! Ther 2011;18:797–801): 9.5 GPa for the plain Amplatz wire, 17 GPa for the Amplatz "stiff", 60.3
//! GPa for the "super stiff". The plain Amplatz is the default: a PTCD wire must follow the ducts.
//!
//! Tip: the distal few centimetres are far softer, specified by their tip load, the force that
//! bends the tip 45° at 10 mm from its end (about 1 g for a floppy diagnostic tip). As a cantilever,
//! θ = W L² / (2 EI), so EI_tip = W L² / (2 θ).

use std::f64::consts::PI;

/// Standard gravity (m/s²): tip loads are given in grams-force.
pub const G_M_S2: f64 = 9.80665;

/// The wire's nominal diameter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WireDiameter {
    /// 0.018″ (0.457 mm): passes a 21–22 G needle (the Chiba needles of one-stick systems).
    In018,
    /// 0.035″ (0.889 mm): passes an 18 G needle; the usual wire to place an 8–10 F drain over.
    In035,
}

impl WireDiameter {
    /// As scripts and session files write it.
    pub fn name(self) -> &'static str {
        match self {
            WireDiameter::In018 => "0.018",
            WireDiameter::In035 => "0.035",
        }
    }

    pub fn from_name(name: &str) -> Option<WireDiameter> {
        match name {
            "0.018" => Some(WireDiameter::In018),
            "0.035" => Some(WireDiameter::In035),
            _ => None,
        }
    }

    pub fn mm(self) -> f64 {
        match self {
            WireDiameter::In018 => 0.018 * 25.4,
            WireDiameter::In035 => 0.035 * 25.4,
        }
    }
}

/// The shape of the wire's tip.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WireTip {
    /// Straight floppy tip: it leads with its end, deflected by the walls it glances off.
    Straight,
    /// A J: the tip is bent back on a small radius, so it leads with the bend, turned by
    /// rotating the wire, and presents a curve, not an end, to a wall it meets head-on.
    J,
}

impl WireTip {
    /// As scripts and session files write it.
    pub fn name(self) -> &'static str {
        match self {
            WireTip::Straight => "straight",
            WireTip::J => "j",
        }
    }

    pub fn from_name(name: &str) -> Option<WireTip> {
        match name {
            "straight" => Some(WireTip::Straight),
            "j" => Some(WireTip::J),
            _ => None,
        }
    }
}

/// A guide wire.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WireSpec {
    pub diameter: WireDiameter,
    pub tip: WireTip,
    /// Flexural modulus of the body (GPa).
    pub body_modulus_gpa: f64,
    /// Length of the floppy tip (mm).
    pub floppy_tip_mm: f64,
    /// Tip load: force bending the tip 45° at 10 mm from its end (grams-force).
    pub tip_load_g: f64,
}

/// Lever of the tip load's definition (mm) and its angle (rad).
const TIP_LOAD_LEVER_MM: f64 = 10.0;
const TIP_LOAD_ANGLE_RAD: f64 = PI / 4.0;

impl WireSpec {
    /// A 0.035″ plain Amplatz-like wire with a 30 mm, 1 g floppy tip.
    pub fn new(diameter: WireDiameter, tip: WireTip) -> WireSpec {
        WireSpec {
            diameter,
            tip,
            body_modulus_gpa: 9.5,
            floppy_tip_mm: 30.0,
            tip_load_g: 1.0,
        }
    }

    pub fn radius_mm(&self) -> f64 {
        self.diameter.mm() / 2.0
    }

    /// EI of the body (N·mm²): E (N/mm² = MPa) · π d⁴ / 64.
    pub fn body_rigidity_nmm2(&self) -> f64 {
        let d = self.diameter.mm();
        self.body_modulus_gpa * 1e3 * PI * d * d * d * d / 64.0
    }

    /// The tip load in newtons.
    pub fn tip_load_n(&self) -> f64 {
        self.tip_load_g * 1e-3 * G_M_S2
    }

    /// EI of the floppy tip (N·mm²), from its tip load as a cantilever.
    pub fn tip_rigidity_nmm2(&self) -> f64 {
        self.tip_load_n() * TIP_LOAD_LEVER_MM * TIP_LOAD_LEVER_MM / (2.0 * TIP_LOAD_ANGLE_RAD)
    }

    /// Axial force (N) at which a free span of `length_mm` with rigidity `ei` buckles, clamped at
    /// one end and free at the other (Euler: P = π² EI / (4 L²)).
    pub fn buckling_n(ei: f64, length_mm: f64) -> f64 {
        PI * PI * ei / (4.0 * length_mm * length_mm)
    }

    /// The force (N) the blocked tip pushes with before it folds into a loop: the floppy tip's
    /// buckling load over its own length; once the fold has taken up the floppy tip, the body's
    /// over the same span.
    pub fn push_limit_n(&self, folded_mm: f64) -> f64 {
        let ei = if folded_mm < self.floppy_tip_mm {
            self.tip_rigidity_nmm2()
        } else {
            self.body_rigidity_nmm2()
        };
        WireSpec::buckling_n(ei, self.floppy_tip_mm)
    }

    /// Checks the numbers a script or a scenario may give.
    pub fn validate(&self) -> Result<(), crate::SettingsError> {
        let ok = |v: f64, lo: f64, hi: f64| v.is_finite() && (lo..=hi).contains(&v);
        if !ok(self.body_modulus_gpa, 0.5, 250.0)
            || !ok(self.floppy_tip_mm, 5.0, 150.0)
            || !ok(self.tip_load_g, 0.1, 40.0)
        {
            return Err(crate::SettingsError::Wire(format!(
                "modulus {} GPa (0.5 … 250), floppy tip {} mm (5 … 150), tip load {} g (0.1 … 40)",
                self.body_modulus_gpa, self.floppy_tip_mm, self.tip_load_g
            )));
        }
        Ok(())
    }
}
