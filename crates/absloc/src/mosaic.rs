//! A nadir view wider than one frame, rendered from recent frames and their poses, for maps
//! too coarse to match a single frame against (issue #29 item 1).
//!
//! At 10 m a 500-pixel frame covers 10 m of ground: 40 × 40 pixels of a 25 cm HiRISE map,
//! too few for any matcher. The SLAM knows how the last tens of metres of frames fit
//! together, so the frames are projected onto the ground and resampled into a *virtual
//! frame* of the camera's size: an orthographic view of the ground centred on the newest
//! frame's optical axis, its axes those of the newest frame laid on the ground, its pixels
//! `zoom` times the newest frame's ground pixel at the centre. The absolute localiser takes it
//! like a frame from `zoom` times the altitude, and its fix is, like any fix, the ground point
//! under the newest frame's optical axis, tied to that frame's keyframe.
//!
//! Orthographic, not a perspective from the newest camera: at 10 m a ground point 40 m away
//! is seen 76° off the axis, where 3° of tilt changes the scale by a fifth and 1 m of relief
//! moves the point by 4 m; in an orthographic view neither does.
//!
//! The ground is a plane (`n · X = d` in the poses' frame): at 10 m the relief the plane
//! misses shifts a point between two frames by (relief / altitude) × their baseline, a few
//! map pixels at most. Each virtual pixel takes the frame in which it lies nearest to the
//! principal point (least lens distortion, least parallax), sampled from a thumbnail
//! box-filtered to about the virtual pixel's size so that nothing aliases.

use image::GrayImage;
use jointloc_geometry::{CameraToWorld, PinholeCamera};
use nalgebra::{Point2, Point3, Vector3};
use rayon::prelude::*;

use crate::warp::bilinear;

/// A frame box-filtered by an integer `factor` (thumbnail pixel `(i, j)` covers frame pixels
/// `[i·f, (i+1)·f) × [j·f, (j+1)·f)`), kept per frame for the mosaic: 1/f² of the memory.
#[derive(Debug, Clone)]
pub struct Thumbnail {
    pub image: GrayImage,
    pub factor: u32,
}

impl Thumbnail {
    /// Box-filters `frame` by `factor` (≥ 1); a partial last row or column is dropped.
    pub fn new(frame: &GrayImage, factor: u32) -> Self {
        let f = factor.max(1);
        let (w, h) = ((frame.width() / f).max(1), (frame.height() / f).max(1));
        let n = f * f;
        let image = GrayImage::from_fn(w, h, |i, j| {
            let mut sum = 0u32;
            for y in j * f..((j + 1) * f).min(frame.height()) {
                for x in i * f..((i + 1) * f).min(frame.width()) {
                    sum += frame.get_pixel(x, y)[0] as u32;
                }
            }
            image::Luma([((sum + n / 2) / n) as u8])
        });
        Self { image, factor: f }
    }

    /// The thumbnail value at frame pixel `(u, v)` (bilinear), `None` outside.
    fn sample(&self, u: f64, v: f64) -> Option<f64> {
        let f = self.factor as f64;
        bilinear(&self.image, (u + 0.5) / f - 0.5, (v + 0.5) / f - 0.5)
    }
}

/// One frame seen by the mosaic: its camera-to-world pose (any frame shared with the other
/// sources and the ground plane, e.g. the SLAM's) and its thumbnail.
#[derive(Debug, Clone, Copy)]
pub struct MosaicSource<'a> {
    pub pose: CameraToWorld,
    pub thumbnail: &'a Thumbnail,
}

/// The ground as a plane `normal · X = offset` in the poses' frame (`normal` a unit vector).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GroundPlane {
    pub normal: Vector3<f64>,
    pub offset: f64,
}

impl GroundPlane {
    /// Where the ray `origin + t · dir` (t > 0) meets the plane.
    fn intersect(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> Option<Point3<f64>> {
        let denom = self.normal.dot(dir);
        if denom.abs() < 1e-9 {
            return None;
        }
        let t = (self.offset - self.normal.dot(&origin.coords)) / denom;
        (t > 0.0 && t.is_finite()).then(|| origin + dir * t)
    }
}

/// A rendered virtual frame.
#[derive(Debug, Clone)]
pub struct Mosaic {
    /// The virtual frame, the camera's size; pixels no source covers hold the mean grey level
    /// of those covered (a flat fill gives detectors nothing to find).
    pub image: GrayImage,
    /// Row-major: whether a source covers the pixel.
    pub valid: Vec<bool>,
    /// Ground covered per side, relative to one frame: the virtual focal length is the
    /// camera's divided by this.
    pub zoom: f64,
    /// Sources that gave at least one pixel.
    pub sources_used: usize,
    /// Share of the virtual frame covered.
    pub coverage: f64,
}

/// Renders the virtual frame of `centre` (the newest frame's pose) with focal lengths divided
/// by `zoom`, from `sources` over `ground`. `camera` is the frames' camera (its lens is applied
/// when sampling a source; the virtual frame is an ideal pinhole with the same principal
/// point). `margin_px`: source pixels this near their border are not used.
pub fn render(
    camera: &PinholeCamera,
    centre: &CameraToWorld,
    ground: &GroundPlane,
    zoom: f64,
    sources: &[MosaicSource<'_>],
    margin_px: f64,
) -> Mosaic {
    let (w, h) = (camera.width as usize, camera.height as usize);
    let Some(ortho) = Ortho::new(camera, centre, ground, zoom) else {
        return Mosaic {
            image: GrayImage::new(w as u32, h as u32),
            valid: vec![false; w * h],
            zoom,
            sources_used: 0,
            coverage: 0.0,
        };
    };
    // Each source's footprint as a box of virtual pixels, to skip sources quickly.
    let boxes: Vec<Option<[f64; 4]>> = sources
        .iter()
        .map(|s| footprint_box(camera, &ortho, ground, &s.pose))
        .collect();
    let world_to_src: Vec<_> = sources.iter().map(|s| s.pose.inverse()).collect();
    let (cx, cy) = (camera.cx, camera.cy);
    let half_diag = (cx * cx + cy * cy).sqrt().max(1.0);
    let rows: Vec<(Vec<f64>, Vec<Option<usize>>)> = (0..h)
        .into_par_iter()
        .map(|v| {
            let mut values = vec![0.0; w];
            let mut from = vec![None; w];
            for u in 0..w {
                let (uf, vf) = (u as f64, v as f64);
                let x = ortho.ground_point(uf, vf);
                let mut best: Option<(f64, usize, f64)> = None;
                for (i, s) in sources.iter().enumerate() {
                    let Some(b) = boxes[i] else { continue };
                    if uf < b[0] || uf > b[2] || vf < b[1] || vf > b[3] {
                        continue;
                    }
                    let pc = world_to_src[i].transform_point(&x);
                    let Some(p) = camera.project(&pc) else {
                        continue;
                    };
                    if !camera.contains(&p, margin_px) {
                        continue;
                    }
                    let d = ((p.x - cx).powi(2) + (p.y - cy).powi(2)).sqrt() / half_diag;
                    if best.is_some_and(|(bd, _, _)| bd <= d) {
                        continue;
                    }
                    if let Some(val) = s.thumbnail.sample(p.x, p.y) {
                        best = Some((d, i, val));
                    }
                }
                if let Some((_, i, val)) = best {
                    values[u] = val;
                    from[u] = Some(i);
                }
            }
            (values, from)
        })
        .collect();
    let mut valid = vec![false; w * h];
    let mut used = vec![false; sources.len()];
    let (mut sum, mut n) = (0.0, 0usize);
    for (v, (values, from)) in rows.iter().enumerate() {
        for u in 0..w {
            if let Some(i) = from[u] {
                valid[v * w + u] = true;
                used[i] = true;
                sum += values[u];
                n += 1;
            }
        }
    }
    let mean = if n > 0 { sum / n as f64 } else { 0.0 };
    let image = GrayImage::from_fn(w as u32, h as u32, |u, v| {
        let (u, v) = (u as usize, v as usize);
        let p = if valid[v * w + u] { rows[v].0[u] } else { mean };
        image::Luma([p.round().clamp(0.0, 255.0) as u8])
    });
    Mosaic {
        image,
        valid,
        zoom,
        sources_used: used.iter().filter(|&&b| b).count(),
        coverage: n as f64 / (w * h).max(1) as f64,
    }
}

/// The virtual frame's geometry: virtual pixel `(u, v)` is the ground point
/// `origin + ((u − cx) e1 + (v − cy) e2) · step`.
struct Ortho {
    origin: Point3<f64>,
    e1: Vector3<f64>,
    e2: Vector3<f64>,
    step: f64,
    cx: f64,
    cy: f64,
}

impl Ortho {
    /// Centred on the ground point under `centre`'s optical axis, its axes `centre`'s image
    /// axes laid on the plane, its step `zoom` times the ground pixel of a nadir camera at
    /// `centre`'s height above the plane.
    fn new(
        camera: &PinholeCamera,
        centre: &CameraToWorld,
        ground: &GroundPlane,
        zoom: f64,
    ) -> Option<Self> {
        let r = centre.rotation_matrix();
        let c = centre.centre();
        let n = ground.normal;
        let origin = ground.intersect(&c, &(r * Vector3::z()))?;
        let x = r * Vector3::x();
        let e1 = (x - n * n.dot(&x)).try_normalize(1e-9)?;
        let e2 = (-n).cross(&e1);
        let height = n.dot(&c.coords) - ground.offset;
        let f = 0.5 * (camera.fx + camera.fy);
        let step = height * zoom / f;
        (height > 0.0 && step.is_finite()).then_some(Self {
            origin,
            e1,
            e2,
            step,
            cx: camera.cx,
            cy: camera.cy,
        })
    }

    fn ground_point(&self, u: f64, v: f64) -> Point3<f64> {
        self.origin + (self.e1 * (u - self.cx) + self.e2 * (v - self.cy)) * self.step
    }

    fn pixel(&self, x: &Point3<f64>) -> (f64, f64) {
        let d = x - self.origin;
        (
            self.cx + d.dot(&self.e1) / self.step,
            self.cy + d.dot(&self.e2) / self.step,
        )
    }
}

/// The box of virtual pixels a source's frame covers on the ground (its corners and edge
/// midpoints projected; a little slack for the lens), `None` when it misses the ground.
fn footprint_box(
    camera: &PinholeCamera,
    ortho: &Ortho,
    ground: &GroundPlane,
    source: &CameraToWorld,
) -> Option<[f64; 4]> {
    let (w, h) = (camera.width as f64 - 1.0, camera.height as f64 - 1.0);
    let r = source.rotation_matrix();
    let o = source.centre();
    let mut b = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    for (fu, fv) in [
        (0.0, 0.0),
        (0.5, 0.0),
        (1.0, 0.0),
        (1.0, 0.5),
        (1.0, 1.0),
        (0.5, 1.0),
        (0.0, 1.0),
        (0.0, 0.5),
    ] {
        let d = camera.unproject(&Point2::new(fu * w, fv * h))?;
        let x = ground.intersect(&o, &(r * d))?;
        let (u, v) = ortho.pixel(&x);
        b = [b[0].min(u), b[1].min(v), b[2].max(u), b[3].max(v)];
    }
    let slack = 0.05 * ((b[2] - b[0]) + (b[3] - b[1])) + 2.0;
    Some([b[0] - slack, b[1] - slack, b[2] + slack, b[3] + slack])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A nadir camera at `(x, y, z)` (image x east, image y south).
    fn nadir(x: f64, y: f64, z: f64) -> CameraToWorld {
        let q = crate::localizer::nadir_orientation(0.0);
        CameraToWorld::from_rotation_translation(q, Vector3::new(x, y, z))
    }

    /// A ground texture: grey level as a function of world (x, y).
    fn texture(x: f64, y: f64) -> f64 {
        128.0 + 60.0 * (x * 1.3).sin() * (y * 0.7).cos() + 40.0 * (0.5 * x + 0.9 * y).sin()
    }

    /// The frame a nadir camera at `pose` sees of [`texture`] on z = 0.
    fn frame(camera: &PinholeCamera, pose: &CameraToWorld) -> GrayImage {
        let r = pose.rotation_matrix();
        let o = pose.centre();
        let ground = GroundPlane {
            normal: Vector3::z(),
            offset: 0.0,
        };
        GrayImage::from_fn(camera.width, camera.height, |u, v| {
            let d = camera.unproject(&Point2::new(u as f64, v as f64)).unwrap();
            let x = ground.intersect(&o, &(r * d)).unwrap();
            image::Luma([texture(x.x, x.y).round() as u8])
        })
    }

    #[test]
    fn the_virtual_frame_shows_the_ground_where_it_lies() {
        let camera = PinholeCamera::ideal(100.0, 100, 100);
        // Frames 4 m apart along x at 10 m: each covers 10 m of ground.
        let poses: Vec<_> = (0..5).map(|i| nadir(-4.0 * i as f64, 0.0, 10.0)).collect();
        let thumbs: Vec<_> = poses
            .iter()
            .map(|p| Thumbnail::new(&frame(&camera, p), 1))
            .collect();
        let sources: Vec<_> = poses
            .iter()
            .zip(&thumbs)
            .map(|(p, t)| MosaicSource {
                pose: *p,
                thumbnail: t,
            })
            .collect();
        let ground = GroundPlane {
            normal: Vector3::z(),
            offset: 0.0,
        };
        let m = render(&camera, &poses[0], &ground, 4.0, &sources, 1.0);
        assert_eq!(m.sources_used, 5);
        // A strip 10 m wide and 26 m long in a 40 m square view: about 16 % of it.
        assert!(m.coverage > 0.13 && m.coverage < 0.2, "{}", m.coverage);
        // Every covered virtual pixel shows the texture at its ground point (0.4 m pixels,
        // sampled from 0.1 m frame pixels: within a few grey levels).
        let mut worst: f64 = 0.0;
        for v in 0..100 {
            for u in 0..100 {
                if !m.valid[v * 100 + u] {
                    continue;
                }
                let x = 0.4 * (u as f64 - 49.5);
                let y = -0.4 * (v as f64 - 49.5);
                let err = (m.image.get_pixel(u as u32, v as u32)[0] as f64 - texture(x, y)).abs();
                worst = worst.max(err);
            }
        }
        assert!(worst < 12.0, "worst grey-level error {worst}");
        // Nothing ahead of the newest frame (x > 5 m) is covered.
        assert!(!m.valid[50 * 100 + 95]);
    }

    #[test]
    fn thumbnails_average_blocks() {
        let img = GrayImage::from_fn(4, 4, |u, v| image::Luma([(u * 10 + v * 40) as u8]));
        let t = Thumbnail::new(&img, 2);
        assert_eq!(t.image.dimensions(), (2, 2));
        // Block (0, 0): 0, 10, 40, 50 → 25.
        assert_eq!(t.image.get_pixel(0, 0)[0], 25);
        assert_eq!(t.image.get_pixel(1, 1)[0], 125);
    }
}
