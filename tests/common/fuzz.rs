//! The stable fuzz harness (issue 9, "Continuous checks: fuzzing"): a deterministic byte
//! mutator and a driver that runs a target over mutated seeds, on stable Rust, inside
//! `cargo test`.
//!
//! cargo-fuzz (libFuzzer) needs a nightly toolchain and a second, instrumented build of every
//! dependency (about as long as the whole CI run on this machine), so the project uses this
//! harness instead: no coverage feedback, but mutations chosen for the formats it feeds (GLB
//! chunk headers and lengths are little-endian u32 fields, glTF and constraints are JSON, PNG and
//! JPEG carry sizes in their headers): bit flips, "interesting" integers written over aligned
//! words and over numbers in text, range deletion, duplication and splicing between seeds, and
//! format tokens from a dictionary. Every run is reproducible from its seed.
//!
//! A finding (a panic, an error the target calls internal, or an input that takes longer than
//! the target's liveness bound) is written to `target/fuzz-findings/<target>-<n>.bin` and the
//! test fails listing them. A fixed finding is committed under `tests/data/fuzz/<target>/` and
//! replayed by every default run (see `replay_regressions`).

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use super::mutate::{Format, Mutator};

/// How a target judged one input.
pub enum Verdict {
    /// Accepted (and everything after acceptance went through).
    Accepted,
    /// Refused with a clear error.
    Refused,
    /// A finding: what went wrong.
    Finding(String),
}

/// One fuzz target's run.
pub struct Campaign<'a> {
    /// Target name (findings are `<name>-<n>.bin`).
    pub name: &'a str,
    /// Inputs to mutate (each is also run unmutated first).
    pub seeds: Vec<Vec<u8>>,
    /// How inputs are mutated.
    pub format: Format,
    /// Tokens the mutator inserts.
    pub dictionary: &'a [&'a str],
    /// Mutated inputs to run.
    pub iterations: usize,
    /// Mutator seed.
    pub seed: u64,
    /// An input slower than this is a finding (a hang, not a speed figure).
    pub liveness: Duration,
    /// Least fraction of mutated inputs that must be accepted: a campaign whose mutants all
    /// fail the first check exercises nothing past it.
    pub min_accepted: f64,
}

/// Where findings are written.
pub fn findings_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/fuzz-findings")
}

/// Iterations from `RETEX_FUZZ_ITERATIONS` (a longer local run), else `default`.
pub fn iterations(default: usize) -> usize {
    std::env::var("RETEX_FUZZ_ITERATIONS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// Runs `target` over the seeds and `iterations` mutations of them; panics listing the findings.
pub fn run(campaign: Campaign<'_>, target: impl Fn(&[u8]) -> Verdict) {
    assert!(
        !campaign.seeds.is_empty(),
        "{}: no seed inputs (the corpus is missing)",
        campaign.name
    );
    let mut mutator = Mutator::new(campaign.seed, campaign.dictionary);
    let mut findings = Vec::new();
    let mut accepted = 0usize;
    let total = campaign.seeds.len() + campaign.iterations;
    for i in 0..total {
        let input = if i < campaign.seeds.len() {
            campaign.seeds[i].clone()
        } else {
            let a = mutator.below(campaign.seeds.len());
            let b = mutator.below(campaign.seeds.len());
            mutator.mutate_as(campaign.format, &campaign.seeds[a], &campaign.seeds[b])
        };
        let start = Instant::now();
        let verdict = catch_unwind(AssertUnwindSafe(|| target(&input)))
            .unwrap_or_else(|p| Verdict::Finding(format!("panic: {}", panic_text(&p))));
        let elapsed = start.elapsed();
        let problem = match verdict {
            Verdict::Finding(why) => Some(why),
            _ if elapsed > campaign.liveness => Some(format!(
                "took {elapsed:?} (liveness bound {:?})",
                campaign.liveness
            )),
            Verdict::Accepted => {
                accepted += (i >= campaign.seeds.len()) as usize;
                None
            }
            Verdict::Refused => None,
        };
        if let Some(why) = problem {
            let dir = findings_dir();
            std::fs::create_dir_all(&dir).unwrap();
            let path = dir.join(format!("{}-{}.bin", campaign.name, findings.len()));
            std::fs::write(&path, &input).unwrap();
            findings.push(format!("{}: {why}", path.display()));
            if findings.len() >= 20 {
                break;
            }
        }
    }
    let fraction = accepted as f64 / campaign.iterations.max(1) as f64;
    eprintln!(
        "fuzz {}: {total} inputs, {:.1}% of the mutants accepted, {} finding(s)",
        campaign.name,
        100.0 * fraction,
        findings.len()
    );
    assert!(
        findings.is_empty(),
        "{}: {} finding(s) in {total} inputs:\n{}",
        campaign.name,
        findings.len(),
        findings.join("\n")
    );
    assert!(
        fraction >= campaign.min_accepted,
        "{}: only {:.1}% of the mutants were accepted (at least {:.1}% expected): the mutations \
         do not get past the first checks",
        campaign.name,
        100.0 * fraction,
        100.0 * campaign.min_accepted
    );
}

/// The committed regression inputs of `target` (`tests/data/fuzz/<target>/`), sorted.
pub fn regressions(target: &str) -> Vec<(String, Vec<u8>)> {
    let dir = super::test_data_dir().join("fuzz").join(target);
    let mut out: Vec<(String, Vec<u8>)> = match std::fs::read_dir(&dir) {
        Ok(entries) => entries
            .filter_map(|e| e.ok())
            .filter(|e| e.path().is_file())
            .map(|e| {
                let name = e.file_name().to_string_lossy().into_owned();
                (name, std::fs::read(e.path()).unwrap())
            })
            .collect(),
        Err(_) => Vec::new(),
    };
    out.sort();
    out
}

fn panic_text(p: &Box<dyn std::any::Any + Send>) -> String {
    p.downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "non-string panic".into())
}
