//! Sharp enlargement of a view drawn at reduced resolution: Catmull-Rom cubic interpolation
//! (Keys 1981, a = −½), separable, pixel centres aligned, edges clamped.
//!
//! A view the CPU cannot draw at full resolution within its frame budget is drawn smaller and
//! enlarged. Bilinear enlargement by 3–4× smears every edge over the whole enlargement; the cubic
//! kernel keeps an edge's slope (it interpolates the source's gradients, not just its values), so
//! organ borders, the needle and text drawn into the view stay crisp. The slight overshoot at a
//! hard edge is clamped to 0 … 255.
//!
//! Weights for a sample at fraction t between source pixels 1 and 2 of four (0 … 3):
//!
//!   w₀ = (−t³ + 2t² − t)/2,  w₁ = (3t³ − 5t² + 2)/2,  w₂ = (−3t³ + 4t² + t)/2,  w₃ = (t³ − t²)/2.

use rayon::prelude::*;

use crate::image::Image;

/// The four source indices and weights of each destination index along one axis.
fn taps(src: u32, dst: u32) -> Vec<([usize; 4], [f32; 4])> {
    let scale = src as f32 / dst as f32;
    let last = src as i64 - 1;
    (0..dst)
        .map(|d| {
            let x = (d as f32 + 0.5) * scale - 0.5;
            let base = x.floor();
            let t = x - base;
            let (t2, t3) = (t * t, t * t * t);
            let w = [
                (-t3 + 2.0 * t2 - t) * 0.5,
                (3.0 * t3 - 5.0 * t2 + 2.0) * 0.5,
                (-3.0 * t3 + 4.0 * t2 + t) * 0.5,
                (t3 - t2) * 0.5,
            ];
            let i = base as i64;
            let idx = [i - 1, i, i + 1, i + 2].map(|k| k.clamp(0, last) as usize);
            (idx, w)
        })
        .collect()
}

impl Image {
    /// Catmull-Rom enlargement (or reduction) to `width` × `height` (see the module).
    pub fn upscale_sharp(&self, width: u32, height: u32) -> Image {
        let mut out = Image::new(width, height);
        if width == 0 || height == 0 || self.width == 0 || self.height == 0 {
            return out;
        }
        let columns = taps(self.width, width);
        let rows = taps(self.height, height);
        let src_w = self.width as usize;
        // Along x first: every source row at the destination's width.
        let mut wide = vec![[0f32; 4]; self.height as usize * width as usize];
        wide.par_chunks_mut(width as usize).enumerate().for_each(|(r, dst)| {
            let src = &self.rgba[r * src_w..][..src_w];
            for (px, (idx, w)) in dst.iter_mut().zip(&columns) {
                for ch in 0..4 {
                    px[ch] = idx.iter().zip(w).map(|(&i, &w)| f32::from(src[i][ch]) * w).sum();
                }
            }
        });
        // Then along y.
        let wide_w = width as usize;
        out.rgba
            .par_chunks_mut(width as usize)
            .zip(&rows)
            .for_each(|(dst, (idx, w))| {
                for (c, px) in dst.iter_mut().enumerate() {
                    for ch in 0..4 {
                        let v: f32 = idx.iter().zip(w).map(|(&r, &w)| wide[r * wide_w + c][ch] * w).sum();
                        px[ch] = v.round().clamp(0.0, 255.0) as u8;
                    }
                }
            });
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Pixels of `row` of a horizontal edge image between 10 % and 90 % of the step.
    fn blurred_width(img: &Image, row: u32) -> usize {
        (0..img.width)
            .map(|c| img.get(c, row)[0])
            .filter(|&v| v > 25 && v < 230)
            .count()
    }

    fn edge(width: u32, height: u32) -> Image {
        let mut img = Image::new(width, height);
        for r in 0..height {
            for c in width / 2..width {
                img.set(c, r, [255, 255, 255, 255]);
            }
        }
        img
    }

    #[test]
    fn flat_images_stay_flat_and_the_same_size_is_the_same_image() {
        let mut flat = Image::new(7, 5);
        flat.rgba.fill([90, 140, 200, 255]);
        assert!(
            flat.upscale_sharp(29, 17)
                .rgba
                .iter()
                .all(|&p| p == [90, 140, 200, 255])
        );
        let e = edge(16, 4);
        assert_eq!(e.upscale_sharp(16, 4), e);
        assert_eq!(Image::new(0, 3).upscale_sharp(4, 4), Image::new(4, 4));
    }

    #[test]
    fn an_edge_stays_sharper_than_bilinear_enlargement_leaves_it() {
        let small = edge(16, 4);
        let (sharp, soft) = (small.upscale_sharp(64, 16), small.upscale(64, 16));
        let (s, b) = (blurred_width(&sharp, 8), blurred_width(&soft, 8));
        assert!(s < b, "cubic {s} px against bilinear {b} px between 10 % and 90 %");
        // Monotone away from the edge, with no value out of range (the overshoot is clamped).
        let row: Vec<u8> = (0..64).map(|c| sharp.get(c, 8)[0]).collect();
        assert_eq!(row[..24], [0; 24]);
        assert_eq!(row[40..], [255; 24]);
    }

    #[test]
    fn ramps_are_reproduced() {
        // A linear ramp is reproduced exactly by the cubic kernel away from the borders.
        let mut ramp = Image::new(8, 1);
        for c in 0..8 {
            ramp.set(c, 0, [(c * 30) as u8, 0, 0, 255]);
        }
        let big = ramp.upscale_sharp(16, 1);
        for c in 4..12 {
            let x = (c as f32 + 0.5) * 0.5 - 0.5;
            assert!(
                (f32::from(big.get(c, 0)[0]) - x * 30.0).abs() <= 0.5,
                "{c}: {:?}",
                big.get(c, 0)
            );
        }
    }
}
