//! The memory a job may need and how the configuration fits it into `memory_bytes` (issue 9,
//! item 1: "a documented worst-case memory per job and per worker that the config's worker
//! count respects"; README "Service", memory per job and per worker).
//!
//! [`ServeConfig::fit_workers`] first makes one job fit: when the worst case of one job is over
//! the budget, the limits that make up the worst case (`max_body_bytes`,
//! `max_decoded_image_bytes`, `max_vertices`, `max_triangles`, `max_method_bytes`) are all
//! scaled by the same factor, budget / worst case, so the largest terms (triangles, the method's
//! working set, the body) lose the most, and no limit is singled out by a guess. Then `workers`
//! is lowered to the number of worst-case jobs the budget holds. [`MIN_JOB_BYTES`] is not from
//! a paper: below it the scaled limits (about 5,000 triangles, a 260 KB body) would refuse
//! every useful job, so the server refuses to start instead.

use super::{ConfigError, ServeConfig};

/// The smallest budget one job may be fitted into by lowering its limits: 256 MiB.
pub const MIN_JOB_BYTES: u64 = 256 << 20;

impl ServeConfig {
    /// The worst-case memory of one job under these settings, in bytes (README "Service",
    /// memory per job): the encoded inputs three times (the upload read from the blob store,
    /// the loaded assets' copies of their buffers and images, the output model), the decoded
    /// images (`max_decoded_image_bytes`), the instanced geometry of the surfaces and their
    /// BVHs (`max_vertices`, `max_triangles`) and the method's own working set
    /// (`max_method_bytes`, which bounds `output.texture_size` too).
    pub fn job_memory_bytes(&self) -> u64 {
        use crate::engine::asset::budget::{TRIANGLE_BYTES, VERTEX_BYTES};
        let l = &self.limits;
        [
            self.max_body_bytes.saturating_mul(3),
            l.max_decoded_image_bytes,
            l.max_vertices.saturating_mul(VERTEX_BYTES),
            l.max_triangles.saturating_mul(TRIANGLE_BYTES),
            l.max_method_bytes,
        ]
        .into_iter()
        .fold(0u64, u64::saturating_add)
    }

    /// Fits the jobs into `memory_bytes` (unset or 0: no cap, nothing changes): when one job's
    /// worst case is over it, scales the per-job limits down to fit one job; then lowers
    /// `workers` to the number of worst-case jobs it holds. Returns one line per change, for
    /// the start-up log.
    ///
    /// # Errors
    /// [`ConfigError::Invalid`] (`memory_bytes`) when it is under [`MIN_JOB_BYTES`] and one job
    /// does not fit.
    pub fn fit_workers(&mut self) -> Result<Vec<String>, ConfigError> {
        let budget = match self.memory_bytes {
            None | Some(0) => return Ok(Vec::new()),
            Some(b) => b,
        };
        let mut notes = Vec::new();
        let job = self.job_memory_bytes();
        if job > budget {
            if budget < MIN_JOB_BYTES {
                return Err(ConfigError::Invalid {
                    field: "memory_bytes",
                    message: format!(
                        "memory_bytes = {budget} does not hold one job's worst case of {job} bytes, and is under the {MIN_JOB_BYTES} bytes the per-job limits may be lowered to; give the server more memory or set memory_bytes (README \"Service\")"
                    ),
                });
            }
            notes.push(self.scale_limits(budget, job));
        }
        let job = self.job_memory_bytes();
        if job > budget {
            return Err(ConfigError::Invalid {
                field: "memory_bytes",
                message: format!(
                    "memory_bytes = {budget} does not hold one job's worst case of {job} bytes; lower max_body_bytes or the [limits] max_decoded_image_bytes, max_vertices, max_triangles, max_method_bytes (README \"Service\")"
                ),
            });
        }
        let fit = usize::try_from(budget / job.max(1)).unwrap_or(usize::MAX);
        if fit < self.workers {
            notes.push(format!(
                "workers lowered from {} to {fit}: memory_bytes = {budget} holds {fit} jobs of at most {job} bytes each",
                self.workers
            ));
            self.workers = fit;
        }
        Ok(notes)
    }

    /// Scales the limits behind [`ServeConfig::job_memory_bytes`] by `budget / job` (rounding
    /// down, so the new worst case is at most `budget`) and says what changed.
    fn scale_limits(&mut self, budget: u64, job: u64) -> String {
        let scale = |v: &mut u64| {
            let old = *v;
            *v = ((u128::from(old) * u128::from(budget)) / u128::from(job.max(1))) as u64;
            *v = (*v).max(1);
            (old, *v)
        };
        let l = &mut self.limits;
        let changes = [
            ("max_body_bytes", scale(&mut self.max_body_bytes)),
            (
                "max_decoded_image_bytes",
                scale(&mut l.max_decoded_image_bytes),
            ),
            ("max_vertices", scale(&mut l.max_vertices)),
            ("max_triangles", scale(&mut l.max_triangles)),
            ("max_method_bytes", scale(&mut l.max_method_bytes)),
        ];
        // A part or the whole input cannot be larger than the body that carries it.
        self.max_part_bytes = self.max_part_bytes.min(self.max_body_bytes);
        l.max_input_bytes = l.max_input_bytes.min(self.max_body_bytes);
        let list: Vec<String> = changes
            .iter()
            .map(|(name, (old, new))| format!("{name} {old} -> {new}"))
            .collect();
        format!(
            "memory_bytes = {budget} does not hold one job's worst case of {job} bytes: per-job limits scaled by {:.4} to fit: {} (max_part_bytes {}, max_input_bytes {}); worst case per job now {} bytes",
            budget as f64 / job as f64,
            list.join(", "),
            self.max_part_bytes,
            self.limits.max_input_bytes,
            self.job_memory_bytes()
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_worst_case_is_the_documented_one() {
        let c = ServeConfig::default();
        // 3 GiB + 0.5 GiB + 1.28 GB + 8 GB + 4 GiB (README "Service").
        let expected = 3 * (1u64 << 30) + (512 << 20) + 1_280_000_000 + 8_000_000_000 + (4 << 30);
        assert_eq!(c.job_memory_bytes(), expected);
    }

    #[test]
    fn workers_fit_the_memory_budget() {
        let mut c = ServeConfig {
            workers: 8,
            ..ServeConfig::default()
        };
        let job = c.job_memory_bytes();
        assert!(c.fit_workers().unwrap().is_empty(), "unset: no cap");
        c.memory_bytes = Some(0);
        assert!(c.fit_workers().unwrap().is_empty(), "0: no cap");
        assert_eq!(c.workers, 8);
        // Budgets for n jobs (and a little more) give n workers, limits untouched.
        for n in [1usize, 2, 3, 5] {
            let mut c = ServeConfig {
                workers: 8,
                memory_bytes: Some(n as u64 * job + job / 2),
                ..ServeConfig::default()
            };
            let notes = c.fit_workers().unwrap();
            assert_eq!(c.workers, n, "{notes:?}");
            assert_eq!(c.job_memory_bytes(), job, "limits kept");
            assert_eq!(notes.len(), 1, "{notes:?}");
        }
        // More budget than the workers need: nothing changes.
        let mut c = ServeConfig {
            workers: 2,
            memory_bytes: Some(10 * job),
            ..ServeConfig::default()
        };
        assert!(c.fit_workers().unwrap().is_empty());
        assert_eq!(c.workers, 2);
    }

    #[test]
    fn a_budget_below_one_job_lowers_the_limits_instead_of_refusing() {
        let default = ServeConfig::default();
        let job = default.job_memory_bytes();
        // This machine's 23.5 GiB after the reserve, a 8 GiB and a 2 GiB container, the floor.
        for budget in [job - 1, 8 << 30, 2 << 30, MIN_JOB_BYTES] {
            let mut c = ServeConfig {
                workers: 2,
                memory_bytes: Some(budget),
                ..ServeConfig::default()
            };
            let notes = c.fit_workers().unwrap();
            assert!(notes[0].contains("scaled"), "{notes:?}");
            assert!(notes[0].contains("max_triangles"), "{notes:?}");
            let now = c.job_memory_bytes();
            assert!(now <= budget, "{now} > {budget}");
            // Fitted tightly: the scaled limits use the budget (rounding loses a few bytes).
            assert!(now as f64 >= budget as f64 * 0.999, "{now} vs {budget}");
            assert_eq!(c.workers, 1, "{notes:?}");
            c.validate().unwrap();
            let ratio = c.limits.max_triangles as f64 / default.limits.max_triangles as f64;
            let body = c.max_body_bytes as f64 / default.max_body_bytes as f64;
            assert!((ratio - body).abs() < 1e-6, "one factor for every limit");
            assert!(c.max_part_bytes <= c.max_body_bytes);
            assert!(c.limits.max_input_bytes <= c.max_body_bytes);
        }
        let mut c = ServeConfig {
            memory_bytes: Some(MIN_JOB_BYTES - 1),
            ..ServeConfig::default()
        };
        let e = c.fit_workers().unwrap_err();
        assert!(e.to_string().contains("memory_bytes"), "{e}");
        // Limits already small enough are never raised or touched.
        let mut c = ServeConfig {
            workers: 2,
            memory_bytes: Some(MIN_JOB_BYTES - 1),
            max_body_bytes: 1 << 20,
            ..ServeConfig::default()
        };
        c.limits.max_vertices = 10_000;
        c.limits.max_triangles = 10_000;
        c.limits.max_decoded_image_bytes = 16 << 20;
        c.limits.max_method_bytes = 64 << 20;
        let before = c.job_memory_bytes();
        assert!(c.fit_workers().unwrap().is_empty());
        assert_eq!(c.job_memory_bytes(), before);
    }
}
