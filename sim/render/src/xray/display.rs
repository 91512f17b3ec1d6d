//! From attenuation to grey (docs/xray.md "Display"): the detector's log signal is the line
//! integral a = −ln(I/I₀) itself, shown through a window as on a fluoroscopy monitor, where more
//! photons are brighter: air white, bone, steel and contrast medium dark.

use stylet_atlas::manifest::XrayWindowToml;

use crate::image::Image;

/// The range of a mapped from white (`low`) to black (`high`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct XrayWindow {
    pub low: f32,
    pub high: f32,
}

impl XrayWindow {
    /// The scenario's window (`[scenarios.c_arm] window`, checked when the atlas loads).
    pub fn from_toml(w: &XrayWindowToml) -> XrayWindow {
        XrayWindow {
            low: w.low as f32,
            high: w.high as f32,
        }
    }

    /// Names a bad window.
    pub fn validate(&self) -> Result<(), super::XrayError> {
        if !(self.low.is_finite() && self.high.is_finite() && self.low >= 0.0 && self.high > self.low) {
            return Err(super::XrayError::Window {
                low: self.low,
                high: self.high,
            });
        }
        Ok(())
    }

    /// Grey level of attenuation `a`: 255·(1 − clamp((a − low)/(high − low), 0, 1)), rounded.
    #[inline]
    pub fn grey(&self, a: f32) -> u8 {
        let x = ((a - self.low) / (self.high - self.low)).clamp(0.0, 1.0);
        (255.0 * (1.0 - x)).round() as u8
    }
}

/// A radiograph as the detector measured it: a per pixel, rows top to bottom.
#[derive(Debug, Clone, PartialEq)]
pub struct Radiograph {
    pub width: u32,
    pub height: u32,
    pub attenuation: Vec<f32>,
}

impl Radiograph {
    #[inline]
    pub fn at(&self, col: u32, row: u32) -> f32 {
        self.attenuation[row as usize * self.width as usize + col as usize]
    }

    /// The windowed grey image.
    pub fn to_image(&self, window: XrayWindow) -> Image {
        let mut image = Image::new(self.width, self.height);
        for (px, &a) in image.rgba.iter_mut().zip(&self.attenuation) {
            let g = window.grey(a);
            *px = [g, g, g, 255];
        }
        image
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_window_maps_low_to_white_and_high_to_black() {
        let w = XrayWindow { low: 1.0, high: 3.0 };
        assert_eq!(w.grey(0.0), 255);
        assert_eq!(w.grey(1.0), 255);
        assert_eq!(w.grey(2.0), 128);
        assert_eq!(w.grey(9.0), 0);
        assert!(w.validate().is_ok());
        assert!(XrayWindow { low: 2.0, high: 2.0 }.validate().is_err());
        assert!(
            XrayWindow {
                low: f32::NAN,
                high: 2.0
            }
            .validate()
            .is_err()
        );
    }
}
