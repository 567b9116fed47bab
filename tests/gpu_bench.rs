//! The benchmark's CI run: `gi_bench --quick --check docs/benchmark.json` renders every method with its
//! defaults on `cornell` and `cellar` (error only) and fails when a default's block relative RMSE is more
//! than 10 % above the committed benchmark's. This test runs the built example, then reads its JSON and
//! checks the same bound itself, so a bench that silently measured nothing fails too.
#![cfg(feature = "gpu_tests")]

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

/// `target/<profile>/examples/NAME`, next to this test's own `target/<profile>/deps/`.
fn example_binary(name: &str) -> PathBuf {
    let exe = std::env::current_exe().expect("the test's path");
    exe.parent().and_then(Path::parent).expect("target/<profile>").join("examples").join(name)
}

fn records(path: &Path) -> Vec<serde_json::Value> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let json: serde_json::Value = serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    json["records"].as_array().cloned().unwrap_or_default()
}

#[test]
fn the_defaults_error_has_not_risen_above_the_committed_benchmark() {
    let binary = example_binary("gi_bench");
    assert!(binary.is_file(), "{} was not built", binary.display());
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/gi_bench");
    std::fs::create_dir_all(&dir).unwrap();
    let run_json = dir.join("quick.json");
    let _ = std::fs::remove_file(&run_json);
    let committed = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("docs/benchmark.json");
    let output = {
        let _guard = common::render_lock();
        Command::new(&binary)
            .args(["--quick", "--json"])
            .arg(&run_json)
            .arg("--check")
            .arg(&committed)
            .env("WGPU_BACKEND", std::env::var("WGPU_BACKEND").unwrap_or_else(|_| "vulkan".into()))
            .output()
            .expect("gi_bench runs")
    };
    let stdout = String::from_utf8_lossy(&output.stdout);
    eprintln!("{stdout}");
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "gi_bench --quick --check failed:\n{stdout}\n{}", stderr.lines().filter(|l| l.contains("gi_bench")).collect::<Vec<_>>().join("\n"));

    // The same bound, read back: six methods on two scenes, each within 10 % of the committed value.
    let run = records(&run_json);
    let committed = records(&committed);
    assert_eq!(run.len(), 12, "the quick run should measure 6 methods × 2 scenes, measured {}", run.len());
    for r in &run {
        let key = |v: &serde_json::Value| (v["scene"].as_str().map(str::to_string), v["method"].as_str().map(str::to_string), v["preset"].as_str().map(str::to_string));
        let c = committed.iter().find(|c| key(c) == key(r)).unwrap_or_else(|| panic!("no committed record for {:?}", key(r)));
        let (now, then) = (r["block_rmse"].as_f64().unwrap(), c["block_rmse"].as_f64().unwrap());
        assert!(now.is_finite() && now <= then * 1.10, "{:?}: block RMSE {now:.4} against the committed {then:.4}", key(r));
    }
}
