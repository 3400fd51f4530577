//! Running the `tricons` binary as a user does, and small recordings for it.

use std::fs;
use std::path::Path;
use std::process::{Command, Output};

/// An absolute path inside the repository.
pub fn repo(path: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(path).to_str().unwrap().to_string()
}

/// The binary under test. `TRICONS_TEST_RUNNER` (e.g. `qemu-aarch64-static -L
/// /usr/aarch64-linux-gnu`, set by cross/check.sh) prefixes it where the host
/// cannot execute it directly.
pub fn tricons(args: &[&str]) -> Output {
    command().args(args).env("RUST_LOG", "warn").output().unwrap()
}

/// The binary as a command, behind `TRICONS_TEST_RUNNER` when set.
fn command() -> Command {
    let exe = env!("CARGO_BIN_EXE_tricons");
    let runner = std::env::var("TRICONS_TEST_RUNNER").unwrap_or_default();
    let mut parts = runner.split_whitespace();
    match parts.next() {
        Some(program) => {
            let mut c = Command::new(program);
            c.args(parts).arg(exe);
            c
        }
        None => Command::new(exe),
    }
}

pub fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// A failure the way the guide wants it: non-zero exit, a message, no panic.
pub fn assert_clean_failure(o: &Output, needle: &str) {
    let err = stderr(o);
    assert!(!o.status.success(), "expected failure, got success; stderr: {err}");
    assert!(!err.contains("panicked"), "panicked: {err}");
    assert!(err.contains(needle), "stderr does not mention {needle:?}: {err}");
}

/// A copy of the first `frames` frames of the demo recording in `dir/rec`, with or without
/// their annotations (keeps the slow qemu runs of the full pipeline short).
pub fn demo_subset(dir: &Path, frames: usize, annotations: bool) -> std::path::PathBuf {
    let rec = dir.join("rec");
    fs::create_dir_all(&rec).unwrap();
    let demo = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/synthnocs-demo");
    let mut manifest: serde_json::Value =
        serde_json::from_str(&fs::read_to_string(demo.join("manifest.json")).unwrap()).unwrap();
    let list = manifest["frames"].as_array_mut().unwrap();
    list.truncate(frames);
    for f in list.iter_mut() {
        let mut keys = vec!["color", "depth"];
        if annotations {
            keys.push("annotations");
            let ann: serde_json::Value =
                serde_json::from_str(&fs::read_to_string(demo.join(f["annotations"].as_str().unwrap())).unwrap())
                    .unwrap();
            for key in ["mask", "nocs"] {
                if let Some(name) = ann[key].as_str() {
                    fs::copy(demo.join(name), rec.join(name)).unwrap();
                }
            }
        } else {
            f.as_object_mut().unwrap().remove("annotations");
        }
        for key in keys {
            let name = f[key].as_str().unwrap().to_string();
            fs::copy(demo.join(&name), rec.join(&name)).unwrap();
        }
    }
    fs::write(rec.join("manifest.json"), serde_json::to_string(&manifest).unwrap()).unwrap();
    rec
}

/// Starts the binary with piped stdout/stderr and `RUST_LOG=info` (for tests that signal it).
pub fn spawn_tricons(args: &[&str]) -> std::process::Child {
    command()
        .args(args)
        .env("RUST_LOG", "info")
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap()
}

/// Sends `signal` (e.g. "TERM", "INT") to a child process.
pub fn signal(child: &std::process::Child, signal: &str) {
    let status = Command::new("kill").arg(format!("-{signal}")).arg(child.id().to_string()).status().unwrap();
    assert!(status.success(), "kill -{signal} failed");
}

/// Waits until `ready()` holds, polling; panics after `timeout`.
pub fn wait_for(what: &str, timeout: std::time::Duration, mut ready: impl FnMut() -> bool) {
    let start = std::time::Instant::now();
    while !ready() {
        assert!(start.elapsed() < timeout, "timed out waiting for {what}");
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
}
