//! The committed SPIR-V is what `shaders/build.sh`'s command makes of the
//! GLSL sources (so a shader edit without recompiling fails here).

use std::path::Path;
use std::process::Command;

#[test]
fn committed_spirv_matches_glsl_sources() {
    let required = std::env::var("LIPAC_REQUIRE_VULKAN").is_ok_and(|v| v == "1");
    let shaders = Path::new(env!("CARGO_MANIFEST_DIR")).join("shaders");
    let probe = Command::new("glslangValidator").arg("--version").output();
    if probe.is_err() {
        assert!(
            !required,
            "glslangValidator missing (apt-get install glslang-tools)"
        );
        eprintln!(
            "SKIPPED committed_spirv_matches_glsl_sources: glslangValidator not installed \
             (apt-get install glslang-tools; LIPAC_REQUIRE_VULKAN=1 makes this fail)"
        );
        return;
    }
    let out_dir = std::env::temp_dir().join(format!("lipac-spv-{}", std::process::id()));
    std::fs::create_dir_all(&out_dir).unwrap();
    let mut checked = 0;
    for entry in std::fs::read_dir(&shaders).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().and_then(|e| e.to_str()) != Some("comp") {
            continue;
        }
        let stem = path.file_stem().unwrap().to_str().unwrap().to_owned();
        let fresh = out_dir.join(format!("{stem}.spv"));
        // The same command as shaders/build.sh, run from the shaders directory.
        let status = Command::new("glslangValidator")
            .current_dir(&shaders)
            .args(["--target-env", "vulkan1.2", "-I."])
            .arg("-o")
            .arg(&fresh)
            .arg(path.file_name().unwrap())
            .output()
            .unwrap();
        assert!(
            status.status.success(),
            "{stem}: {}",
            String::from_utf8_lossy(&status.stdout)
        );
        let committed = std::fs::read(shaders.join("spv").join(format!("{stem}.spv")))
            .unwrap_or_else(|e| panic!("{stem}.spv not committed: {e}"));
        let fresh = std::fs::read(&fresh).unwrap();
        assert!(
            committed == fresh,
            "shaders/spv/{stem}.spv is stale: run lipac-vk/shaders/build.sh and commit"
        );
        checked += 1;
    }
    let _ = std::fs::remove_dir_all(&out_dir);
    assert_eq!(
        checked,
        lipac_vk::shaders::ALL_SPV.len(),
        "every .comp shader is embedded (shaders::ALL_SPV) and every embedded one has a source"
    );
    for (name, embedded) in lipac_vk::shaders::ALL_SPV {
        assert_eq!(
            std::fs::read(shaders.join(format!("spv/{name}.spv"))).unwrap(),
            embedded,
            "the embedded SPIR-V of {name} is the committed file"
        );
    }
}
