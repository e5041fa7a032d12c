//! Bag-of-words vectors and DBoW2's L1 similarity score.

use jointloc_features::orb::Descriptor;

use super::vocabulary::Vocabulary;

/// A keyframe's words with their tf-idf weights, L1-normalised, sorted by word.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct BowVector(Vec<(u32, f32)>);

impl BowVector {
    /// The tf-idf vector of a set of descriptors (DBoW2's TF_IDF weighting, L1 norm).
    pub fn new(vocabulary: &Vocabulary, descriptors: &[Descriptor]) -> Self {
        let mut words: Vec<u32> = descriptors.iter().map(|d| vocabulary.word(d)).collect();
        words.sort_unstable();
        let mut out: Vec<(u32, f32)> = Vec::new();
        for w in words {
            match out.last_mut() {
                Some((last, count)) if *last == w => *count += 1.0,
                _ => out.push((w, 1.0)),
            }
        }
        let n = descriptors.len().max(1) as f32;
        for (w, v) in &mut out {
            *v = *v / n * vocabulary.idf(*w);
        }
        out.retain(|(_, v)| *v > 0.0);
        let norm: f32 = out.iter().map(|(_, v)| v).sum();
        if norm > 0.0 {
            for (_, v) in &mut out {
                *v /= norm;
            }
        }
        Self(out)
    }

    pub fn len(&self) -> usize {
        self.0.len()
    }

    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// DBoW2's L1 score `1 − ½ ‖a − b‖₁` in [0, 1]: 1 for the same words in the same
    /// proportions, 0 for no word in common.
    pub fn score(&self, other: &Self) -> f64 {
        let (a, b) = (&self.0, &other.0);
        let (mut i, mut j) = (0, 0);
        let mut common = 0.0f64;
        while i < a.len() && j < b.len() {
            match a[i].0.cmp(&b[j].0) {
                std::cmp::Ordering::Less => i += 1,
                std::cmp::Ordering::Greater => j += 1,
                std::cmp::Ordering::Equal => {
                    let (x, y) = (a[i].1 as f64, b[j].1 as f64);
                    // |x| + |y| − |x − y| summed over common words = 2 − ‖a − b‖₁.
                    common += x + y - (x - y).abs();
                    i += 1;
                    j += 1;
                }
            }
        }
        (0.5 * common).clamp(0.0, 1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::place::vocabulary::{VocabularyConfig, noisy};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn the_same_place_scores_higher_than_another() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let place = |rng: &mut ChaCha8Rng| -> Vec<Descriptor> {
            (0..200)
                .map(|_| {
                    let mut d = [0u8; 32];
                    rng.fill(&mut d);
                    d
                })
                .collect()
        };
        let (a, b) = (place(&mut rng), place(&mut rng));
        let training: Vec<Vec<Descriptor>> = vec![a.clone(), b.clone(), place(&mut rng)];
        let voc = Vocabulary::train(
            &training,
            &VocabularyConfig {
                depth: 3,
                ..Default::default()
            },
        )
        .unwrap();
        let va = BowVector::new(&voc, &a);
        assert!((va.score(&va) - 1.0).abs() < 1e-6);
        let a_again: Vec<Descriptor> = a.iter().map(|d| noisy(d, 0.05, &mut rng)).collect();
        let same = va.score(&BowVector::new(&voc, &a_again));
        let other = va.score(&BowVector::new(&voc, &b));
        assert!(
            same > 2.0 * other && same > 0.2,
            "same {same}, other {other}"
        );
        assert_eq!(va.score(&BowVector::default()), 0.0);
    }
}
