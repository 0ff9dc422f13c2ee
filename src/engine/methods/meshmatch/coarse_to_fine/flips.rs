//! Region flips of a coarse level's field (Chen et al. 2012 §4.2 has none; ours, module
//! [`super::super::region_flip`]): the part of [`CoarseToFine`]'s level loop that re-grows
//! coherent regions and keeps them when the level's EM energy drops.

use super::super::histogram::HistogramBias;
use super::super::matcher::Nnf;
use super::super::region_flip::{
    coherent_regions, largest_neighbour, regrow, FlipGeometry, MIN_REGION,
};
use super::super::vote::{vote, SourcePatches};
use super::super::MeshMatchError;
use super::{CoarseToFine, Level};
use crate::engine::rng::mix;

impl CoarseToFine<'_> {
    /// Region flips (module [`super::super::region_flip`]) on a level of at most
    /// `region_flip_vertices` target vertices, outside the by-example and update modes: every
    /// coherent region of [`MIN_REGION`] vertices up to half the level, smallest first, is
    /// re-grown from its largest neighbour, the level's EM iterations run from there, and the
    /// result is kept when its energy (after one more vote) is below the current field's.
    /// Returns how many were kept.
    pub(super) fn flip_regions(
        &self,
        lv: &Level<'_>,
        patches: &SourcePatches<'_>,
        sigma: f32,
        nnf: &mut Nnf,
        colors: &mut Vec<[f32; 3]>,
    ) -> Result<usize, MeshMatchError> {
        if lv.nt > self.params.region_flip_vertices || lv.fixed.is_some() || lv.allowed.is_some() {
            return Ok(0);
        }
        let level = lv.index;
        let geometry = FlipGeometry {
            target_positions: &self.tgt.surface(level).positions,
            source_positions: &self.src.surface(level).positions,
            target_adjacency: self.tgt.rings(level),
            source_faces: &self.src.surface(level).faces,
            source_bvh: &self.src.bvh[level],
            source_edge: self.src.mean_edge[level],
        };
        let (mut labels, sizes) = coherent_regions(&geometry, nnf);
        let mut order: Vec<u32> = (0..sizes.len() as u32)
            .filter(|&r| 2 * sizes[r as usize] < lv.nt && sizes[r as usize] >= MIN_REGION)
            .collect();
        order.sort_by_key(|&r| (sizes[r as usize], r));
        let mut current = self.field_energy(lv, patches, sigma, nnf, colors)?;
        let mut flips = 0;
        for region in order {
            self.control.check()?;
            let Some(from) = largest_neighbour(&geometry, &labels, region) else {
                continue;
            };
            let mut candidate = regrow(&geometry, nnf, &labels, region, from);
            let mut settled = self.vote_from(lv, patches, sigma, &candidate, colors);
            self.iterate(lv, patches, sigma, &mut candidate, &mut settled)?;
            let tried = self.field_energy(lv, patches, sigma, &candidate, &settled)?;
            if tried.energy < current.energy {
                *nnf = candidate;
                current = tried;
                flips += 1;
                for l in labels.iter_mut().filter(|l| **l == region) {
                    *l = from;
                }
            }
        }
        if flips > 0 {
            *colors = current.colors;
            nnf.distance = current.distance;
        }
        Ok(flips)
    }

    /// The EM energy of `nnf` (mean dissimilarity, without the finest-colour histogram cost)
    /// after one vote from it, with the voted colours and the refreshed dissimilarities;
    /// `colors` are the current colours (the histogram bias of the vote).
    fn field_energy(
        &self,
        lv: &Level<'_>,
        patches: &SourcePatches<'_>,
        sigma: f32,
        nnf: &Nnf,
        colors: &[[f32; 3]],
    ) -> Result<FieldEnergy, MeshMatchError> {
        let voted = self.vote_from(lv, patches, sigma, nnf, colors);
        // Judged without the finest-colour histogram cost (module `fine_histogram`): a flip is
        // kept for a better map, not for a better histogram (README "Finest-colour histogram cost").
        let inputs = self.step_inputs(lv, nnf, &voted, false)?;
        let step = self.e_step(lv, &inputs, mix(self.seed, 0xf11b, lv.index as u64));
        let mut refreshed = nnf.clone();
        step.refresh(&mut refreshed);
        Ok(FieldEnergy {
            energy: refreshed.energy(),
            colors: voted,
            distance: refreshed.distance,
        })
    }

    /// The colours voted from `nnf`, with the histogram bias of the current `colors`.
    fn vote_from(
        &self,
        lv: &Level<'_>,
        patches: &SourcePatches<'_>,
        sigma: f32,
        nnf: &Nnf,
        colors: &[[f32; 3]],
    ) -> Vec<[f32; 3]> {
        let bias = HistogramBias::new(&lv.centers, colors, self.schedule.histogram_weight);
        vote(&lv.stencil, nnf, patches, sigma, lv.keep(), bias.as_ref())
    }
}

/// A field's energy after one vote from it (see [`CoarseToFine::field_energy`]).
struct FieldEnergy {
    /// Mean dissimilarity.
    energy: f64,
    /// The voted colours.
    colors: Vec<[f32; 3]>,
    /// The refreshed dissimilarity of every match.
    distance: Vec<f32>,
}
