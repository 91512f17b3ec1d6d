//! Skin and bone masks for the palpation distance maps (thesis §3.6, Fig. 3.7).
//!
//! Skin: threshold the CT at t_air→skin, then remove air cavities (lung, bowel gas) by region
//! growing the outside air from the volume's faces: whatever air the growth cannot reach is inside
//! the body. Bone: CT ≥ t_fat→bone.

use crate::Volume;

/// The body (inside the skin): everything not connected to the outside air, largest piece only.
///
/// The outside air is grown (6-connectivity) from the voxels of the four volume faces that are
/// parallel to the cranio-caudal axis and below t_air→skin. The two remaining faces are skipped:
/// CTs are cropped there, so lungs or bowel gas may touch them without being outside air. Of what
/// remains only the largest 6-connected piece is kept: the patient's trunk, without the CT table
/// or arms lying apart from it.
pub fn body_mask(ct: &Volume<f32>, air_skin_hu: f64) -> Vec<bool> {
    let grid = ct.grid();
    let [nx, ny, nz] = grid.dims();
    let cc = grid.cranio_caudal_axis();
    let air: Vec<bool> = ct.data().iter().map(|&v| (v as f64) < air_skin_hu).collect();
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
                let on_face = [i == 0 || i == nx - 1, j == 0 || j == ny - 1, k == 0 || k == nz - 1];
                let seeded = (0..3).any(|a| a != cc && on_face[a]);
                if seeded {
                    seed(i, j, k, &mut outside, &mut stack);
                }
            }
        }
    }
    // The stack holds (i, j, k) to avoid divisions when visiting neighbours.
    let mut stack: Vec<[u32; 3]> = stack
        .into_iter()
        .map(|idx| grid.unlinear(idx).map(|v| v as u32))
        .collect();
    while let Some([i, j, k]) = stack.pop() {
        let (i, j, k) = (i as usize, j as usize, k as usize);
        let idx = i + nx * (j + ny * k);
        let mut visit = |n: usize, c: [usize; 3]| {
            if air[n] && !outside[n] {
                outside[n] = true;
                stack.push(c.map(|v| v as u32));
            }
        };
        // Far neighbours first so the next pop walks along the row (cache-friendly).
        if k > 0 {
            visit(idx - nx * ny, [i, j, k - 1]);
        }
        if k + 1 < nz {
            visit(idx + nx * ny, [i, j, k + 1]);
        }
        if j > 0 {
            visit(idx - nx, [i, j - 1, k]);
        }
        if j + 1 < ny {
            visit(idx + nx, [i, j + 1, k]);
        }
        if i > 0 {
            visit(idx - 1, [i - 1, j, k]);
        }
        if i + 1 < nx {
            visit(idx + 1, [i + 1, j, k]);
        }
    }
    let inside: Vec<bool> = outside.into_iter().map(|o| !o).collect();
    largest_component(grid, &inside)
}

/// The largest 6-connected component of a mask (the first one found on ties).
pub fn largest_component(grid: &crate::Grid, mask: &[bool]) -> Vec<bool> {
    let [nx, ny, nz] = grid.dims();
    let mut component = vec![0u32; mask.len()];
    let mut sizes: Vec<usize> = vec![0];
    let mut stack = Vec::new();
    for start in 0..mask.len() {
        if !mask[start] || component[start] != 0 {
            continue;
        }
        let id = sizes.len() as u32;
        sizes.push(0);
        component[start] = id;
        stack.push(grid.unlinear(start).map(|v| v as u32));
        while let Some([i, j, k]) = stack.pop() {
            sizes[id as usize] += 1;
            let (i, j, k) = (i as usize, j as usize, k as usize);
            let idx = i + nx * (j + ny * k);
            // Far neighbours first so the next pop walks along the row (cache-friendly).
            let neighbours = [
                (k > 0).then(|| (idx - nx * ny, [i, j, k - 1])),
                (k + 1 < nz).then(|| (idx + nx * ny, [i, j, k + 1])),
                (j > 0).then(|| (idx - nx, [i, j - 1, k])),
                (j + 1 < ny).then(|| (idx + nx, [i, j + 1, k])),
                (i > 0).then(|| (idx - 1, [i - 1, j, k])),
                (i + 1 < nx).then(|| (idx + 1, [i + 1, j, k])),
            ];
            for (n, c) in neighbours.into_iter().flatten() {
                if mask[n] && component[n] == 0 {
                    component[n] = id;
                    stack.push(c.map(|v| v as u32));
                }
            }
        }
    }
    let best = (1..sizes.len()).max_by(|&a, &b| sizes[a].cmp(&sizes[b]).then(b.cmp(&a)));
    match best {
        Some(b) => component.iter().map(|&c| c == b as u32).collect(),
        None => vec![false; mask.len()],
    }
}

/// Bone: CT at or above t_fat→bone, inside the body (the CT table is not bone).
pub fn bone_mask(ct: &Volume<f32>, fat_bone_hu: f64, body: &[bool]) -> Vec<bool> {
    ct.data()
        .iter()
        .zip(body)
        .map(|(&v, &b)| b && (v as f64) >= fat_bone_hu)
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
        assert!(body[grid.linear(5, 5, 0)], "cavity touching the cropped face is inside");
        assert!(body[grid.linear(5, 5, 3)]);
        assert!(body[grid.linear(2, 5, 3)]);
        assert!(!body[grid.linear(0, 0, 3)]);
        assert!(!body[grid.linear(1, 5, 3)]);
        assert_eq!(count(&body), 8 * 8 * 6);
    }

    /// A table (a separate slab of dense material) is neither body nor bone.
    #[test]
    fn the_table_is_not_part_of_the_body() {
        let grid = Grid::new([12, 12, 3], Affine::from_spacing([1.0; 3], DVec3::ZERO)).unwrap();
        let mut ct = Volume::filled(grid, -1000.0f32);
        for k in 0..3 {
            for j in 2..8 {
                for i in 2..10 {
                    ct.set(i, j, k, 40.0);
                }
            }
            for i in 0..12 {
                ct.set(i, 10, k, 400.0); // table
            }
            ct.set(5, 4, k, 700.0); // a bone inside the body
        }
        let body = body_mask(&ct, -500.0);
        assert!(!body[grid.linear(5, 10, 1)]);
        assert!(body[grid.linear(5, 5, 1)]);
        let bone = bone_mask(&ct, 200.0, &body);
        assert_eq!(count(&bone), 3);
    }
}
