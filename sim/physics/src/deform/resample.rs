//! What the renderers read (thesis Alg. 4.1 lines 15–16, eq. 3.1.1): the deformed sub-image
//! J(x) = I(X(x)) on the nodes of Ω_J, where X(x) inverts x = X + u(X) by the fixed point
//! X⁺ = x − u(X) ([CLC⁺08]); and the displacement magnitude for the MPR's colour map.

use glam::DVec3;
use rayon::prelude::*;

use super::field::DeformField;
use crate::grid::{Affine, Grid};
use crate::{PunctureAtlas, Volume};

/// Fixed-point iterations of the inverse (the error shrinks by |∇u| per iteration).
pub const INVERSE_ITERATIONS: u32 = 8;

/// The grid of Ω_J as a volume grid (axis-aligned, spacing h).
pub fn grid_of(field: &DeformField) -> Grid {
    let l = field.lattice();
    Grid::new([l.n; 3], Affine::from_spacing([l.h_mm; 3], l.origin_mm)).expect("a lattice is a valid grid")
}

/// J on the nodes of Ω_J: the CT value at the reference point of each world node (HU).
pub fn deformed_ct(atlas: &PunctureAtlas, field: &DeformField) -> Volume<f32> {
    let l = *field.lattice();
    let n = l.n;
    let mut data = vec![0.0f32; l.len()];
    data.par_chunks_mut(n * n).enumerate().for_each(|(k, plane)| {
        for j in 0..n {
            for i in 0..n {
                let x = l.position(i, j, k);
                let x_ref = field.to_reference(x, INVERSE_ITERATIONS);
                plane[i + n * j] = atlas.hu_at(x_ref) as f32;
            }
        }
    });
    Volume::new(grid_of(field), data).expect("sizes match")
}

/// |u| at the world nodes of Ω_J (mm), for the displacement colour map.
pub fn displacement_magnitude(field: &DeformField) -> Volume<f32> {
    let l = *field.lattice();
    let n = l.n;
    let mut data = vec![0.0f32; l.len()];
    data.par_chunks_mut(n * n).enumerate().for_each(|(k, plane)| {
        for j in 0..n {
            for i in 0..n {
                let x = l.position(i, j, k);
                let x_ref = field.to_reference(x, INVERSE_ITERATIONS);
                plane[i + n * j] = field.displacement(x_ref).length() as f32;
            }
        }
    });
    Volume::new(grid_of(field), data).expect("sizes match")
}

/// World position of reference point `x_ref` (x = X + u(X)).
pub fn to_world(field: &DeformField, x_ref: DVec3) -> DVec3 {
    x_ref + field.displacement(x_ref)
}
