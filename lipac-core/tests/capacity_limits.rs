//! Room a caller asks for is an error when it cannot be had, never an
//! abort: `Manager::reserve(usize::MAX)` (2^24 slots, about 3.7 GB), a
//! read-back ring of `u32::MAX` slots, a hashed index of 2^31 buckets, a
//! grid of 4.3 billion hitbox records.
//!
//! The checks run in a child process of this test binary under an
//! address-space limit of 2 GB (`ulimit -v`, through `sh`), where each of
//! those allocations fails (it aborted the process before); the Manager
//! stays usable after its refused reservation.
#![cfg(unix)]

use glam::{Affine3A, Vec3};
use lipac_core::error::CoreError;
use lipac_core::manager::ManagerError;
use lipac_core::{
    Aabb, BuildEstimate, GridConfig, HashedConfig, HashedHitboxes, HitboxGrid, InstanceDesc,
    Manager, ManagerConfig, MeshCatalog, MeshId, MeshLod, ReadbackRing,
};

const CHILD: &str = "LIPAC_CAPACITY_LIMITS_CHILD";
/// The address-space limit of the child, KiB (2 GB).
const LIMIT_KIB: u64 = 2_000_000;

fn catalog() -> MeshCatalog {
    let mut c = MeshCatalog::new();
    let lod = MeshLod {
        estimate: BuildEstimate {
            primitives: 12,
            result_bytes: 4096,
            build_scratch_bytes: 1024,
            update_scratch_bytes: 256,
        },
        data_bytes: 32,
    };
    c.insert(MeshId(1), vec![lod]).unwrap();
    c
}

fn grid(cells_per_side: f64) -> HitboxGrid {
    HitboxGrid::new(GridConfig {
        min: [0.0, 0.0],
        max: [cells_per_side, cells_per_side],
        cell_size: 1.0,
    })
    .unwrap()
}

fn out_of_memory(e: &ManagerError) -> bool {
    matches!(e, ManagerError::Core(CoreError::OutOfMemory { .. }))
}

/// The checks, under the limit.
fn child() {
    let mut m = Manager::new(grid(64.0), ManagerConfig::new(7), catalog()).unwrap();
    let e = m.reserve(usize::MAX).unwrap_err();
    assert!(out_of_memory(&e), "{e}");
    assert!(e.to_string().contains("cannot reserve room"), "{e}");
    // Still usable.
    m.reserve(100).unwrap();
    let aabb = Aabb::new(Vec3::splat(1.0), Vec3::splat(2.0));
    m.register(InstanceDesc::new(MeshId(1), Affine3A::IDENTITY, aabb))
        .unwrap();

    // 65535 x 65535 cells: 4.3 billion hitbox records.
    let e = Manager::new(grid(65535.0), ManagerConfig::new(7), catalog()).unwrap_err();
    assert!(out_of_memory(&e), "{e}");

    let e = ReadbackRing::new(u32::MAX).unwrap_err();
    assert!(matches!(e, CoreError::OutOfMemory { .. }), "{e}");

    let e = HashedHitboxes::new(HashedConfig {
        initial_buckets: 1 << 31,
        ..HashedConfig::default()
    })
    .unwrap_err();
    assert!(matches!(e, CoreError::OutOfMemory { .. }), "{e}");
    println!("capacity limits: ok");
}

#[test]
fn capacities_beyond_memory_are_errors_not_aborts() {
    if std::env::var_os(CHILD).is_some() {
        child();
        return;
    }
    let exe = std::env::current_exe().unwrap();
    let out = std::process::Command::new("sh")
        .arg("-c")
        .arg(format!("ulimit -v {LIMIT_KIB} && exec \"$0\" \"$@\""))
        .arg(&exe)
        .args([
            "--exact",
            "capacities_beyond_memory_are_errors_not_aborts",
            "--nocapture",
            "--test-threads=1",
        ])
        .env(CHILD, "1")
        .env("RUST_BACKTRACE", "0")
        .output()
        .expect("sh runs");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(
        out.status.success() && text.contains("capacity limits: ok"),
        "under ulimit -v {LIMIT_KIB}: {:?}\n{text}",
        out.status
    );
}
