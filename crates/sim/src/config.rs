//! The simulator's configuration ([`SimConfig`]): what defines a dataset, the presets'
//! draws (suns), the rules that follow the altitude (terrain cell, altimeter noise, map
//! margin) and the validation of every option, with errors that name the field.

use std::path::Path;

use jointloc_geometry::{Distortion, KannalaBrandt, PinholeCamera};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::error::{Result, SimError};
use crate::regional::MAX_MAP_SIDE_PX;
use crate::render::validate_camera;
use crate::satellite::{Difficulty, SatelliteConfig};
use crate::sensor::SensorConfig;
use crate::shading::{ShadingConfig, Sun};
use crate::terrain::{TerrainConfig, TerrainKind};
use crate::trajectory::TrajectoryConfig;

/// Off-axis angle (degrees) up to which a fisheye's view of the ground lies on the map (see
/// [`SimConfig::effective_margin_m`]); the SLAM keeps keypoints up to 70° by default.
pub const FISHEYE_MAP_ANGLE_DEG: f64 = 72.0;

/// `tan` of the angle up to which the map covers `camera`'s view: [`FISHEYE_MAP_ANGLE_DEG`]
/// for a fisheye, `None` (the whole view) otherwise. The map's margin and the renderer's
/// count of expected background pixels both follow it.
pub fn fisheye_cover_tan(camera: &PinholeCamera) -> Option<f64> {
    matches!(camera.distortion, Some(Distortion::KannalaBrandt(_)))
        .then(|| FISHEYE_MAP_ANGLE_DEG.to_radians().tan())
}

/// The simulator's fisheye lens: TUM-VI's cam0 Kannala-Brandt coefficients (a real 195°
/// fisheye calibration, as in ORB-SLAM3's `TUM-VI.yaml`): within 0.3 % of pure equidistant
/// up to 70° off axis.
pub const FISHEYE_LENS: KannalaBrandt = KannalaBrandt {
    k1: 0.0034823894022493434,
    k2: 0.0007150348452162257,
    k3: -0.0020532361418706202,
    k4: 0.00020293673591811182,
};

/// A [`FISHEYE_LENS`] camera whose horizontal field of view spans the image width:
/// `f = (width / 2) / θ_d(fov / 2)` (215.7 px for 133° over 500 px), square pixels, principal
/// point at the image centre.
pub fn fisheye_camera(fov_deg: f64, width: u32, height: u32) -> Result<PinholeCamera> {
    PinholeCamera::fisheye(fov_deg, width, height, FISHEYE_LENS).ok_or_else(|| {
        SimError::InvalidConfig {
            field: "fov_deg",
            value: fov_deg.to_string(),
            reason: "a fisheye's field of view must be in (0, 180) degrees".into(),
        }
    })
}

/// An ideal pinhole whose horizontal field of view spans the image width:
/// `f = (width / 2) / tan(fov / 2)`.
pub fn pinhole_camera(fov_deg: f64, width: u32, height: u32) -> Result<PinholeCamera> {
    if !(fov_deg > 0.0 && fov_deg < 170.0) {
        return Err(SimError::InvalidConfig {
            field: "fov_deg",
            value: fov_deg.to_string(),
            reason: "a pinhole's field of view must be in (0, 170) degrees".into(),
        });
    }
    let f = width as f64 / 2.0 / (fov_deg / 2.0).to_radians().tan();
    Ok(PinholeCamera::ideal(f, width, height))
}

/// Everything that defines a dataset. Same config (seed included) → byte-identical files.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SimConfig {
    /// Terrain kind: crater, gravel or mountain.
    pub terrain_kind: TerrainKind,
    /// Master seed; every random choice derives from it.
    pub seed: u64,
    /// Size of the UAV-to-map gap (satellite GSD, sun change, radiometry).
    pub difficulty: Difficulty,
    /// Flight: length (150 m), speed (1 m/s), rate (5 Hz), altitude (10 m), path shape, jitter.
    pub trajectory: TrajectoryConfig,
    /// UAV camera (default: 500 × 500, fx = fy = 500, principal point at the centre).
    pub camera: PinholeCamera,
    /// UAV camera sensor (blur, exposure, noise, gamma).
    pub sensor: SensorConfig,
    /// σ of the altimeter's Gaussian noise at short range, metres.
    pub altimeter_sigma_m: f64,
    /// The altimeter's noise grows with range: σ = max(`altimeter_sigma_m`, this × the
    /// nominal altitude), a laser altimeter's 10 cm floor (Ingenuity's beyond 5 m) and a
    /// radar altimeter's ≈ 0.5 % of range at 50–200 m.
    pub altimeter_range_fraction: f64,
    /// Side of a square map larger than the flight, metres, with the flight placed in it at
    /// a seeded position; absent: the map is the flight's bounding box plus the margin (the
    /// `mars` preset defaults to 2000 m). See [`crate::regional`].
    pub map_size_m: Option<f64>,
    /// Azimuth difference between the map's sun and the flight's, degrees (0–180);
    /// overrides the preset.
    pub sun_azimuth_change_deg: Option<f64>,
    /// Elevation of the map's sun, degrees; overrides the preset.
    pub sun_elevation_deg: Option<f64>,
    /// Elevation of the flight's sun, degrees; overrides the preset's draw.
    pub flight_sun_elevation_deg: Option<f64>,
    /// Also write the map and the elevation model as GeoTIFF (`satellite.tif`,
    /// `elevation.tif`) in the Mars equirectangular CRS, world (0, 0) at
    /// [`GEOTIFF_ORIGIN_M`]: input for `jointloc map import`.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub geotiff: bool,
    /// Smallest distance from the flown path to the map edge, metres (raised automatically to
    /// cover the camera footprint).
    pub margin_m: f64,
    /// Sun during the flight; drawn from the seed when absent (azimuth 0–360°, elevation 35–60°).
    pub uav_sun: Option<Sun>,
    /// Satellite map settings; the difficulty preset when absent.
    pub satellite: Option<SatelliteConfig>,
    /// Terrain synthesis (cell size 2.5 cm by default).
    pub terrain: TerrainConfig,
    /// Photometry shared by the UAV and the satellite render.
    pub shading: ShadingConfig,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            terrain_kind: TerrainKind::Crater,
            seed: 0,
            difficulty: Difficulty::Easy,
            trajectory: TrajectoryConfig::default(),
            camera: PinholeCamera::ideal(500.0, 500, 500),
            sensor: SensorConfig::default(),
            altimeter_sigma_m: 0.1,
            altimeter_range_fraction: 0.005,
            map_size_m: None,
            sun_azimuth_change_deg: None,
            sun_elevation_deg: None,
            flight_sun_elevation_deg: None,
            geotiff: false,
            margin_m: 12.0,
            uav_sun: None,
            satellite: None,
            terrain: TerrainConfig::default(),
            shading: ShadingConfig::default(),
        }
    }
}

/// Random streams derived from the master seed.
pub(crate) mod stream {
    pub const PATH: u64 = 1;
    pub const TERRAIN: u64 = 2;
    pub const SUN: u64 = 3;
    pub const FLIGHT: u64 = 4;
    pub const ALTIMETER: u64 = 5;
    pub const SATELLITE_NOISE: u64 = 6;
    pub const FRAME_NOISE: u64 = 7;
    pub const DEM: u64 = 8;
    pub const MARS_SUN: u64 = 9;
    pub const PLACEMENT: u64 = 10;
}

/// Map coordinates (Mars equirectangular easting, northing; metres) of world (0, 0) in the
/// GeoTIFFs the simulator writes: Jezero crater (77.45° E, 18.44° N).
pub const GEOTIFF_ORIGIN_M: (f64, f64) = (4_590_960.0, 1_093_031.0);

/// Default side of the `mars` preset's map, metres.
pub const MARS_MAP_SIZE_M: f64 = 2000.0;

/// Highest flight the simulator renders, metres.
pub const MAX_ALTITUDE_M: f64 = 500.0;

/// File name of the simulated elevation model.
pub const ELEVATION_IMAGE: &str = "elevation.png";

/// SplitMix64 of `seed` and `stream`: independent sub-seeds.
pub fn sub_seed(seed: u64, stream: u64) -> u64 {
    let mut z = seed ^ stream.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

impl SimConfig {
    /// Reads a configuration from TOML (missing keys take their defaults).
    pub fn read(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|source| SimError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        toml::from_str(&text).map_err(|e| SimError::Parse {
            path: path.to_path_buf(),
            line: e.span().map_or(0, |s| {
                text[..s.start.min(text.len())].lines().count().max(1)
            }),
            message: e.message().to_string(),
        })
    }

    /// The configuration as TOML (what `sim.toml` holds).
    pub fn to_toml_string(&self) -> Result<String> {
        toml::to_string(self).map_err(|e| SimError::InvalidConfig {
            field: "config",
            value: String::new(),
            reason: e.to_string(),
        })
    }

    /// The satellite settings in force (explicit, or the difficulty preset).
    pub fn satellite_config(&self) -> SatelliteConfig {
        self.satellite
            .clone()
            .unwrap_or_else(|| self.difficulty.satellite_config())
    }

    /// Suns of the flight and of the map: the preset's (the `mars` preset draws them from
    /// its ranges), then the explicit overrides.
    pub fn suns(&self) -> (Sun, Sun) {
        let mut rng = ChaCha8Rng::seed_from_u64(sub_seed(self.seed, stream::SUN));
        let drawn = Sun {
            azimuth_deg: rng.random_range(0.0..360.0),
            elevation_deg: rng.random_range(35.0..60.0),
        };
        let mut uav = self.uav_sun.unwrap_or(drawn);
        let sat = self.satellite_config();
        let sign = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
        let mut change = sat.sun_azimuth_change_deg;
        let mut elevation = sat.sun_elevation_deg;
        if self.difficulty == Difficulty::Mars {
            let mut m = ChaCha8Rng::seed_from_u64(sub_seed(self.seed, stream::MARS_SUN));
            let (c, e, f) = (
                m.random_range(30.0..=180.0),
                m.random_range(35.0..=45.0),
                m.random_range(15.0..=60.0),
            );
            if self.satellite.is_none() {
                (change, elevation) = (c, e);
            }
            if self.uav_sun.is_none() {
                uav.elevation_deg = f;
            }
        }
        change = self.sun_azimuth_change_deg.unwrap_or(change);
        elevation = self.sun_elevation_deg.unwrap_or(elevation);
        uav.elevation_deg = self.flight_sun_elevation_deg.unwrap_or(uav.elevation_deg);
        let satellite = Sun {
            azimuth_deg: (uav.azimuth_deg + sign * change).rem_euclid(360.0),
            elevation_deg: elevation,
        };
        (uav, satellite)
    }

    /// Side of the map when it is larger than the flight (explicit, or the `mars` preset's).
    pub fn effective_map_size_m(&self) -> Option<f64> {
        self.map_size_m
            .or((self.difficulty == Difficulty::Mars).then_some(MARS_MAP_SIZE_M))
    }

    /// σ of the altimeter noise at the nominal altitude.
    pub fn altimeter_noise_m(&self) -> f64 {
        self.altimeter_sigma_m
            .max(self.altimeter_range_fraction * self.trajectory.altitude_m)
    }

    /// The terrain cell: detail for the UAV's ground sampling distance (altitude / focal),
    /// never finer than `terrain.cell_m`, and a whole fraction of the map's GSD. At 10 m with
    /// f = 500 px this is `terrain.cell_m` (2.5 cm); at 200 m on a 25 cm map, 25 cm.
    pub fn terrain_cell_m(&self) -> f64 {
        let gsd = self.satellite_config().gsd_m;
        let f = self.camera.fx.max(self.camera.fy);
        let wanted = self
            .terrain
            .cell_m
            .max(1.25 * self.trajectory.altitude_m / f);
        let n = ((gsd / wanted) - 1e-9).ceil().max(1.0);
        if (gsd / self.terrain.cell_m - n).abs() < 1e-6 {
            self.terrain.cell_m
        } else {
            gsd / n
        }
    }

    /// The terrain settings in force (the cell from [`Self::terrain_cell_m`]).
    pub fn effective_terrain(&self) -> TerrainConfig {
        TerrainConfig {
            cell_m: self.terrain_cell_m(),
            ..self.terrain.clone()
        }
    }

    /// Checks every section; errors name the field.
    pub fn validate(&self) -> Result<()> {
        self.trajectory.validate()?;
        validate_camera(&self.camera)?;
        self.sensor.validate("sensor")?;
        self.terrain.validate()?;
        self.satellite_config().validate(self.terrain_cell_m())?;
        self.validate_envelope()?;
        for (field, v) in [
            ("altimeter_sigma_m", self.altimeter_sigma_m),
            ("altimeter_range_fraction", self.altimeter_range_fraction),
            ("margin_m", self.margin_m),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(SimError::InvalidConfig {
                    field,
                    value: v.to_string(),
                    reason: "must be ≥ 0".into(),
                });
            }
        }
        if let Some(sun) = self.uav_sun
            && !(sun.azimuth_deg.is_finite()
                && sun.elevation_deg > 0.0
                && sun.elevation_deg <= 90.0)
        {
            return Err(SimError::InvalidConfig {
                field: "uav_sun",
                value: format!("{sun:?}"),
                reason: "needs a finite azimuth and an elevation in (0, 90]".into(),
            });
        }
        Ok(())
    }

    /// The options of the Mars envelope: map size, suns, altitude.
    fn validate_envelope(&self) -> Result<()> {
        let bad = |field: &'static str, v: f64, reason: &str| SimError::InvalidConfig {
            field,
            value: v.to_string(),
            reason: reason.into(),
        };
        if let Some(s) = self.map_size_m {
            if !(s.is_finite() && s > 0.0) {
                return Err(bad("map_size_m", s, "must be a positive length in metres"));
            }
            let gsd = self.satellite_config().gsd_m;
            if s / gsd > MAX_MAP_SIDE_PX as f64 {
                return Err(bad(
                    "map_size_m",
                    s,
                    &format!("the map would be over {MAX_MAP_SIDE_PX} pixels a side at {gsd} m/px"),
                ));
            }
        }
        if let Some(a) = self.sun_azimuth_change_deg
            && !(0.0..=180.0).contains(&a)
        {
            return Err(bad(
                "sun_azimuth_change_deg",
                a,
                "must be in [0, 180] degrees",
            ));
        }
        for (field, e) in [
            ("sun_elevation_deg", self.sun_elevation_deg),
            ("flight_sun_elevation_deg", self.flight_sun_elevation_deg),
        ] {
            if let Some(e) = e
                && !(e > 0.0 && e <= 90.0)
            {
                return Err(bad(field, e, "must be in (0, 90] degrees"));
            }
        }
        if self.altimeter_range_fraction > 0.5 {
            return Err(bad(
                "altimeter_range_fraction",
                self.altimeter_range_fraction,
                "must be ≤ 0.5",
            ));
        }
        if self.trajectory.altitude_m > MAX_ALTITUDE_M {
            return Err(bad(
                "trajectory.altitude_m",
                self.trajectory.altitude_m,
                &format!("must be ≤ {MAX_ALTITUDE_M} m"),
            ));
        }
        Ok(())
    }

    /// Distance from the path to the map edge: `margin_m`, or more when the camera footprint
    /// (at the highest altitude, with 2° of tilt to spare) reaches further.
    pub fn effective_margin_m(&self) -> f64 {
        let cam = &self.camera;
        let (w, h) = (cam.width as f64, cam.height as f64);
        // The corners, and for a fisheye the whole border: a pixel that does not unproject
        // (at or beyond 90° off axis) counts as the 80° cap below.
        let corners = [
            (-0.5, -0.5),
            (w - 0.5, -0.5),
            (-0.5, h - 0.5),
            (w - 0.5, h - 0.5),
        ];
        let cover_tan = fisheye_cover_tan(cam);
        let fisheye = cover_tan.is_some();
        let border: Vec<(f64, f64)> = if fisheye {
            let (nw, nh) = (cam.width as usize, cam.height as usize);
            (0..=nw)
                .flat_map(|u| [(u as f64 - 0.5, -0.5), (u as f64 - 0.5, h - 0.5)])
                .chain((0..=nh).flat_map(|v| [(-0.5, v as f64 - 0.5), (w - 0.5, v as f64 - 0.5)]))
                .collect()
        } else {
            corners.to_vec()
        };
        let corner_tan = border
            .iter()
            .map(|&(u, v)| {
                cam.unproject(&nalgebra::Point2::new(u, v))
                    .map_or(f64::INFINITY, |r| r.xy().norm())
            })
            .filter(|t| fisheye || t.is_finite())
            .fold(0.0, f64::max);
        // A fisheye's periphery sees the ground at grazing angles tens of metres away: the map
        // covers it up to FISHEYE_MAP_ANGLE_DEG, beyond that the frame shows the background.
        let corner_tan = cover_tan.map_or(corner_tan, |c| corner_tan.min(c));
        let tilt = (corner_tan.atan() + 2f64.to_radians())
            .min(80f64.to_radians())
            .tan();
        let height = self.trajectory.altitude_m + self.trajectory.altitude_variation_m;
        self.margin_m.max(1.2 * height * tilt + 1.0)
    }
}
