//! The image side of the `pattern` method (issue 12, Soler, Cani & Angelidis 2002 §4.1, §4.2,
//! §4.4): mask rasterisation, the best fit by FFT (eq. 2) and the local relaxation, on
//! procedural patterns made here and on two tileable textures of the shared assets.
//!
//! Planted placements: a band of triangles around a patch is mapped into the pattern by a known
//! rigid placement, rasterised into a mask, and the fit must find that placement again (within
//! 1 px and at the right orientation), across several random plants and patterns.

use retex::engine::asset::DecodedImage;
use retex::engine::methods::pattern::fit::{
    best_fit, best_fit_with_rotation, coarse_ranking, error_image, placement_error, rotate,
    Placement,
};
use retex::engine::methods::pattern::mask::{rasterise_mask, Mask, MaskTriangle};
use retex::engine::methods::pattern::relax::{relax, Corner, RelaxProblem, SeamEdge};
use retex::engine::methods::pattern::texture::PatternTexture;
use retex::engine::rng::SplitMix64;

use crate::common::shared_asset;

const TAU: f32 = std::f32::consts::TAU;

/// Smooth coloured waves, periodic on `w × h` (integer frequencies), with no shorter period.
fn waves(w: u32, h: u32) -> DecodedImage {
    let mut pixels = Vec::with_capacity((w * h) as usize);
    for y in 0..h {
        for x in 0..w {
            let (u, v) = ((x as f32 + 0.5) / w as f32, (y as f32 + 0.5) / h as f32);
            let a = (TAU * (u + 2.0 * v)).sin();
            let b = (TAU * (3.0 * u - v) + 1.0).sin();
            let c = (TAU * (2.0 * u + 3.0 * v) + 2.0).sin() * 0.5 + (TAU * v).cos() * 0.5;
            let byte = |t: f32| ((t * 0.5 + 0.5) * 255.0).round().clamp(0.0, 255.0) as u8;
            pixels.push([byte(a), byte(b), byte(c), 255]);
        }
    }
    DecodedImage {
        width: w,
        height: h,
        pixels,
    }
}

/// Periodic value noise: random colours on a coarse lattice, smoothstep-interpolated.
fn blobs(w: u32, h: u32, cells: u32, seed: u64) -> DecodedImage {
    let mut rng = SplitMix64::new(seed);
    let lattice: Vec<[f32; 3]> = (0..cells * cells)
        .map(|_| [rng.unit_f32(), rng.unit_f32(), rng.unit_f32()])
        .collect();
    let at = |i: u32, j: u32| lattice[((j % cells) * cells + (i % cells)) as usize];
    let smooth = |t: f32| t * t * (3.0 - 2.0 * t);
    let mut pixels = Vec::with_capacity((w * h) as usize);
    for y in 0..h {
        for x in 0..w {
            let gx = (x as f32 + 0.5) / w as f32 * cells as f32;
            let gy = (y as f32 + 0.5) / h as f32 * cells as f32;
            let (i, j) = (gx.floor() as u32, gy.floor() as u32);
            let (fx, fy) = (smooth(gx.fract()), smooth(gy.fract()));
            let mut px = [0u8, 0, 0, 255];
            for c in 0..3 {
                let top = at(i, j)[c] * (1.0 - fx) + at(i + 1, j)[c] * fx;
                let bottom = at(i, j + 1)[c] * (1.0 - fx) + at(i + 1, j + 1)[c] * fx;
                px[c] = ((top * (1.0 - fy) + bottom * fy) * 255.0).round() as u8;
            }
            pixels.push(px);
        }
    }
    DecodedImage {
        width: w,
        height: h,
        pixels,
    }
}

fn load_png(relative: &str) -> DecodedImage {
    let path = shared_asset(relative);
    let image = image::open(&path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
        .to_rgba8();
    DecodedImage {
        width: image.width(),
        height: image.height(),
        pixels: image.pixels().map(|p| p.0).collect(),
    }
}

/// The band of a square patch `[0, side]²` in its frame: a ring of width `band` outside it on
/// the sides listed (0 = top, 1 = right, 2 = bottom, 3 = left), as two triangles per side.
fn band_triangles(
    side: f32,
    band: f32,
    sides: &[usize],
    placement: &Placement,
) -> Vec<MaskTriangle> {
    let mut out = Vec::new();
    for &s in sides {
        let [x0, y0, x1, y1] = match s {
            0 => [-band, -band, side + band, 0.0],
            1 => [side, 0.0, side + band, side],
            2 => [-band, side, side + band, side + band],
            _ => [-band, 0.0, 0.0, side],
        };
        for tri in [
            [[x0, y0], [x1, y0], [x1, y1]],
            [[x0, y0], [x1, y1], [x0, y1]],
        ] {
            out.push(MaskTriangle {
                frame_px: tri,
                pattern_px: tri.map(|p| placement.apply(p)),
                weight: [1.0; 3],
            });
        }
    }
    out
}

/// Distance between two pattern positions, modulo the torus when `period` is given.
fn distance(a: [f32; 2], b: [f32; 2], period: Option<[f32; 2]>) -> f32 {
    let mut d = [a[0] - b[0], a[1] - b[1]];
    if let Some(p) = period {
        for k in 0..2 {
            d[k] -= (d[k] / p[k]).round() * p[k];
        }
    }
    d[0].hypot(d[1])
}

fn angle_difference(a: f32, b: f32) -> f32 {
    let d = (a - b).rem_euclid(TAU);
    d.min(TAU - d)
}

struct Plant {
    placement: Placement,
    k: usize,
    phi: f32,
}

/// A random placement on the orientation grid `2πk/n + φ` (φ random too).
fn plant(rng: &mut SplitMix64, n: usize, size: [f32; 2], margin: f32) -> Plant {
    let k = rng.below(n as u64) as usize;
    let phi = rng.unit_f32() * TAU / n as f32;
    let rotation = TAU * k as f32 / n as f32 + phi;
    // Put the patch centre (frame (s/2, s/2)) at a random point of the pattern, `margin` inside.
    let centre = [
        margin + rng.unit_f32() * (size[0] - 2.0 * margin),
        margin + rng.unit_f32() * (size[1] - 2.0 * margin),
    ];
    Plant {
        placement: Placement {
            rotation,
            translation_px: [centre[0], centre[1]],
        },
        k,
        phi,
    }
}

/// The placement whose frame point `(side/2, side/2)` lands on `placement`'s translation.
fn centred(placement: Placement, side: f32) -> Placement {
    let c = rotate(placement.rotation, [side / 2.0, side / 2.0]);
    Placement {
        rotation: placement.rotation,
        translation_px: [
            placement.translation_px[0] - c[0],
            placement.translation_px[1] - c[1],
        ],
    }
}

/// Plants, fits with the planted φ, and returns (translation error px, orientation matched,
/// fit error, true placement error, random placement error).
fn plant_and_fit(
    texture: &PatternTexture,
    rng: &mut SplitMix64,
    side: f32,
    band: f32,
    sides: &[usize],
) -> (f32, bool, f32, f32, f32) {
    let size = [texture.width() as f32, texture.height() as f32];
    let margin = if texture.toroidal() { 0.0 } else { 1.5 * side };
    let p = plant(rng, texture.orientations(), size, margin);
    let truth = centred(p.placement, side);
    let mask = rasterise_mask(texture, &band_triangles(side, band, sides, &truth));
    let bbox = [[0.0, 0.0], [side, side]];
    let ranking = coarse_ranking(texture, &mask, bbox, p.phi);
    if let Some(rank) = ranking.iter().position(|(_, k)| *k == p.k) {
        let (best, median) = (ranking[0].0, ranking[ranking.len() / 2].0);
        println!(
            "coarse rank of the planted orientation {rank} of {}: margin position {:.3}",
            ranking.len(),
            (ranking[rank].0 - best) / (median - best).max(1e-12)
        );
    }
    let fit = best_fit_with_rotation(texture, &mask, bbox, p.phi).expect("a fit");
    let period = texture.toroidal().then_some(size);
    let centre = [side / 2.0, side / 2.0];
    let offset = distance(fit.placement.apply(centre), truth.apply(centre), period);
    let true_error = placement_error(texture, &mask, &truth).unwrap();
    let random = Placement {
        rotation: rng.unit_f32() * TAU,
        translation_px: [rng.unit_f32() * size[0], rng.unit_f32() * size[1]],
    };
    let random_error = placement_error(texture, &mask, &random).unwrap();
    (
        offset,
        fit.orientation_index == p.k,
        fit.error,
        true_error,
        random_error,
    )
}

#[test]
fn planted_placements_are_recovered_on_procedural_patterns() {
    let patterns = [
        (
            "waves",
            PatternTexture::new(&waves(96, 80), true, 19).unwrap(),
        ),
        (
            "blobs",
            PatternTexture::new(&blobs(128, 96, 8, 3), true, 19).unwrap(),
        ),
        (
            "blobs-clamped",
            PatternTexture::new(&blobs(128, 112, 6, 9), false, 19).unwrap(),
        ),
    ];
    for (name, texture) in &patterns {
        let mut rng = SplitMix64::new(41);
        for trial in 0..6 {
            let sides: &[usize] = if trial % 2 == 0 { &[0, 3] } else { &[0, 1, 2] };
            let (offset, same_k, fit_error, true_error, random_error) =
                plant_and_fit(texture, &mut rng, 24.0, 6.0, sides);
            assert!(same_k, "{name} trial {trial}: wrong orientation");
            assert!(offset < 1.0, "{name} trial {trial}: off by {offset} px");
            assert!(
                true_error < 1e-6,
                "{name}: true placement error {true_error}"
            );
            assert!(
                fit_error < 0.02 * random_error && random_error > 0.01,
                "{name} trial {trial}: fit {fit_error} vs random {random_error}"
            );
        }
    }
}

#[test]
fn hashed_mask_rotation_finds_the_nearest_orientation() {
    let texture = PatternTexture::new(&blobs(128, 128, 8, 5), true, 19).unwrap();
    let step = TAU / 19.0;
    let mut rng = SplitMix64::new(7);
    for trial in 0..6 {
        // Any rotation, not on the grid: the fit must land within one orientation step of it.
        let truth = centred(
            Placement {
                rotation: rng.unit_f32() * TAU,
                translation_px: [rng.unit_f32() * 128.0, rng.unit_f32() * 128.0],
            },
            32.0,
        );
        let mask = rasterise_mask(&texture, &band_triangles(32.0, 8.0, &[0, 1], &truth));
        let fit = best_fit(&texture, &mask, [[0.0, 0.0], [32.0, 32.0]]).expect("a fit");
        let again = best_fit(&texture, &mask, [[0.0, 0.0], [32.0, 32.0]]).unwrap();
        assert_eq!(fit, again, "deterministic");
        let d = angle_difference(fit.placement.rotation, truth.rotation);
        assert!(
            d <= step,
            "trial {trial}: rotation off by {d} rad (step {step})"
        );
        let random = placement_error(
            &texture,
            &mask,
            &Placement {
                rotation: rng.unit_f32() * TAU,
                translation_px: [rng.unit_f32() * 128.0, rng.unit_f32() * 128.0],
            },
        )
        .unwrap();
        assert!(
            fit.error < 0.25 * random,
            "trial {trial}: {} vs {random}",
            fit.error
        );
    }
}

#[test]
fn non_toroidal_fits_keep_patch_and_mask_inside() {
    let texture = PatternTexture::new(&blobs(96, 80, 5, 11), false, 19).unwrap();
    let mut rng = SplitMix64::new(3);
    for _ in 0..6 {
        // Masks taken from anywhere (also wrapped positions off the image): the fit must still stay
        // inside.
        let truth = Placement {
            rotation: rng.unit_f32() * TAU,
            translation_px: [rng.unit_f32() * 140.0 - 20.0, rng.unit_f32() * 120.0 - 20.0],
        };
        let side = 20.0;
        let mask = rasterise_mask(&texture, &band_triangles(side, 5.0, &[0, 1, 2, 3], &truth));
        let bbox = [[0.0, 0.0], [side, side]];
        let fit = best_fit(&texture, &mask, bbox).expect("a 30 px patch fits in 96x80");
        let inside = |p: [f32; 2]| (0.0..=96.0).contains(&p[0]) && (0.0..=80.0).contains(&p[1]);
        for c in [[0.0, 0.0], [side, 0.0], [0.0, side], [side, side]] {
            assert!(inside(fit.placement.apply(c)), "patch corner outside");
        }
        for j in 0..mask.height {
            for i in 0..mask.width {
                if mask.support[j * mask.width + i] > 0.0 {
                    assert!(
                        inside(fit.placement.apply(mask.cell_centre(i, j))),
                        "mask outside"
                    );
                }
            }
        }
    }
    // A patch larger than the image has no valid placement.
    let truth = Placement {
        rotation: 0.0,
        translation_px: [10.0, 10.0],
    };
    let mask = rasterise_mask(&texture, &band_triangles(20.0, 5.0, &[0], &truth));
    assert!(best_fit(&texture, &mask, [[0.0, 0.0], [200.0, 200.0]]).is_none());
    // No support: no fit.
    assert!(best_fit(&texture, &Mask::default(), [[0.0, 0.0], [1.0, 1.0]]).is_none());
}

/// The FFT image of eq. 2 against a direct evaluation of the same sum at every offset.
#[test]
fn fft_error_equals_brute_force() {
    for (toroidal, grey) in [(true, false), (false, false), (true, true), (false, true)] {
        let mut image = blobs(14, 11, 3, 21);
        if grey {
            // Zero saturation: two colour channels are zero on every texel and skipped by the
            // correlations; the mask's colours below are not grey, so the skip must still count
            // their |I|² and nothing else.
            for p in &mut image.pixels {
                *p = [p[0], p[0], p[0], 255];
            }
        }
        let texture = PatternTexture::new(&image, toroidal, 7).unwrap();
        let truth = Placement {
            rotation: 0.7,
            translation_px: [3.3, 2.1],
        };
        let mut triangles = band_triangles(4.0, 2.0, &[0, 3], &truth);
        triangles[0].weight = [1.0, 0.3, 0.6]; // a faded corner: J is not binary
        let mut mask = rasterise_mask(&texture, &triangles);
        if grey {
            for (k, c) in mask.colour.iter_mut().enumerate() {
                c[0] += 0.2 * (k % 3) as f32 - 0.2;
                c[1] += 0.1 * (k % 5) as f32 - 0.2;
            }
        }
        let total = mask.support_sum();
        assert!(total > 4.0);
        for rotation in [0.0, 0.7, 2.9] {
            let image = error_image(&texture, &mask, [[0.0, 0.0], [4.0, 4.0]], rotation)
                .expect("some valid offset");
            let mut valid = 0;
            let mut brute_min = (f32::INFINITY, 0usize);
            for dy in 0..image.height {
                for dx in 0..image.width {
                    let fft = image.values[dy * image.width + dx];
                    if !fft.is_finite() {
                        continue;
                    }
                    valid += 1;
                    let p = image.placement(dx, dy);
                    let mut e = 0.0f64;
                    let mut scale = 0.0f64;
                    for j in 0..mask.height {
                        for i in 0..mask.width {
                            let w = mask.support[j * mask.width + i] as f64;
                            if w <= 0.0 {
                                continue;
                            }
                            let c = mask.colour[j * mask.width + i];
                            let x = p.apply(mask.cell_centre(i, j));
                            let t = texture.sample(x);
                            let i2: f64 = c.iter().map(|v| (*v as f64).powi(2)).sum();
                            let it: f64 = (0..3).map(|k| c[k] as f64 * t[k] as f64).sum();
                            let t2 = texture.sample_norm_sq(x) as f64;
                            e += w * (i2 - 2.0 * it + t2);
                            scale += w * (i2 + t2);
                        }
                    }
                    let brute = (e / total as f64).max(0.0);
                    let tolerance = 1e-4 * scale / total as f64;
                    assert!(
                        (fft as f64 - brute).abs() <= tolerance,
                        "toroidal {toroidal} grey {grey} rotation {rotation} d ({dx}, {dy}): fft {fft} brute {brute}"
                    );
                    if (brute as f32) < brute_min.0 {
                        brute_min = (brute as f32, dy * image.width + dx);
                    }
                }
            }
            assert!(valid > 0);
            let fft_min = image
                .values
                .iter()
                .enumerate()
                .min_by(|a, b| a.1.total_cmp(b.1))
                .unwrap();
            assert!((fft_min.1 - brute_min.0).abs() < 1e-4, "same minimum");
        }
    }
}

#[test]
fn mask_rasterisation_covers_the_band_with_its_colours() {
    let texture = PatternTexture::new(&waves(64, 64), true, 19).unwrap();
    let truth = Placement {
        rotation: 0.3,
        translation_px: [10.0, 5.0],
    };
    // A band taller than one band of rows of the parallel rasterisation (32) too.
    let big = rasterise_mask(&texture, &band_triangles(80.0, 6.0, &[0, 1], &truth));
    assert!(big.height > 64);
    // Area: top 92 × 6 + right 6 × 80 = 1,032 cells.
    let covered = big.support.iter().filter(|&&s| s > 0.0).count();
    assert!((980..=1090).contains(&covered), "{covered} cells");
    for (index, &support) in big.support.iter().enumerate() {
        if support > 0.0 {
            let (i, j) = (index % big.width, index / big.width);
            let want = texture.sample(truth.apply(big.cell_centre(i, j)));
            assert!((0..3).all(|c| (want[c] - big.colour[index][c]).abs() < 1e-4));
        }
    }
    let mask = rasterise_mask(&texture, &band_triangles(16.0, 4.0, &[0, 1], &truth));
    // Area of the band: top 24 × 4 + right 4 × 16 = 160 cells.
    let covered = mask.support.iter().filter(|&&s| s > 0.0).count();
    assert!((150..=175).contains(&covered), "{covered} cells");
    for j in 0..mask.height {
        for i in 0..mask.width {
            let index = j * mask.width + i;
            if mask.support[index] > 0.0 {
                let want = texture.sample(truth.apply(mask.cell_centre(i, j)));
                let got = mask.colour[index];
                assert!((0..3).all(|c| (want[c] - got[c]).abs() < 1e-4));
            }
        }
    }
    // Cells inside the patch are not in the band.
    let (ci, cj) = (
        (8.0 - mask.origin[0]) as usize,
        (8.0 - mask.origin[1]) as usize,
    );
    assert_eq!(mask.support[cj * mask.width + ci], 0.0);
}

/// A strip of triangles along one seam: the neighbour's side is the true placement, ours is a
/// perturbed copy; relaxation must lower the seam error without flipping a triangle.
#[test]
fn relaxation_lowers_seam_error_without_flips() {
    let texture = PatternTexture::new(&blobs(128, 128, 10, 17), true, 19).unwrap();
    for seed in 0..6u64 {
        let mut rng = SplitMix64::new(seed);
        let truth = Placement {
            rotation: rng.unit_f32() * TAU,
            translation_px: [rng.unit_f32() * 128.0, rng.unit_f32() * 128.0],
        };
        // Seam vertices along y = 0 (x = 0, 6, ..., 48), inner fixed vertices along y = 8.
        let count = 9;
        let seam_frame: Vec<[f32; 2]> = (0..count).map(|i| [i as f32 * 6.0, 0.0]).collect();
        let inner: Vec<[f32; 2]> = seam_frame
            .iter()
            .map(|p| truth.apply([p[0] + 3.0, 8.0]))
            .collect();
        let radius = 2.5;
        let start: Vec<[f32; 2]> = seam_frame
            .iter()
            .map(|&p| {
                let q = truth.apply(p);
                let (a, r) = (rng.unit_f32() * TAU, radius * (0.5 + 0.5 * rng.unit_f32()));
                [q[0] + r * a.cos(), q[1] + r * a.sin()]
            })
            .collect();
        let seams = (0..count - 1)
            .map(|i| SeamEdge {
                ours: [Corner::Movable(i), Corner::Movable(i + 1)],
                theirs_px: [truth.apply(seam_frame[i]), truth.apply(seam_frame[i + 1])],
                weight: 1.0,
            })
            .collect();
        let mut triangles = Vec::new();
        for i in 0..count - 1 {
            triangles.push([
                Corner::Movable(i),
                Corner::Movable(i + 1),
                Corner::Fixed(inner[i]),
            ]);
            if i + 1 < count - 1 {
                triangles.push([
                    Corner::Movable(i + 1),
                    Corner::Fixed(inner[i + 1]),
                    Corner::Fixed(inner[i]),
                ]);
            }
        }
        let problem = RelaxProblem {
            start_px: start.clone(),
            radius_px: 2.0 * radius,
            seams,
            triangles,
        };
        let area = |t: &[Corner; 3], px: &[[f32; 2]]| {
            let [a, b, c] = t.map(|c| match c {
                Corner::Movable(i) => px[i],
                Corner::Fixed(p) => p,
            });
            (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1])
        };
        let relaxed = relax(&texture, &problem, &mut rng);
        assert!(
            relaxed.error_after < 0.5 * relaxed.error_before,
            "seed {seed}: {} -> {}",
            relaxed.error_before,
            relaxed.error_after
        );
        for t in &problem.triangles {
            let before = area(t, &start);
            let after = area(t, &relaxed.px);
            assert!(before * after > 0.0, "seed {seed}: a triangle flipped");
        }
        for (p, s) in relaxed.px.iter().zip(&start) {
            assert!(distance(*p, *s, None) <= 2.0 * radius + 1e-4);
        }
    }
}

/// Two tileable textures of the shared assets (512², an anisotropic wood and a woven fabric).
#[test]
#[ignore = "needs ../shared/assets"]
fn planted_placements_are_recovered_on_shared_textures() {
    for relative in [
        "src_sheen_chair_khronos/glTF/chair_wood_albedo.png",
        "perf_toy_car_khronos/glTF/Fabric_baseColor.png",
    ] {
        let texture = PatternTexture::new(&load_png(relative), true, 19).unwrap();
        let mut rng = SplitMix64::new(5);
        for trial in 0..5 {
            let (offset, same_k, fit_error, true_error, random_error) =
                plant_and_fit(&texture, &mut rng, 48.0, 10.0, &[0, 3]);
            println!(
                "{relative} trial {trial}: off by {offset:.2} px, fit error {fit_error:.5}, random {random_error:.5}"
            );
            assert!(same_k, "{relative} trial {trial}: wrong orientation");
            assert!(offset < 1.0, "{relative} trial {trial}: off by {offset} px");
            assert!(true_error < 1e-6);
            // These textures have detail at the texel scale, so the error at the best *integer*
            // offset is not near 0 (measured 0.19 × a random placement on the wood, trial 0).
            assert!(
                fit_error < 0.5 * random_error,
                "{relative} trial {trial}: {fit_error} vs {random_error}"
            );
        }
    }
}

/// `cargo test --release --test engine bench_pattern_fit -- --ignored --nocapture`: the setup of a
/// 256² pattern with 19 orientations and one best fit of a 64² mask (a 16 px band around a 32 px
/// patch).
#[test]
#[ignore = "benchmark"]
fn bench_pattern_fit() {
    let image = blobs(256, 256, 12, 1);
    let start = std::time::Instant::now();
    let texture = PatternTexture::new(&image, true, 19).unwrap();
    let setup = start.elapsed();
    let truth = Placement {
        rotation: 1.0,
        translation_px: [100.0, 80.0],
    };
    let mask = rasterise_mask(&texture, &band_triangles(32.0, 16.0, &[0, 1, 2, 3], &truth));
    assert_eq!((mask.width, mask.height), (64, 64));
    let runs = 5;
    let start = std::time::Instant::now();
    for _ in 0..runs {
        best_fit(&texture, &mask, [[0.0, 0.0], [32.0, 32.0]]).unwrap();
    }
    let fit = start.elapsed() / runs;
    println!(
        "pattern fit: setup 256² × 19 orientations {:.1} ms; best_fit 64² mask {:.1} ms ({} threads)",
        setup.as_secs_f64() * 1e3,
        fit.as_secs_f64() * 1e3,
        rayon::current_num_threads()
    );
}
