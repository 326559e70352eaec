//! Regressions of issue 12 ("no overflow in any counter, no stale or foreign
//! state"): each test reproduces one finding through the public API and
//! checks that the call is refused with an error (or handled exactly) and
//! that nothing changed. The TLSF serial wrap is covered by the allocator's
//! unit tests (it needs a hook to skip 2^32 allocations).

use glam::{Affine3A, Vec3};
use lipac_core::blas_cache::{BlasCache, BlasError, CacheConfig, MAX_BLAS_BYTES, MAX_FRAME};
use lipac_core::blas_ids::{BlasKey, BuildId, InstanceKey, Lod};
use lipac_core::build_plan::{
    BlasGeometry, BuildBudgets, BuildEstimate, BuildPlanError, BuildScheduler, InstanceBlasRequest,
    SchedulerConfig,
};
use lipac_core::error::CoreError;
use lipac_core::grid::{GridConfig, HitboxGrid};
use lipac_core::instance::InstanceDesc;
use lipac_core::layout::MAX_SLOTS;
use lipac_core::manager::{
    FrameBudgets, Manager, ManagerConfig, ManagerError, MeshCatalog, MeshLod, MAX_LOD_DATA_BYTES,
};
use lipac_core::math::Aabb;
use lipac_core::registry::{InstanceRegistry, RegistryConfig};
use lipac_core::MeshId;

fn grid() -> HitboxGrid {
    HitboxGrid::new(GridConfig {
        min: [0.0, 0.0],
        max: [64.0, 64.0],
        cell_size: 16.0,
    })
    .unwrap()
}

fn desc(x: f32, mesh: u32) -> InstanceDesc {
    InstanceDesc::new(
        MeshId(mesh),
        Affine3A::from_translation(Vec3::new(x, 0.0, 8.0)),
        Aabb::new(Vec3::new(x - 1.0, 0.0, 7.0), Vec3::new(x + 1.0, 2.0, 9.0)),
    )
}

fn lod(triangles: u64, data_bytes: u64) -> MeshLod {
    MeshLod {
        estimate: BuildEstimate {
            primitives: triangles,
            result_bytes: triangles * 64,
            build_scratch_bytes: triangles * 16,
            update_scratch_bytes: triangles * 4,
        },
        data_bytes,
    }
}

fn manager() -> Manager {
    let mut catalog = MeshCatalog::new();
    catalog.insert(MeshId(1), vec![lod(100, 64)]).unwrap();
    Manager::new(grid(), ManagerConfig::new(0xC0BE), catalog).unwrap()
}

fn key(mesh: u32) -> BlasKey {
    BlasKey {
        mesh: MeshId(mesh),
        lod: Lod(0),
        variant: 0,
    }
}

// ---------------------------------------------------------------- finding 1

/// `ack_built(b, u64::MAX, addr)` while another build was in flight
/// panicked in debug ("attempt to add with overflow") and wrapped the
/// memory statistics in release.
#[test]
fn ack_built_with_u64_max_bytes_is_refused_and_changes_nothing() {
    let mut c = BlasCache::new(CacheConfig::default()).unwrap();
    c.begin_frame(1).unwrap();
    let a = c.acquire_shared(key(1), false).unwrap().id();
    let b = c.acquire_shared(key(2), false).unwrap().id();
    assert!(c.try_reserve_build(a, 1000, 100, BuildId(1)).unwrap());
    assert!(c.try_reserve_build(b, 2000, 100, BuildId(2)).unwrap());
    let before = c.stats();
    let err = c.ack_built(BuildId(1), u64::MAX, 0xA000).unwrap_err();
    assert!(matches!(err, BlasError::InvalidAck(_)), "{err:?}");
    assert_eq!(c.stats(), before, "a refused ack changed the statistics");
    assert_eq!(c.in_flight_ops(), 2);
    // The build can still be acknowledged with a real size.
    c.ack_built(BuildId(1), 900, 0xA000).unwrap();
    c.ack_built(BuildId(2), MAX_BLAS_BYTES + 1, 0xB000)
        .unwrap_err();
    c.ack_built(BuildId(2), 1800, 0xB000).unwrap();
    assert_eq!(c.stats().shared_bytes, 2700);
    assert_eq!(c.stats().scratch_in_use, 0);
}

/// Byte counts at the documented limit add up exactly, however many there
/// are (no counter wraps even when their sum exceeds `u64::MAX`).
#[test]
fn blas_byte_counters_never_wrap() {
    let mut c = BlasCache::new(CacheConfig {
        memory_budget: u64::MAX,
        ..CacheConfig::default()
    })
    .unwrap();
    c.begin_frame(1).unwrap();
    // Reserve many maximal builds: their sum passes u64::MAX only if the
    // budget check lets it, which it must not.
    let mut reserved = 0u128;
    for i in 0..70_000u32 {
        let id = c.acquire_shared(key(i), false).unwrap().id();
        let fits = c
            .try_reserve_build(
                id,
                MAX_BLAS_BYTES,
                MAX_BLAS_BYTES,
                BuildId(u64::from(i) + 1),
            )
            .unwrap();
        if fits {
            reserved += u128::from(MAX_BLAS_BYTES);
        }
        assert!(reserved <= u128::from(u64::MAX));
        if !fits {
            break;
        }
    }
    let s = c.stats();
    assert_eq!(u128::from(s.shared_bytes), reserved);
    assert_eq!(u128::from(c.live_bytes()), reserved);
    assert_eq!(u128::from(s.scratch_in_use), reserved);
    assert!(reserved > u128::from(u64::MAX) - u128::from(MAX_BLAS_BYTES) * 2);
}

// ---------------------------------------------------------------- finding 2

/// Frame numbers near `u64::MAX` were accepted by `begin_frame`, then
/// `plan` panicked (`frame + slot`) and deferred frees overflowed
/// (`frame + frames_in_flight`).
#[test]
fn frames_past_max_frame_are_refused_and_max_frame_plans() {
    let mut c = BlasCache::new(CacheConfig::default()).unwrap();
    assert_eq!(
        c.begin_frame(u64::MAX),
        Err(BlasError::FrameOutOfRange {
            frame: u64::MAX,
            max: MAX_FRAME
        })
    );
    assert_eq!(c.frame(), 0, "a refused frame was started");

    let mut s = BuildScheduler::new(SchedulerConfig::default()).unwrap();
    assert!(matches!(
        s.begin_frame(u64::MAX - 1),
        Err(BuildPlanError::Cache(BlasError::FrameOutOfRange { .. }))
    ));
    // The last valid frame: a unique instance (periodic rebuild uses
    // `frame + slot`) and a deferred free (`frame + frames_in_flight`).
    s.begin_frame(MAX_FRAME - 1).unwrap();
    let estimate = BuildEstimate {
        primitives: 10,
        result_bytes: 100,
        build_scratch_bytes: 100,
        update_scratch_bytes: 10,
    };
    let unique = InstanceBlasRequest {
        geometry: BlasGeometry::Unique { mesh: MeshId(1) },
        lod: Lod(0),
        estimate,
        hits: 0,
        in_frustum: false,
    };
    // Keys are GPU slots: the largest is accepted, one beyond is refused.
    assert_eq!(
        s.activate(InstanceKey(MAX_SLOTS), unique),
        Err(BuildPlanError::KeyOutOfRange(InstanceKey(MAX_SLOTS)))
    );
    s.activate(InstanceKey(MAX_SLOTS - 1), unique).unwrap();
    let plan = s.plan(&BuildBudgets::default()).unwrap();
    let b = *plan.builds().next().unwrap();
    s.ack_built(b.id, 100, 0xA000).unwrap();
    s.begin_frame(MAX_FRAME).unwrap();
    let plan = s.plan(&BuildBudgets::default()).unwrap();
    assert_eq!(plan.updates().count(), 1, "the unique BLAS is refit");
    s.deactivate(InstanceKey(MAX_SLOTS - 1)).unwrap();
    assert_eq!(s.stats().cache.pending_frees, 1);
    assert!(s.begin_frame(MAX_FRAME + 1).is_err());

    let mut m = manager();
    m.begin_frame(5).unwrap();
    let err = m.begin_frame(u64::MAX).unwrap_err();
    assert!(
        matches!(
            err,
            ManagerError::Build(BuildPlanError::Cache(BlasError::FrameOutOfRange { .. }))
        ),
        "{err:?}"
    );
    assert_eq!(m.frame(), Some(5));
    // Still usable: the refused frame left the command loop in frame 5.
    let mut tlas = Vec::new();
    m.plan(&FrameBudgets::default()).unwrap();
    m.assemble(&mut tlas).unwrap();
    m.process_feedback().unwrap();
    m.take_commands().unwrap();
    m.begin_frame(MAX_FRAME).unwrap();
    m.plan(&FrameBudgets::default()).unwrap();
}

// ---------------------------------------------------------------- finding 4

/// A handle of registry B removed registry A's instance with `Ok`.
#[test]
fn instance_handle_of_another_registry_is_refused() {
    let mut a = InstanceRegistry::new(grid(), RegistryConfig::default()).unwrap();
    let mut b = InstanceRegistry::new(grid(), RegistryConfig::default()).unwrap();
    let ha = a.register(desc(8.0, 1)).unwrap();
    let hb = b.register(desc(8.0, 1)).unwrap();
    assert_ne!(ha, hb, "handles of two registries compare unequal");
    assert!(!a.contains(hb));
    assert!(matches!(a.slot(hb), Err(CoreError::StaleHandle { .. })));
    assert!(matches!(a.remove(hb), Err(CoreError::StaleHandle { .. })));
    assert_eq!(a.len(), 1, "a foreign handle removed an instance");
    assert_eq!(a.slot(ha).unwrap(), 0);
    a.remove(ha).unwrap();
    assert!(b.contains(hb));
    // The owner costs 4 bytes: the handle stays small.
    use lipac_core::registry::InstanceHandle;
    assert_eq!(std::mem::size_of::<InstanceHandle>(), 12);
    assert_eq!(std::mem::size_of::<Option<InstanceHandle>>(), 12);
    assert!(!a.contains(InstanceHandle::default()));
}

/// The same through two managers.
#[test]
fn instance_handle_of_another_manager_is_refused() {
    let mut a = manager();
    let mut b = manager();
    let ha = a.register(desc(8.0, 1)).unwrap();
    let hb = b.register(desc(8.0, 1)).unwrap();
    let before = a.stats();
    assert!(a.remove(hb).is_err());
    assert!(a.set_lod(hb, 0).is_err());
    assert!(a.instance(hb).is_err());
    assert_eq!(a.stats(), before);
    assert!(a.instance(ha).is_ok());
    assert!(b.remove(hb).is_ok());
    assert!(a.remove(ha).is_ok());
}

// ---------------------------------------------------------------- finding 5

/// A mesh LOD with `data_bytes = u64::MAX` was accepted; the manager then
/// grew its data buffer to u64::MAX and every later `register` failed.
#[test]
fn mesh_lod_sizes_over_the_limits_are_refused() {
    let mut m = manager();
    let err = m
        .register_mesh(MeshId(2), vec![lod(10, u64::MAX)])
        .unwrap_err();
    assert!(matches!(err, ManagerError::InvalidMesh { .. }), "{err:?}");
    assert!(!m.catalog().contains(MeshId(2)));
    let err = m
        .register_mesh(MeshId(3), vec![lod(10, MAX_LOD_DATA_BYTES + 1)])
        .unwrap_err();
    assert!(matches!(err, ManagerError::InvalidMesh { .. }), "{err:?}");
    let mut huge = lod(10, 64);
    huge.estimate.result_bytes = u64::MAX;
    assert!(m.register_mesh(MeshId(4), vec![huge]).is_err());
    let mut huge = lod(10, 64);
    huge.estimate.build_scratch_bytes = u64::MAX;
    assert!(m.register_mesh(MeshId(5), vec![huge]).is_err());
    // At the limit: accepted, and the manager keeps working.
    m.register_mesh(MeshId(6), vec![lod(10, 1 << 20)]).unwrap();
    let capacity = m.data_allocator().capacity();
    m.register(desc(8.0, 1)).unwrap();
    m.register(desc(20.0, 6)).unwrap();
    assert!(m.data_allocator().capacity() <= capacity.max(1 << 22));
}
