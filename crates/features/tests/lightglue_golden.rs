//! LightGlue (ALIKED, DISK) and LighterGlue (XFeat) against the reference PyTorch outputs on
//! the golden sparse features (so these tests do not depend on the detector ports): match
//! sets ≥ 99 % identical, scores within 1e-4, and the adaptive stop layer of the reference.

use std::path::PathBuf;

use jointloc_features::lightglue::{LightGlue, LightGlueConfig, LightGlueFeatures};
use jointloc_features::models::ready_store;
use jointloc_features::{Features, FeaturesError};

fn golden(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/golden")
        .join(name)
}

struct Golden {
    bytes: Vec<u8>,
}

impl Golden {
    fn open(name: &str) -> Self {
        let bytes = std::fs::read(golden(name)).expect("golden file");
        Self { bytes }
    }

    fn f32(&self, key: &str) -> (Vec<usize>, Vec<f32>) {
        let st = safetensors::SafeTensors::deserialize(&self.bytes).expect("safetensors");
        let t = st.tensor(key).expect(key);
        assert_eq!(t.dtype(), safetensors::Dtype::F32, "{key}");
        let v = t
            .data()
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
            .collect();
        (t.shape().to_vec(), v)
    }

    fn i64(&self, key: &str) -> (Vec<usize>, Vec<i64>) {
        let st = safetensors::SafeTensors::deserialize(&self.bytes).expect("safetensors");
        let t = st.tensor(key).expect(key);
        assert_eq!(t.dtype(), safetensors::Dtype::I64, "{key}");
        let v = t
            .data()
            .chunks_exact(8)
            .map(|c| i64::from_le_bytes(c.try_into().unwrap()))
            .collect();
        (t.shape().to_vec(), v)
    }
}

/// Golden sparse features of image `side` ("a" or "b"); the images are 500×500.
fn features(file: &str, side: &str) -> Features {
    let g = Golden::open(file);
    let (ks, k) = g.f32(&format!("{side}.keypoints"));
    let (ds, d) = g.f32(&format!("{side}.descriptors"));
    assert_eq!(ks[0], ds[0]);
    let scores_key = if file.starts_with("xfeat") {
        "scores"
    } else {
        "keypoint_scores"
    };
    let (_, scores) = g.f32(&format!("{side}.{scores_key}"));
    Features {
        keypoints: k.chunks_exact(2).map(|c| [c[0], c[1]]).collect(),
        scores,
        descriptors: d,
        descriptor_dim: ds[1],
        image_size: (500, 500),
    }
}

fn reference_matches(file: &str) -> (Vec<(usize, usize)>, Option<Vec<f32>>) {
    let g = Golden::open(file);
    let (shape, m) = g.i64("matches");
    assert_eq!(shape[1], 2);
    let pairs = m
        .chunks_exact(2)
        .map(|c| (c[0] as usize, c[1] as usize))
        .collect();
    // LighterGlue's golden file has matches only.
    let scores = if file.starts_with("xfeat") {
        None
    } else {
        Some(g.f32("scores").1)
    };
    (pairs, scores)
}

fn summary_stop(model: &str) -> usize {
    let text = std::fs::read_to_string(golden("summary.json")).expect("summary");
    // `"lightglue_adaptive_stop_layer": 2` inside the model's object.
    let obj = &text[text.find(&format!("\"{model}\": {{")).expect(model)..];
    let key = "\"lightglue_adaptive_stop_layer\":";
    let rest = &obj[obj.find(key).expect(key) + key.len()..];
    let num: String = rest
        .trim_start()
        .chars()
        .take_while(char::is_ascii_digit)
        .collect();
    num.parse().expect("stop layer")
}

/// Runs the matcher on the golden pair and checks it against `reference`.
fn check(config: LightGlueConfig, sparse: &str, reference: &str, expected_stop: Option<usize>) {
    let store = ready_store().expect("models (run `jointloc models fetch`)");
    let t = std::time::Instant::now();
    let lg = LightGlue::new(&store, config).expect("LightGlue");
    eprintln!(
        "{reference}: LightGlue::new {:.0} ms",
        t.elapsed().as_secs_f64() * 1e3
    );
    let (a, b) = (features(sparse, "a"), features(sparse, "b"));
    let out = lg.match_pair(&a, &b).expect("match");
    let (ref_pairs, ref_scores) = reference_matches(reference);
    let ours = &out.matches;
    assert!(
        ours.pairs.windows(2).all(|w| w[0].0 < w[1].0),
        "sorted by a"
    );
    let common = ours
        .pairs
        .iter()
        .filter(|p| ref_pairs.binary_search(p).is_ok())
        .count();
    let frac = common as f64 / ours.pairs.len().max(ref_pairs.len()) as f64;
    let mut max_diff = 0.0f32;
    if let Some(rs) = &ref_scores {
        for (p, s) in ours.pairs.iter().zip(&ours.scores) {
            if let Ok(k) = ref_pairs.binary_search(p) {
                max_diff = max_diff.max((s - rs[k]).abs());
            }
        }
    }
    eprintln!(
        "{reference}: ours {} reference {} common {common} ({:.2} %), max score diff {max_diff:.2e}, \
         layers run {}, kept {:?}",
        ours.pairs.len(),
        ref_pairs.len(),
        100.0 * frac,
        out.layers_run,
        out.kept
    );
    assert!(frac >= 0.99, "match sets {:.2} % identical", 100.0 * frac);
    assert!(max_diff <= 1e-4, "score difference {max_diff}");
    if let Some(stop) = expected_stop {
        assert_eq!(out.layers_run, stop, "adaptive stop layer");
    }
}

#[test]
fn aliked_lightglue_full_matches_reference() {
    let c = LightGlueConfig::lightglue(LightGlueFeatures::Aliked).full();
    check(
        c,
        "aliked_sparse.safetensors",
        "aliked_lightglue_full.safetensors",
        Some(9),
    );
}

#[test]
fn aliked_lightglue_adaptive_matches_reference() {
    let c = LightGlueConfig::lightglue(LightGlueFeatures::Aliked);
    let stop = summary_stop("aliked");
    check(
        c,
        "aliked_sparse.safetensors",
        "aliked_lightglue_adaptive.safetensors",
        Some(stop),
    );
}

#[test]
fn disk_lightglue_full_matches_reference() {
    let c = LightGlueConfig::lightglue(LightGlueFeatures::Disk).full();
    check(
        c,
        "disk_sparse.safetensors",
        "disk_lightglue_full.safetensors",
        Some(9),
    );
}

#[test]
fn disk_lightglue_adaptive_matches_reference() {
    let c = LightGlueConfig::lightglue(LightGlueFeatures::Disk);
    let stop = summary_stop("disk");
    check(
        c,
        "disk_sparse.safetensors",
        "disk_lightglue_adaptive.safetensors",
        Some(stop),
    );
}

#[test]
fn xfeat_lighterglue_matches_reference() {
    // min_conf 0.1 and LighterGlue's defaults (no early stop, pruning at 0.95, all 6 layers).
    let c = LightGlueConfig::lighterglue();
    check(
        c,
        "xfeat_sparse.safetensors",
        "xfeat_lighterglue.safetensors",
        Some(6),
    );
}

#[test]
fn mismatched_descriptor_dims_give_a_clear_error_and_empty_sides_no_matches() {
    let store = ready_store().expect("models");
    let lg = LightGlue::new(&store, LightGlueConfig::lighterglue()).expect("LighterGlue");
    // ALIKED's 128-D descriptors into LighterGlue (64-D).
    let a = features("aliked_sparse.safetensors", "a");
    let x = features("xfeat_sparse.safetensors", "b");
    let err = lg.match_pair(&a, &x).expect_err("128-D into a 64-D model");
    let msg = err.to_string();
    assert!(matches!(err, FeaturesError::InvalidInput(_)), "{msg}");
    assert!(msg.contains("128") && msg.contains("64"), "{msg}");
    // Zero keypoints on either side: no matches, no panic.
    let empty = Features {
        descriptor_dim: 64,
        image_size: (500, 500),
        ..Features::default()
    };
    for (p, q) in [(&empty, &x), (&x, &empty), (&empty, &empty)] {
        let out = lg.match_pair(p, q).expect("empty side");
        assert!(out.matches.pairs.is_empty() && out.matches.scores.is_empty());
        assert_eq!(out.layers_run, 0);
    }
    // One keypoint against many still runs (and cannot panic on tiny shapes).
    let one = Features {
        keypoints: x.keypoints[..1].to_vec(),
        scores: x.scores[..1].to_vec(),
        descriptors: x.descriptors[..64].to_vec(),
        descriptor_dim: 64,
        image_size: (500, 500),
    };
    let out = lg.match_pair(&one, &x).expect("one keypoint");
    assert!(out.matches.pairs.len() <= 1);
    // A zero image size cannot normalise keypoints.
    let mut no_size = x.clone();
    no_size.image_size = (0, 0);
    assert!(matches!(
        lg.match_pair(&no_size, &x),
        Err(FeaturesError::InvalidInput(_))
    ));
}
