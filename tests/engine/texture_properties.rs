//! Properties of the texture pipeline end to end: rasterize a UV layout, fill texels from a
//! function of UV, pad, encode to PNG and decode back.
//!
//! `bench_texture_stages_2048` (ignored) prints timings of the hot paths at production sizes; run it with
//! `cargo test --release --test engine texture_properties::bench_ -- --ignored --nocapture`. Timings are not
//! asserted here (they belong in benchmarks).

use retex::engine::texture::bake::{rasterize_uv_layout, TexelHit};
use retex::engine::texture::encode::{decode_png_linear, encode_png_srgb};
use retex::engine::texture::pad::pad;
use retex::engine::texture::sample::sample_image;

use retex::engine::asset::model::{DecodedImage, Sampler};
use retex::engine::texture::color::linear_to_srgb;
use std::time::Instant;

/// A layout of `n × n` square charts separated by gutters; each chart is two triangles.
fn chart_grid(n: usize, gutter: f32) -> Vec<[[f32; 2]; 3]> {
    let cell = 1.0 / n as f32;
    let mut tris = Vec::with_capacity(2 * n * n);
    for j in 0..n {
        for i in 0..n {
            let (u0, v0) = (
                i as f32 * cell + gutter * cell,
                j as f32 * cell + gutter * cell,
            );
            let (u1, v1) = (
                (i + 1) as f32 * cell - gutter * cell,
                (j + 1) as f32 * cell - gutter * cell,
            );
            tris.push([[u0, v0], [u1, v0], [u1, v1]]);
            tris.push([[u0, v0], [u1, v1], [u0, v1]]);
        }
    }
    tris
}

/// The UV of a hit: its barycentrics applied to its triangle's UVs.
fn uv_of(tris: &[[[f32; 2]; 3]], hit: &TexelHit) -> [f32; 2] {
    let t = &tris[hit.triangle as usize];
    let mut uv = [0.0f32; 2];
    for (b, p) in hit.bary.iter().zip(t) {
        uv[0] += b * p[0];
        uv[1] += b * p[1];
    }
    uv
}

fn color_of_uv(uv: [f32; 2]) -> [f32; 4] {
    [
        0.2 + 0.6 * uv[0],
        0.8 - 0.5 * uv[1],
        0.5 * (uv[0] + uv[1]),
        1.0,
    ]
}

#[test]
fn bake_pad_encode_round_trip() {
    let (w, h) = (128u32, 96u32);
    let tris = chart_grid(6, 0.1);
    let map = rasterize_uv_layout(&tris, w, h);
    assert_eq!(map.overlapped, 0);
    // Coverage close to the analytic chart area: 36 charts of (0.8 / 6)² each.
    let analytic = 36.0 * (0.8f64 / 6.0).powi(2) * (w * h) as f64;
    assert!(
        (map.covered() as f64 - analytic).abs() / analytic < 0.05,
        "{} vs {analytic}",
        map.covered()
    );

    let mut pixels = vec![[0.0f32; 4]; (w * h) as usize];
    for (i, hit) in map.hits.iter().enumerate() {
        if let Some(hit) = hit {
            pixels[i] = color_of_uv(uv_of(&tris, hit));
        }
    }
    let covered = map.mask();
    let baked = pixels.clone();
    let report = pad(&mut pixels, &covered, w, h, 2);
    assert_eq!(
        report.padded + report.filled + map.covered(),
        (w * h) as u64
    );

    let png = encode_png_srgb(&pixels, w, h);
    let (dw, dh, back) = decode_png_linear(&png).unwrap();
    assert_eq!((dw, dh), (w, h));
    for i in 0..(w * h) as usize {
        assert!(back[i][3] > 0.99, "texel {i} transparent after padding");
        if covered[i] {
            for k in 0..3 {
                let steps =
                    (linear_to_srgb(back[i][k]) - linear_to_srgb(baked[i][k])).abs() * 255.0;
                assert!(
                    steps <= 0.5 + 1e-3,
                    "texel {i}: {:?} vs {:?}",
                    back[i],
                    baked[i]
                );
            }
        }
    }
    // Deterministic bytes.
    assert_eq!(png, encode_png_srgb(&pixels, w, h));
}

/// Sampling the baked image at a covered texel center returns that texel (bilinear at a center is
/// exact), closing the loop between the rasterizer's texel convention and the sampler's.
#[test]
fn sampler_and_rasterizer_agree_on_texel_centers() {
    let (w, h) = (40u32, 24u32);
    let tris = chart_grid(1, 0.0);
    let map = rasterize_uv_layout(&tris, w, h);
    assert_eq!(map.covered(), (w * h) as u64);
    let img = DecodedImage {
        width: w,
        height: h,
        pixels: (0..w * h)
            .map(|i| [(i % 251) as u8, (i / 7 % 256) as u8, 9, 255])
            .collect(),
    };
    let s = Sampler::default();
    for y in 0..h {
        for x in 0..w {
            let hit = map.hit(x, y).unwrap();
            let c = sample_image(&img, &s, uv_of(&tris, &hit));
            let p = img.pixels[(y * w + x) as usize];
            let expect = retex::engine::texture::color::srgb8_to_linear(p[0]);
            assert!(
                (c[0] - expect).abs() < 1e-3,
                "({x}, {y}): {} vs {expect}",
                c[0]
            );
        }
    }
}

/// CPU time (user + system, all threads) of this process, from /proc/self/stat (10 ms ticks).
fn cpu_time() -> std::time::Duration {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    let after = stat.rsplit(')').next().unwrap_or("");
    let f: Vec<u64> = after
        .split_whitespace()
        .map(|x| x.parse().unwrap_or(0))
        .collect();
    // Fields 14 and 15 of the full line are at 11 and 12 after the command name.
    let ticks = f.get(11).copied().unwrap_or(0) + f.get(12).copied().unwrap_or(0);
    std::time::Duration::from_millis(ticks * 10)
}

#[test]
#[ignore = "benchmark (timing report): run with --ignored --nocapture"]
fn bench_texture_stages_2048() {
    let size = 2048u32;
    // 224² cells × 2 = 100 352 triangles.
    let tris = chart_grid(224, 0.12);
    // Minimum over a few runs: the machine is shared.
    let mut t_raster = std::time::Duration::MAX;
    let mut map = None;
    let c0 = cpu_time();
    for _ in 0..5 {
        let t0 = Instant::now();
        let m = rasterize_uv_layout(&tris, size, size);
        t_raster = t_raster.min(t0.elapsed());
        map = Some(m);
    }
    let map = map.unwrap();
    let cpu_raster = (cpu_time() - c0) / 5;
    let covered = map.mask();
    let unpadded: Vec<[f32; 4]> = covered
        .iter()
        .map(|&c| if c { [0.5, 0.4, 0.3, 1.0] } else { [0.0; 4] })
        .collect();
    let mut t_pad = std::time::Duration::MAX;
    let mut pixels = Vec::new();
    let mut report = Default::default();
    let mut cpu_pad = std::time::Duration::ZERO;
    for _ in 0..5 {
        pixels = unpadded.clone();
        let c1 = cpu_time();
        let t1 = Instant::now();
        report = pad(&mut pixels, &covered, size, size, 8);
        t_pad = t_pad.min(t1.elapsed());
        cpu_pad += cpu_time() - c1;
    }
    let cpu_pad = cpu_pad / 5;
    let mut t_pull_push = std::time::Duration::MAX;
    let mut report_pp = Default::default();
    let mut cpu_pp = std::time::Duration::ZERO;
    for _ in 0..5 {
        let mut p = unpadded.clone();
        let c1 = cpu_time();
        let t1 = Instant::now();
        report_pp = pad(&mut p, &covered, size, size, 1);
        t_pull_push = t_pull_push.min(t1.elapsed());
        cpu_pp += cpu_time() - c1;
    }
    let cpu_pp = cpu_pp / 5;
    println!("cpu time per call (all threads): rasterize {cpu_raster:?}, pad 8 {cpu_pad:?}, pad 1 + pull-push {cpu_pp:?}");
    let img = DecodedImage {
        width: 2048,
        height: 2048,
        pixels: (0..2048u32 * 2048)
            .map(|i| [(i % 256) as u8, (i / 2048 % 256) as u8, 7, 255])
            .collect(),
    };
    let s = Sampler::default();
    let t2 = Instant::now();
    let mut acc = 0.0f32;
    for i in 0..4_000_000u32 {
        let uv = [(i % 2000) as f32 * 0.000_51, (i / 2000) as f32 * 0.000_49];
        acc += sample_image(&img, &s, uv)[0];
    }
    let t_sample = t2.elapsed();
    let t3 = Instant::now();
    let png = encode_png_srgb(&pixels, size, size);
    let t_encode = t3.elapsed();
    println!(
        "threads {}: rasterize {} tris at {size}²: {:?} (covered {}); pad 8: {:?} ({report:?}); pad 1 + pull-push: {:?} ({report_pp:?}); \
         4M bilinear samples: {:?} (checksum {acc}); png encode: {:?} ({} bytes)",
        rayon::current_num_threads(),
        tris.len(),
        t_raster,
        map.covered(),
        t_pad,
        t_pull_push,
        t_sample,
        t_encode,
        png.len()
    );
}
