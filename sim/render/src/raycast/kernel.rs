//! What a batch of samples is evaluated against, and the evaluation: each sample's record read
//! (value and gradient), its colour from the transfer table and its Phong terms (thesis
//! eq. 3.2.3), eight at a time on the AVX2 lanes (`Avx2::evaluate`) or one at a time (the
//! reference, `Kernel::evaluate_one_at_a_time`), the same numbers bit for bit.

use stylet_physics::glam::Vec3;

use super::appearance::Appearance;
use super::avx2::Avx2;
use super::batch::{Batch, Evaluated, LANES};
use super::cell::Cell;
use super::gradient_volume::{GradientVolume, RecordSlice};
use super::sampler::world_gradient;
use super::shading::{MIN_GRADIENT, PhongTerms};
use super::window::Window;
use crate::transfer_table::TransferTable;

/// What a batch is evaluated against: the records, and the table and shading terms of the
/// frame.
#[derive(Clone, Copy)]
pub(crate) struct Kernel<'a> {
    pub grads: &'a GradientVolume,
    pub look: Appearance<'a>,
    /// The AVX2 lanes with the 16-bit records they read and the records' strides along y and
    /// z (taken out of `grads` once: [`Self::prefetch`] is called for every visible sample);
    /// `None`: one sample at a time.
    lanes: Option<(Avx2, &'a [[i16; 4]], usize, usize)>,
}

impl<'a> Kernel<'a> {
    /// The kernel for `grads`: AVX2 lanes when `avx2` is given and the records are 16-bit
    /// integers; else one sample at a time (the reference).
    pub fn new(
        grads: &'a GradientVolume,
        table: &'a TransferTable,
        phong: &'a PhongTerms,
        half_rows: [Vec3; 3],
        avx2: Option<Avx2>,
    ) -> Self {
        let lanes = match (avx2, grads.records()) {
            (Some(avx2), RecordSlice::Int16(records)) => {
                let (sy, sz) = grads.strides();
                Some((avx2, records, sy, sz))
            }
            _ => None,
        };
        Kernel {
            grads,
            look: Appearance {
                table,
                phong,
                half_rows,
            },
            lanes,
        }
    }

    /// Asks the CPU to start loading the four record rows a located sample will read (the batch
    /// reads them only once it is full, up to seven samples later).
    #[inline(always)]
    pub fn prefetch(&self, cell: &Cell) {
        if let Some((avx2, records, sy, sz)) = self.lanes {
            let o = cell.b[0] as usize + sy * cell.b[1] as usize + sz * cell.b[2] as usize;
            avx2.prefetch(records, sy, sz, o);
        }
    }

    /// [`Self::prefetch`] of all eight points of a window, visible or not: their records'
    /// offsets worked out on the lanes, then four prefetches per point. Prefetching the points
    /// the batch will not read costs less than a branch per point (measured on the chest CT).
    #[inline(always)]
    pub fn prefetch_window(&self, window: &Window) {
        if let Some((avx2, records, sy, sz)) = self.lanes {
            avx2.prefetch_window(records, sy, sz, window);
        }
    }

    /// The batch's first min(len, [`LANES`]) samples, evaluated, moved out of the batch into
    /// `out` (which must hold none).
    #[inline(always)]
    pub fn take_front(&self, batch: &mut Batch, half: Vec3, out: &mut Evaluated) {
        debug_assert_eq!(out.len, 0, "evaluated samples not composited");
        self.evaluate(batch, half, out);
        let n = batch.len().min(LANES);
        out.t.copy_from_slice(&batch.t[..LANES]);
        out.counted_before.copy_from_slice(&batch.counted_before[..LANES]);
        out.len = n;
        batch.drop_front(n);
    }

    /// Whether batches go through the AVX2 lanes.
    #[cfg(test)]
    pub fn uses_avx2(&self) -> bool {
        self.lanes.is_some()
    }

    /// Reads, classifies and lights the batch's samples for a ray with Phong half vector
    /// `half`: the first min(`batch.len()`, [`LANES`]) entries. Later entries of `out` are
    /// unspecified.
    #[inline(always)]
    pub fn evaluate(&self, batch: &Batch, half: Vec3, out: &mut Evaluated) {
        if let Some((avx2, records, sy, sz)) = self.lanes {
            avx2.evaluate(&self.look, records, (sy, sz), batch, half, out);
            return;
        }
        self.evaluate_one_at_a_time(batch, half, out);
    }

    /// The reference: each sample as the one-at-a-time loop computes it.
    pub fn evaluate_one_at_a_time(&self, batch: &Batch, half: Vec3, out: &mut Evaluated) {
        out.unshaded = 0;
        for i in 0..batch.len.min(LANES) {
            let r = self.grads.interpolate(&batch.cell(i));
            out.colour[i] = self.look.table.lookup(r.w);
            let g = world_gradient(&self.look.half_rows, r.truncate());
            let len = g.length();
            if len < MIN_GRADIENT {
                out.unshaded |= 1 << i;
                out.lit[i] = 0.0;
            } else {
                out.lit[i] = self.look.phong.lit(g, len, half);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::raycast::Lanes;
    use crate::raycast::avx2::available_for_lane_tests;
    use crate::raycast::batch::CAPACITY;
    use crate::scene::Light;
    use crate::transfer::{TransferFunction, Trapezoid};
    use stylet_physics::glam::Vec3;

    fn ct(dims: [usize; 3]) -> Vec<f32> {
        let mut v = Vec::with_capacity(dims.iter().product());
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    // Edges, a flat block whose inside has no gradient (unshaded), and values
                    // beyond both ends of the table (its clamps).
                    let x = ((i * 37 + j * 11 + k * 5) % 23) as f32;
                    v.push(if i < 5 && j < 5 && k < 5 {
                        40.0
                    } else if i == 8 && j % 3 == 0 {
                        4000.0
                    } else if j == 7 && k % 2 == 0 {
                        -3000.0
                    } else {
                        x * 90.0 - 1000.0
                    });
                }
            }
        }
        v
    }

    #[test]
    fn lanes_give_the_bits_of_one_sample_at_a_time() {
        let lanes_here = available_for_lane_tests();
        let dims = [9usize, 8, 7];
        let data = ct(dims);
        let d = dims.map(|n| n as u32);
        let grads = GradientVolume::new(&data, d);
        let grid = super::super::sampler::Grid3::new(&data, d);
        // Soft tissue, and bone visible up to the table's top end (where the clamp matters).
        let tf = TransferFunction::Trapezoids(vec![
            Trapezoid {
                tissue: "soft".into(),
                hu: [-400.0, -100.0, 300.0, 900.0],
                rgb: [0.9, 0.6, 0.5],
                opacity: 0.7,
                weight: 1.0,
            },
            Trapezoid {
                tissue: "bone".into(),
                hu: [700.0, 1000.0, 3000.0, 3100.0],
                rgb: [1.0, 0.95, 0.9],
                opacity: 0.9,
                weight: 1.0,
            },
        ]);
        let table = TransferTable::new(&tf, -1024.0, 1200.0, 0.5);
        let rows = [
            Vec3::new(0.7, 0.1, 0.0),
            Vec3::new(-0.1, 0.8, 0.05),
            Vec3::new(0.0, 0.02, 0.3),
        ];
        for shininess in [0.0, 1.0, 20.0, 7.5] {
            for specular in [0.0, 0.4] {
                let light = Light {
                    toward_light: Vec3::new(0.3, -0.5, 0.8).normalize(),
                    ambient: 0.25,
                    diffuse: 0.6,
                    specular,
                    shininess,
                    shadow_in: 0.3,
                };
                let phong = PhongTerms::new(&light);
                let lanes = Kernel::new(&grads, &table, &phong, rows, Avx2::detect(Lanes::Auto));
                let one = Kernel::new(&grads, &table, &phong, rows, Avx2::detect(Lanes::OneAtATime));
                assert_eq!(lanes.uses_avx2(), lanes_here);
                assert!(!one.uses_avx2());
                let mut batch = Batch::default();
                let (mut n, mut unshaded) = (0, 0);
                // Samples whose value lies below or above the table (clamped to its ends).
                let (mut below, mut above) = (0, 0);
                for s in 0..600 {
                    let f = s as f32;
                    let c = Vec3::new(
                        (f * 0.37).sin() * 4.6 + 4.0,
                        (f * 0.11).cos() * 4.1 + 3.5,
                        (f * 0.23).sin() * 3.6 + 3.0,
                    ) * if s % 3 == 0 { 0.45 } else { 1.0 };
                    let Some(cell) = grid.locate(c) else { continue };
                    batch.push(cell, f, 0);
                    // Full batches and, every so often, a short one.
                    if batch.is_full() || s % 97 == 0 {
                        let half = Vec3::new(f.sin(), 0.4, f.cos()).normalize();
                        // A short batch's entries past its length are never read: poisoned with
                        // cells far outside the records (the lanes repeat sample 0 there).
                        for e in batch.len()..CAPACITY {
                            for a in 0..3 {
                                batch.b[a][e] = 1 << 30;
                                batch.f[a][e] = f32::NAN;
                            }
                        }
                        let (mut a, mut b) = (Evaluated::default(), Evaluated::default());
                        lanes.evaluate(&batch, half, &mut a);
                        one.evaluate(&batch, half, &mut b);
                        for i in 0..batch.len() {
                            let v = grads.interpolate(&batch.cell(i)).w;
                            below += usize::from(v < -1024.0);
                            above += usize::from(v > 1200.0);
                            assert_eq!(a.colour[i].map(f32::to_bits), b.colour[i].map(f32::to_bits), "{s}/{i}");
                            assert_eq!(a.lit[i].to_bits(), b.lit[i].to_bits(), "sample {s}, lane {i}");
                            for f_shadow in [1.0, 0.3] {
                                let want = if b.unshaded & (1 << i) != 0 {
                                    1.0
                                } else {
                                    let g = {
                                        let r = grads.interpolate(&batch.cell(i));
                                        rows[0] * r.x + rows[1] * r.y + rows[2] * r.z
                                    };
                                    phong.shade(g, g.length(), half, f_shadow)
                                };
                                assert_eq!(a.shade(i, &phong, f_shadow).to_bits(), want.to_bits());
                            }
                        }
                        assert_eq!(a.unshaded, b.unshaded, "sample {s}");
                        unshaded += b.unshaded.count_ones() as usize;
                        n += batch.len();
                        batch.drop_front(batch.len());
                    }
                }
                assert!(n > 400, "{n} samples compared");
                assert!(below > 10 && above > 10, "{below} below and {above} above the table");
                assert!(unshaded > 0 && unshaded < n, "{unshaded} of {n} samples unshaded");
            }
        }
    }
}
