//! Seeded, hash-based procedural noise: gradient (Perlin-style) noise, fBm and ridged
//! multifractal sums, evaluated at world coordinates in metres.
//!
//! Every value is a pure function of `(seed, x, y)`, so any row of a grid can be computed on
//! any thread and the result never depends on the thread count.

use std::ops::Range;

/// SplitMix64 finaliser: a fast bijective 64-bit mixer.
#[inline]
pub fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// A child seed for an independent stream (`stream` names the consumer).
#[inline]
pub fn derive_seed(seed: u64, stream: u64) -> u64 {
    mix64(seed ^ mix64(stream.wrapping_add(0x9e37_79b9_7f4a_7c15)))
}

/// Hash of an integer lattice point under `seed`.
#[inline]
pub fn hash2(seed: u64, ix: i64, iy: i64) -> u64 {
    mix64(
        seed ^ (ix as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15)
            ^ (iy as u64)
                .wrapping_mul(0xc2b2_ae3d_27d4_eb4f)
                .rotate_left(29),
    )
}

/// Uniform value in [0, 1) attached to a lattice point (per-cell grain).
#[inline]
pub fn unit_hash(seed: u64, ix: i64, iy: i64) -> f32 {
    (hash2(seed, ix, iy) >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
}

/// Floor as an integer without a libm call (baseline x86-64 has no rounding instruction).
/// Valid for |x| < 2^62, far beyond any lattice coordinate here.
#[inline]
pub fn fast_floor(x: f64) -> i64 {
    let i = x as i64;
    if (i as f64) > x { i - 1 } else { i }
}

/// 32 unit gradients at odd multiples of 360°/64, so none is axis-aligned.
const GRAD: [[f32; 2]; 32] = [
    [0.995_184_7, 0.098_017_14],
    [0.956_940_3, 0.290_284_7],
    [0.881_921_3, 0.471_396_74],
    [0.773_010_43, 0.634_393_3],
    [0.634_393_3, 0.773_010_43],
    [0.471_396_74, 0.881_921_3],
    [0.290_284_7, 0.956_940_3],
    [0.098_017_14, 0.995_184_7],
    [-0.098_017_14, 0.995_184_7],
    [-0.290_284_7, 0.956_940_3],
    [-0.471_396_74, 0.881_921_3],
    [-0.634_393_3, 0.773_010_43],
    [-0.773_010_43, 0.634_393_3],
    [-0.881_921_3, 0.471_396_74],
    [-0.956_940_3, 0.290_284_7],
    [-0.995_184_7, 0.098_017_14],
    [-0.995_184_7, -0.098_017_14],
    [-0.956_940_3, -0.290_284_7],
    [-0.881_921_3, -0.471_396_74],
    [-0.773_010_43, -0.634_393_3],
    [-0.634_393_3, -0.773_010_43],
    [-0.471_396_74, -0.881_921_3],
    [-0.290_284_7, -0.956_940_3],
    [-0.098_017_14, -0.995_184_7],
    [0.098_017_14, -0.995_184_7],
    [0.290_284_7, -0.956_940_3],
    [0.471_396_74, -0.881_921_3],
    [0.634_393_3, -0.773_010_43],
    [0.773_010_43, -0.634_393_3],
    [0.881_921_3, -0.471_396_74],
    [0.956_940_3, -0.290_284_7],
    [0.995_184_7, -0.098_017_14],
];

const KX: u64 = 0x9e37_79b9_7f4a_7c15;
const KY: u64 = 0xc2b2_ae3d_27d4_eb4f;

/// Gradient of a lattice point from its premixed coordinates `seed ^ ix·KX ^ iy·KY`: only
/// 5 bits are needed, so one multiply-xorshift round is enough (this is the hot path of
/// all terrain noise).
#[inline]
fn grad_dot(mixed: u64, fx: f32, fy: f32) -> f32 {
    let mut h = (mixed ^ (mixed >> 29)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    h ^= h >> 32;
    let g = GRAD[(h >> 59) as usize];
    g[0] * fx + g[1] * fy
}

#[inline]
fn fade(t: f32) -> f32 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

/// Gradient noise at lattice coordinates (x, y): smooth, zero at lattice points, roughly in
/// [-1, 1] with standard deviation ≈ 0.3.
#[inline]
pub fn gradient_noise(seed: u64, x: f64, y: f64) -> f32 {
    let (ix, iy) = (fast_floor(x), fast_floor(y));
    let (fx, fy) = ((x - ix as f64) as f32, (y - iy as f64) as f32);
    // (i + 1)·K = i·K + K in wrapping arithmetic: two multiplications for four corners.
    let x0 = (ix as u64).wrapping_mul(KX);
    let x1 = x0.wrapping_add(KX);
    let y0 = (iy as u64).wrapping_mul(KY);
    let (y0, y1) = (seed ^ y0, seed ^ y0.wrapping_add(KY));
    let n00 = grad_dot(x0 ^ y0, fx, fy);
    let n10 = grad_dot(x1 ^ y0, fx - 1.0, fy);
    let n01 = grad_dot(x0 ^ y1, fx, fy - 1.0);
    let n11 = grad_dot(x1 ^ y1, fx - 1.0, fy - 1.0);
    let (u, v) = (fade(fx), fade(fy));
    let a = n00 + (n10 - n00) * u;
    let b = n01 + (n11 - n01) * u;
    (a + (b - a) * v) * std::f32::consts::SQRT_2
}

/// One octave: its own seed, frequency, amplitude and a rotation + offset of the lattice, so
/// octaves do not share axes (which would show as grid-aligned artefacts).
#[derive(Debug, Clone, Copy)]
struct Octave {
    seed: u64,
    freq: f64,
    amp: f32,
    cos: f64,
    sin: f64,
    off_x: f64,
    off_y: f64,
}

impl Octave {
    #[inline]
    fn eval(&self, x: f64, y: f64) -> f32 {
        let u = (x * self.cos - y * self.sin) * self.freq + self.off_x;
        let v = (x * self.sin + y * self.cos) * self.freq + self.off_y;
        gradient_noise(self.seed, u, v)
    }
}

/// A sum of gradient-noise octaves from `wavelength_m` down to `min_wavelength_m`.
///
/// The amplitude of octave `o` is `gain^o` (first octave amplitude 1); with lacunarity 2,
/// a gain of 0.5 keeps the slope contributed per octave constant (Hurst exponent 1).
#[derive(Debug, Clone)]
pub struct Fbm {
    octaves: Vec<Octave>,
    amp_sum: f32,
}

impl Fbm {
    /// Octaves from `wavelength_m` down to (not below) `min_wavelength_m`, at least one.
    pub fn new(
        seed: u64,
        wavelength_m: f64,
        min_wavelength_m: f64,
        gain: f64,
        lacunarity: f64,
    ) -> Self {
        let lacunarity = if lacunarity > 1.01 { lacunarity } else { 2.0 };
        let mut octaves = Vec::new();
        let mut wl = wavelength_m.max(1e-6);
        let mut amp = 1.0f64;
        let mut o = 0u64;
        loop {
            let s = derive_seed(seed, o);
            let angle = 1.173 * o as f64 + (s >> 40) as f64 * 1e-7;
            octaves.push(Octave {
                seed: s,
                freq: 1.0 / wl,
                amp: amp as f32,
                cos: angle.cos(),
                sin: angle.sin(),
                off_x: ((s >> 8) & 0xffff) as f64 / 655.36,
                off_y: ((s >> 24) & 0xffff) as f64 / 655.36,
            });
            wl /= lacunarity;
            amp *= gain;
            o += 1;
            if wl < min_wavelength_m || o >= 24 {
                break;
            }
        }
        let amp_sum = octaves.iter().map(|o| o.amp).sum();
        Self { octaves, amp_sum }
    }

    /// Index of the first octave whose wavelength is below `wavelength_m`.
    pub fn octaves_above(&self, wavelength_m: f64) -> usize {
        self.octaves
            .iter()
            .take_while(|o| 1.0 / o.freq >= wavelength_m)
            .count()
    }

    /// Number of octaves.
    pub fn len(&self) -> usize {
        self.octaves.len()
    }

    /// Always false (at least one octave); here for clippy's `len` convention.
    pub fn is_empty(&self) -> bool {
        self.octaves.is_empty()
    }

    /// Sum of octave amplitudes (bounds |fbm| up to the noise range).
    pub fn amplitude_sum(&self) -> f32 {
        self.amp_sum
    }

    /// Plain fBm: Σ amp·noise, standard deviation ≈ 0.3 for the first octave.
    #[inline]
    pub fn eval(&self, x: f64, y: f64) -> f32 {
        self.eval_octaves(x, y, 0..self.octaves.len())
    }

    /// The fBm sum over a range of octaves only (coarse and fine parts add up to `eval`).
    #[inline]
    pub fn eval_octaves(&self, x: f64, y: f64, octaves: Range<usize>) -> f32 {
        let end = octaves.end.min(self.octaves.len());
        let start = octaves.start.min(end);
        self.octaves[start..end]
            .iter()
            .map(|o| o.amp * o.eval(x, y))
            .sum()
    }

    /// Ridged multifractal (Musgrave): sharp crests where the noise crosses zero, detail
    /// concentrated on the ridges, smooth valleys. Result in about [0, 1].
    #[inline]
    pub fn ridged(&self, x: f64, y: f64) -> f32 {
        let RidgedState(sum, _) =
            self.ridged_octaves(x, y, 0..self.octaves.len(), RidgedState::START, 0.0);
        sum / self.amp_sum
    }

    /// Continues a ridged sum over `octaves` from `state` (the running sum and the weight
    /// the previous octave hands on). Returns the unnormalised state; divide the final
    /// sum by [`Fbm::amplitude_sum`]. `crease` > 0 replaces |n| by √(n² + c²) − c, rounding
    /// the crests (a smooth field can then be interpolated from a lattice).
    #[inline]
    pub fn ridged_octaves(
        &self,
        x: f64,
        y: f64,
        octaves: Range<usize>,
        state: RidgedState,
        crease: f32,
    ) -> RidgedState {
        let end = octaves.end.min(self.octaves.len());
        let start = octaves.start.min(end);
        let RidgedState(mut sum, mut weight) = state;
        for o in &self.octaves[start..end] {
            let n = o.eval(x, y);
            let n = if crease > 0.0 {
                (n * n + crease * crease).sqrt() - crease
            } else {
                n.abs()
            };
            let mut s = 1.0 - n.min(1.0);
            s *= s;
            s *= weight;
            weight = if crease > 0.0 {
                (s * 2.0).tanh()
            } else {
                (s * 2.0).clamp(0.0, 1.0)
            };
            sum += s * o.amp;
        }
        RidgedState(sum, weight)
    }
}

/// Running state of a ridged multifractal sum: (sum, weight).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RidgedState(pub f32, pub f32);

impl RidgedState {
    /// Before the first octave.
    pub const START: RidgedState = RidgedState(0.0, 1.0);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gradient_noise_is_seeded_smooth_and_bounded() {
        let mut diff = 0usize;
        let mut sum2 = 0.0f64;
        let n = 4000;
        for i in 0..n {
            let (x, y) = (i as f64 * 0.137, i as f64 * 0.0711 - 3.0);
            let a = gradient_noise(1, x, y);
            let b = gradient_noise(2, x, y);
            assert!(a.abs() <= 1.5, "{a}");
            if a != b {
                diff += 1;
            }
            sum2 += (a as f64).powi(2);
            // Continuity: a tiny step changes the value a little.
            let c = gradient_noise(1, x + 1e-4, y);
            assert!((a - c).abs() < 1e-3);
        }
        assert!(diff > n * 9 / 10);
        let std = (sum2 / n as f64).sqrt();
        assert!((0.15..0.5).contains(&std), "std {std}");
    }

    #[test]
    fn fbm_octaves_follow_wavelengths() {
        let f = Fbm::new(7, 10.0, 0.1, 0.5, 2.0);
        // 10, 5, 2.5, 1.25, 0.625, 0.3125, 0.156 (then 0.078 < 0.1 stops).
        assert_eq!(f.len(), 7);
        let r = f.ridged(3.3, 4.4);
        assert!((0.0..=1.0).contains(&r));
    }
}
