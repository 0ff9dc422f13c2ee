//! The report of the `pattern` method (issue 12): clusters per level (textured / split), FFT
//! fits performed, the flatness and fitting errors of the accepted patches, the relaxation's
//! seam errors, and what was written. Timings per stage come from the job's `Control`.

use serde::Serialize;

/// One level of the driver.
#[derive(Clone, Debug, Default, Serialize)]
pub struct LevelStats {
    /// Depth (0 = the components).
    pub level: usize,
    /// Clusters considered (not already inside a patch).
    pub clusters: usize,
    /// Accepted as patches.
    pub textured: usize,
    /// Split into their children.
    pub split: usize,
    /// Split because they are not discs.
    pub not_disc: usize,
    /// Split because they are not flat enough.
    pub not_flat: usize,
    /// Split because their best fit was above the threshold (or impossible).
    pub fit_rejected: usize,
    /// Left for the next level (no textured neighbour yet).
    pub deferred: usize,
    /// Split because, placed like a first patch, they do not fit inside a non-toroidal image.
    pub too_large: usize,
    /// FFT best-fit searches.
    pub fits: usize,
}

/// Mean and largest of a set of values.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct Spread {
    /// Values counted.
    pub count: usize,
    /// Mean.
    pub mean: f32,
    /// Largest.
    pub max: f32,
}

impl Spread {
    fn add(&mut self, v: f32) {
        self.mean = (self.mean * self.count as f32 + v) / (self.count + 1) as f32;
        self.max = self.max.max(v);
        self.count += 1;
    }
}

/// The driver's figures.
#[derive(Clone, Debug, Default, Serialize)]
pub struct DriverStats {
    /// Per level.
    pub levels: Vec<LevelStats>,
    /// FFT best-fit searches in all.
    pub fits: usize,
    /// Patches placed as the first of their component.
    pub first_patches: usize,
    /// Patches placed like a first one because no neighbour was textured.
    pub fresh_patches: usize,
    /// Accepted patches.
    pub patches: usize,
    /// Faces per accepted patch.
    pub patch_faces: Spread,
    /// E_flat of the accepted patches (area-weighted mean |r − 1|).
    pub flatness_error: Spread,
    /// Fit error of the fitted patches (relative to random placement, after relaxation).
    pub fit_error: Spread,
    /// Seam error before the relaxation (relax's own measure), per relaxed patch.
    pub relax_before: Spread,
    /// Seam error after the relaxation.
    pub relax_after: Spread,
    /// Mean squared colour difference of two random pattern pixels (the fit error's unit).
    pub random_pair_error: f32,
}

impl DriverStats {
    /// Records an accepted patch.
    pub fn record_patch(&mut self, faces: usize, e_flat: f32, fit_error: Option<f32>) {
        self.patches += 1;
        self.patch_faces.add(faces as f32);
        self.flatness_error.add(e_flat);
        if let Some(e) = fit_error {
            self.fit_error.add(e);
        }
    }

    /// Records a relaxation.
    pub fn record_relax(&mut self, before: f32, after: f32) {
        self.relax_before.add(before);
        self.relax_after.add(after);
    }
}

/// What `pattern` reports.
#[derive(Clone, Debug, Serialize)]
pub struct PatternReport {
    /// Pattern size in pixels.
    pub pattern_size: [u32; 2],
    /// World units per image width.
    pub scale: f32,
    /// Whether the pattern tiles.
    pub toroidal: bool,
    /// Faces of the target surface.
    pub faces: usize,
    /// Connected components (hierarchy roots).
    pub components: usize,
    /// Hierarchy clusters per level.
    pub hierarchy_levels: Vec<usize>,
    /// Splits of the hierarchy whose seeds were drawn more than once (control vertices nearly
    /// aligned or too close).
    pub seed_redraws: usize,
    /// The driver.
    pub driver: DriverStats,
    /// Mean seam error along patch borders: the colour difference across each seam edge
    /// (sampled at its midpoint and quarter points on both sides), divided by the random-pair
    /// error so that random placement scores about 1.
    pub mean_seam_error: f32,
    /// Output vertices written (corners split only where patches meet).
    pub output_vertices: usize,
    /// Things the user should know.
    pub warnings: Vec<String>,
}
