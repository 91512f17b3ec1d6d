//! Rendered images: 8-bit RGBA pixels, PNG output, the half-resolution upscale both renderers
//! share, and the per-pixel difference statistics the GPU-versus-CPU and golden-image tests use.

use std::path::Path;

use crate::RenderError;

/// An RGBA8 image, rows top to bottom.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub rgba: Vec<[u8; 4]>,
}

impl Image {
    pub fn new(width: u32, height: u32) -> Image {
        Image {
            width,
            height,
            rgba: vec![[0, 0, 0, 255]; width as usize * height as usize],
        }
    }

    #[inline]
    pub fn get(&self, col: u32, row: u32) -> [u8; 4] {
        self.rgba[row as usize * self.width as usize + col as usize]
    }

    #[inline]
    pub fn set(&mut self, col: u32, row: u32, px: [u8; 4]) {
        let w = self.width as usize;
        self.rgba[row as usize * w + col as usize] = px;
    }

    /// Bilinear upscale to `width` × `height` with pixel centres aligned (edges clamped): the
    /// half-resolution mode renders ⌈w/2⌉ × ⌈h/2⌉ and both renderers upscale with this.
    pub fn upscale(&self, width: u32, height: u32) -> Image {
        use rayon::prelude::*;
        let mut out = Image::new(width, height);
        if width == 0 || height == 0 || self.width == 0 || self.height == 0 {
            return out;
        }
        let sx = self.width as f32 / width as f32;
        let sy = self.height as f32 / height as f32;
        // Per column once: the two source columns and the weight of the right one.
        let columns: Vec<(usize, usize, f32)> = (0..width)
            .map(|col| {
                let x = ((col as f32 + 0.5) * sx - 0.5).clamp(0.0, (self.width - 1) as f32);
                let (x0, fx) = (x.floor() as u32, x - x.floor());
                let x1 = (x0 + 1).min(self.width - 1);
                (x0 as usize, x1 as usize, fx)
            })
            .collect();
        let src_w = self.width as usize;
        out.rgba
            .par_chunks_mut(width as usize)
            .enumerate()
            .for_each(|(row, dst)| {
                let y = ((row as f32 + 0.5) * sy - 0.5).clamp(0.0, (self.height - 1) as f32);
                let (y0, fy) = (y.floor() as u32, y - y.floor());
                let y1 = (y0 + 1).min(self.height - 1);
                let top_row = &self.rgba[y0 as usize * src_w..][..src_w];
                let bottom_row = &self.rgba[y1 as usize * src_w..][..src_w];
                for (px, &(x0, x1, fx)) in dst.iter_mut().zip(&columns) {
                    let (a, b, c, d) = (top_row[x0], top_row[x1], bottom_row[x0], bottom_row[x1]);
                    for ch in 0..4 {
                        let top = a[ch] as f32 * (1.0 - fx) + b[ch] as f32 * fx;
                        let bottom = c[ch] as f32 * (1.0 - fx) + d[ch] as f32 * fx;
                        px[ch] = (top * (1.0 - fy) + bottom * fy).round() as u8;
                    }
                }
            });
        out
    }

    /// Writes an 8-bit RGBA PNG.
    pub fn write_png(&self, path: &Path) -> Result<(), RenderError> {
        let err = |message: String| RenderError::Write {
            path: path.display().to_string(),
            message,
        };
        let file = std::fs::File::create(path).map_err(|e| err(e.to_string()))?;
        self.encode_png(std::io::BufWriter::new(file))
            .map_err(|e| err(e.to_string()))
    }

    /// The 8-bit RGBA PNG's bytes (pictures served over HTTP).
    pub fn to_png(&self) -> Result<Vec<u8>, RenderError> {
        let mut out = Vec::new();
        self.encode_png(&mut out).map_err(|e| RenderError::Write {
            path: "(memory)".into(),
            message: e.to_string(),
        })?;
        Ok(out)
    }

    fn encode_png(&self, to: impl std::io::Write) -> Result<(), png::EncodingError> {
        let mut enc = png::Encoder::new(to, self.width, self.height);
        enc.set_color(png::ColorType::Rgba);
        enc.set_depth(png::BitDepth::Eight);
        let mut w = enc.write_header()?;
        w.write_image_data(self.rgba.as_flattened())?;
        w.finish()
    }

    /// Reads an 8-bit RGB or RGBA PNG (golden images).
    pub fn read_png(path: &Path) -> Result<Image, RenderError> {
        let err = |message: String| RenderError::Read {
            path: path.display().to_string(),
            message,
        };
        let file = std::fs::File::open(path).map_err(|e| err(e.to_string()))?;
        let mut dec = png::Decoder::new(std::io::BufReader::new(file));
        dec.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
        let mut reader = dec.read_info().map_err(|e| err(e.to_string()))?;
        let info = reader.info();
        let (width, height) = (info.width, info.height);
        if width == 0 || height == 0 || width as u64 * height as u64 > 64 << 20 {
            return Err(err(format!("{width} × {height} pixels is not a golden image")));
        }
        let size = reader
            .output_buffer_size()
            .ok_or_else(|| err(format!("{width} × {height} pixels do not fit in memory")))?;
        let mut buf = vec![0; size];
        let frame = reader.next_frame(&mut buf).map_err(|e| err(e.to_string()))?;
        let bytes = &buf[..frame.buffer_size()];
        let rgba = match frame.color_type {
            png::ColorType::Rgba => bytes.chunks_exact(4).map(|p| [p[0], p[1], p[2], p[3]]).collect(),
            png::ColorType::Rgb => bytes.chunks_exact(3).map(|p| [p[0], p[1], p[2], 255]).collect(),
            png::ColorType::Grayscale => bytes.iter().map(|&g| [g, g, g, 255]).collect(),
            png::ColorType::GrayscaleAlpha => bytes.chunks_exact(2).map(|p| [p[0], p[0], p[0], p[1]]).collect(),
            other => return Err(err(format!("unsupported colour type {other:?}"))),
        };
        Ok(Image { width, height, rgba })
    }
}

/// Per-pixel difference between two images of one size: for each pixel the largest absolute
/// difference over R, G and B (0 … 255), summarised.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DiffStats {
    pub mean: f64,
    pub p99: u8,
    pub max: u8,
}

impl std::fmt::Display for DiffStats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "mean {:.3}, 99th percentile {}, max {}",
            self.mean, self.p99, self.max
        )
    }
}

/// Tolerances for [`DiffStats`]: every statistic must be at or under its limit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tolerance {
    pub mean: f64,
    pub p99: u8,
    pub max: u8,
}

impl Tolerance {
    pub fn admits(&self, d: &DiffStats) -> bool {
        d.mean <= self.mean && d.p99 <= self.p99 && d.max <= self.max
    }
}

/// Difference statistics of `a` against `b`; `None` when the sizes differ.
pub fn diff(a: &Image, b: &Image) -> Option<DiffStats> {
    if a.width != b.width || a.height != b.height {
        return None;
    }
    let mut hist = [0u64; 256];
    let mut sum = 0u64;
    for (p, q) in a.rgba.iter().zip(&b.rgba) {
        let d = (0..3).map(|c| p[c].abs_diff(q[c])).max().unwrap_or(0);
        hist[d as usize] += 1;
        sum += d as u64;
    }
    let n = a.rgba.len().max(1) as u64;
    let max = (0..256).rev().find(|&d| hist[d] > 0).unwrap_or(0) as u8;
    let target = (n * 99).div_ceil(100);
    let mut seen = 0;
    let mut p99 = 0u8;
    for (d, &count) in hist.iter().enumerate() {
        seen += count;
        if seen >= target {
            p99 = d as u8;
            break;
        }
    }
    Some(DiffStats {
        mean: sum as f64 / n as f64,
        p99,
        max,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn diff_statistics_count_the_worst_channel() {
        let a = Image::new(10, 10);
        let mut b = a.clone();
        b.set(0, 0, [0, 200, 0, 255]);
        b.set(1, 0, [3, 0, 0, 255]);
        let d = diff(&a, &b).unwrap();
        assert_eq!(d.max, 200);
        assert_eq!(d.p99, 3);
        assert!((d.mean - 2.03).abs() < 1e-9);
        assert!(diff(&a, &Image::new(9, 10)).is_none());
    }

    #[test]
    fn upscaling_keeps_flat_images_flat_and_interpolates_ramps() {
        let mut small = Image::new(2, 1);
        small.set(0, 0, [0, 0, 0, 255]);
        small.set(1, 0, [200, 200, 200, 255]);
        let big = small.upscale(4, 2);
        let row: Vec<u8> = (0..4).map(|c| big.get(c, 1)[0]).collect();
        assert_eq!(row, vec![0, 50, 150, 200]);
    }

    /// The bilinear formula pixel by pixel, as first written: the parallel, per-column-hoisted
    /// upscale must give the same bytes (golden images and GPU comparisons rely on it).
    fn upscale_pixel_by_pixel(src: &Image, width: u32, height: u32) -> Image {
        let mut out = Image::new(width, height);
        let sx = src.width as f32 / width as f32;
        let sy = src.height as f32 / height as f32;
        for row in 0..height {
            let y = ((row as f32 + 0.5) * sy - 0.5).clamp(0.0, (src.height - 1) as f32);
            let (y0, fy) = (y.floor() as u32, y - y.floor());
            let y1 = (y0 + 1).min(src.height - 1);
            for col in 0..width {
                let x = ((col as f32 + 0.5) * sx - 0.5).clamp(0.0, (src.width - 1) as f32);
                let (x0, fx) = (x.floor() as u32, x - x.floor());
                let x1 = (x0 + 1).min(src.width - 1);
                let (a, b, c, d) = (src.get(x0, y0), src.get(x1, y0), src.get(x0, y1), src.get(x1, y1));
                let mut px = [0u8; 4];
                for ch in 0..4 {
                    let top = a[ch] as f32 * (1.0 - fx) + b[ch] as f32 * fx;
                    let bottom = c[ch] as f32 * (1.0 - fx) + d[ch] as f32 * fx;
                    px[ch] = (top * (1.0 - fy) + bottom * fy).round() as u8;
                }
                out.set(col, row, px);
            }
        }
        out
    }

    #[test]
    fn upscaling_matches_the_pixel_by_pixel_formula() {
        let mut state = 0x2545_f491u32;
        for (w, h, big_w, big_h) in [(1, 1, 3, 2), (7, 5, 13, 9), (613, 508, 1225, 1016), (40, 3, 80, 6)] {
            let mut small = Image::new(w, h);
            for px in &mut small.rgba {
                for ch in px.iter_mut() {
                    state ^= state << 13;
                    state ^= state >> 17;
                    state ^= state << 5;
                    *ch = state as u8;
                }
            }
            assert_eq!(
                small.upscale(big_w, big_h),
                upscale_pixel_by_pixel(&small, big_w, big_h),
                "{w}×{h} → {big_w}×{big_h}"
            );
        }
        assert_eq!(Image::new(0, 4).upscale(3, 3), Image::new(3, 3));
    }

    #[test]
    fn png_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let mut a = Image::new(3, 2);
        a.set(2, 1, [1, 2, 3, 255]);
        let p = dir.path().join("a.png");
        a.write_png(&p).unwrap();
        assert_eq!(Image::read_png(&p).unwrap(), a);
    }
}
