//! Control of a running engine call: a cancel flag, named stages with their timings and a
//! progress fraction.
//!
//! A [`Control`] is cheap to clone (shared state behind an `Arc`); the service keeps one clone to
//! poll progress and request cancellation while the engine runs on a worker thread. Long loops
//! call [`StageProgress::tick`] (or [`Control::check`]) at least every ~100 ms of work; both
//! return [`Cancelled`] once cancellation was requested.
//!
//! **Timings.** Every [`Control::stage`] closes the previous stage and opens a new one;
//! [`Control::timings`] lists each stage's wall-clock time, which is what reports show (no
//! method keeps its own stopwatch).
//!
//! **Progress.** There is no stage count to plan: the overall fraction is divided into nested
//! [`Control::span`]s (the pipeline gives the method its share of the job, a method gives each
//! phase, e.g. each hierarchy level, its share of that), and inside the innermost span the
//! current stage's ticks move the fraction from the span's start to its end. The published
//! fraction never goes backwards and reaches 1 only at [`Control::finish`].

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

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
    /// Overall fraction done, 0..=1 (monotone; 1 only once finished).
    pub fraction: f64,
    /// Stages finished so far.
    pub stages_done: u32,
    /// Stages started so far (the run does not know its stage count in advance; `fraction` is
    /// the measure of the whole).
    pub stages_total: u32,
}

/// Wall-clock time of one stage.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct StageTiming {
    /// Stage name (with its prefix, e.g. `meshmatch level 2/9: vote`).
    pub stage: String,
    /// Milliseconds from the stage's start to the next stage's start (or the finish).
    pub ms: f64,
}

#[derive(Debug, Default)]
struct StageState {
    name: String,
    /// Prepended to stage names (`"<prefix>: <name>"`) while set.
    prefix: String,
    started: u32,
    finished: bool,
    /// Absolute [start, end] fractions of the open spans, innermost last.
    spans: Vec<(f64, f64)>,
    /// Lowest fraction that may still be published (keeps it monotone).
    floor: f64,
    /// Start of the current stage.
    stage_start: Option<Instant>,
    /// The absolute span the current stage started in: its ticks move the fraction there, even
    /// after a new span opens before the next stage (a poll between a span's opening and its
    /// first stage would otherwise map the finished stage onto the new span's end).
    stage_span: (f64, f64),
    /// Finished stages.
    timings: Vec<StageTiming>,
}

impl StageState {
    fn span(&self) -> (f64, f64) {
        self.spans.last().copied().unwrap_or((0.0, 1.0))
    }

    fn close_stage(&mut self, now: Instant) {
        if let Some(start) = self.stage_start.take() {
            self.timings.push(StageTiming {
                stage: self.name.clone(),
                ms: (now - start).as_secs_f64() * 1e3,
            });
        }
    }
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

    /// Gives the stages that follow, until the guard drops, the share `[start, end]` (fractions
    /// of the enclosing span) of the overall progress. Spans nest.
    pub fn span(&self, start: f64, end: f64) -> Span<'_> {
        let mut s = self.lock();
        let (lo, hi) = s.span();
        let (start, end) = (start.clamp(0.0, 1.0), end.clamp(0.0, 1.0));
        let abs = (lo + (hi - lo) * start, lo + (hi - lo) * end.max(start));
        s.floor = s.floor.max(abs.0);
        s.spans.push(abs);
        Span { control: self }
    }

    /// Wall-clock time of every stage so far (the current one up to now).
    pub fn timings(&self) -> Vec<StageTiming> {
        let s = self.lock();
        let mut out = s.timings.clone();
        if let Some(start) = s.stage_start {
            out.push(StageTiming {
                stage: s.name.clone(),
                ms: start.elapsed().as_secs_f64() * 1e3,
            });
        }
        out
    }

    /// Sets a context shown before every following stage name (`""` clears it), e.g. the level
    /// and iteration of a multi-level method whose helpers name their own stages.
    pub fn set_prefix(&self, prefix: &str) {
        self.lock().prefix = prefix.to_string();
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
            let now = Instant::now();
            s.close_stage(now);
            // The previous stage's progress stays published.
            let before = self.fraction_in(&s);
            s.floor = s.floor.max(before);
            s.name = if s.prefix.is_empty() {
                name.to_string()
            } else {
                format!("{}: {name}", s.prefix)
            };
            s.started += 1;
            s.stage_start = Some(now);
            s.stage_span = s.span();
            self.inner.total.store(total_work, Ordering::Relaxed);
            self.inner.done.store(0, Ordering::Relaxed);
        }
        Ok(StageProgress { control: self })
    }

    fn stage_fraction(&self) -> f64 {
        let total = self.inner.total.load(Ordering::Relaxed);
        let done = self.inner.done.load(Ordering::Relaxed);
        if total == 0 {
            0.0
        } else {
            (done as f64 / total as f64).min(1.0)
        }
    }

    /// The fraction the current stage's ticks give inside the span it started in.
    fn fraction_in(&self, s: &StageState) -> f64 {
        if s.started == 0 {
            return 0.0;
        }
        let (lo, hi) = s.stage_span;
        lo + (hi - lo) * self.stage_fraction()
    }

    /// The current progress (the fraction never decreases from one call to the next).
    pub fn progress(&self) -> Progress {
        let mut s = self.lock();
        let stages_done = if s.finished {
            s.started
        } else {
            s.started.saturating_sub(1)
        };
        let fraction = if s.finished {
            1.0
        } else {
            // Below 1 until `finish`: the last stage may still be writing.
            let f = self.fraction_in(&s).max(s.floor).min(0.999);
            s.floor = f;
            f
        };
        Progress {
            stage: s.name.clone(),
            stage_fraction: self.stage_fraction(),
            fraction,
            stages_done,
            stages_total: s.started,
        }
    }

    /// Marks every stage finished (fraction 1) and closes the last stage's timing.
    pub fn finish(&self) {
        let mut s = self.lock();
        s.close_stage(Instant::now());
        s.finished = true;
        s.name = "done".to_string();
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, StageState> {
        // A panic while holding this lock cannot leave the state inconsistent (plain fields).
        self.inner.stage.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// An open progress span (see [`Control::span`]); closing it publishes at least its end.
#[derive(Debug)]
pub struct Span<'a> {
    control: &'a Control,
}

impl Drop for Span<'_> {
    fn drop(&mut self) {
        let mut s = self.control.lock();
        if let Some((_, end)) = s.spans.pop() {
            s.floor = s.floor.max(end);
        }
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
    fn fraction_follows_spans_and_the_current_stage() {
        let c = Control::new();
        {
            let _load = c.span(0.0, 0.25);
            let s = c.stage("load", 10).unwrap();
            s.tick(5).unwrap();
            let p = c.progress();
            assert_eq!(p.stage, "load");
            assert!((p.fraction - 0.125).abs() < 1e-9, "{p:?}");
        }
        {
            let _method = c.span(0.25, 1.0);
            let _half = c.span(0.0, 0.5);
            let s = c.stage("bake", 4).unwrap();
            s.tick(2).unwrap();
            let p = c.progress();
            assert_eq!(p.stages_done, 1);
            // 0.25 + 0.75 * (0.5 * 0.5)
            assert!((p.fraction - 0.4375).abs() < 1e-9, "{p:?}");
        }
        assert!(c.progress().fraction >= 1.0 - 1e-3 - 1e-9);
        assert!(c.progress().fraction < 1.0, "1 only at finish");
        c.finish();
        assert!(
            (c.progress().fraction - 1.0).abs() < 1e-9,
            "{:?}",
            c.progress()
        );
    }

    #[test]
    fn fraction_never_goes_backwards_and_stages_are_timed() {
        let c = Control::new();
        let _all = c.span(0.0, 1.0);
        let s = c.stage("a", 10).unwrap();
        s.tick(9).unwrap();
        let high = c.progress().fraction;
        // A new stage in the same span starts its ticks from zero: the fraction holds.
        c.stage("b", 10).unwrap();
        assert!(c.progress().fraction >= high);
        c.set_prefix("level 1/2");
        c.stage("c", 0).unwrap();
        c.finish();
        let names: Vec<String> = c.timings().into_iter().map(|t| t.stage).collect();
        assert_eq!(names, ["a", "b", "level 1/2: c"]);
        assert!(c.timings().iter().all(|t| t.ms >= 0.0));
    }

    #[test]
    fn a_finished_stage_does_not_jump_into_a_span_opened_after_it() {
        let c = Control::new();
        let load = c.span(0.0, 0.05);
        c.stage("load", 4).unwrap().tick(4).unwrap();
        drop(load);
        let _method = c.span(0.05, 0.95);
        // No stage of the method yet: the finished load is still 5 %, not 95 %.
        let f = c.progress().fraction;
        assert!((f - 0.05).abs() < 1e-9, "{f}");
        c.stage("first", 2).unwrap().tick(1).unwrap();
        assert!((c.progress().fraction - 0.5).abs() < 1e-9);
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
