//! Trains the bag-of-words vocabulary of `jointloc_slam::place` on the frames of rendered
//! flights: ORB descriptors (the SLAM's default extractor) of every `EVERY`-th frame.
//!
//! The embedded vocabulary (`crates/slam/vocabulary/orb-mars-k10-l4.jlvoc`) was made by:
//!
//! ```sh
//! for s in 9101:crater 9102:gravel 9103:mountain; do
//!   jointloc sim --terrain ${s#*:} --seed ${s%%:*} --length-m 150 --out train-${s#*:}
//! done
//! cargo run --release -p jointloc-slam --example train_vocabulary -- \
//!   crates/slam/vocabulary/orb-mars-k10-l4.jlvoc 5 train-crater train-gravel train-mountain
//! ```
//!
//! Usage: `train_vocabulary OUT.jlvoc EVERY DATASET...` (refuses to overwrite OUT).

use std::path::PathBuf;

use jointloc_features::orb::{OrbConfig, OrbExtractor};
use jointloc_formats::Sequence;
use jointloc_slam::place::{Vocabulary, VocabularyConfig};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 4 {
        return Err("usage: train_vocabulary OUT.jlvoc EVERY DATASET...".into());
    }
    let out = PathBuf::from(&args[1]);
    if out.exists() && std::fs::metadata(&out)?.len() > 0 {
        return Err(format!("{}: exists, not overwritten", out.display()).into());
    }
    let every: usize = args[2]
        .parse()
        .map_err(|e| format!("EVERY {:?}: {e}", args[2]))?;
    let extractor = OrbExtractor::new(OrbConfig::default())?;
    let mut images = Vec::new();
    for dir in &args[3..] {
        let seq = Sequence::open(&PathBuf::from(dir))?;
        for i in (0..seq.len()).step_by(every.max(1)) {
            let img = seq.load_image(i)?;
            images.push(extractor.extract(&img)?.descriptors);
        }
        eprintln!("{dir}: {} images so far", images.len());
    }
    let started = std::time::Instant::now();
    let vocabulary = Vocabulary::train(&images, &VocabularyConfig::default())?;
    eprintln!(
        "{} words from {} descriptors of {} images in {:.1} s",
        vocabulary.n_words(),
        images.iter().map(Vec::len).sum::<usize>(),
        images.len(),
        started.elapsed().as_secs_f64()
    );
    std::fs::write(&out, vocabulary.to_bytes())?;
    Ok(())
}
