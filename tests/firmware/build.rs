use std::{env, fs, path::PathBuf};

/// Golden-vector cases (file stems written by `nav-sim golden`).
const CASES: [&str; 6] = [
    "ta9",
    "ta12",
    "vc_classical",
    "vc_aided",
    "seeker_ins",
    "mission",
];

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("OUT_DIR"));
    fs::write(out.join("memory.x"), include_bytes!("memory.x")).expect("write memory.x");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-changed=build.rs");

    // Golden vectors: copied from NAV_GOLDEN_DIR (default: the workspace's target/golden);
    // a missing file becomes an empty one and the firmware reports the case as skipped.
    println!("cargo:rerun-if-env-changed=NAV_GOLDEN_DIR");
    let manifest = PathBuf::from(env::var_os("CARGO_MANIFEST_DIR").expect("CARGO_MANIFEST_DIR"));
    let dir = env::var_os("NAV_GOLDEN_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| manifest.join("../../target/golden"));
    for case in CASES {
        for ext in ["in.f32", "out.f32", "design.f64"] {
            let name = format!("{case}.{ext}");
            let src = dir.join(&name);
            println!("cargo:rerun-if-changed={}", src.display());
            let bytes = fs::read(&src).unwrap_or_default();
            fs::write(out.join(&name), bytes).expect("write golden file");
        }
    }
}
