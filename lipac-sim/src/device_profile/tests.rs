use super::*;
use crate::memory::{blas_bytes, build_estimate, tlas_bytes};

fn profiles_dir() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("profiles")
}

fn h200() -> DeviceProfile {
    DeviceProfile::load(&profiles_dir().join("nvidia-h200.json")).unwrap()
}

#[test]
fn builtin_is_todays_model_exactly() {
    let p = DeviceProfile::builtin();
    p.validate().unwrap();
    assert!(p.is_builtin());
    let m = p.memory_model();
    assert_eq!(m, MemoryModel::default());
    for n in (0..300).chain([4096, 131_072, 1 << 24, u64::from(u32::MAX)]) {
        assert_eq!(m.blas_bytes(n), blas_bytes(n), "BLAS of {n}");
        assert_eq!(m.tlas_bytes(n), tlas_bytes(n), "TLAS of {n}");
        assert_eq!(m.build_estimate(n), build_estimate(n), "estimate of {n}");
    }
    assert_eq!(
        m.tlas_bytes_per_instance(),
        crate::memory::TLAS_BYTES_PER_INSTANCE
    );
    assert_eq!(p.gpu_model(), GpuModel::PUBLISHED);
    // Round trip through JSON.
    let back = DeviceProfile::from_json(&p.to_json()).unwrap();
    assert!(back.is_builtin());
}

#[test]
fn shipped_profiles_load_and_differ_from_the_builtin() {
    let mut names = Vec::new();
    for entry in std::fs::read_dir(profiles_dir()).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().and_then(|e| e.to_str()) != Some("json") {
            continue;
        }
        let p = DeviceProfile::load(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        assert!(!p.is_builtin(), "{}", path.display());
        names.push(p.name.clone());
    }
    names.sort();
    assert_eq!(names, ["lavapipe", "nvidia-h200"]);
}

#[test]
fn h200_profile_is_the_transcribed_figures() {
    let p = h200();
    assert!(
        p.source.to_lowercase().contains("transcribed"),
        "{}",
        p.source
    );
    let m = p.memory_model();
    // 92 B per triangle built, 76 compacted; 161 B per TLAS instance.
    assert_eq!(m.blas_bytes(512), 92 * 512);
    assert_eq!(m.blas_bytes(131_072), 92 * 131_072);
    assert_eq!(m.blas_bytes(10_000), 92 * 10_000);
    assert_eq!(m.blas_compacted_bytes(10_000), 76 * 10_000);
    assert_eq!(m.tlas_bytes_per_instance(), 161);
    assert_eq!(m.tlas_bytes(1_000_000), 161_000_000);
    // 60 Mtri/s for 256 x 512 triangles, 538 Mtri/s for 131k-triangle
    // meshes: the fit gives them back.
    let g = p.gpu_model();
    let per_build = |tris: u64| g.frame(tris, 1, 0, 0, 0).blas_build_ms * 1e-3;
    let small = 256.0 * 512.0 / (256.0 * per_build(512));
    let large = 131_072.0 / per_build(131_072);
    assert!((small / 60e6 - 1.0).abs() < 0.01, "{small}");
    assert!((large / 538e6 - 1.0).abs() < 0.01, "{large}");
    // TLAS of 1M instances in 1.69 ms.
    assert!((g.frame(0, 0, 0, 1_000_000, 0).tlas_build_ms - 1.69).abs() < 1e-9);
    // Refits and rays: the published rates (no profile measures them).
    assert_eq!(
        g.refit_triangles_per_s,
        GpuModel::PUBLISHED.refit_triangles_per_s
    );
    assert_eq!(g.rays_per_s, GpuModel::PUBLISHED.rays_per_s);
}

fn base_json() -> serde_json::Value {
    serde_json::from_str(&h200().to_json()).unwrap()
}

fn refused(v: &serde_json::Value) -> String {
    match DeviceProfile::from_json(&v.to_string()) {
        Ok(_) => panic!("accepted {v}"),
        Err(e) => {
            assert!(matches!(e, SimError::DeviceProfile(_)), "{e:?}");
            e.to_string()
        }
    }
}

/// A change to a valid profile's JSON.
type Mutation = Box<dyn Fn(&mut serde_json::Value)>;

#[test]
fn malformed_profiles_are_clear_errors() {
    assert!(DeviceProfile::from_json(&base_json().to_string()).is_ok());
    let cases: Vec<(Mutation, &str)> = vec![
        (
            Box::new(|v| v["format"] = "something else".into()),
            "format",
        ),
        (Box::new(|v| v["version"] = 2.into()), "version 2"),
        (Box::new(|v| v["name"] = "".into()), "name"),
        (Box::new(|v| v["source"] = " ".into()), "source"),
        (Box::new(|v| v["extra"] = 1.into()), "unknown field"),
        (
            Box::new(|v| v["blas"]["sizes"] = serde_json::json!([])),
            "blas.sizes",
        ),
        (
            Box::new(|v| v["blas"]["sizes"][0]["built_bytes"] = 0.into()),
            "blas.sizes[0]",
        ),
        (
            Box::new(|v| v["blas"]["sizes"][1]["triangles"] = 512.into()),
            "strictly increase",
        ),
        (
            Box::new(|v| v["blas"]["sizes"][1]["built_bytes"] = 10.into()),
            "must not decrease",
        ),
        (
            Box::new(|v| v["blas"]["sizes"][0]["compacted_bytes"] = 1_000_000.into()),
            "compacted",
        ),
        (
            Box::new(|v| v["blas"]["sizes"][0]["built_bytes"] = u64::MAX.into()),
            "bytes each",
        ),
        (
            Box::new(|v| v["blas"]["builds"][0]["ms"] = (-1.0).into()),
            "blas.builds[0].ms",
        ),
        (
            Box::new(|v| v["blas"]["builds"][0]["meshes"] = 0.into()),
            "meshes",
        ),
        (
            Box::new(|v| v["tlas"]["sizes"][0]["instances"] = 0.into()),
            "tlas.sizes[0]",
        ),
        (
            Box::new(|v| v["tlas"]["builds"][0]["ms"] = 0.0.into()),
            "tlas.builds[0].ms",
        ),
        (Box::new(|v| v["blas"]["min_bytes"] = 0.into()), "min_bytes"),
        (
            Box::new(|v| {
                let many: Vec<serde_json::Value> = (1..=300u64)
                    .map(|i| serde_json::json!({"instances": i, "bytes": 200 * i}))
                    .collect();
                v["tlas"]["sizes"] = many.into();
            }),
            "300 entries",
        ),
        (Box::new(|v| v["tlas"] = "no".into()), "not a profile"),
    ];
    for (mutate, says) in cases {
        let mut v = base_json();
        mutate(&mut v);
        let e = refused(&v);
        assert!(e.contains(says), "{e} should say {says}");
    }
    // NaN is not JSON; a string where a number goes is refused by the parser.
    let e = DeviceProfile::from_json("{\"format\": 1}")
        .unwrap_err()
        .to_string();
    assert!(e.contains("not a profile"), "{e}");
    assert!(DeviceProfile::from_json("not json").is_err());
}

#[test]
fn load_names_the_file_and_bounds_its_size() {
    let dir = std::env::temp_dir().join(format!("lipac-profile-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let missing = dir.join("missing.json");
    let e = DeviceProfile::load(&missing).unwrap_err().to_string();
    assert!(e.contains("missing.json"), "{e}");
    let big = dir.join("big.json");
    std::fs::write(&big, vec![b' '; MAX_PROFILE_BYTES as usize + 10]).unwrap();
    let e = DeviceProfile::load(&big).unwrap_err().to_string();
    assert!(e.contains("larger than"), "{e}");
    let bad = dir.join("bad.json");
    std::fs::write(&bad, "{\"format\": \"lipac-device-profile\"}").unwrap();
    let e = DeviceProfile::load(&bad).unwrap_err().to_string();
    assert!(e.contains("bad.json") && e.contains("missing field"), "{e}");
    assert!(DeviceProfile::load_or_builtin(None).unwrap().is_builtin());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn fit_recovers_a_cost_per_build_and_a_rate() {
    // 10 µs per build + 1 ns per triangle.
    let pts: Vec<(f64, f64)> = [512.0, 8192.0, 131_072.0]
        .iter()
        .map(|&n| (n, 10e-6 + n * 1e-9))
        .collect();
    let (c, s) = fit_affine(&pts).unwrap();
    assert!(
        (c - 10e-6).abs() < 1e-12 && (s - 1e-9).abs() < 1e-15,
        "{c} {s}"
    );
    // One point: the rate alone.
    let (c, s) = fit_affine(&pts[..1]).unwrap();
    assert_eq!(c, 0.0);
    assert!((s - pts[0].1 / 512.0).abs() < 1e-18);
    // Larger meshes faster per build (no positive slope): rate alone.
    let (c, _) = fit_affine(&[(512.0, 2e-5), (1024.0, 1e-5)]).unwrap();
    assert_eq!(c, 0.0);
    assert!(fit_affine(&[]).is_none());
}

#[test]
fn a_profile_changes_the_memory_model() {
    let m = h200().memory_model();
    let b = MemoryModel::default();
    assert!(m.blas_bytes(10_000) < b.blas_bytes(10_000));
    assert!(m.tlas_bytes(10_000) < b.tlas_bytes(10_000));
    assert_ne!(h200().describe(), DeviceProfile::builtin().describe());
}
