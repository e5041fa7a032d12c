//! Property/fuzz test of the bag-of-words vocabulary reader (`Vocabulary::from_bytes`), a file
//! a user may bring: arbitrary bytes and mutations of the embedded vocabulary (bit flips,
//! truncation, hostile counts) give a vocabulary or an error, never a panic or an allocation
//! sized by a field of the file. Cases: `JOINTLOC_FUZZ_CASES` (default 500), seed
//! `JOINTLOC_FUZZ_SEED` (docs/testing.md).

// The fuzz runner shared with the other crates' fuzz tests.
#[path = "../../formats/tests/common/mod.rs"]
mod common;

use jointloc_slam::place::Vocabulary;
use proptest::prelude::*;

use common::fuzz;

/// A small valid vocabulary file (the embedded one is 0.5 MB: too slow to mutate per case).
fn small() -> Vec<u8> {
    let images: Vec<Vec<[u8; 32]>> = (0..4u8)
        .map(|i| (0..60u8).map(|j| [i.wrapping_mul(37) ^ j; 32]).collect())
        .collect();
    let config = jointloc_slam::place::VocabularyConfig {
        branching: 4,
        depth: 2,
        ..Default::default()
    };
    Vocabulary::train(&images, &config)
        .expect("train")
        .to_bytes()
}

fn check(bytes: &[u8]) -> Result<(), String> {
    if let Ok(v) = Vocabulary::from_bytes(bytes) {
        // A vocabulary that loads must be usable: every descriptor reaches a word.
        let w = v.word(&[0x5a; 32]);
        if w as usize >= v.n_words() {
            return Err(format!("word {w} of {}", v.n_words()));
        }
        let _ = v.idf(w);
    }
    Ok(())
}

#[test]
fn fuzz_vocabulary_arbitrary_bytes() {
    fuzz(proptest::collection::vec(any::<u8>(), 0..2000), check);
}

#[test]
fn fuzz_vocabulary_mutations() {
    let valid = small();
    assert!(Vocabulary::from_bytes(&valid).is_ok());
    let n = valid.len();
    let strategy = (
        proptest::collection::vec((0..n, any::<u8>()), 1..8),
        0..=n,
        proptest::collection::vec(any::<u8>(), 0..4),
    )
        .prop_map(move |(flips, cut, tail)| {
            let mut b = valid.clone();
            for (at, v) in flips {
                b[at] = v;
            }
            b.truncate(cut.max(1));
            b.extend(tail);
            b
        });
    fuzz(strategy, check);
}
