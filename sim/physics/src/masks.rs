//! Skin and bone masks for the palpation distance maps (thesis §3.6, Fig. 3.7).
//!
//! Skin: threshold the CT at t_air→skin, then remove air cavities (lung, bowel gas) by region
//! growing the outside air from the volume's faces: whatever air the growth cannot reach is inside
//! the body. Bone: CT ≥ t_fat→bone.

use crate::Volume;

/// The body (inside the skin): everything not connected to the outside air.
///
/// The outside air is grown (6-connectivity) from the voxels of the four volume faces that are
/// parallel to the cranio-caudal axis and below t_air→skin. The two remaining faces are skipped:
/// CTs are cropped there, so lungs or bowel gas may touch them without being outside air.
pub fn body_mask(ct: &Volume<f32>, air_skin_hu: f64) -> Vec<bool> {
    let grid = ct.grid();
    let [nx, ny, nz] = grid.dims();
    let cc = grid.cranio_caudal_axis();
    let air: Vec<bool> = ct
        .data()
        .iter()
        .map(|&v| (v as f64) < air_skin_hu)
        .collect();
    let mut outside = vec![false; grid.len()];
    let mut stack: Vec<usize> = Vec::new();
    let seed = |i: usize, j: usize, k: usize, outside: &mut Vec<bool>, stack: &mut Vec<usize>| {
        let idx = grid.linear(i, j, k);
        if air[idx] && !outside[idx] {
            outside[idx] = true;
            stack.push(idx);
        }
    };
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let on_face = [
                    i == 0 || i == nx - 1,
                    j == 0 || j == ny - 1,
                    k == 0 || k == nz - 1,
                ];
                let seeded = (0..3).any(|a| a != cc && on_face[a]);
                if seeded {
                    seed(i, j, k, &mut outside, &mut stack);
                }
            }
        }
    }
    while let Some(idx) = stack.pop() {
        let [i, j, k] = grid.unlinear(idx);
        let mut visit = |n: usize| {
            if air[n] && !outside[n] {
                outside[n] = true;
                stack.push(n);
            }
        };
        if i > 0 {
            visit(idx - 1);
        }
        if i + 1 < nx {
            visit(idx + 1);
        }
        if j > 0 {
            visit(idx - nx);
        }
        if j + 1 < ny {
            visit(idx + nx);
        }
        if k > 0 {
            visit(idx - nx * ny);
        }
        if k + 1 < nz {
            visit(idx + nx * ny);
        }
    }
    outside.into_iter().map(|o| !o).collect()
}

/// Bone: CT at or above t_fat→bone.
pub fn bone_mask(ct: &Volume<f32>, fat_bone_hu: f64) -> Vec<bool> {
    ct.data()
        .iter()
        .map(|&v| (v as f64) >= fat_bone_hu)
        .collect()
}

/// Number of true voxels.
pub fn count(mask: &[bool]) -> usize {
    mask.iter().filter(|&&b| b).count()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Affine, Grid};
    use glam::DVec3;

    /// A hollow box of tissue (a "body" with an internal air cavity) that touches the top and
    /// bottom faces: the cavity must count as inside, the surroundings as outside.
    #[test]
    fn cavities_are_inside_and_cropped_faces_are_not_seeds() {
        let grid = Grid::new([12, 12, 6], Affine::from_spacing([1.0; 3], DVec3::ZERO)).unwrap();
        let mut ct = Volume::filled(grid, -1000.0f32);
        for k in 0..6 {
            for j in 2..10 {
                for i in 2..10 {
                    let wall = i == 2 || i == 9 || j == 2 || j == 9;
                    ct.set(i, j, k, if wall { 40.0 } else { -900.0 });
                }
            }
        }
        let body = body_mask(&ct, -500.0);
        assert!(
            body[grid.linear(5, 5, 0)],
            "cavity touching the cropped face is inside"
        );
        assert!(body[grid.linear(5, 5, 3)]);
        assert!(body[grid.linear(2, 5, 3)]);
        assert!(!body[grid.linear(0, 0, 3)]);
        assert!(!body[grid.linear(1, 5, 3)]);
        assert_eq!(count(&body), 8 * 8 * 6);
    }
}
