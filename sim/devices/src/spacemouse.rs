//! 3Dconnexion SpaceMouse input reports (USB HID, read raw through hidapi).
//!
//! Two report layouts exist (as spacenavd and the community captures document them):
//! - **Wired family** (SpaceNavigator, SpaceExplorer, SpacePilot Pro, SpaceMouse Pro, Compact):
//!   report 1 carries the translation (three little-endian `i16`: X, Y, Z), report 2 the
//!   rotation (Rx, Ry, Rz), report 3 the buttons (a little-endian bit map).
//! - **Wireless family** (SpaceMouse Wireless, Pro Wireless, Enterprise, the Universal
//!   Receiver): report 1 carries all six axes (translation then rotation, 12 bytes); report 3 the
//!   buttons. Other reports (battery level 0x17, LED) are ignored.
//!
//! The HID frame is x right, y toward the user, z down (pushing the cap is +Z). Stylet's device
//! frame is x right, y away from the user, z up: the HID frame turned 180° about x, so
//! translations and rotations (axial vectors) both map as (x, −y, −z). Each model lists its signs
//! so a model that differs can be corrected in the table.

use stylet_physics::glam::DVec3;

/// USB vendor ids of 3Dconnexion devices (the older ones carry Logitech's).
pub const VENDOR_LOGITECH: u16 = 0x046d;
pub const VENDOR_3DCONNEXION: u16 = 0x256f;

/// Which report layout a model uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Family {
    /// Translation in report 1, rotation in report 2.
    Wired,
    /// All six axes in report 1.
    Wireless,
}

/// A known SpaceMouse model.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Model {
    pub vendor_id: u16,
    pub product_id: u16,
    pub name: &'static str,
    pub family: Family,
    /// Sign applied to HID X, Y, Z, Rx, Ry, Rz to get Stylet's device frame.
    pub signs: [i8; 6],
}

/// HID frame → device frame (x, −y, −z) for translation and rotation.
const HID_TO_DEVICE: [i8; 6] = [1, -1, -1, 1, -1, -1];

const fn model(vendor_id: u16, product_id: u16, name: &'static str, family: Family) -> Model {
    Model {
        vendor_id,
        product_id,
        name,
        family,
        signs: HID_TO_DEVICE,
    }
}

/// The models Stylet recognises.
pub const MODELS: [Model; 12] = [
    model(VENDOR_LOGITECH, 0xc626, "SpaceNavigator", Family::Wired),
    model(VENDOR_LOGITECH, 0xc627, "SpaceExplorer", Family::Wired),
    model(VENDOR_LOGITECH, 0xc628, "SpaceNavigator for Notebooks", Family::Wired),
    model(VENDOR_LOGITECH, 0xc629, "SpacePilot Pro", Family::Wired),
    model(VENDOR_LOGITECH, 0xc62b, "SpaceMouse Pro", Family::Wired),
    model(VENDOR_3DCONNEXION, 0xc635, "SpaceMouse Compact", Family::Wired),
    model(
        VENDOR_3DCONNEXION,
        0xc62e,
        "SpaceMouse Wireless (cable)",
        Family::Wireless,
    ),
    model(
        VENDOR_3DCONNEXION,
        0xc62f,
        "SpaceMouse Wireless (receiver)",
        Family::Wireless,
    ),
    model(
        VENDOR_3DCONNEXION,
        0xc631,
        "SpaceMouse Pro Wireless (cable)",
        Family::Wireless,
    ),
    model(
        VENDOR_3DCONNEXION,
        0xc632,
        "SpaceMouse Pro Wireless (receiver)",
        Family::Wireless,
    ),
    model(VENDOR_3DCONNEXION, 0xc633, "SpaceMouse Enterprise", Family::Wireless),
    model(
        VENDOR_3DCONNEXION,
        0xc652,
        "3Dconnexion Universal Receiver",
        Family::Wireless,
    ),
];

/// The model with these USB ids, if Stylet knows it.
pub fn find_model(vendor_id: u16, product_id: u16) -> Option<Model> {
    MODELS
        .into_iter()
        .find(|m| m.vendor_id == vendor_id && m.product_id == product_id)
}

/// A report Stylet could not use.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ReportError {
    #[error("an empty report")]
    Empty,
    #[error("report {id} of a {family:?} SpaceMouse has {len} bytes; it needs at least {need}")]
    TooShort {
        id: u8,
        family: Family,
        len: usize,
        need: usize,
    },
}

/// What a report changed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Update {
    Translation,
    Rotation,
    Both,
    Buttons,
    /// A report that carries nothing Stylet uses (battery, LED state).
    Ignored,
}

/// The latest axes and buttons of one SpaceMouse, in HID counts (about ±350 at full deflection).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SpaceMouseState {
    /// HID X, Y, Z.
    pub translation: [i16; 3],
    /// HID Rx, Ry, Rz.
    pub rotation: [i16; 3],
    /// Button bits (bit 0: the left button).
    pub buttons: u32,
}

fn axes(bytes: &[u8]) -> [i16; 3] {
    let v = |i: usize| i16::from_le_bytes([bytes[2 * i], bytes[2 * i + 1]]);
    [v(0), v(1), v(2)]
}

impl SpaceMouseState {
    /// Applies one input report as hidapi reads it (the report id first).
    pub fn apply(&mut self, family: Family, report: &[u8]) -> Result<Update, ReportError> {
        let (&id, body) = report.split_first().ok_or(ReportError::Empty)?;
        let need = |n: usize| {
            if body.len() < n {
                Err(ReportError::TooShort {
                    id,
                    family,
                    len: report.len(),
                    need: n + 1,
                })
            } else {
                Ok(())
            }
        };
        match (id, family) {
            (1, Family::Wired) => {
                need(6)?;
                self.translation = axes(&body[..6]);
                Ok(Update::Translation)
            }
            (1, Family::Wireless) => {
                need(12)?;
                self.translation = axes(&body[..6]);
                self.rotation = axes(&body[6..12]);
                Ok(Update::Both)
            }
            (2, Family::Wired) => {
                need(6)?;
                self.rotation = axes(&body[..6]);
                Ok(Update::Rotation)
            }
            (3, _) => {
                need(1)?;
                let mut b = [0u8; 4];
                for (dst, src) in b.iter_mut().zip(body) {
                    *dst = *src;
                }
                self.buttons = u32::from_le_bytes(b);
                Ok(Update::Buttons)
            }
            _ => Ok(Update::Ignored),
        }
    }

    /// Translation and rotation deflection in Stylet's device frame (x right, y away from the
    /// user, z up), in counts.
    pub fn motion(&self, model: &Model) -> Motion6 {
        let s = |i: usize, v: i16| f64::from(model.signs[i]) * f64::from(v);
        let [x, y, z] = self.translation;
        let [rx, ry, rz] = self.rotation;
        Motion6 {
            translation: DVec3::new(s(0, x), s(1, y), s(2, z)),
            rotation: DVec3::new(s(3, rx), s(4, ry), s(5, rz)),
        }
    }
}

/// A six-axis deflection in the device frame (counts).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Motion6 {
    pub translation: DVec3,
    pub rotation: DVec3,
}

#[cfg(test)]
mod tests {
    use super::*;

    const NAVIGATOR: Model = MODELS[0];

    #[test]
    fn the_wired_family_reads_three_reports() {
        // Reports as captured from a SpaceNavigator with usbmon: no motion, a rotation about the
        // second axis (Ry = −30), button 1 pressed, both pressed, released.
        let mut s = SpaceMouseState::default();
        assert_eq!(
            s.apply(Family::Wired, &[0x01, 0, 0, 0, 0, 0, 0]),
            Ok(Update::Translation)
        );
        assert_eq!(
            s.apply(Family::Wired, &[0x02, 0x00, 0x00, 0xe2, 0xff, 0x00, 0x00]),
            Ok(Update::Rotation)
        );
        assert_eq!(s.rotation, [0, -30, 0]);
        assert_eq!(s.apply(Family::Wired, &[0x03, 0x01, 0x00]), Ok(Update::Buttons));
        assert_eq!(s.buttons, 1);
        s.apply(Family::Wired, &[0x03, 0x03, 0x00]).unwrap();
        assert_eq!(s.buttons, 3);
        s.apply(Family::Wired, &[0x03, 0x00, 0x00]).unwrap();
        assert_eq!(s.buttons, 0);
        // Pushing the cap right (+X 120), toward the user (+Y 40) and down (+Z 350).
        s.apply(Family::Wired, &[0x01, 120, 0, 40, 0, 0x5e, 0x01]).unwrap();
        assert_eq!(s.translation, [120, 40, 350]);
        let m = s.motion(&NAVIGATOR);
        assert_eq!(m.translation, DVec3::new(120.0, -40.0, -350.0));
        assert_eq!(m.rotation, DVec3::new(0.0, 30.0, 0.0));
    }

    #[test]
    fn the_wireless_family_reads_six_axes_in_one_report() {
        let mut s = SpaceMouseState::default();
        // X = 10, Y = −20, Z = 300, Rx = −5, Ry = 0, Rz = 256.
        let r = [0x01, 10, 0, 0xec, 0xff, 0x2c, 0x01, 0xfb, 0xff, 0, 0, 0x00, 0x01];
        assert_eq!(s.apply(Family::Wireless, &r), Ok(Update::Both));
        assert_eq!(s.translation, [10, -20, 300]);
        assert_eq!(s.rotation, [-5, 0, 256]);
        // Battery (report 0x17) and anything else: ignored, state unchanged.
        assert_eq!(s.apply(Family::Wireless, &[0x17, 0x64]), Ok(Update::Ignored));
        assert_eq!(s.translation, [10, -20, 300]);
        // Buttons of a Pro: several bytes.
        s.apply(Family::Wireless, &[0x03, 0x00, 0x10, 0x00, 0x00]).unwrap();
        assert_eq!(s.buttons, 1 << 12);
    }

    #[test]
    fn short_and_empty_reports_are_refused_without_changing_the_state() {
        let mut s = SpaceMouseState {
            translation: [1, 2, 3],
            ..Default::default()
        };
        assert_eq!(s.apply(Family::Wired, &[]), Err(ReportError::Empty));
        let e = s.apply(Family::Wireless, &[0x01, 1, 0, 2, 0, 3, 0]).unwrap_err();
        assert_eq!(
            e,
            ReportError::TooShort {
                id: 1,
                family: Family::Wireless,
                len: 7,
                need: 13
            }
        );
        assert!(e.to_string().contains("needs at least 13"), "{e}");
        assert!(s.apply(Family::Wired, &[0x02, 1, 0]).is_err());
        assert!(s.apply(Family::Wired, &[0x03]).is_err());
        assert_eq!(s.translation, [1, 2, 3]);
    }

    #[test]
    fn models_are_found_by_usb_ids() {
        assert_eq!(find_model(0x046d, 0xc626).unwrap().name, "SpaceNavigator");
        assert_eq!(find_model(0x256f, 0xc632).unwrap().family, Family::Wireless);
        assert!(find_model(0x256f, 0x0001).is_none());
        // Ids are unique.
        for (i, a) in MODELS.iter().enumerate() {
            for b in &MODELS[i + 1..] {
                assert!((a.vendor_id, a.product_id) != (b.vendor_id, b.product_id));
            }
        }
    }
}
