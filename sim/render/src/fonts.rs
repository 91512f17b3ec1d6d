//! Registers the embedded font with plotters once (plotters is built without system fonts, and text
//! fails with FontUnavailable at run time without a registered font).

use std::sync::Once;

use plotters::style::FontStyle;

static REGISTER: Once = Once::new();

/// The family name to use in text styles after [`ensure_fonts`].
pub const SANS: &str = "sans-serif";

pub fn ensure_fonts() {
    REGISTER.call_once(|| {
        for style in [FontStyle::Normal, FontStyle::Bold] {
            plotters::style::register_font(SANS, style, epaint_default_fonts::UBUNTU_LIGHT)
                .unwrap_or_else(|_| panic!("the embedded Ubuntu-Light font is valid"));
        }
    });
}
