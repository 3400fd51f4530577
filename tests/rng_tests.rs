//! The runtime RNG and point sampler against tests/fixtures/rng/sequences.json, the
//! sequences of the Python port (tools/tricons_pose/tricons_rng.py) that lets the PyTorch
//! evaluation draw exactly the points `tricons replay` draws.

use serde_json::Value;
use tricons::pose::preprocess::sample_indices;
use tricons::rng::{Rng, mix_seed};

fn fixture() -> Value {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/rng/sequences.json");
    serde_json::from_str(&std::fs::read_to_string(path).expect("read rng fixture")).expect("parse rng fixture")
}

fn u64_of(v: &Value) -> u64 {
    v.as_str().expect("u64 as a decimal string").parse().expect("u64")
}

fn usizes(v: &Value) -> Vec<usize> {
    v.as_array().expect("array").iter().map(|x| x.as_u64().expect("index") as usize).collect()
}

#[test]
fn mix_seed_matches_the_python_port() {
    let f = fixture();
    for case in f["mix_seed"].as_array().unwrap() {
        let words: Vec<u64> = case["words"].as_array().unwrap().iter().map(u64_of).collect();
        assert_eq!(mix_seed(&words), u64_of(&case["seed"]), "mix_seed({words:?})");
    }
}

#[test]
fn next_u64_and_below_match_the_python_port() {
    let f = fixture();
    for case in f["next_u64"].as_array().unwrap() {
        let mut rng = Rng::new(u64_of(&case["seed"]));
        let got: Vec<u64> = case["values"].as_array().unwrap().iter().map(|_| rng.next_u64()).collect();
        let want: Vec<u64> = case["values"].as_array().unwrap().iter().map(u64_of).collect();
        assert_eq!(got, want, "seed {}", case["seed"]);
    }
    for case in f["below"].as_array().unwrap() {
        let mut rng = Rng::new(u64_of(&case["seed"]));
        let n = case["n"].as_u64().unwrap() as usize;
        let want = usizes(&case["values"]);
        let got: Vec<usize> = want.iter().map(|_| rng.below(n)).collect();
        assert_eq!(got, want, "below({n}) seed {}", case["seed"]);
    }
}

#[test]
fn sample_indices_match_the_python_port() {
    let f = fixture();
    for case in f["sample_indices"].as_array().unwrap() {
        let (n_valid, n) = (case["n_valid"].as_u64().unwrap() as usize, case["n"].as_u64().unwrap() as usize);
        let got = sample_indices(n_valid, n, &mut Rng::new(u64_of(&case["seed"])));
        assert_eq!(got, usizes(&case["indices"]), "n_valid {n_valid}, n {n}");
        if n_valid >= n {
            let mut distinct = got.clone();
            distinct.sort_unstable();
            distinct.dedup();
            assert_eq!(distinct.len(), n, "without replacement when there are enough points");
        }
        assert!(got.iter().all(|&i| i < n_valid));
    }
    // The per-instance stream of `tricons replay --seed s`: frame f, instance i.
    for case in f["instance_rng"].as_array().unwrap() {
        let (s, fr, i) =
            (case["seed"].as_u64().unwrap(), case["frame"].as_u64().unwrap(), case["instance"].as_u64().unwrap());
        let mut rng = Rng::from_words(&[mix_seed(&[s, fr]), i]);
        assert_eq!(sample_indices(50, 8, &mut rng), usizes(&case["indices"]), "seed {s} frame {fr} instance {i}");
    }
}
