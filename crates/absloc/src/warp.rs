//! Resampling of the UAV frame: to the map's GSD and north-up orientation before matching
//! (a similarity), and into map pixels under the estimated homography for the SSIM.
//!
//! Downsampling by 2.5× (10 m altitude, 0.05 m map pixels) would alias with plain bilinear
//! sampling, so every output pixel averages `k × k` bilinear samples spread over its footprint
//! (`k = ⌈source pixels per output pixel⌉`): an area filter.
//!
//! A camera with a lens model (a fisheye) is undistorted in the same resampling: the
//! similarity acts on the pixels of the distortion-free pinhole with the camera's intrinsics
//! ([`Lens`]), and each output sample is pushed through the lens model to find its frame
//! pixel. There is one resampling, not an undistortion followed by a warp.

use image::GrayImage;
use jointloc_geometry::PinholeCamera;
use nalgebra::{Matrix3, Point2, Vector2};

/// Largest supersampling factor per axis.
const MAX_SUPERSAMPLING: usize = 8;

/// Bilinear sample at `(x, y)` (pixel centres at integers); `None` outside the image.
pub fn bilinear(img: &GrayImage, x: f64, y: f64) -> Option<f64> {
    let (w, h) = img.dimensions();
    if !(x >= 0.0 && y >= 0.0 && x <= (w - 1) as f64 && y <= (h - 1) as f64) {
        return None;
    }
    let (x0, y0) = (x.floor() as u32, y.floor() as u32);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (fx, fy) = (x - x0 as f64, y - y0 as f64);
    let p = |x, y| img.get_pixel(x, y)[0] as f64;
    let top = p(x0, y0) * (1.0 - fx) + p(x1, y0) * fx;
    let bottom = p(x0, y1) * (1.0 - fx) + p(x1, y1) * fx;
    Some(top * (1.0 - fy) + bottom * fy)
}

/// Samples `src` at `dst_to_src(u, v)` for every output pixel of a `width × height` image,
/// averaging `k × k` samples over each output pixel. Returns values and a mask of the pixels
/// whose centre falls inside `src` (outside ones are 0).
pub fn resample(
    src: &GrayImage,
    width: usize,
    height: usize,
    k: usize,
    dst_to_src: impl Fn(f64, f64) -> Option<(f64, f64)> + Sync,
) -> (Vec<f32>, Vec<bool>) {
    let k = k.clamp(1, MAX_SUPERSAMPLING);
    let offsets: Vec<f64> = (0..k).map(|i| (i as f64 + 0.5) / k as f64 - 0.5).collect();
    let mut values = vec![0f32; width * height];
    let mut mask = vec![false; width * height];
    for v in 0..height {
        for u in 0..width {
            let (uf, vf) = (u as f64, v as f64);
            if dst_to_src(uf, vf)
                .and_then(|(x, y)| bilinear(src, x, y))
                .is_none()
            {
                continue;
            }
            let (mut sum, mut n) = (0.0, 0u32);
            for &dv in &offsets {
                for &du in &offsets {
                    if let Some(s) =
                        dst_to_src(uf + du, vf + dv).and_then(|(x, y)| bilinear(src, x, y))
                    {
                        sum += s;
                        n += 1;
                    }
                }
            }
            values[v * width + u] = (sum / n.max(1) as f64) as f32;
            mask[v * width + u] = true;
        }
    }
    (values, mask)
}

/// The lens of a frame being resampled: undistorted pixels (those of
/// [`PinholeCamera::without_distortion`]) → frame pixels, within `max_tan` of the axis.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lens {
    pub camera: PinholeCamera,
    /// `tan` of the largest off-axis angle sampled.
    pub max_tan: f64,
}

impl Lens {
    /// `None` for a camera without distortion (frame pixels are undistorted pixels).
    pub fn of(camera: &PinholeCamera, max_off_axis_deg: f64) -> Option<Self> {
        camera.has_distortion().then(|| Self {
            camera: *camera,
            max_tan: max_off_axis_deg.clamp(1.0, 89.0).to_radians().tan(),
        })
    }

    /// The frame pixel of undistorted pixel `(x, y)`; `None` beyond `max_tan`.
    pub fn distort(&self, x: f64, y: f64) -> Option<(f64, f64)> {
        let c = &self.camera;
        let xn = Vector2::new((x - c.cx) / c.fx, (y - c.cy) / c.fy);
        let r = xn.norm();
        if r.is_nan() || r > self.max_tan {
            return None;
        }
        c.distort_to_pixel(&xn).map(|p| (p.x, p.y))
    }

    /// The undistorted pixel of frame pixel `(x, y)`; `None` beyond `max_tan`.
    pub fn undistort(&self, x: f64, y: f64) -> Option<(f64, f64)> {
        let c = &self.camera;
        let r = c.unproject(&Point2::new(x, y))?;
        (r.xy().norm() <= self.max_tan).then(|| (c.fx * r.x + c.cx, c.fy * r.y + c.cy))
    }
}

/// The similarity `p' = s·R(θ)·(p − c) + c'` from frame pixels to normalised pixels
/// (image axes: x right, y down; θ turns x towards y).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Similarity {
    pub scale: f64,
    pub angle: f64,
    /// `c`: frame pixel that goes to `c'`.
    pub src_centre: [f64; 2],
    /// `c'`.
    pub dst_centre: [f64; 2],
}

impl Similarity {
    /// Frame pixel → normalised pixel.
    pub fn forward(&self, x: f64, y: f64) -> (f64, f64) {
        let (s, c) = self.angle.sin_cos();
        let (dx, dy) = (x - self.src_centre[0], y - self.src_centre[1]);
        (
            self.scale * (c * dx - s * dy) + self.dst_centre[0],
            self.scale * (s * dx + c * dy) + self.dst_centre[1],
        )
    }

    /// Normalised pixel → frame pixel.
    pub fn inverse(&self, u: f64, v: f64) -> (f64, f64) {
        let (s, c) = self.angle.sin_cos();
        let (du, dv) = (
            (u - self.dst_centre[0]) / self.scale,
            (v - self.dst_centre[1]) / self.scale,
        );
        (
            c * du + s * dv + self.src_centre[0],
            -s * du + c * dv + self.src_centre[1],
        )
    }

    /// As a 3 × 3 matrix (frame → normalised).
    pub fn matrix(&self) -> Matrix3<f64> {
        let (s, c) = self.angle.sin_cos();
        let (a, b) = (self.scale * c, self.scale * s);
        let [cx, cy] = self.src_centre;
        let [ux, uy] = self.dst_centre;
        Matrix3::new(
            a,
            -b,
            ux - a * cx + b * cy,
            b,
            a,
            uy - b * cx - a * cy,
            0.0,
            0.0,
            1.0,
        )
    }
}

/// A frame resampled by a [`Similarity`].
#[derive(Debug, Clone)]
pub struct NormalisedFrame {
    /// The resampled image; pixels outside the frame hold the frame's mean grey level (a flat
    /// fill gives detectors no corners to find there).
    pub image: GrayImage,
    /// Frame → `image`.
    pub transform: Similarity,
    /// Frame size.
    pub frame_size: (u32, u32),
    /// The frame's lens, when `transform` acts on undistorted pixels.
    pub lens: Option<Lens>,
}

impl NormalisedFrame {
    /// Whether normalised pixel `(u, v)` comes from the frame at least `margin` frame pixels
    /// inside its border (keypoints nearer the border see the fill edge).
    pub fn inside(&self, u: f64, v: f64, margin: f64) -> bool {
        let (x, y) = self.transform.inverse(u, v);
        let Some((x, y)) = self.lens.map_or(Some((x, y)), |l| l.distort(x, y)) else {
            return false;
        };
        let (w, h) = (self.frame_size.0 as f64, self.frame_size.1 as f64);
        x >= margin && y >= margin && x <= w - 1.0 - margin && y <= h - 1.0 - margin
    }
}

/// Resamples `frame` by `scale` (output pixels per frame pixel) and rotation `angle` about
/// `centre`, into the smallest image holding the whole frame.
pub fn normalise(frame: &GrayImage, centre: (f64, f64), scale: f64, angle: f64) -> NormalisedFrame {
    normalise_lens(frame, None, centre, scale, angle, None)
}

/// [`normalise`] for a frame seen through `lens`: the similarity acts on undistorted pixels
/// and the output holds the undistorted frame up to the lens's largest off-axis angle. With
/// `max_size`, an output larger than it is cropped to it around `centre`'s image.
pub fn normalise_lens(
    frame: &GrayImage,
    lens: Option<Lens>,
    centre: (f64, f64),
    scale: f64,
    angle: f64,
    max_size: Option<(usize, usize)>,
) -> NormalisedFrame {
    let (w, h) = (frame.width() as f64, frame.height() as f64);
    let probe = Similarity {
        scale,
        angle,
        src_centre: [centre.0, centre.1],
        dst_centre: [0.0, 0.0],
    };
    let extent = match &lens {
        Some(l) => {
            let [u0, v0, u1, v1] = l.camera.undistorted_bounds(l.max_tan.atan());
            [u0 + 0.5, v0 + 0.5, u1 - 0.5, v1 - 0.5]
        }
        None => [0.0, 0.0, w - 1.0, h - 1.0],
    };
    let corners = [
        (extent[0], extent[1]),
        (extent[2], extent[1]),
        (extent[2], extent[3]),
        (extent[0], extent[3]),
    ]
    .map(|(x, y)| probe.forward(x, y));
    let min_u = corners.iter().map(|c| c.0).fold(f64::INFINITY, f64::min);
    let max_u = corners
        .iter()
        .map(|c| c.0)
        .fold(f64::NEG_INFINITY, f64::max);
    let min_v = corners.iter().map(|c| c.1).fold(f64::INFINITY, f64::min);
    let max_v = corners
        .iter()
        .map(|c| c.1)
        .fold(f64::NEG_INFINITY, f64::max);
    let mut out_w = ((max_u - min_u).ceil() as usize + 3).max(8);
    let mut out_h = ((max_v - min_v).ceil() as usize + 3).max(8);
    let mut dst_centre = [1.0 - min_u, 1.0 - min_v];
    if let Some((mw, mh)) = max_size {
        if out_w > mw.max(8) {
            out_w = mw.max(8);
            dst_centre[0] = 0.5 * (out_w as f64 - 1.0);
        }
        if out_h > mh.max(8) {
            out_h = mh.max(8);
            dst_centre[1] = 0.5 * (out_h as f64 - 1.0);
        }
    }
    let transform = Similarity {
        dst_centre,
        ..probe
    };
    let k = (1.0 / scale).ceil().max(1.0) as usize;
    let (values, mask) = resample(frame, out_w, out_h, k, |u, v| {
        let (x, y) = transform.inverse(u, v);
        match &lens {
            Some(l) => l.distort(x, y),
            None => Some((x, y)),
        }
    });
    let mean = {
        let raw = frame.as_raw();
        raw.iter().map(|&p| p as f64).sum::<f64>() / raw.len().max(1) as f64
    };
    let image = GrayImage::from_fn(out_w as u32, out_h as u32, |u, v| {
        let i = v as usize * out_w + u as usize;
        let p = if mask[i] { values[i] as f64 } else { mean };
        image::Luma([p.round().clamp(0.0, 255.0) as u8])
    });
    NormalisedFrame {
        image,
        transform,
        frame_size: frame.dimensions(),
        lens,
    }
}

/// The frame warped into the map window `[x0, x0 + width) × [y0, y0 + height)` by
/// `h_map_from_frame`, area-filtered with `k × k` samples per map pixel; with the mask of map
/// pixels the frame covers.
pub fn warp_into_map(
    frame: &GrayImage,
    h_map_from_frame: &Matrix3<f64>,
    origin: (u32, u32),
    size: (usize, usize),
    k: usize,
) -> Option<(Vec<f32>, Vec<bool>)> {
    warp_into_map_lens(frame, None, h_map_from_frame, origin, size, k)
}

/// [`warp_into_map`] for a frame seen through `lens`: `h_map_from_frame` maps undistorted
/// pixels, and each sample goes through the lens model to the frame.
pub fn warp_into_map_lens(
    frame: &GrayImage,
    lens: Option<Lens>,
    h_map_from_frame: &Matrix3<f64>,
    (x0, y0): (u32, u32),
    (width, height): (usize, usize),
    k: usize,
) -> Option<(Vec<f32>, Vec<bool>)> {
    let inv = h_map_from_frame.try_inverse()?;
    Some(resample(frame, width, height, k, |u, v| {
        let q = inv * Point2::new(u + x0 as f64, v + y0 as f64).to_homogeneous();
        let (x, y) = (q.z.abs() > 1e-12).then(|| (q.x / q.z, q.y / q.z))?;
        match &lens {
            Some(l) => l.distort(x, y),
            None => Some((x, y)),
        }
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp(w: u32, h: u32) -> GrayImage {
        GrayImage::from_fn(w, h, |x, y| image::Luma([((x + 2 * y) % 256) as u8]))
    }

    #[test]
    fn similarity_inverts_and_matches_its_matrix() {
        let s = Similarity {
            scale: 0.4,
            angle: 0.7,
            src_centre: [249.5, 249.5],
            dst_centre: [140.0, 138.0],
        };
        let m = s.matrix();
        for (x, y) in [(0.0, 0.0), (499.0, 10.0), (123.4, 321.0)] {
            let (u, v) = s.forward(x, y);
            let (bx, by) = s.inverse(u, v);
            assert!((bx - x).abs() < 1e-9 && (by - y).abs() < 1e-9);
            let q = m * Point2::new(x, y).to_homogeneous();
            assert!((q.x - u).abs() < 1e-9 && (q.y - v).abs() < 1e-9);
        }
    }

    /// A view larger than `max_size` (a frame from high above, resampled to a finer map) is
    /// cropped to it around the frame's centre, with the grey levels of the uncropped view.
    #[test]
    fn a_view_larger_than_its_bound_is_cropped_around_the_centre() {
        let frame = ramp(500, 500);
        let centre = (249.5, 249.5);
        for angle in [0.0, 0.6] {
            let full = normalise_lens(&frame, None, centre, 1.6, angle, None);
            let crop = normalise_lens(&frame, None, centre, 1.6, angle, Some((600, 600)));
            assert!(full.image.width() > 600 && full.image.height() > 600);
            assert_eq!(crop.image.dimensions(), (600, 600));
            let (u, v) = crop.transform.forward(centre.0, centre.1);
            assert!((u - 299.5).abs() < 1e-9 && (v - 299.5).abs() < 1e-9);
            // The same frame pixel lands on the same grey level in both views.
            let (x, y) = (300.0, 220.0);
            let (fu, fv) = full.transform.forward(x, y);
            let (cu, cv) = crop.transform.forward(x, y);
            let grey = |n: &NormalisedFrame, u: f64, v: f64| {
                n.image.get_pixel(u.round() as u32, v.round() as u32).0[0]
            };
            // (Up to half an output pixel apart: the ramp changes by < 2 grey levels there.)
            let (a, b) = (grey(&full, fu, fv), grey(&crop, cu, cv));
            assert!(a.abs_diff(b) <= 2, "{a} vs {b}");
        }
        // A view within its bound is left as it is.
        let small = normalise_lens(&frame, None, centre, 0.5, 0.3, Some((600, 600)));
        let free = normalise_lens(&frame, None, centre, 0.5, 0.3, None);
        assert_eq!(small.image, free.image);
    }

    #[test]
    fn normalisation_holds_the_whole_frame_and_averages_areas() {
        let frame = ramp(100, 80);
        for angle in [0.0, 0.5, -2.0, std::f64::consts::FRAC_PI_2] {
            let n = normalise(&frame, (49.5, 39.5), 0.5, angle);
            for (x, y) in [(0.0, 0.0), (99.0, 0.0), (99.0, 79.0), (0.0, 79.0)] {
                let (u, v) = n.transform.forward(x, y);
                assert!(
                    u >= 0.0
                        && v >= 0.0
                        && u <= (n.image.width() - 1) as f64
                        && v <= (n.image.height() - 1) as f64
                );
            }
            assert!(n.inside(
                n.transform.forward(50.0, 40.0).0,
                n.transform.forward(50.0, 40.0).1,
                5.0
            ));
            assert!(!n.inside(0.0, 0.0, 0.0) || angle == 0.0);
        }
        // A linear ramp averaged over any footprint is its value at the footprint's centre.
        for angle in [0.0, 0.6] {
            let n = normalise(&frame, (49.5, 39.5), 0.5, angle);
            for (u, v) in [(10u32, 12u32), (20, 20), (25, 15)] {
                let (x, y) = n.transform.inverse(u as f64, v as f64);
                if n.inside(u as f64, v as f64, 2.0) && x + 2.0 * y < 250.0 {
                    let got = n.image.get_pixel(u, v)[0] as f64;
                    assert!(
                        (got - (x + 2.0 * y)).abs() <= 0.51,
                        "{got} vs {}",
                        x + 2.0 * y
                    );
                }
            }
        }
    }

    #[test]
    fn homography_warp_reproduces_a_shifted_image() {
        let frame = ramp(60, 60);
        // Map pixel = frame pixel + (100, 50).
        let h = Matrix3::new(1.0, 0.0, 100.0, 0.0, 1.0, 50.0, 0.0, 0.0, 1.0);
        let (vals, mask) = warp_into_map(&frame, &h, (100, 50), (70, 70), 1).unwrap();
        for y in 0..70 {
            for x in 0..70 {
                let inside = x < 60 && y < 60;
                assert_eq!(mask[y * 70 + x], inside, "{x},{y}");
                if inside {
                    assert_eq!(
                        vals[y * 70 + x],
                        frame.get_pixel(x as u32, y as u32)[0] as f32
                    );
                }
            }
        }
    }
}
