//! The committed SPIR-V is what `shaders/build.sh`'s command makes of the
//! GLSL sources (so a shader edit without recompiling fails here).

use std::path::Path;
use std::process::Command;

/// The shader sources' directory (compiled in; the harness runs this test
/// only where it exists and glslangValidator runs).
pub fn shader_dir() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("shaders")
}

/// Source file extensions build.sh compiles.
const STAGES: [&str; 5] = ["comp", "rgen", "rchit", "rahit", "rmiss"];

pub fn committed_spirv_matches_glsl_sources() {
    let shaders = shader_dir();
    let out_dir = std::env::temp_dir().join(format!("lipac-spv-{}", std::process::id()));
    std::fs::create_dir_all(&out_dir).unwrap();
    let mut checked = 0;
    for entry in std::fs::read_dir(&shaders).unwrap() {
        let path = entry.unwrap().path();
        let Some(ext) = path.extension().and_then(|e| e.to_str()) else {
            continue;
        };
        if !STAGES.contains(&ext) {
            continue;
        }
        // build.sh's names: NAME.comp -> NAME.spv, NAME.STAGE -> NAME.STAGE.spv.
        let file = path.file_name().unwrap().to_str().unwrap().to_owned();
        let stem = if ext == "comp" {
            path.file_stem().unwrap().to_str().unwrap().to_owned()
        } else {
            file
        };
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
        "every shader source is embedded (shaders::ALL_SPV) and every embedded one has a source"
    );
    for (name, embedded) in lipac_vk::shaders::ALL_SPV {
        assert_eq!(
            std::fs::read(shaders.join(format!("spv/{name}.spv"))).unwrap(),
            embedded,
            "the embedded SPIR-V of {name} is the committed file"
        );
    }
}
