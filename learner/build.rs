//! Gives every binary of this crate (the `learner` binary, tests, benches) a RUNPATH to libtorch,
//! so they start without LD_LIBRARY_PATH: the local libtorch this crate was built against
//! (`LIBTORCH`), and the places a GPU machine's Python wheel of torch usually lives.

fn main() {
    println!("cargo:rerun-if-env-changed=LIBTORCH");
    println!("cargo:rerun-if-changed=build.rs");
    let mut dirs = Vec::new();
    if let Ok(root) = std::env::var("LIBTORCH") {
        let lib = std::path::Path::new(&root).join("lib");
        println!("cargo:rustc-env=GESTHOR_LIBTORCH_LIB={}", lib.display());
        dirs.push(lib.display().to_string());
    } else {
        println!("cargo:rustc-env=GESTHOR_LIBTORCH_LIB=");
    }
    dirs.push("/usr/local/lib/python3.12/dist-packages/torch/lib".into());
    dirs.push("/usr/lib/python3/dist-packages/torch/lib".into());
    for d in dirs {
        println!("cargo:rustc-link-arg=-Wl,-rpath,{d}");
    }
}
