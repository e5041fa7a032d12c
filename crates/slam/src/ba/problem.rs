//! The bundle-adjustment problem, independent of the SLAM map: the map builds one of these for
//! its local window, solves it, and writes the optimised poses and points back.

use jointloc_geometry::{PinholeCamera, RobustKernel, Sim3, WorldToCamera};
use nalgebra::{Matrix3, Matrix3x6, Point2, Vector3};

use super::factors::global_position;
use crate::{Result, SlamError};

/// χ² of 3 degrees of freedom at 95 %: the default Huber threshold of a global-position factor.
pub const CHI2_3DOF_95: f64 = 7.815;

/// A keyframe of the window: its extrinsics in the SLAM frame, and whether the optimiser may move
/// it (ORB-SLAM fixes the keyframes that see the local points but are not in the window).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BaCamera {
    /// World(SLAM)-to-camera transform `T_cw`.
    pub pose: WorldToCamera,
    /// Held constant when true.
    pub fixed: bool,
}

/// A map point in the SLAM frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BaPoint {
    /// Position in the SLAM frame, metres (or SLAM units before the scale is known).
    pub position: Vector3<f64>,
    /// Held constant when true.
    pub fixed: bool,
}

/// One keypoint measurement of a point in a camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Observation {
    /// Index into [`BaProblem::cameras`].
    pub camera: usize,
    /// Index into [`BaProblem::points`].
    pub point: usize,
    /// Measured pixel (undistorted when the problem's camera has no distortion model).
    pub pixel: Point2<f64>,
    /// Information `1/σ²` in px⁻²; the χ² of the observation is `information · ‖e‖²`.
    pub information: f64,
}

impl Observation {
    /// An observation detected at pyramid `level` of a pyramid with `scale_factor` between levels:
    /// σ = `scale_factor^level` pixels, as in ORB-SLAM (one pixel at level 0).
    pub fn at_level(
        camera: usize,
        point: usize,
        pixel: Point2<f64>,
        level: u32,
        scale_factor: f64,
    ) -> Self {
        let sigma2 = scale_factor.powi(2 * level as i32);
        Self {
            camera,
            point,
            pixel,
            information: 1.0 / sigma2,
        }
    }
}

/// The paper's global-position factor (§III-C, `e_G = P_G − P_L`): pulls the centre `C_i` of a
/// keyframe, mapped into the world by the current SLAM→world similarity, onto an absolute fix.
///
/// Residual `r = S · C_i − P_G` with `C_i = −Rᵀt`; or, with `point_in_camera` = `o`, of that
/// point of the camera frame, `r = S · Rᵀ(o − t) − P_G` (a map fix locates the ground point on
/// the optical axis, not the camera). Its cost is `½ · w · ρ(‖r‖² / σ²)`: the
/// confidence `w` multiplies the robustified term, exactly as in `f(x) = … + Σ w_G ρ(…)`, so
/// `w = 0` removes the factor. `σ` (metres, world frame) says how far a fix of confidence 1 may
/// be from the truth; the fusion sets it from the absolute localiser's accuracy. `S` is held
/// fixed during the optimisation (the fusion re-estimates it between runs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GlobalPositionFactor {
    /// Index into [`BaProblem::cameras`].
    pub camera: usize,
    /// The absolute fix `P_G` in the world frame (x east, y north, z up), metres.
    pub world_position: Vector3<f64>,
    /// The point of the camera frame (SLAM units) the fix locates; zero: the camera centre.
    pub point_in_camera: Vector3<f64>,
    /// The SLAM→world similarity `S`, held constant.
    pub slam_to_world: Sim3,
    /// Confidence `w ≥ 0` of the fix.
    pub weight: f64,
    /// Standard deviation `σ_G > 0` of a fix of confidence 1, metres.
    pub sigma: f64,
    /// Kernel on the normalised squared residual `‖r‖²/σ²`.
    pub kernel: RobustKernel,
    /// σ of the world z component over `sigma` (1: isotropic). A fix's x, y come from the
    /// map, its z from the altimeter and the elevation model, whose errors grow with the
    /// range: at 100 m an isotropic σ let the heights' noise roll the map (§ "The end at
    /// altitude" of the fusion's documentation).
    pub vertical_sigma_scale: f64,
}

impl GlobalPositionFactor {
    /// Residual and Jacobian at a camera pose ([`super::factors::global_point_residual`]),
    /// the z row divided by `vertical_sigma_scale`: whitened for the anisotropy, so that
    /// `‖r‖²/σ²` is the factor's normalised squared residual.
    pub(crate) fn whitened_residual(
        &self,
        rotation: &Matrix3<f64>,
        translation: &Vector3<f64>,
    ) -> (Vector3<f64>, Matrix3x6<f64>) {
        let (mut r, mut j) = global_position(
            rotation,
            translation,
            &self.slam_to_world,
            &self.point_in_camera,
            &self.world_position,
        );
        if self.vertical_sigma_scale != 1.0 {
            let k = 1.0 / self.vertical_sigma_scale;
            r.z *= k;
            j.row_mut(2).scale_mut(k);
        }
        (r, j)
    }

    /// A factor with `σ_G = 1 m` and a Huber kernel at the 95 % χ² bound of 3 DoF.
    pub fn new(
        camera: usize,
        world_position: Vector3<f64>,
        slam_to_world: Sim3,
        weight: f64,
    ) -> Self {
        Self {
            camera,
            world_position,
            point_in_camera: Vector3::zeros(),
            slam_to_world,
            weight,
            sigma: 1.0,
            kernel: RobustKernel::Huber {
                delta: CHI2_3DOF_95.sqrt(),
            },
            vertical_sigma_scale: 1.0,
        }
    }
}

/// A Gaussian prior on a camera centre in the SLAM frame (e.g. an altimeter-scaled initial
/// guess); cost `½ ‖C_i − position‖² / σ²`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PositionPrior {
    /// Index into [`BaProblem::cameras`].
    pub camera: usize,
    /// Prior camera centre in the SLAM frame.
    pub position: Vector3<f64>,
    /// Standard deviation, SLAM units.
    pub sigma: f64,
}

/// The terrain near a point, as a plane: height `height` (world z, metres) at world
/// `anchor` (x, y), slope `(∂h/∂x, ∂h/∂y)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GroundPlane {
    pub anchor: [f64; 2],
    pub height: f64,
    pub slope: [f64; 2],
}

/// A map point lies on the terrain of an elevation model: cost `½ ρ(r² / σ²)` with `r` the
/// world height of `S · X` above the model's plane there. Many points over a keyframe window
/// fix the tilt of the local map, which the position fixes (a few per window, their heights
/// from a 0.1 m altimeter) leave loose: over near-flat ground a monocular SLAM confuses tilt
/// with a sideways shift.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GroundHeightFactor {
    /// Index into [`BaProblem::points`].
    pub point: usize,
    /// The SLAM→world similarity `S`, held constant.
    pub slam_to_world: Sim3,
    /// The terrain at the point's world x, y when the problem was built.
    pub ground: GroundPlane,
    /// σ of the model's height at a map point, metres (model error + the point's own relief).
    pub sigma: f64,
    /// Kernel on `r² / σ²`.
    pub kernel: RobustKernel,
}

/// Everything a (local) bundle adjustment needs.
#[derive(Debug, Clone, PartialEq)]
pub struct BaProblem {
    /// Intrinsics shared by every camera.
    pub intrinsics: PinholeCamera,
    /// Cameras (keyframes), free or fixed.
    pub cameras: Vec<BaCamera>,
    /// Map points, free or fixed.
    pub points: Vec<BaPoint>,
    /// Reprojection measurements.
    pub observations: Vec<Observation>,
    /// Absolute position fixes (JointLoc's fusion terms).
    pub global_factors: Vec<GlobalPositionFactor>,
    /// Priors on camera centres in the SLAM frame.
    pub position_priors: Vec<PositionPrior>,
    /// Map points on the terrain of an elevation model.
    pub ground_factors: Vec<GroundHeightFactor>,
}

impl BaProblem {
    /// An empty problem for cameras with these intrinsics.
    pub fn new(intrinsics: PinholeCamera) -> Self {
        Self {
            intrinsics,
            cameras: Vec::new(),
            points: Vec::new(),
            observations: Vec::new(),
            global_factors: Vec::new(),
            position_priors: Vec::new(),
            ground_factors: Vec::new(),
        }
    }

    /// Adds a camera and returns its index.
    pub fn add_camera(&mut self, pose: WorldToCamera, fixed: bool) -> usize {
        self.cameras.push(BaCamera { pose, fixed });
        self.cameras.len() - 1
    }

    /// Adds a point and returns its index.
    pub fn add_point(&mut self, position: Vector3<f64>, fixed: bool) -> usize {
        self.points.push(BaPoint { position, fixed });
        self.points.len() - 1
    }

    /// Adds a measurement of `point` in `camera` with information `1/σ²`.
    pub fn add_observation(
        &mut self,
        camera: usize,
        point: usize,
        pixel: Point2<f64>,
        information: f64,
    ) {
        self.observations.push(Observation {
            camera,
            point,
            pixel,
            information,
        });
    }

    /// Adds a global-position factor.
    pub fn add_global_factor(&mut self, factor: GlobalPositionFactor) {
        self.global_factors.push(factor);
    }

    /// Adds a ground-height factor.
    pub fn add_ground_factor(&mut self, factor: GroundHeightFactor) {
        self.ground_factors.push(factor);
    }

    /// Adds a camera-centre prior.
    pub fn add_position_prior(&mut self, prior: PositionPrior) {
        self.position_priors.push(prior);
    }

    /// Checks indices, finiteness and ranges, so the solver never sees NaN or a bad index.
    pub fn validate(&self) -> Result<()> {
        let k = &self.intrinsics;
        if ![k.fx, k.fy, k.cx, k.cy].iter().all(|v| v.is_finite()) || k.fx <= 0.0 || k.fy <= 0.0 {
            return Err(SlamError::NonFinite("camera intrinsics"));
        }
        if self.cameras.iter().any(|c| !c.pose.is_finite()) {
            return Err(SlamError::NonFinite("camera pose"));
        }
        if self.points.iter().any(|p| !all_finite(&p.position)) {
            return Err(SlamError::NonFinite("point position"));
        }
        let nc = self.cameras.len();
        let np = self.points.len();
        for (i, o) in self.observations.iter().enumerate() {
            check_index("observation camera", i, o.camera, nc)?;
            check_index("observation point", i, o.point, np)?;
            if !o.pixel.coords.iter().all(|v| v.is_finite()) || !o.information.is_finite() {
                return Err(SlamError::NonFinite("observation"));
            }
            if o.information <= 0.0 {
                return Err(SlamError::InvalidProblem(format!(
                    "observation {i} has information {} (must be > 0)",
                    o.information
                )));
            }
        }
        for (i, g) in self.global_factors.iter().enumerate() {
            check_index("global factor camera", i, g.camera, nc)?;
            let s = &g.slam_to_world;
            if !all_finite(&g.world_position)
                || !all_finite(&g.point_in_camera)
                || !g.weight.is_finite()
                || !g.sigma.is_finite()
                || !g.vertical_sigma_scale.is_finite()
                || !sim3_finite(s)
            {
                return Err(SlamError::NonFinite("global-position factor"));
            }
            if g.weight < 0.0 || g.sigma <= 0.0 || g.vertical_sigma_scale <= 0.0 || s.scale <= 0.0 {
                return Err(SlamError::InvalidProblem(format!(
                    "global factor {i}: weight {} must be >= 0, sigma {}, vertical sigma scale {} \
                     and scale {} > 0",
                    g.weight, g.sigma, g.vertical_sigma_scale, s.scale
                )));
            }
            check_kernel(&g.kernel)?;
        }
        for (i, p) in self.position_priors.iter().enumerate() {
            check_index("position prior camera", i, p.camera, nc)?;
            if !all_finite(&p.position) || !p.sigma.is_finite() {
                return Err(SlamError::NonFinite("position prior"));
            }
            if p.sigma <= 0.0 {
                return Err(SlamError::InvalidProblem(format!(
                    "position prior {i}: sigma {} must be > 0",
                    p.sigma
                )));
            }
        }
        for (i, g) in self.ground_factors.iter().enumerate() {
            check_index("ground factor point", i, g.point, np)?;
            let s = &g.slam_to_world;
            let plane = &g.ground;
            if ![
                plane.height,
                plane.anchor[0],
                plane.anchor[1],
                plane.slope[0],
                plane.slope[1],
            ]
            .iter()
            .all(|v| v.is_finite())
                || !g.sigma.is_finite()
                || !sim3_finite(s)
            {
                return Err(SlamError::NonFinite("ground-height factor"));
            }
            if g.sigma <= 0.0 || s.scale <= 0.0 {
                return Err(SlamError::InvalidProblem(format!(
                    "ground factor {i}: sigma {} and scale {} must be > 0",
                    g.sigma, s.scale
                )));
            }
            check_kernel(&g.kernel)?;
        }
        Ok(())
    }
}

fn all_finite(v: &Vector3<f64>) -> bool {
    v.iter().all(|x| x.is_finite())
}

fn sim3_finite(s: &Sim3) -> bool {
    s.scale.is_finite()
        && all_finite(&s.translation)
        && s.rotation.coords.iter().all(|v| v.is_finite())
}

fn check_index(what: &str, item: usize, index: usize, len: usize) -> Result<()> {
    if index < len {
        Ok(())
    } else {
        Err(SlamError::InvalidProblem(format!(
            "{what} of item {item} is {index}, but there are only {len}"
        )))
    }
}

/// Rejects kernels with a non-positive or non-finite scale.
pub(crate) fn check_kernel(kernel: &RobustKernel) -> Result<()> {
    let scale = match *kernel {
        RobustKernel::Trivial => return Ok(()),
        RobustKernel::Huber { delta } => delta,
        RobustKernel::Cauchy { c } => c,
    };
    if scale.is_finite() && scale > 0.0 {
        Ok(())
    } else {
        Err(SlamError::InvalidConfig {
            field: "robust kernel",
            value: format!("{kernel:?}"),
            reason: "the kernel scale must be finite and > 0",
        })
    }
}
