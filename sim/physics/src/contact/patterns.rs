//! Contact-node patterns x_i⁰ in the tool's frame (thesis Fig. 3.8): the tool presses along its
//! +z axis; a probe's transducer array runs along its +x axis.

use glam::DVec3;

/// Which tool a pattern belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ContactKind {
    Finger,
    LinearProbe,
    ConvexProbe,
}

impl ContactKind {
    pub fn name(self) -> &'static str {
        match self {
            ContactKind::Finger => "finger",
            ContactKind::LinearProbe => "linear probe",
            ContactKind::ConvexProbe => "convex probe",
        }
    }
}

/// A set of contact nodes.
#[derive(Debug, Clone, PartialEq)]
pub struct ContactPattern {
    kind: ContactKind,
    points: Vec<DVec3>,
}

impl ContactPattern {
    pub fn kind(&self) -> ContactKind {
        self.kind
    }
    pub fn points(&self) -> &[DVec3] {
        &self.points
    }

    /// A fingertip pad: a spherical cap of radius 8 mm, 7 nodes (centre and a ring of six 4 mm
    /// out), the centre at the tool position.
    pub fn fingertip() -> Self {
        let r: f64 = 8.0;
        let mut points = vec![DVec3::ZERO];
        for k in 0..6 {
            let a = k as f64 * std::f64::consts::PI / 3.0;
            let (s, c) = (libm::sin(a), libm::cos(a));
            let rho: f64 = 4.0;
            // On the sphere: z below the apex by r − √(r² − ρ²).
            let z = -(r - (r * r - rho * rho).sqrt());
            points.push(DVec3::new(rho * c, rho * s, z));
        }
        ContactPattern {
            kind: ContactKind::Finger,
            points,
        }
    }

    /// A linear array probe face: 40 × 10 mm, 8 × 4 nodes on a flat face.
    pub fn linear_probe() -> Self {
        let mut points = Vec::with_capacity(32);
        for iy in 0..4 {
            for ix in 0..8 {
                points.push(DVec3::new(-17.5 + 5.0 * ix as f64, -5.0 + 10.0 / 3.0 * iy as f64, 0.0));
            }
        }
        ContactPattern {
            kind: ContactKind::LinearProbe,
            points,
        }
    }

    /// A convex (curvilinear) probe face: 60° of a 50 mm radius along x, 16 mm wide, 8 × 4 nodes.
    pub fn convex_probe() -> Self {
        let radius: f64 = 50.0;
        let mut points = Vec::with_capacity(32);
        for iy in 0..4 {
            for ix in 0..8 {
                let a = (-30.0 + 60.0 / 7.0 * ix as f64).to_radians();
                let x = radius * libm::sin(a);
                let z = -(radius - radius * libm::cos(a));
                points.push(DVec3::new(x, -8.0 + 16.0 / 3.0 * iy as f64, z));
            }
        }
        ContactPattern {
            kind: ContactKind::ConvexProbe,
            points,
        }
    }
}
