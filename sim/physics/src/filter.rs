//! Separable Gaussian smoothing of a volume, deterministic: a fixed kernel summed in a fixed
//! order, each output voxel depending only on the input, so the parallel loops give the same bits
//! on any thread count. Used for the phantom's point-spread function and for the sub-voxel
//! correction of the distance maps.

use rayon::prelude::*;

use crate::Grid;

fn kernel(sigma_vox: f64) -> Vec<f64> {
    let r = (3.0 * sigma_vox).ceil() as usize;
    let mut w: Vec<f64> = (0..=2 * r)
        .map(|i| {
            let u = (i as f64 - r as f64) / sigma_vox;
            libm::exp(-0.5 * u * u)
        })
        .collect();
    let total: f64 = w.iter().sum();
    w.iter_mut().for_each(|x| *x /= total);
    w
}

/// Convolves one line with the kernel, edges clamped.
fn convolve_line(src: &[f64], w: &[f64], out: &mut [f64]) {
    let n = src.len();
    let r = w.len() / 2;
    for (p, o) in out.iter_mut().enumerate() {
        let mut acc = 0.0;
        for (t, wt) in w.iter().enumerate() {
            let q = (p + t).saturating_sub(r).min(n - 1);
            acc += wt * src[q];
        }
        *o = acc;
    }
}

/// Blurs `data` (on `grid`) with a Gaussian of standard deviation `sigma_mm`, kernel to ±3σ,
/// edges clamped.
pub fn gaussian_blur(grid: &Grid, data: &mut [f32], sigma_mm: f64) {
    if sigma_mm <= 0.0 {
        return;
    }
    let [nx, ny, nz] = grid.dims();
    let spacing = grid.spacing_mm();
    let slab = nx * ny;
    // Along i and j: lines inside one k-slab, slabs in parallel.
    for axis in 0..2 {
        let s = sigma_mm / spacing[axis];
        if (3.0 * s).ceil() < 1.0 || grid.dims()[axis] == 1 {
            continue;
        }
        let w = kernel(s);
        let (n, stride, lines) = if axis == 0 { (nx, 1, ny) } else { (ny, nx, nx) };
        data.par_chunks_mut(slab).for_each_init(
            || (vec![0.0f64; n], vec![0.0f64; n]),
            |(line, out), plane| {
                for l in 0..lines {
                    let start = if axis == 0 { l * nx } else { l };
                    for (p, v) in line.iter_mut().enumerate() {
                        *v = plane[start + p * stride] as f64;
                    }
                    convolve_line(line, &w, out);
                    for (p, v) in out.iter().enumerate() {
                        plane[start + p * stride] = *v as f32;
                    }
                }
            },
        );
    }
    // Along k: columns of one j-row per task into a buffer, scattered back by k-slab.
    let s = sigma_mm / spacing[2];
    if (3.0 * s).ceil() >= 1.0 && nz > 1 {
        let w = kernel(s);
        let src: &[f32] = data;
        let columns: Vec<Vec<f32>> = (0..ny)
            .into_par_iter()
            .map_init(
                || (vec![0.0f64; nz], vec![0.0f64; nz]),
                |(line, out), j| {
                    let mut col = vec![0.0f32; nx * nz];
                    for i in 0..nx {
                        for (k, v) in line.iter_mut().enumerate() {
                            *v = src[i + nx * (j + ny * k)] as f64;
                        }
                        convolve_line(line, &w, out);
                        for (k, v) in out.iter().enumerate() {
                            col[i * nz + k] = *v as f32;
                        }
                    }
                    col
                },
            )
            .collect();
        data.par_chunks_mut(slab).enumerate().for_each(|(k, plane)| {
            for (j, col) in columns.iter().enumerate() {
                for i in 0..nx {
                    plane[i + nx * j] = col[i * nz + k];
                }
            }
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Affine;
    use glam::DVec3;

    #[test]
    fn blur_keeps_linear_ramps_and_spreads_a_step_on_every_axis() {
        for axis in 0..3 {
            let mut dims = [3, 3, 3];
            dims[axis] = 40;
            let g = Grid::new(dims, Affine::from_spacing([1.0; 3], DVec3::ZERO)).unwrap();
            let mut ramp: Vec<f32> = (0..g.len()).map(|i| g.unlinear(i)[axis] as f32).collect();
            let before = ramp.clone();
            gaussian_blur(&g, &mut ramp, 1.5);
            for i in 0..g.len() {
                let p = g.unlinear(i)[axis];
                if (6..34).contains(&p) {
                    assert!(
                        (ramp[i] - before[i]).abs() < 1e-4,
                        "axis {axis}: {} vs {}",
                        ramp[i],
                        before[i]
                    );
                }
            }
            let mut step: Vec<f32> = (0..g.len())
                .map(|i| if g.unlinear(i)[axis] < 20 { 0.0 } else { 1.0 })
                .collect();
            gaussian_blur(&g, &mut step, 1.5);
            let at = |p: usize| {
                let mut c = [1usize; 3];
                c[axis] = p;
                step[g.linear(c[0], c[1], c[2])]
            };
            assert!(
                at(19) > 0.2 && at(19) < 0.5 && at(20) > 0.5 && at(20) < 0.8,
                "axis {axis}: {} {}",
                at(19),
                at(20)
            );
        }
    }
}
