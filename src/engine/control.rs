//! Control of a running engine call: a cancel flag, named stages and a progress fraction.
//!
//! A [`Control`] is cheap to clone (shared state behind an `Arc`); the service keeps one clone to
//! poll progress and request cancellation while the engine runs on a worker thread. Long loops
//! call [`StageProgress::tick`] (or [`Control::check`]) at least every ~100 ms of work; both
//! return [`Cancelled`] once cancellation was requested.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

/// Returned by checks once cancellation has been requested.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
#[error("cancelled")]
pub struct Cancelled;

/// A snapshot of progress.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Progress {
    /// Name of the current stage (`""` before the first).
    pub stage: String,
    /// Fraction of the current stage done, 0..=1.
    pub stage_fraction: f64,
    /// Overall fraction done, 0..=1: finished stages plus the current stage's fraction, over
    /// the planned stage count.
    pub fraction: f64,
    /// Stages finished so far.
    pub stages_done: u32,
    /// Stages planned (grows if more stages start than planned).
    pub stages_total: u32,
}

#[derive(Debug, Default)]
struct StageState {
    name: String,
    /// Prepended to stage names (`"<prefix>: <name>"`) while set.
    prefix: String,
    started: u32,
    planned: u32,
    finished: bool,
}

#[derive(Debug, Default)]
struct Inner {
    cancel: AtomicBool,
    stage: Mutex<StageState>,
    /// Work units done in the current stage.
    done: AtomicU64,
    /// Work units of the current stage.
    total: AtomicU64,
}

/// Cancel flag plus progress, shared between the engine and whoever watches it.
#[derive(Clone, Debug, Default)]
pub struct Control {
    inner: Arc<Inner>,
}

impl Control {
    /// A fresh control: not cancelled, no stage.
    pub fn new() -> Self {
        Self::default()
    }

    /// Declares how many stages the run will have (for the overall fraction).
    pub fn plan(&self, stages: u32) {
        self.lock().planned = stages;
    }

    /// Sets a context shown before every following stage name (`""` clears it), e.g. the level
    /// and iteration of a multi-level method whose helpers name their own stages.
    pub fn set_prefix(&self, prefix: &str) {
        self.lock().prefix = prefix.to_string();
    }

    /// Stages started so far.
    pub fn stages_started(&self) -> u32 {
        self.lock().started
    }

    /// Raises the planned stage count to at least `started + more` (a method that learns its
    /// size while running, e.g. the number of hierarchy levels).
    pub fn plan_more(&self, more: u32) {
        let mut s = self.lock();
        let want = s.started + more;
        if s.planned < want {
            s.planned = want;
        }
    }

    /// Requests cancellation; running loops stop at their next check.
    pub fn cancel(&self) {
        self.inner.cancel.store(true, Ordering::SeqCst);
    }

    /// Whether cancellation was requested.
    pub fn is_cancelled(&self) -> bool {
        self.inner.cancel.load(Ordering::Relaxed)
    }

    /// Returns `Err(Cancelled)` once cancellation was requested.
    pub fn check(&self) -> Result<(), Cancelled> {
        if self.is_cancelled() {
            Err(Cancelled)
        } else {
            Ok(())
        }
    }

    /// Starts stage `name` with `total_work` units (0 for an indivisible stage); the previous
    /// stage counts as done. Fails if cancelled.
    pub fn stage(&self, name: &str, total_work: u64) -> Result<StageProgress<'_>, Cancelled> {
        self.check()?;
        {
            let mut s = self.lock();
            s.name = if s.prefix.is_empty() {
                name.to_string()
            } else {
                format!("{}: {name}", s.prefix)
            };
            s.started += 1;
            if s.planned < s.started {
                s.planned = s.started;
            }
        }
        self.inner.total.store(total_work, Ordering::Relaxed);
        self.inner.done.store(0, Ordering::Relaxed);
        Ok(StageProgress { control: self })
    }

    /// The current progress.
    pub fn progress(&self) -> Progress {
        let s = self.lock();
        let total = self.inner.total.load(Ordering::Relaxed);
        let done = self.inner.done.load(Ordering::Relaxed);
        let stage_fraction = if total == 0 {
            0.0
        } else {
            (done as f64 / total as f64).min(1.0)
        };
        let stages_done = if s.finished {
            s.started
        } else {
            s.started.saturating_sub(1)
        };
        let planned = s.planned.max(1);
        let fraction = if s.finished {
            1.0
        } else if s.started == 0 {
            0.0
        } else {
            ((stages_done as f64 + stage_fraction) / planned as f64).min(1.0)
        };
        Progress {
            stage: s.name.clone(),
            stage_fraction,
            fraction,
            stages_done,
            stages_total: s.planned,
        }
    }

    /// Marks every stage finished (fraction 1).
    pub fn finish(&self) {
        let mut s = self.lock();
        s.finished = true;
        s.planned = s.started;
        s.name = "done".to_string();
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, StageState> {
        // A panic while holding this lock cannot leave the state inconsistent (plain fields).
        self.inner.stage.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// Progress handle of the current stage.
#[derive(Debug)]
pub struct StageProgress<'a> {
    control: &'a Control,
}

impl StageProgress<'_> {
    /// Adds `work` finished units (thread-safe) and checks for cancellation.
    pub fn tick(&self, work: u64) -> Result<(), Cancelled> {
        self.control.inner.done.fetch_add(work, Ordering::Relaxed);
        self.control.check()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fraction_counts_finished_stages_and_the_current_one() {
        let c = Control::new();
        c.plan(4);
        let s = c.stage("load", 10).unwrap();
        s.tick(5).unwrap();
        let p = c.progress();
        assert_eq!(p.stage, "load");
        assert!((p.fraction - 0.125).abs() < 1e-9, "{p:?}");
        c.stage("bake", 0).unwrap();
        let p = c.progress();
        assert_eq!(p.stages_done, 1);
        assert!((p.fraction - 0.25).abs() < 1e-9);
        c.finish();
        assert!(
            (c.progress().fraction - 1.0).abs() < 1e-9,
            "{:?}",
            c.progress()
        );
    }

    #[test]
    fn cancellation_stops_ticks_and_new_stages() {
        let c = Control::new();
        let other = c.clone();
        let s = c.stage("work", 100).unwrap();
        assert!(s.tick(1).is_ok());
        other.cancel();
        assert_eq!(s.tick(1), Err(Cancelled));
        assert!(c.stage("next", 1).is_err());
    }
}
