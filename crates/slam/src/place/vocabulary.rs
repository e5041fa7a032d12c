//! A vocabulary of binary words (Gálvez-López & Tardós, "Bags of binary words for fast place
//! recognition", T-RO 2012, the DBoW2 library ORB-SLAM2 uses): a tree of ORB descriptor
//! centres, `branching` children per node and `depth` levels, built by k-majority clustering
//! (k-means with Hamming distances, centres by per-bit majority vote); its leaves are the words,
//! each weighted by its inverse document frequency over the training images.
//!
//! ORB-SLAM2's vocabulary (trained on Bovisa and other city imagery) is not ours to ship; this
//! one is trained on our own rendered Mars frames by a committed command
//! (`examples/train_vocabulary.rs`, `docs/vo.md` §6.1c), and is embedded in the library
//! ([`Vocabulary::embedded`]).

use std::sync::{Arc, OnceLock};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use jointloc_features::orb::{Descriptor, hamming};

use super::error::{PlaceError, Result};

/// The vocabulary embedded in the library: branching 10, depth 4, trained on 3 rendered flights
/// (one per terrain) by `examples/train_vocabulary.rs`.
const EMBEDDED: &[u8] = include_bytes!("../../vocabulary/orb-mars-k10-l4.jlvoc");

/// Magic bytes and version of the file format.
const MAGIC: &[u8; 8] = b"JLVOC\x00\x00\x01";

/// Settings of [`Vocabulary::train`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct VocabularyConfig {
    /// Children per node (DBoW2 / ORB-SLAM2: 10).
    pub branching: usize,
    /// Levels below the root (ORB-SLAM2: 6, a million words for any scene; 4 gives ten
    /// thousand, plenty for one planetary map).
    pub depth: usize,
    /// k-majority iterations per node at most (stops earlier when no assignment changes).
    pub iterations: usize,
    /// Seed of the k-means++ initialisation.
    pub seed: u64,
}

impl Default for VocabularyConfig {
    fn default() -> Self {
        Self {
            branching: 10,
            depth: 4,
            iterations: 10,
            seed: 1,
        }
    }
}

/// One node of the tree.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Node {
    centre: Descriptor,
    /// Index of the first child; children are contiguous.
    first_child: u32,
    /// Number of children; 0 for a word (a leaf).
    children: u8,
    /// The word's index, for a leaf.
    word: u32,
}

/// A trained vocabulary tree (see the module doc).
#[derive(Debug, Clone, PartialEq)]
pub struct Vocabulary {
    branching: usize,
    depth: usize,
    /// Node 0 is the root (its centre is unused).
    nodes: Vec<Node>,
    /// Inverse document frequency of each word, `ln(N / n_w)`.
    idf: Vec<f32>,
}

impl Vocabulary {
    /// The vocabulary shipped with the library (see [`EMBEDDED`]).
    pub fn embedded() -> Self {
        Self::from_bytes(EMBEDDED).expect("the embedded vocabulary is valid (tested)")
    }

    /// [`Vocabulary::embedded`], read once per process and shared: the tracker and the loop
    /// closer of every map use the same one.
    pub fn shared() -> Arc<Self> {
        static SHARED: OnceLock<Arc<Vocabulary>> = OnceLock::new();
        SHARED.get_or_init(|| Arc::new(Self::embedded())).clone()
    }

    /// Number of words (leaves).
    pub fn n_words(&self) -> usize {
        self.idf.len()
    }

    pub fn branching(&self) -> usize {
        self.branching
    }

    pub fn depth(&self) -> usize {
        self.depth
    }

    /// The word of a descriptor: down the tree, to the nearest centre at each level.
    pub fn word(&self, d: &Descriptor) -> u32 {
        let mut node = &self.nodes[0];
        while node.children > 0 {
            let first = node.first_child as usize;
            let mut best = first;
            let mut best_distance = u32::MAX;
            for c in first..first + node.children as usize {
                let h = hamming(d, &self.nodes[c].centre);
                if h < best_distance {
                    best_distance = h;
                    best = c;
                }
            }
            node = &self.nodes[best];
        }
        node.word
    }

    /// Inverse document frequency of `word`.
    pub fn idf(&self, word: u32) -> f32 {
        self.idf[word as usize]
    }

    /// Trains a vocabulary on the descriptors of a set of images (one `Vec` per image; the
    /// images are the documents of the words' idf).
    pub fn train(images: &[Vec<Descriptor>], config: &VocabularyConfig) -> Result<Self> {
        if !(2..=255).contains(&config.branching) {
            return Err(PlaceError::InvalidConfig {
                field: "branching",
                value: config.branching.to_string(),
                reason: "must be in 2..=255",
            });
        }
        if !(1..=8).contains(&config.depth) {
            return Err(PlaceError::InvalidConfig {
                field: "depth",
                value: config.depth.to_string(),
                reason: "must be in 1..=8",
            });
        }
        let all: Vec<Descriptor> = images.iter().flatten().copied().collect();
        if all.len() < config.branching {
            return Err(PlaceError::TooFewDescriptors {
                required: config.branching,
                found: all.len(),
            });
        }
        let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
        let mut nodes = vec![Node {
            centre: [0; 32],
            first_child: 0,
            children: 0,
            word: 0,
        }];
        // Breadth-first: (node, its descriptors, level).
        let mut queue = std::collections::VecDeque::from([(0usize, all, 0usize)]);
        while let Some((node, members, level)) = queue.pop_front() {
            if level == config.depth || members.len() <= 1 {
                continue;
            }
            let clusters = k_majority(&members, config.branching, config.iterations, &mut rng);
            if clusters.len() < 2 {
                continue;
            }
            nodes[node].first_child = nodes.len() as u32;
            nodes[node].children = clusters.len() as u8;
            let first = nodes.len();
            for (centre, _) in &clusters {
                nodes.push(Node {
                    centre: *centre,
                    first_child: 0,
                    children: 0,
                    word: 0,
                });
            }
            for (i, (_, m)) in clusters.into_iter().enumerate() {
                queue.push_back((first + i, m, level + 1));
            }
        }
        let mut n_words = 0u32;
        for n in nodes.iter_mut().skip(1).filter(|n| n.children == 0) {
            n.word = n_words;
            n_words += 1;
        }
        let mut vocabulary = Self {
            branching: config.branching,
            depth: config.depth,
            nodes,
            idf: vec![0.0; n_words as usize],
        };
        let mut documents = vec![0usize; n_words as usize];
        for image in images {
            let mut words: Vec<u32> = image.iter().map(|d| vocabulary.word(d)).collect();
            words.sort_unstable();
            words.dedup();
            for w in words {
                documents[w as usize] += 1;
            }
        }
        let n = images.len().max(1) as f64;
        for (idf, &count) in vocabulary.idf.iter_mut().zip(&documents) {
            // A word no training image holds is as rare as can be.
            *idf = (n / count.max(1) as f64).ln() as f32;
        }
        Ok(vocabulary)
    }

    /// The file format: magic, branching, depth, node count (u32 LE each), then per node its
    /// centre (32 bytes), first child (u32), children (u8), word (u32), then per word its idf
    /// (f32). Nodes are stored in tree order: children after their parent.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(20 + self.nodes.len() * 41 + self.idf.len() * 4);
        out.extend_from_slice(MAGIC);
        for v in [self.branching, self.depth, self.nodes.len(), self.idf.len()] {
            out.extend_from_slice(&(v as u32).to_le_bytes());
        }
        for n in &self.nodes {
            out.extend_from_slice(&n.centre);
            out.extend_from_slice(&n.first_child.to_le_bytes());
            out.push(n.children);
            out.extend_from_slice(&n.word.to_le_bytes());
        }
        for w in &self.idf {
            out.extend_from_slice(&w.to_le_bytes());
        }
        out
    }

    /// Reads [`Self::to_bytes`]' format, checking every count and index against the data (a
    /// corrupt or hostile file is an error, never a panic or a huge allocation).
    pub fn from_bytes(bytes: &[u8]) -> Result<Self> {
        let corrupt = |reason: String| PlaceError::CorruptVocabulary { reason };
        if bytes.len() < MAGIC.len() + 16 || &bytes[..MAGIC.len()] != MAGIC {
            return Err(corrupt("not a jointloc vocabulary (bad magic)".into()));
        }
        let u32_at = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().expect("4"));
        let header = MAGIC.len();
        let (branching, depth) = (u32_at(header) as usize, u32_at(header + 4) as usize);
        let (n_nodes, n_words) = (u32_at(header + 8) as usize, u32_at(header + 12) as usize);
        let body = header + 16;
        let expected = n_nodes
            .checked_mul(41)
            .and_then(|n| n.checked_add(n_words.checked_mul(4)?))
            .and_then(|n| n.checked_add(body));
        if expected != Some(bytes.len()) {
            return Err(corrupt(format!(
                "{n_nodes} nodes and {n_words} words do not fit its {} bytes",
                bytes.len()
            )));
        }
        if n_nodes == 0 || !(2..=255).contains(&branching) || !(1..=8).contains(&depth) {
            return Err(corrupt(format!(
                "{n_nodes} nodes, branching {branching}, depth {depth}"
            )));
        }
        let mut nodes = Vec::with_capacity(n_nodes);
        for i in 0..n_nodes {
            let at = body + i * 41;
            let node = Node {
                centre: bytes[at..at + 32].try_into().expect("32"),
                first_child: u32_at(at + 32),
                children: bytes[at + 36],
                word: u32_at(at + 37),
            };
            if node.children > 0 {
                let first = node.first_child as usize;
                if first <= i || first + node.children as usize > n_nodes {
                    return Err(corrupt(format!("node {i}: children out of order or range")));
                }
            } else if i > 0 && node.word as usize >= n_words {
                return Err(corrupt(format!(
                    "node {i}: word {} of {n_words}",
                    node.word
                )));
            }
            nodes.push(node);
        }
        if nodes[0].children == 0 {
            return Err(corrupt("the root has no children".into()));
        }
        let words_at = body + n_nodes * 41;
        let idf: Vec<f32> = (0..n_words)
            .map(|w| {
                f32::from_le_bytes(
                    bytes[words_at + 4 * w..words_at + 4 * w + 4]
                        .try_into()
                        .expect("4"),
                )
            })
            .collect();
        if idf.iter().any(|w| !w.is_finite() || *w < 0.0) {
            return Err(corrupt("an idf weight is negative or not finite".into()));
        }
        Ok(Self {
            branching,
            depth,
            nodes,
            idf,
        })
    }
}

/// k-majority clustering of `members` into at most `k` clusters: k-means++ seeds, Hamming
/// assignment, per-bit majority centres. Returns (centre, members) per non-empty cluster.
fn k_majority(
    members: &[Descriptor],
    k: usize,
    iterations: usize,
    rng: &mut ChaCha8Rng,
) -> Vec<(Descriptor, Vec<Descriptor>)> {
    if members.len() <= k {
        return members.iter().map(|d| (*d, vec![*d])).collect();
    }
    // k-means++: each next seed drawn with probability ∝ squared distance to the nearest.
    let mut centres = vec![members[rng.random_range(0..members.len())]];
    let mut nearest: Vec<u32> = members.iter().map(|d| hamming(d, &centres[0])).collect();
    while centres.len() < k {
        let total: f64 = nearest.iter().map(|&d| (d as f64).powi(2)).sum();
        if total == 0.0 {
            break;
        }
        let mut pick = rng.random::<f64>() * total;
        let mut chosen = members.len() - 1;
        for (i, &d) in nearest.iter().enumerate() {
            pick -= (d as f64).powi(2);
            if pick <= 0.0 {
                chosen = i;
                break;
            }
        }
        let c = members[chosen];
        for (n, d) in nearest.iter_mut().zip(members) {
            *n = (*n).min(hamming(d, &c));
        }
        centres.push(c);
    }
    let mut assignment = vec![usize::MAX; members.len()];
    for _ in 0..iterations.max(1) {
        let mut changed = false;
        for (a, d) in assignment.iter_mut().zip(members) {
            let best = (0..centres.len())
                .min_by_key(|&c| (hamming(d, &centres[c]), c))
                .expect("at least one centre");
            changed |= *a != best;
            *a = best;
        }
        if !changed {
            break;
        }
        centres = majority_centres(members, &assignment, &centres);
    }
    let mut clusters: Vec<(Descriptor, Vec<Descriptor>)> =
        centres.iter().map(|c| (*c, Vec::new())).collect();
    for (a, d) in assignment.iter().zip(members) {
        clusters[*a].1.push(*d);
    }
    clusters.retain(|(_, m)| !m.is_empty());
    clusters
}

/// Per-bit majority of each cluster's members (a cluster left empty keeps its centre).
fn majority_centres(
    members: &[Descriptor],
    assignment: &[usize],
    previous: &[Descriptor],
) -> Vec<Descriptor> {
    let mut counts = vec![[0u32; 256]; previous.len()];
    let mut sizes = vec![0u32; previous.len()];
    for (d, &a) in members.iter().zip(assignment) {
        sizes[a] += 1;
        for (bit, count) in counts[a].iter_mut().enumerate() {
            *count += u32::from(d[bit / 8] >> (bit % 8) & 1);
        }
    }
    previous
        .iter()
        .enumerate()
        .map(|(c, old)| {
            if sizes[c] == 0 {
                return *old;
            }
            let mut centre = [0u8; 32];
            for (bit, &count) in counts[c].iter().enumerate() {
                if 2 * count > sizes[c] {
                    centre[bit / 8] |= 1 << (bit % 8);
                }
            }
            centre
        })
        .collect()
}

/// A random descriptor near `base`: each bit flipped with probability `p` (tests).
#[cfg(test)]
pub(crate) fn noisy(base: &Descriptor, p: f64, rng: &mut ChaCha8Rng) -> Descriptor {
    let mut d = *base;
    for bit in 0..256 {
        if rng.random::<f64>() < p {
            d[bit / 8] ^= 1 << (bit % 8);
        }
    }
    d
}

#[cfg(test)]
mod tests {
    use super::*;

    fn random_descriptor(rng: &mut ChaCha8Rng) -> Descriptor {
        let mut d = [0u8; 32];
        rng.fill(&mut d);
        d
    }

    /// 40 well-separated "true words", each seen in every image with 8 % of bits flipped.
    fn clustered(images: usize) -> (Vec<Descriptor>, Vec<Vec<Descriptor>>) {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let words: Vec<Descriptor> = (0..40).map(|_| random_descriptor(&mut rng)).collect();
        let data = (0..images)
            .map(|_| words.iter().map(|w| noisy(w, 0.08, &mut rng)).collect())
            .collect();
        (words, data)
    }

    #[test]
    fn noisy_copies_of_a_word_fall_in_one_word() {
        let (words, data) = clustered(30);
        let config = VocabularyConfig {
            branching: 8,
            depth: 3,
            ..Default::default()
        };
        let voc = Vocabulary::train(&data, &config).unwrap();
        assert!(voc.n_words() >= 40, "{} words", voc.n_words());
        let mut rng = ChaCha8Rng::seed_from_u64(99);
        let mut same = 0;
        let mut total = 0;
        let mut distinct = std::collections::BTreeSet::new();
        for w in &words {
            let home = voc.word(w);
            distinct.insert(home);
            for _ in 0..20 {
                same += usize::from(voc.word(&noisy(w, 0.08, &mut rng)) == home);
                total += 1;
            }
        }
        // Different true words land in different vocabulary words, and a fresh noisy copy
        // mostly in its own word (a tree can split a cluster: DBoW2's known weakness).
        assert_eq!(distinct.len(), 40);
        assert!(same * 10 >= total * 7, "{same} of {total}");
    }

    #[test]
    fn the_file_format_round_trips_and_rejects_corruption() {
        let (_, data) = clustered(5);
        let voc = Vocabulary::train(&data, &VocabularyConfig::default()).unwrap();
        let bytes = voc.to_bytes();
        assert_eq!(Vocabulary::from_bytes(&bytes).unwrap(), voc);
        assert!(Vocabulary::from_bytes(&bytes[..bytes.len() - 1]).is_err());
        assert!(Vocabulary::from_bytes(b"JLVOC").is_err());
        let mut bad = bytes.clone();
        bad[MAGIC.len() + 8] = 0xff; // node count
        assert!(Vocabulary::from_bytes(&bad).is_err());
        let mut cycle = bytes.clone();
        // Root's first child pointing at itself.
        let at = MAGIC.len() + 16 + 32;
        cycle[at..at + 4].copy_from_slice(&0u32.to_le_bytes());
        assert!(Vocabulary::from_bytes(&cycle).is_err());
    }

    #[test]
    fn training_is_seeded_and_checks_its_settings() {
        let (_, data) = clustered(4);
        let config = VocabularyConfig {
            depth: 2,
            ..Default::default()
        };
        assert_eq!(
            Vocabulary::train(&data, &config).unwrap(),
            Vocabulary::train(&data, &config).unwrap()
        );
        let bad = VocabularyConfig {
            branching: 1,
            ..Default::default()
        };
        assert!(Vocabulary::train(&data, &bad).is_err());
        assert!(Vocabulary::train(&[vec![[0u8; 32]]], &config).is_err());
    }

    #[test]
    fn the_embedded_vocabulary_loads() {
        let voc = Vocabulary::embedded();
        assert_eq!((voc.branching(), voc.depth()), (10, 4));
        assert!(voc.n_words() > 5000, "{} words", voc.n_words());
    }
}
