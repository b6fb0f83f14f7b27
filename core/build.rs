//! With the `step` feature: compile `src/mesh/step.cpp` against OpenCASCADE and link its toolkits.
//! Without it: nothing.

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-changed=src/mesh/step.cpp");
    println!("cargo:rerun-if-env-changed=OCCT_INCLUDE_DIR");
    println!("cargo:rerun-if-env-changed=OCCT_LIB_DIR");
    #[cfg(feature = "step")]
    step();
}

#[cfg(feature = "step")]
fn step() {
    let include = std::env::var("OCCT_INCLUDE_DIR").unwrap_or("/usr/include/opencascade".into());
    if !std::path::Path::new(&include)
        .join("STEPControl_Reader.hxx")
        .exists()
    {
        eprintln!(
            "error: the `step` feature needs OpenCASCADE's headers (STEPControl_Reader.hxx) in \
             {include}: install Debian's libocct-data-exchange-dev and \
             libocct-modeling-algorithms-dev, or set OCCT_INCLUDE_DIR and OCCT_LIB_DIR"
        );
        std::process::exit(1);
    }
    cc::Build::new()
        .cpp(true)
        .std("c++17")
        .include(&include)
        .file("src/mesh/step.cpp")
        // OpenCASCADE's own headers warn (deprecated std::iterator); RIS's code is checked by
        // the Rust side's tests.
        .warnings(false)
        .flag_if_supported("-Wno-deprecated-declarations")
        .compile("ris_step");
    if let Ok(dir) = std::env::var("OCCT_LIB_DIR") {
        println!("cargo:rustc-link-search=native={dir}");
    }
    for lib in [
        "TKSTEP",
        "TKSTEPAttr",
        "TKSTEP209",
        "TKSTEPBase",
        "TKXSBase",
        "TKMesh",
        "TKShHealing",
        "TKTopAlgo",
        "TKGeomAlgo",
        "TKBRep",
        "TKGeomBase",
        "TKG3d",
        "TKG2d",
        "TKMath",
        "TKernel",
    ] {
        println!("cargo:rustc-link-lib=dylib={lib}");
    }
}
