//! Raw-HID device profiles: a TOML file that says where a device's input report carries the tool
//! pose and buttons, and how its output report takes a force, so a force-feedback device that
//! speaks plain HID can be used without code (docs/devices.md "HID profiles";
//! `profiles/example-3dof.toml`).
//!
//! A profile is checked completely when loaded: every field inside its report, no two fields
//! overlapping, scales finite and non-zero, a known physics profile. Reports are then decoded and
//! encoded without further checks that could fail mid-session.

use serde::Deserialize;
use stylet_physics::DeviceProfile;
use stylet_physics::glam::{DQuat, DVec3};

/// Longest report a profile may declare (bytes, report id included).
pub const MAX_REPORT_BYTES: u16 = 1024;

/// A number's encoding in a report (little-endian).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FieldType {
    U8,
    I8,
    U16,
    I16,
    U32,
    I32,
    F32,
}

impl FieldType {
    pub fn size(self) -> usize {
        match self {
            FieldType::U8 | FieldType::I8 => 1,
            FieldType::U16 | FieldType::I16 => 2,
            FieldType::U32 | FieldType::I32 | FieldType::F32 => 4,
        }
    }

    fn read(self, b: &[u8]) -> f64 {
        match self {
            FieldType::U8 => f64::from(b[0]),
            FieldType::I8 => f64::from(b[0] as i8),
            FieldType::U16 => f64::from(u16::from_le_bytes([b[0], b[1]])),
            FieldType::I16 => f64::from(i16::from_le_bytes([b[0], b[1]])),
            FieldType::U32 => f64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            FieldType::I32 => f64::from(i32::from_le_bytes([b[0], b[1], b[2], b[3]])),
            FieldType::F32 => f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
        }
    }

    /// Writes `v` rounded and clamped to the type's range (NaN writes 0).
    fn write(self, v: f64, out: &mut [u8]) {
        let v = if v.is_nan() { 0.0 } else { v };
        let int = |lo: f64, hi: f64| v.round().clamp(lo, hi);
        match self {
            FieldType::U8 => out[0] = int(0.0, 255.0) as u8,
            FieldType::I8 => out[0] = int(-128.0, 127.0) as i8 as u8,
            FieldType::U16 => out[..2].copy_from_slice(&(int(0.0, 65535.0) as u16).to_le_bytes()),
            FieldType::I16 => out[..2].copy_from_slice(&(int(-32768.0, 32767.0) as i16).to_le_bytes()),
            FieldType::U32 => out[..4].copy_from_slice(&(int(0.0, 4294967295.0) as u32).to_le_bytes()),
            FieldType::I32 => out[..4].copy_from_slice(&(int(-2147483648.0, 2147483647.0) as i32).to_le_bytes()),
            FieldType::F32 => {
                out[..4].copy_from_slice(&(v.clamp(f32::MIN as f64, f32::MAX as f64) as f32).to_le_bytes())
            }
        }
    }
}

/// A scaled number in a report: value = raw · scale.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Field {
    pub offset: u16,
    #[serde(rename = "type")]
    pub kind: FieldType,
    #[serde(default = "one")]
    pub scale: f64,
}

fn one() -> f64 {
    1.0
}

/// The button bits' place in the input report.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ButtonsField {
    pub offset: u16,
    #[serde(rename = "type")]
    pub kind: FieldType,
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InputReport {
    pub report_id: u8,
    pub length: u16,
    /// x, y, z (mm per count).
    pub position: [Field; 3],
    /// w, x, y, z of a quaternion, normalised after reading.
    pub orientation: Option<[Field; 4]>,
    pub buttons: Option<ButtonsField>,
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OutputReport {
    pub report_id: u8,
    pub length: u16,
    /// x, y, z (N per count).
    pub force: [Field; 3],
}

/// A raw-HID device profile as written in TOML.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HidProfile {
    pub name: String,
    pub vendor_id: u16,
    pub product_id: u16,
    /// Name of the built-in [`DeviceProfile`] whose display limits the physics uses.
    pub physics: String,
    pub input: InputReport,
    pub output: Option<OutputReport>,
}

/// Why a profile was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ProfileError {
    #[error("not a valid HID profile: {0}")]
    Toml(String),
    #[error("name must be 1 to 100 characters")]
    Name,
    #[error("physics profile '{0}' is unknown (known: touch, premium, ideal)")]
    Physics(String),
    #[error("{report}: length {length} must be 2 … {MAX_REPORT_BYTES} bytes (the report id and at least one byte)")]
    Length { report: &'static str, length: u16 },
    #[error("{field}: bytes {start}..{end} lie outside the {length}-byte report (byte 0 is the report id)")]
    Outside {
        field: String,
        start: usize,
        end: usize,
        length: u16,
    },
    #[error("{field}: scale {scale} must be a finite number other than 0")]
    Scale { field: String, scale: f64 },
    #[error("{a} and {b} overlap")]
    Overlap { a: String, b: String },
    #[error("the input and output reports have the same id {0}; give each its own")]
    SameReportId(u8),
}

/// A report that does not fit the profile.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum HidReportError {
    #[error("report id {got}, the profile's input report is {want}")]
    OtherReport { got: u8, want: u8 },
    #[error("report of {got} bytes, the profile's input report has {want}")]
    Length { got: usize, want: u16 },
}

/// One decoded input report.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HidSample {
    pub position_mm: DVec3,
    /// `None` without an orientation in the profile, or when it reads as a zero quaternion.
    pub orientation: Option<DQuat>,
    pub buttons: u32,
}

impl HidProfile {
    /// Parses and checks a profile.
    pub fn parse(text: &str) -> Result<HidProfile, ProfileError> {
        let p: HidProfile = toml::from_str(text).map_err(|e| ProfileError::Toml(e.to_string()))?;
        p.validate()?;
        Ok(p)
    }

    /// The physics display limits this device uses.
    pub fn physics_profile(&self) -> DeviceProfile {
        DeviceProfile::by_name(&self.physics).expect("validated")
    }

    fn validate(&self) -> Result<(), ProfileError> {
        if self.name.trim().is_empty() || self.name.chars().count() > 100 {
            return Err(ProfileError::Name);
        }
        if DeviceProfile::by_name(&self.physics).is_none() {
            return Err(ProfileError::Physics(self.physics.clone()));
        }
        let inp = &self.input;
        let mut fields: Vec<(String, usize, usize, Option<f64>)> = Vec::new();
        for (f, axis) in inp.position.iter().zip(["x", "y", "z"]) {
            fields.push((
                format!("input.position.{axis}"),
                f.offset as usize,
                f.kind.size(),
                Some(f.scale),
            ));
        }
        if let Some(q) = &inp.orientation {
            for (f, c) in q.iter().zip(["w", "x", "y", "z"]) {
                fields.push((
                    format!("input.orientation.{c}"),
                    f.offset as usize,
                    f.kind.size(),
                    Some(f.scale),
                ));
            }
        }
        if let Some(b) = &inp.buttons {
            fields.push(("input.buttons".into(), b.offset as usize, b.kind.size(), None));
        }
        check_report("input", inp.length, &fields)?;
        if let Some(out) = &self.output {
            if out.report_id == inp.report_id {
                return Err(ProfileError::SameReportId(out.report_id));
            }
            let fields: Vec<_> = out
                .force
                .iter()
                .zip(["x", "y", "z"])
                .map(|(f, axis)| {
                    (
                        format!("output.force.{axis}"),
                        f.offset as usize,
                        f.kind.size(),
                        Some(f.scale),
                    )
                })
                .collect();
            check_report("output", out.length, &fields)?;
        }
        Ok(())
    }

    /// Decodes an input report as hidapi reads it (report id first).
    pub fn decode(&self, report: &[u8]) -> Result<HidSample, HidReportError> {
        let inp = &self.input;
        let got = report.first().copied().unwrap_or(0);
        if report.is_empty() || got != inp.report_id {
            return Err(HidReportError::OtherReport {
                got,
                want: inp.report_id,
            });
        }
        if report.len() < inp.length as usize {
            return Err(HidReportError::Length {
                got: report.len(),
                want: inp.length,
            });
        }
        // Validated: every field lies inside `length` bytes.
        let value = |f: &Field| f.kind.read(&report[f.offset as usize..]) * f.scale;
        let [x, y, z] = &inp.position;
        let orientation = inp.orientation.as_ref().and_then(|[w, qx, qy, qz]| {
            let q = DQuat::from_xyzw(value(qx), value(qy), value(qz), value(w));
            (q.is_finite() && q.length_squared() > 1e-12).then(|| q.normalize())
        });
        let buttons = inp
            .buttons
            .map_or(0, |b| b.kind.read(&report[b.offset as usize..]).max(0.0) as u32);
        Ok(HidSample {
            position_mm: DVec3::new(value(x), value(y), value(z)),
            orientation,
            buttons,
        })
    }

    /// The output report that displays `force_n` (clamped to the physics profile's maximum),
    /// or `None` for a device without force output.
    pub fn encode_force(&self, force_n: DVec3) -> Option<Vec<u8>> {
        let out = self.output.as_ref()?;
        let max = self.physics_profile().max_force_n;
        let f = if force_n.is_finite() {
            force_n.clamp_length_max(max)
        } else {
            DVec3::ZERO
        };
        let mut report = vec![0u8; out.length as usize];
        report[0] = out.report_id;
        for (field, v) in out.force.iter().zip([f.x, f.y, f.z]) {
            field.kind.write(v / field.scale, &mut report[field.offset as usize..]);
        }
        Some(report)
    }
}

fn check_report(
    report: &'static str,
    length: u16,
    fields: &[(String, usize, usize, Option<f64>)],
) -> Result<(), ProfileError> {
    if !(2..=MAX_REPORT_BYTES).contains(&length) {
        return Err(ProfileError::Length { report, length });
    }
    for (name, start, size, scale) in fields {
        let end = start + size;
        if *start < 1 || end > length as usize {
            return Err(ProfileError::Outside {
                field: name.clone(),
                start: *start,
                end,
                length,
            });
        }
        if let Some(s) = scale
            && !(s.is_finite() && *s != 0.0)
        {
            return Err(ProfileError::Scale {
                field: name.clone(),
                scale: *s,
            });
        }
    }
    for (i, (a, sa, na, _)) in fields.iter().enumerate() {
        for (b, sb, nb, _) in &fields[i + 1..] {
            if sa < &(sb + nb) && sb < &(sa + na) {
                return Err(ProfileError::Overlap {
                    a: format!("{a} (bytes {sa}..{})", sa + na),
                    b: format!("{b} (bytes {sb}..{})", sb + nb),
                });
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const EXAMPLE: &str = include_str!("../profiles/example-3dof.toml");

    #[test]
    fn the_example_profile_decodes_input_and_encodes_force() {
        let p = HidProfile::parse(EXAMPLE).unwrap();
        assert_eq!((p.vendor_id, p.product_id), (0x1209, 0x0001));
        assert_eq!(p.physics_profile().name, "touch");
        let mut r = vec![0u8; 16];
        r[0] = 1;
        r[1..3].copy_from_slice(&1234i16.to_le_bytes()); // x = 12.34 mm
        r[3..5].copy_from_slice(&(-500i16).to_le_bytes()); // y = −5 mm
        r[5..7].copy_from_slice(&0i16.to_le_bytes());
        r[7..9].copy_from_slice(&10000i16.to_le_bytes()); // w = 1
        r[15] = 0b10;
        let s = p.decode(&r).unwrap();
        assert!((s.position_mm - DVec3::new(12.34, -5.0, 0.0)).length() < 1e-9);
        assert_eq!(s.orientation, Some(DQuat::IDENTITY));
        assert_eq!(s.buttons, 2);
        // A zero quaternion reads as "no orientation".
        r[7..9].copy_from_slice(&0i16.to_le_bytes());
        assert_eq!(p.decode(&r).unwrap().orientation, None);
        // Force: 1.5 N along z; 10 N is clamped to the Touch's 3.3 N.
        let out = p.encode_force(DVec3::new(0.0, 0.0, 1.5)).unwrap();
        assert_eq!(out.len(), 7);
        assert_eq!(out[0], 2);
        assert_eq!(i16::from_le_bytes([out[5], out[6]]), 1500);
        let out = p.encode_force(DVec3::new(10.0, 0.0, 0.0)).unwrap();
        assert_eq!(i16::from_le_bytes([out[1], out[2]]), 3300);
        assert_eq!(p.encode_force(DVec3::NAN).unwrap()[1..], [0; 6]);
    }

    #[test]
    fn reports_that_do_not_fit_are_refused() {
        let p = HidProfile::parse(EXAMPLE).unwrap();
        assert_eq!(p.decode(&[]), Err(HidReportError::OtherReport { got: 0, want: 1 }));
        assert_eq!(
            p.decode(&[3, 0, 0]),
            Err(HidReportError::OtherReport { got: 3, want: 1 })
        );
        assert_eq!(p.decode(&[1, 0, 0]), Err(HidReportError::Length { got: 3, want: 16 }));
    }

    fn refused(edit: impl Fn(&str) -> String) -> String {
        HidProfile::parse(&edit(EXAMPLE)).unwrap_err().to_string()
    }

    #[test]
    fn bad_profiles_are_refused_with_the_reason() {
        let e = refused(|t| t.replace("physics = \"touch\"", "physics = \"falcon\""));
        assert!(e.contains("physics profile 'falcon' is unknown"), "{e}");
        let e = refused(|t| {
            t.replace(
                "{ offset = 5, type = \"i16\", scale = 0.01 }",
                "{ offset = 15, type = \"i16\", scale = 0.01 }",
            )
        });
        assert!(
            e.contains("input.position.z: bytes 15..17 lie outside the 16-byte report"),
            "{e}"
        );
        let e = refused(|t| {
            t.replace(
                "{ offset = 3, type = \"i16\", scale = 0.01 }",
                "{ offset = 2, type = \"i16\", scale = 0.01 }",
            )
        });
        assert!(
            e.contains("input.position.x (bytes 1..3) and input.position.y (bytes 2..4) overlap"),
            "{e}"
        );
        let e = refused(|t| {
            t.replace(
                "{ offset = 1, type = \"i16\", scale = 0.001 }",
                "{ offset = 1, type = \"i16\", scale = 0.0 }",
            )
        });
        assert!(
            e.contains("output.force.x: scale 0 must be a finite number other than 0"),
            "{e}"
        );
        let e = refused(|t| t.replace("report_id = 2", "report_id = 1"));
        assert!(e.contains("same id 1"), "{e}");
        let e = refused(|t| t.replace("length = 7", "length = 1"));
        assert!(e.contains("output: length 1 must be 2"), "{e}");
        let e = refused(|t| t.replace("type = \"u8\"", "type = \"u12\""));
        assert!(e.starts_with("not a valid HID profile:") && e.contains("u12"), "{e}");
        let e = refused(|t| t.replace("vendor_id = 0x1209", "vendor_id = 0x12099"));
        assert!(e.starts_with("not a valid HID profile:"), "{e}");
        let e = refused(|t| format!("{t}\nsurprise = 1\n"));
        assert!(e.contains("surprise"), "{e}");
        let e = refused(|t| {
            t.replace(
                "{ offset = 1, type = \"i16\", scale = 0.01 }",
                "{ offset = 0, type = \"i16\", scale = 0.01 }",
            )
        });
        assert!(e.contains("byte 0 is the report id"), "{e}");
        let e = refused(|t| t.replace("Example 3-DOF haptic arm", " "));
        assert!(e.contains("name must be"), "{e}");
    }
}
