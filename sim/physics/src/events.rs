//! Events: named commands that enter the tick queue and pass through every component (thesis
//! §6.3, the event pipeline; docs/physics.md "The tick"): tool changes, stylet, X-ray, contrast,
//! breathing, the steps of the Seldinger exchange.

use crate::needle::spec::Gauge;
use crate::second_hand::HandTool;
use crate::wire::{WireDiameter, WireTip};

/// Which ultrasound probe.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ProbeKind {
    Linear,
    Convex,
}

/// A tool the trainee can hold.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ToolSpec {
    Needle {
        gauge: Gauge,
        length_mm: f64,
        stylet_in: bool,
    },
    Finger,
    Probe(ProbeKind),
}

impl ToolSpec {
    pub fn name(&self) -> &'static str {
        match self {
            ToolSpec::Needle { .. } => "needle",
            ToolSpec::Finger => "finger",
            ToolSpec::Probe(ProbeKind::Linear) => "linear probe",
            ToolSpec::Probe(ProbeKind::Convex) => "convex probe",
        }
    }
}

/// An event of one tick.
#[derive(Debug, Clone, PartialEq)]
pub enum Event {
    /// Take another tool (a needle in the body is withdrawn).
    SelectTool(ToolSpec),
    /// The second hand takes another tool, or puts its tool down (two-handed sessions only;
    /// ignored otherwise).
    SecondTool(Option<HandTool>),
    /// Remove the stylet from the needle (to check for bile outflow).
    StyletRemove,
    StyletInsert,
    XrayOn,
    XrayOff,
    /// Inject contrast agent through the needle (ml).
    ContrastInject {
        ml: f64,
    },
    /// Breath hold: breathing time stops.
    BreathHold,
    BreathRelease,
    /// A guide wire into the needle's hub (the stylet out); the hand then feeds the wire while
    /// the needle stays where it is.
    WireIn {
        diameter: WireDiameter,
        tip: WireTip,
    },
    /// The needle out over the wire, which stays.
    NeedleOut,
    /// The wire out (after the needle): out of a catheter on it, whose pigtail then forms;
    /// otherwise the hand takes up a needle again.
    WireOut,
    /// A dilator of this size (French) onto the wire (the needle out); the hand then feeds it.
    DilatorIn {
        size_fr: u8,
    },
    /// The dilator out over the wire; the hand holds the wire again.
    DilatorOut,
    /// The drainage catheter of this size (French) onto the wire; the hand then feeds it.
    CatheterIn {
        size_fr: u8,
    },
}

impl Event {
    /// The event's name in scripts and session files.
    pub fn name(&self) -> &'static str {
        match self {
            Event::SelectTool(_) => "tool",
            Event::SecondTool(_) => "tool2",
            Event::StyletRemove => "stylet-remove",
            Event::StyletInsert => "stylet-insert",
            Event::XrayOn => "xray-on",
            Event::XrayOff => "xray-off",
            Event::ContrastInject { .. } => "contrast-inject",
            Event::BreathHold => "breath-hold",
            Event::BreathRelease => "breath-release",
            Event::WireIn { .. } => "wire-in",
            Event::NeedleOut => "needle-out",
            Event::WireOut => "wire-out",
            Event::DilatorIn { .. } => "dilator-in",
            Event::DilatorOut => "dilator-out",
            Event::CatheterIn { .. } => "catheter-in",
        }
    }
}
