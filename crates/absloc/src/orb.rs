//! ORB (the classic path, `jointloc_features::orb`) behind the [`Detector`]/[`Matcher`] contract.
//!
//! [`Features`] holds float descriptors, so the 256 BRIEF bits travel as 256 floats of 0 or 1
//! (bit `8·byte + k` is bit `k` of byte `byte`, the ORB module's LSB-first packing). That costs
//! 32× the memory of packed bits in RAM, but keeps one feature type for every matcher; the
//! tile cache packs 0/1 descriptors back to bits on disk. The matcher repacks to bytes and
//! matches by Hamming distance (mutual nearest neighbours, ratio test); its score is
//! `1 − distance / 256`, a similarity in [0, 1] like the learned matchers' (random pairs of
//! descriptors sit near 0.5).

use jointloc_features::orb::{
    Descriptor, KeyPoint, MatcherConfig, OrbConfig, OrbExtractor, OrbFeatures, match_mutual,
};
use jointloc_features::{Detector, Features, FeaturesError, Matcher, Matches};

/// Bits per descriptor.
pub const ORB_BITS: usize = 256;

/// ORB extraction as a [`Detector`].
#[derive(Debug, Clone)]
pub struct OrbDetector {
    extractor: OrbExtractor,
}

impl OrbDetector {
    /// An ORB detector with `config` (checked).
    pub fn new(config: OrbConfig) -> Result<Self, FeaturesError> {
        Ok(Self {
            extractor: OrbExtractor::new(config)?,
        })
    }

    /// The settings.
    pub fn config(&self) -> &OrbConfig {
        self.extractor.config()
    }
}

/// Unpacks a descriptor to 0/1 floats.
pub fn bits_to_floats(d: &Descriptor, out: &mut Vec<f32>) {
    out.extend((0..ORB_BITS).map(|b| f32::from((d[b / 8] >> (b % 8)) & 1)));
}

/// Packs 0/1 floats (non-zero is 1) to a descriptor.
pub fn floats_to_bits(v: &[f32]) -> Descriptor {
    let mut d = [0u8; 32];
    for (b, &x) in v.iter().take(ORB_BITS).enumerate() {
        if x != 0.0 {
            d[b / 8] |= 1 << (b % 8);
        }
    }
    d
}

impl Detector for OrbDetector {
    fn detect(&self, image: &image::GrayImage) -> jointloc_features::Result<Features> {
        let orb = self.extractor.extract(image)?;
        let mut f = Features {
            descriptor_dim: ORB_BITS,
            image_size: image.dimensions(),
            ..Default::default()
        };
        for (k, d) in orb.keypoints.iter().zip(&orb.descriptors) {
            f.keypoints.push([k.x as f32, k.y as f32]);
            f.scores.push(k.response);
            bits_to_floats(d, &mut f.descriptors);
        }
        Ok(f)
    }
}

/// Hamming matching of ORB features carried as 0/1 floats.
#[derive(Debug, Clone, Default)]
pub struct OrbMatcher {
    config: MatcherConfig,
}

impl OrbMatcher {
    /// A matcher with `config` (orientation checks need angles the contract does not carry,
    /// so `check_orientation` is ignored).
    pub fn new(config: MatcherConfig) -> Self {
        Self {
            config: MatcherConfig {
                check_orientation: false,
                ..config
            },
        }
    }
}

fn to_orb(f: &Features) -> jointloc_features::Result<OrbFeatures> {
    if f.descriptor_dim != ORB_BITS || f.descriptors.len() != f.len() * ORB_BITS {
        return Err(FeaturesError::InvalidInput(format!(
            "ORB matching needs {ORB_BITS}-bit descriptors, got {}-D",
            f.descriptor_dim
        )));
    }
    Ok(OrbFeatures {
        keypoints: f
            .keypoints
            .iter()
            .map(|k| KeyPoint {
                x: k[0] as f64,
                y: k[1] as f64,
                octave: 0,
                angle: 0.0,
                response: 0.0,
                size: 31.0,
            })
            .collect(),
        descriptors: (0..f.len())
            .map(|i| floats_to_bits(f.descriptor(i)))
            .collect(),
        level_scales: vec![1.0],
    })
}

impl Matcher for OrbMatcher {
    fn match_features(&self, a: &Features, b: &Features) -> jointloc_features::Result<Matches> {
        let (qa, qb) = (to_orb(a)?, to_orb(b)?);
        let found = match_mutual(&qa, &qb, &self.config);
        Ok(Matches {
            pairs: found.iter().map(|m| (m.query, m.train)).collect(),
            scores: found
                .iter()
                .map(|m| 1.0 - m.distance as f32 / ORB_BITS as f32)
                .collect(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bits_round_trip() {
        let mut d = [0u8; 32];
        for (i, b) in d.iter_mut().enumerate() {
            *b = (i as u8).wrapping_mul(37) ^ 0x5a;
        }
        let mut v = Vec::new();
        bits_to_floats(&d, &mut v);
        assert_eq!(v.len(), 256);
        assert!(v.iter().all(|&x| x == 0.0 || x == 1.0));
        assert_eq!(floats_to_bits(&v), d);
        assert_eq!(v[8 + 1], f32::from((d[1] >> 1) & 1));
    }

    #[test]
    fn matches_a_shifted_image_to_itself() {
        // Non-repeating texture: random lattices at two scales, bilinearly interpolated.
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let coarse: Vec<f64> = (0..27 * 27).map(|_| rng.random_range(0.0..1.0)).collect();
        let fine: Vec<f64> = (0..68 * 68).map(|_| rng.random_range(0.0..1.0)).collect();
        let lerp = |g: &[f64], n: usize, x: f64, y: f64| {
            let (x0, y0) = (x.floor() as usize, y.floor() as usize);
            let (fx, fy) = (x - x0 as f64, y - y0 as f64);
            let at = |i: usize, j: usize| g[j.min(n - 1) * n + i.min(n - 1)];
            (at(x0, y0) * (1.0 - fx) + at(x0 + 1, y0) * fx) * (1.0 - fy)
                + (at(x0, y0 + 1) * (1.0 - fx) + at(x0 + 1, y0 + 1) * fx) * fy
        };
        let img = image::GrayImage::from_fn(200, 200, |x, y| {
            let (x, y) = (x as f64, y as f64);
            let v = 150.0 * lerp(&coarse, 27, x / 8.0, y / 8.0)
                + 90.0 * lerp(&fine, 68, x / 3.0, y / 3.0);
            image::Luma([v.clamp(0.0, 255.0) as u8])
        });
        let shifted = image::imageops::crop_imm(&img, 10, 5, 180, 180).to_image();
        let det = OrbDetector::new(OrbConfig {
            n_features: 300,
            ..Default::default()
        })
        .unwrap();
        let (a, b) = (det.detect(&img).unwrap(), det.detect(&shifted).unwrap());
        assert!(a.len() > 50 && b.len() > 50);
        let m = OrbMatcher::default().match_features(&a, &b).unwrap();
        let good = m
            .pairs
            .iter()
            .filter(|&&(i, j)| {
                let (p, q) = (a.keypoints[i], b.keypoints[j]);
                (p[0] - 10.0 - q[0]).abs() < 1.5 && (p[1] - 5.0 - q[1]).abs() < 1.5
            })
            .count();
        assert!(
            good >= 30 && good * 10 >= m.pairs.len() * 8,
            "{good} of {}",
            m.pairs.len()
        );
        assert!(m.scores.iter().all(|s| (0.0..=1.0).contains(s)));
        // Float descriptors of another length are refused.
        let mut bad = a.clone();
        bad.descriptor_dim = 64;
        assert!(OrbMatcher::default().match_features(&bad, &b).is_err());
    }
}
