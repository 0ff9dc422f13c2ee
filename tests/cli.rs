//! The `retex` binary: transfer writes a valid model and exits 0; failures exit non-zero with the
//! error; inspect describes a model.
#![cfg(feature = "cli")]

mod common;
#[path = "engine/meshmatch_common.rs"]
mod meshmatch_common;

use common::planar_pattern;
use common::*;
use std::path::Path;
use std::process::Command;

fn retex() -> Command {
    Command::new(env!("CARGO_BIN_EXE_retex"))
}

/// `retex transfer` of `source` onto `target` writing `out` and the artifacts into
/// `artifacts/` next to it; asserts that it exits 0.
fn transfer_with_artifacts(source: &Path, target: &Path, constraints: &Path, out: &Path) {
    let artifacts = out.parent().unwrap().join("artifacts");
    let status = retex()
        .args(["transfer", "--quiet", "--source"])
        .arg(source)
        .arg("--target")
        .arg(target)
        .arg("--constraints")
        .arg(constraints)
        .arg("--out")
        .arg(out)
        .arg("--artifacts")
        .arg(artifacts)
        .status()
        .unwrap();
    assert!(status.success(), "retex transfer {} failed", out.display());
}

#[test]
fn transfer_writes_a_valid_model_and_artifacts() {
    let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/test-outputs/cli");
    std::fs::create_dir_all(&dir).unwrap();
    let constraints = dir.join("c.json");
    std::fs::write(
        &constraints,
        br#"{"version": 1, "output": {"texture_size": 256}}"#,
    )
    .unwrap();
    let out = dir.join("fox_on_fox.glb");
    transfer_with_artifacts(
        &test_data("src_fox_khronos/glTF/Fox.gltf"),
        &test_data("src_fox_khronos/glTF-Binary/Fox.glb"),
        &constraints,
        &out,
    );
    assert_validator_clean(&std::fs::read(&out).unwrap(), "cli_fox_on_fox.glb");
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("artifacts/report.json")).unwrap()).unwrap();
    assert_eq!(report["method"], "project");
    assert!(
        report["method_report"]["textures"][0]["covered"]
            .as_u64()
            .unwrap()
            > 0
    );
}

#[test]
fn transfer_failure_exits_non_zero_with_the_error() {
    let out = retex()
        .args(["transfer", "--quiet", "--source"])
        .arg(test_data("edge_draco_box_khronos/glTF-Draco/Box.gltf"))
        .arg("--target")
        .arg(test_data("src_spot_keenan/spot_textured_derived.glb"))
        .args(["--out", "/tmp/retex-never-written.glb"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("error:"));
    let out = retex()
        .args(["transfer", "--quiet", "--method", "nonsense", "--source"])
        .arg(test_data("src_spot_keenan/spot_textured_derived.glb"))
        .arg("--target")
        .arg(test_data("src_spot_keenan/spot_textured_derived.glb"))
        .args(["--out", "/tmp/retex-never-written.glb"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("unknown method"));
}

#[test]
fn inspect_reports_counts_and_problems() {
    let out = retex()
        .args(["inspect", "--json"])
        .arg(test_data("src_spot_keenan/spot_textured_derived.glb"))
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let d: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(d["meshes"][0]["primitives"][0]["vertices"], 3225);
    assert_eq!(d["meshes"][0]["primitives"][0]["triangles"], 5856);
    assert_eq!(
        d["surface"]["vertices"], 2930,
        "welded across UV seams: {}",
        d["surface"]
    );
    assert_eq!(d["surface"]["euler_characteristic"], 2);
    assert_eq!(d["materials"][0]["base_color_texture"]["width"], 1024);
}

#[test]
#[ignore = "needs the shared assets (RETEX_SHARED_ASSETS or ../shared/assets)"]
fn inspect_names_the_open_boundary_of_a_scanned_bust() {
    let text = retex()
        .arg("inspect")
        .arg(shared_asset(
            "tgt_demosthenes_bust_odedstein/demosthenes-low-res_derived.glb",
        ))
        .output()
        .unwrap();
    let s = String::from_utf8_lossy(&text.stdout);
    assert!(s.contains("open boundary"), "{s}");
}

#[test]
fn transfer_checks_the_output_folder_before_reading_the_models() {
    // The source does not exist either: the output is checked first, so the error names it.
    let out = retex()
        .args(["transfer", "--quiet", "--source", "/nonexistent/src.glb"])
        .args(["--target", "/nonexistent/tgt.glb"])
        .args(["--out", "/tmp/retex-missing-folder/sub/x.glb"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("the folder /tmp/retex-missing-folder/sub does not exist"),
        "{err}"
    );
    assert!(!err.contains("src.glb"), "{err}");
    // An existing folder given as --out.
    let out = retex()
        .args(["transfer", "--quiet", "--source", "/nonexistent/src.glb"])
        .args(["--target", "/nonexistent/tgt.glb", "--out", "/tmp"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("is a folder"));
}

#[test]
fn unexpected_output_extensions_warn() {
    // The warning comes before the models are read (the missing source then fails the run).
    let out = retex()
        .args(["transfer", "--quiet", "--source", "/nonexistent/src.glb"])
        .args([
            "--target",
            "/nonexistent/tgt.glb",
            "--out",
            "/tmp/retex-out.obj",
        ])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("warning: --out /tmp/retex-out.obj does not end in .glb or .gltf"),
        "{err}"
    );
    assert!(err.contains("/nonexistent/src.glb"), "{err}");
    let out = retex()
        .args([
            "preview",
            "/nonexistent/model.glb",
            "--out",
            "/tmp/retex-strip.jpg",
        ])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("does not end in .png"), "{err}");
    let out = retex()
        .args([
            "preview",
            "/nonexistent/model.glb",
            "--out",
            "/tmp/retex-missing-folder/a.png",
        ])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("does not exist"), "{err}");
    assert!(!err.contains("model.glb"), "{err}");
}

#[test]
fn a_model_that_is_not_gltf_is_named() {
    let out = retex()
        .arg("inspect")
        .arg(test_data("src_spot_keenan/spot_triangulated.obj"))
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("is a Wavefront OBJ file, not glTF"), "{err}");
    assert!(err.contains("obj2gltf"), "{err}");
}

#[test]
fn a_method_registered_in_a_test_runs_through_the_cli() {
    use retex::cli::transfer::{run_with, Args};
    use retex::engine::methods::Registry;
    let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/test-outputs/cli");
    std::fs::create_dir_all(&dir).unwrap();
    let jpeg = planar_pattern::small_jpeg();
    let pattern = dir.join("tiles.jpg");
    std::fs::write(&pattern, &jpeg).unwrap();
    let constraints = dir.join("pattern.json");
    std::fs::write(&constraints, br#"{"version": 1, "method": "pattern"}"#).unwrap();
    let spot = test_data("src_spot_keenan/spot_textured_derived.glb");
    let out = dir.join("pattern_on_spot.glb");
    let artifacts = dir.join("pattern_artifacts");
    let registry = Registry::builtin().with(&planar_pattern::PLANAR_PATTERN);
    run_with(
        &registry,
        &Args {
            source: None,
            target: spot.clone(),
            source_base: None,
            pattern: Some(pattern.clone()),
            constraints: Some(constraints.clone()),
            method: None,
            out: out.clone(),
            artifacts: Some(artifacts.clone()),
            quiet: true,
        },
    )
    .unwrap();
    let glb = std::fs::read(&out).unwrap();
    assert_validator_clean(&glb, "cli_pattern_on_spot.glb");
    let back = load_bytes(&glb, "out.glb");
    assert_eq!(
        back.images.last().unwrap().bytes.as_slice(),
        jpeg.as_slice()
    );
    assert!(artifacts.join("planar.txt").exists());
    assert!(artifacts.join("report.json").exists());
    // `detail` reads a source: without one it is a clear error naming the input.
    let run = retex()
        .args(["transfer", "--quiet", "--method", "detail", "--target"])
        .arg(&spot)
        .arg("--pattern")
        .arg(&pattern)
        .arg("--out")
        .arg(dir.join("refused.glb"))
        .output()
        .unwrap();
    assert!(!run.status.success());
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(err.contains("source"), "{err}");
}

/// Runs `retex` with `args` and returns (success, stderr, peak resident set in bytes), the peak
/// from the kernel's accounting of exactly this child (`wait4`).
// The child is reaped by `wait4` (which `Child::wait` cannot do while reporting its rusage).
#[allow(clippy::zombie_processes)]
fn run_measured(args: &[&std::ffi::OsStr]) -> (bool, String, u64) {
    use std::io::Read;
    let mut child = retex()
        .args(args)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut stderr = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut stderr)
        .unwrap();
    let mut status = 0;
    // SAFETY: plain FFI calls on a zeroed rusage and our own child's pid.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let pid = unsafe { libc::wait4(child.id() as i32, &mut status, 0, &mut usage) };
    assert_eq!(pid, child.id() as i32);
    let ok = libc::WIFEXITED(status) && libc::WEXITSTATUS(status) == 0;
    (ok, stderr, usage.ru_maxrss as u64 * 1024)
}

#[test]
fn transfer_refuses_a_png_bomb_naming_the_image_and_the_limit() {
    let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/test-outputs/cli");
    std::fs::create_dir_all(&dir).unwrap();
    let bomb = dir.join("bomb16384.glb");
    std::fs::write(&bomb, textured_triangle_glb(&[bomb_png(16384, 16384)], 1)).unwrap();
    let target = test_data("tgt_spot_remeshed_odedstein/spot_derived.glb");
    let out = dir.join("never-written.glb");
    let (ok, stderr, peak) = run_measured(&[
        "transfer".as_ref(),
        "--quiet".as_ref(),
        "--source".as_ref(),
        bomb.as_os_str(),
        "--target".as_ref(),
        target.as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
    ]);
    assert!(!ok, "{stderr}");
    assert!(
        stderr.contains("source: images[0] (16384x16384)")
            && stderr.contains("max_decoded_image_bytes = 536870912"),
        "{stderr}"
    );
    println!("peak resident set of the refused transfer: {peak} bytes");
    assert!(peak < 200 << 20, "{peak}");
}

#[test]
fn transfer_never_decodes_an_image_no_primitive_samples() {
    let dir = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/test-outputs/cli");
    std::fs::create_dir_all(&dir).unwrap();
    // Image 1 declares 16384² (1 GiB decoded) with a few bytes of data, on an unused material.
    let source = dir.join("unused16384.glb");
    std::fs::write(
        &source,
        textured_triangle_glb(&[small_png(8, 4), bomb_png(16384, 16384)], 1),
    )
    .unwrap();
    let constraints = dir.join("c64.json");
    std::fs::write(
        &constraints,
        br#"{"version": 1, "output": {"texture_size": 64}}"#,
    )
    .unwrap();
    let target = test_data("tgt_spot_remeshed_odedstein/spot_derived.glb");
    let out = dir.join("unused_on_spot.glb");
    let (ok, stderr, peak) = run_measured(&[
        "transfer".as_ref(),
        "--quiet".as_ref(),
        "--source".as_ref(),
        source.as_os_str(),
        "--target".as_ref(),
        target.as_os_str(),
        "--constraints".as_ref(),
        constraints.as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
    ]);
    assert!(ok, "{stderr}");
    println!("peak resident set: {peak} bytes");
    assert!(peak < 300 << 20, "{peak}");
}

/// MeshMatch texture update (§5.3) through the CLI: a striped capsule whose second half was
/// lengthened; the unmoved half is given as the copy region. The output must be validator-clean,
/// the report must count the copied synthesis vertices, and the copied half must be the
/// source's colour.
#[test]
fn meshmatch_texture_update_runs_through_the_cli() {
    use meshmatch_common::{colored_points, update_copy_error, update_pair};
    let dir =
        std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/test-outputs/cli-update");
    std::fs::create_dir_all(&dir).unwrap();
    let pair = update_pair(2.0);
    std::fs::write(dir.join("source.glb"), &pair.source).unwrap();
    std::fs::write(dir.join("target.glb"), &pair.target).unwrap();
    let constraints = serde_json::json!({"version": 1, "method": "meshmatch", "seed": 1,
        "output": {"vertex_colors": true},
        "params": {"samples": 4096, "vertex_color_samples": 20000,
                   "update": {"copy": {"faces": [{"mesh": 0, "primitive": 0, "triangles": pair.unmoved}]}}}});
    std::fs::write(dir.join("c.json"), constraints.to_string()).unwrap();
    let out = dir.join("updated.glb");
    transfer_with_artifacts(
        &dir.join("source.glb"),
        &dir.join("target.glb"),
        &dir.join("c.json"),
        &out,
    );
    let model = std::fs::read(&out).unwrap();
    assert_validator_clean(&model, "cli_meshmatch_update.glb");
    let report: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("artifacts/report.json")).unwrap()).unwrap();
    let r = &report["method_report"];
    let (copied, total) = (
        r["copied_samples"].as_u64().unwrap(),
        r["target_samples"].as_u64().unwrap(),
    );
    assert!(
        copied > total / 5 && copied < total / 2,
        "copied {copied} of {total}"
    );
    let (err, n) = update_copy_error(&colored_points(&model), 0.05, 0.9);
    assert!(
        n > 200 && err < 0.02,
        "copied half: error {err} over {n} points"
    );
}
