//! Scan conversion and the training aids (docs/ultrasound.md "Display"): the frame's lines and
//! samples are resampled onto a square-pixel image of the sector (bilinear in line and depth,
//! black outside the fan), Doppler colour laid over by nearest sample, then the outlined target
//! (green) and the guide line (dashed yellow), and depth marks every centimetre on the right.

use rayon::prelude::*;
use stylet_physics::glam::Vec3;

use super::probe::ScanGeometry;
use super::{FLAG_DOPPLER, FLAG_TARGET};
use crate::image::Image;

/// Outline and guide colours.
pub const TARGET_RGB: [u8; 3] = [60, 220, 90];
pub const GUIDE_RGB: [u8; 3] = [250, 210, 40];
/// Dash period of the guide line (pixels).
const DASH_PX: f32 = 10.0;

/// One frame before scan conversion: per sample (line-major: line i, sample j at
/// i·samples + j) the display value 0 … 1, the Doppler colour and flags.
#[derive(Debug, Clone, PartialEq)]
pub struct Sonogram {
    pub geometry: ScanGeometry,
    pub bmode: Vec<f32>,
    pub colour: Vec<[u8; 3]>,
    pub flags: Vec<u8>,
    pub guide_mm: Option<[Vec3; 2]>,
    pub outline_target: bool,
}

/// Where image pixels lie in the image plane: u = u0 + (col + ½)·mm_per_px, likewise v.
#[derive(Debug, Clone, Copy)]
struct Raster {
    u0: f32,
    v0: f32,
    mm_per_px: f32,
}

impl Sonogram {
    /// The sample index of line `i`, sample `j`.
    pub fn at(&self, i: u32, j: u32) -> usize {
        i as usize * self.geometry.samples as usize + j as usize
    }

    /// The pixel size (mm) and placement that fit the sector into `width` × `height`, centred.
    fn raster(&self, width: u32, height: u32) -> Raster {
        let (u_lo, u_hi, v_lo, v_hi) = self.geometry.bounds();
        let mm_per_px = ((u_hi - u_lo) / width as f32).max((v_hi - v_lo) / height as f32);
        Raster {
            u0: (u_lo + u_hi) / 2.0 - mm_per_px * width as f32 / 2.0,
            v0: v_lo,
            mm_per_px,
        }
    }

    /// The (line, sample) of the image pixel, if inside the sector.
    fn index_of(&self, r: &Raster, col: u32, row: u32) -> Option<(f32, f32)> {
        let u = r.u0 + (col as f32 + 0.5) * r.mm_per_px;
        let v = r.v0 + (row as f32 + 0.5) * r.mm_per_px;
        self.geometry.index_at(u, v)
    }

    /// The scan-converted image with Doppler colour and the aids.
    pub fn to_image(&self, width: u32, height: u32) -> Image {
        if width == 0 || height == 0 {
            return Image::new(width, height);
        }
        let r = self.raster(width, height);
        let (lines, samples) = (self.geometry.lines as usize, self.geometry.samples as usize);
        let mut img = Image::new(width, height);
        let mut target = vec![false; width as usize * height as usize];
        img.rgba
            .par_chunks_mut(width as usize)
            .zip(target.par_chunks_mut(width as usize))
            .enumerate()
            .for_each(|(row, (px, tgt))| {
                for col in 0..width as usize {
                    let Some((fi, fj)) = self.index_of(&r, col as u32, row as u32) else {
                        px[col] = [0, 0, 0, 255];
                        continue;
                    };
                    let (fi, fj) = (fi.clamp(0.0, (lines - 1) as f32), fj.clamp(0.0, (samples - 1) as f32));
                    let (i0, j0) = (fi.floor() as usize, fj.floor() as usize);
                    let (i1, j1) = ((i0 + 1).min(lines - 1), (j0 + 1).min(samples - 1));
                    let (a, b) = (fi - i0 as f32, fj - j0 as f32);
                    let v = |i: usize, j: usize| self.bmode[i * samples + j];
                    let top = v(i0, j0) * (1.0 - b) + v(i0, j1) * b;
                    let bottom = v(i1, j0) * (1.0 - b) + v(i1, j1) * b;
                    let grey = ((top * (1.0 - a) + bottom * a) * 255.0).round() as u8;
                    let near = fi.round() as usize * samples + fj.round() as usize;
                    px[col] = if self.flags[near] & FLAG_DOPPLER != 0 {
                        let [r, g, b] = self.colour[near];
                        [r, g, b, 255]
                    } else {
                        [grey, grey, grey, 255]
                    };
                    tgt[col] = self.flags[near] & FLAG_TARGET != 0;
                }
            });
        if self.outline_target {
            outline(&mut img, &target);
        }
        if let Some([a, b]) = self.guide_mm {
            self.draw_guide(&mut img, &r, a, b);
        }
        depth_marks(&mut img, &r, self.geometry.depth_mm);
        img
    }

    /// The guide line projected into the image plane, dashed, inside the sector only.
    fn draw_guide(&self, img: &mut Image, r: &Raster, a: Vec3, b: Vec3) {
        let to_px = |x: Vec3| {
            let (u, v, _) = self.geometry.plane_coords(x);
            ((u - r.u0) / r.mm_per_px - 0.5, (v - r.v0) / r.mm_per_px - 0.5)
        };
        let (pa, pb) = (to_px(a), to_px(b));
        let len = ((pb.0 - pa.0).powi(2) + (pb.1 - pa.1).powi(2)).sqrt();
        if !(len.is_finite() && len > 0.0) {
            return;
        }
        let steps = (len.ceil() as u32).min(16_384);
        for k in 0..=steps {
            let t = k as f32 / steps as f32;
            if (t * len / DASH_PX).fract() >= 0.6 {
                continue;
            }
            let (x, y) = (pa.0 + (pb.0 - pa.0) * t, pa.1 + (pb.1 - pa.1) * t);
            let (col, row) = (x.round(), y.round());
            if col < 0.0 || row < 0.0 || col >= img.width as f32 || row >= img.height as f32 {
                continue;
            }
            if self.index_of(r, col as u32, row as u32).is_some() {
                let [rr, g, bb] = GUIDE_RGB;
                img.set(col as u32, row as u32, [rr, g, bb, 255]);
            }
        }
    }
}

/// Colours the pixels of `mask` that touch a pixel outside it.
fn outline(img: &mut Image, mask: &[bool]) {
    let (w, h) = (img.width as usize, img.height as usize);
    let inside = |c: isize, r: isize| {
        c >= 0 && r >= 0 && (c as usize) < w && (r as usize) < h && mask[r as usize * w + c as usize]
    };
    for row in 0..h {
        for col in 0..w {
            if !mask[row * w + col] {
                continue;
            }
            let (c, r) = (col as isize, row as isize);
            if !(inside(c - 1, r) && inside(c + 1, r) && inside(c, r - 1) && inside(c, r + 1)) {
                let [rr, g, b] = TARGET_RGB;
                img.set(col as u32, row as u32, [rr, g, b, 255]);
            }
        }
    }
}

/// A white tick every 10 mm of depth (longer every 50 mm) at the right edge.
fn depth_marks(img: &mut Image, r: &Raster, depth_mm: f32) {
    let mut d = 10.0;
    while d <= depth_mm + 1e-3 {
        let row = ((d - r.v0) / r.mm_per_px - 0.5).round();
        if row >= 0.0 && row < img.height as f32 {
            let long = (d as u32).is_multiple_of(50);
            let len = if long { 12 } else { 6 };
            for k in 0..len.min(img.width) {
                img.set(img.width - 1 - k, row as u32, [255, 255, 255, 255]);
            }
        }
        d += 10.0;
    }
}
