//! Random restarts of the coarsest level (ours; Chen et al. 2012 §4 start the coarsest level
//! from one random field): the part of [`CoarseToFine`]'s level loop that starts a level's
//! field and runs its EM iterations.
//!
//! **Why.** Every finer level inherits the coarsest level's map through upsampling, and the EM
//! iterations only improve it locally. One unlucky random start can settle the whole synthesis
//! in a poor basin: on Blub → remeshed fish without correspondences (16K, seed 4) the fish's
//! face matched Blub's back below the dorsal fin and came out orange; its coarsest level ended
//! at energy 54.4 against 38.8-40.7 for seeds 1, 2, 3 and 5, and every finer level stayed
//! higher too (finest 6.4 against 0.9; README "meshmatch", coarsest restarts).
//!
//! **What.** In a plain transfer (no by-example or update mask) the coarsest level's EM runs
//! from `coarsest_restarts` random fields, the first of them the single start it always had,
//! and the field with the lowest final energy (mean patch dissimilarity after the last E-step)
//! is kept. The coarsest level has a few hundred vertices, so each start costs little. The
//! energy compares like with like here: one level, the same fans, features and iterations.
//!
//! **Default 1 (off).** Swept on the real pairs without correspondences (16K, seeds 1-5) and
//! the three stripe files (64K, seeds 1-10): with 4 starts the real pairs meet issue 14's
//! statistics on 15 runs of 15 (14 with one start), but the stripes lose (28 of 30 in bounds
//! against 29, and the bar's seed 7 swirls, rings 0.90): on a symmetric source many starts are
//! equally good by the energy, and the one it picks can hold a mirror seam. 2 starts do not
//! fix Blub's seed 4 and break Spot → cat's seed 1; 8 are no better than 4; choosing by the
//! shape features' distance alone swirls the bar's seed 4. So it is an option for organic pairs
//! without correspondences (README "Coarsest restarts").
//!
//! **Restarts on a deviation (`coarsest_restart_deviation`, default ln 2.5).** A poor basin
//! shows in the first start's statistics: the finest-colour histogram its matches imply
//! ([`super::super::fine_histogram`]) has a bin far off the source's share. Measured at the end
//! of the first start (16K real pairs, seeds 1-30, without correspondences; stripe files 64K,
//! seeds 1-10), the largest |log ratio| is 0.98-1.06 on all six runs that ended in Blub's
//! orange face, at most 0.79 on the stripe files, at most 0.30 on Fox → koala and 0.49-1.18
//! on Spot → cat. Beyond the limit the level runs [`DEVIATION_RESTARTS`] starts (or
//! `coarsest_restarts`, if more) and keeps the lowest energy, as above; below it, the single
//! start stands, so the symmetric stripe files, whose first starts stay under it, keep their
//! field.

use super::super::em::IterationReport;
use super::super::matcher::Nnf;
use super::super::vote::{vote, SourcePatches};
use super::super::{MeshMatchError, DEVIATION_RESTARTS};
use super::{CoarseToFine, Level};

/// A level's field after its EM iterations.
pub(super) struct Start {
    pub nnf: Nnf,
    pub colors: Vec<[f32; 3]>,
    pub iterations: Vec<IterationReport>,
    pub converged: bool,
    /// Final energy of every start when there were several (see the module docs).
    pub restart_energies: Vec<f64>,
    /// The first start's finest-colour deviation, when it was measured (module docs).
    pub first_start_deviation: Option<f32>,
}

impl Start {
    /// The final EM energy (infinite when no iteration ran).
    fn energy(&self) -> f64 {
        self.iterations.last().map_or(f64::INFINITY, |i| i.energy)
    }
}

impl CoarseToFine<'_> {
    /// The level's field: initialized (at random on the coarsest level, upsampled from
    /// `coarser` on the others), voted and iterated; on the coarsest level of a plain transfer
    /// the best of `coarsest_restarts` starts (module docs).
    pub(super) fn start(
        &self,
        lv: &Level<'_>,
        coarser: &Nnf,
        patches: &SourcePatches<'_>,
        sigma: f32,
    ) -> Result<Start, MeshMatchError> {
        let plain_coarsest =
            lv.index + 1 == self.levels && lv.fixed.is_none() && lv.allowed.is_none();
        if !plain_coarsest {
            return self.run_from(lv, coarser, patches, sigma, 0);
        }
        let mut best = self.run_from(lv, coarser, patches, sigma, 0)?;
        let mut restarts = self.params.coarsest_restarts.max(1);
        let limit = self.params.coarsest_restart_deviation;
        let first_start_deviation = match self.normalization.fine_histograms.as_ref() {
            Some(fine) if limit > 0.0 => Some(fine.deviation(lv.index, &best.nnf.source)),
            _ => None,
        };
        if first_start_deviation.is_some_and(|d| d > limit) {
            restarts = restarts.max(DEVIATION_RESTARTS);
        }
        if restarts > 1 {
            let mut energies = vec![best.energy()];
            for restart in 1..restarts {
                self.control.check()?;
                let run = self.run_from(lv, coarser, patches, sigma, restart as u64)?;
                energies.push(run.energy());
                if run.energy() < best.energy() {
                    best = run;
                }
            }
            best.restart_energies = energies;
        }
        best.first_start_deviation = first_start_deviation;
        Ok(best)
    }

    /// One start: the initial field (`restart` picks the random one on the coarsest level), the
    /// fixed matches of the update mode, the first vote and the EM iterations.
    fn run_from(
        &self,
        lv: &Level<'_>,
        coarser: &Nnf,
        patches: &SourcePatches<'_>,
        sigma: f32,
        restart: u64,
    ) -> Result<Start, MeshMatchError> {
        let mut nnf = self.initial_field(lv, coarser, restart)?;
        if let Some(f) = lv.fixed.filter(|_| lv.fixed_matches) {
            for (t, &is_fixed) in f.iter().enumerate() {
                if is_fixed {
                    nnf.source[t] = t as u32;
                    nnf.rotation[t] = 0;
                }
            }
        }
        let mut colors = vote(&lv.stencil, &nnf, patches, sigma, lv.keep(), None);
        let (iterations, converged) = self.iterate(lv, patches, sigma, &mut nnf, &mut colors)?;
        Ok(Start {
            nnf,
            colors,
            iterations,
            converged,
            restart_energies: Vec::new(),
            first_start_deviation: None,
        })
    }
}
