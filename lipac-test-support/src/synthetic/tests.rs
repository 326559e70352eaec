use lipac_core::blas_ids::{InstanceKey, Lod};
use lipac_core::build_plan::{
    BlasGeometry, BuildBudgets, BuildEstimate, BuildScheduler, InstanceBlasRequest, SchedulerConfig,
};
use lipac_core::MeshId;

use super::*;

const FIF: u32 = 2;

fn scheduler() -> BuildScheduler {
    let mut config = SchedulerConfig::default();
    config.cache.frames_in_flight = FIF;
    BuildScheduler::new(config).unwrap()
}

fn request(mesh: u32) -> InstanceBlasRequest {
    InstanceBlasRequest {
        geometry: BlasGeometry::Shared {
            mesh: MeshId(mesh),
            variant: 0,
            compactable: false,
        },
        lod: Lod(0),
        estimate: BuildEstimate {
            primitives: 10,
            result_bytes: 1000 + u64::from(mesh),
            build_scratch_bytes: 100,
            update_scratch_bytes: 10,
        },
        hits: 10,
        in_frustum: true,
    }
}

/// One instance built, traced, released: returns the device afterwards
/// and the frame the free came in.
fn life_cycle(device_fif: u32) -> (SyntheticDevice, u64) {
    let mut s = scheduler();
    let mut dev = SyntheticDevice::new(device_fif, 0);
    s.begin_frame(1).unwrap();
    s.activate(InstanceKey(0), request(3)).unwrap();
    let plan = s.plan(&BuildBudgets::default()).unwrap();
    let owed = dev.execute_blas(&plan);
    let id = plan.builds().next().unwrap().id;
    let built = Owed::Built {
        id,
        bytes: 1003,
        compactable: false,
    };
    assert_eq!(owed, [built]);
    assert_eq!((dev.builds, dev.compactions), (1, 0));
    dev.acknowledge(&mut s, built).unwrap();
    let address = s.blas_address(InstanceKey(0)).unwrap();
    assert_eq!(dev.live.get(&address), Some(&1003));
    // A refused acknowledgement (a duplicate) creates nothing.
    assert!(dev.acknowledge(&mut s, built).is_err());
    assert_eq!(dev.live.len(), 1);
    dev.traced(address, 1);
    s.deactivate(InstanceKey(0)).unwrap();
    s.trim_cache();
    let mut freed_at = 0;
    for f in 2..=10 {
        s.begin_frame(f).unwrap();
        let plan = s.plan(&BuildBudgets::default()).unwrap();
        if !plan.frees.is_empty() {
            freed_at = f;
        }
        assert!(dev.execute_blas(&plan).is_empty());
    }
    (dev, freed_at)
}

#[test]
fn a_structure_lives_from_its_acknowledgement_until_its_free() {
    let (dev, freed_at) = life_cycle(FIF);
    assert!(dev.live.is_empty(), "{:?}", dev.live);
    assert_eq!(dev.frees, 1);
    // Used by frame 1: freed from frame 1 + FIF on.
    assert!(freed_at > u64::from(FIF), "freed at {freed_at}");
}

#[test]
#[should_panic(expected = "freed at")]
fn a_free_while_a_frame_in_flight_may_use_it_fails() {
    // The device thinks more frames are in flight than the scheduler.
    life_cycle(FIF + 5);
}

#[test]
#[should_panic(expected = "TLAS uses a dead BLAS")]
fn tracing_a_dead_structure_fails() {
    SyntheticDevice::new(FIF, 0).traced(0x100, 1);
}

#[test]
fn acknowledgements_go_to_a_bare_scheduler_and_arrive_when_due() {
    let mut s = scheduler();
    let mut dev = SyntheticDevice::new(FIF, 0);
    let mut queue = AckQueue::new();
    s.begin_frame(1).unwrap();
    for k in 0..3 {
        s.activate(InstanceKey(k), request(k)).unwrap();
    }
    let plan = s.plan(&BuildBudgets::default()).unwrap();
    let owed = dev.execute_blas(&plan);
    assert_eq!(owed.len(), 3);
    for (i, o) in owed.into_iter().enumerate() {
        queue.push(1 + i as u64, o);
    }
    // Frame 2: two are due; the second of them is held back.
    let mut answers = [true, false].into_iter();
    let due = queue.take_due(2, || answers.next().unwrap());
    assert_eq!((due.len(), queue.len()), (1, 2));
    for o in due {
        dev.acknowledge(&mut s, o).unwrap();
    }
    assert_eq!(dev.live.len(), 1);
    let rest = queue.take_due(3, || true);
    assert!(queue.is_empty());
    for o in rest {
        dev.acknowledge(&mut s, o).unwrap();
    }
    for k in 0..3 {
        let a = s.blas_address(InstanceKey(k)).unwrap();
        assert_eq!(dev.live[&a], 1000 + u64::from(k));
    }
}

#[test]
fn immediate_acks_acknowledge_every_build_at_its_estimate() {
    let mut s = scheduler();
    s.begin_frame(1).unwrap();
    s.activate(InstanceKey(0), request(0)).unwrap();
    s.activate(InstanceKey(1), request(1)).unwrap();
    let plan = s.plan(&BuildBudgets::default()).unwrap();
    let acks = ImmediateAcks::new(0x1000).acks(&plan);
    let built: Vec<(u64, u64)> = acks
        .iter()
        .map(|a| match *a {
            Ack::Built {
                result_bytes,
                address,
                ..
            } => (result_bytes, address),
            _ => panic!("{a:?}"),
        })
        .collect();
    let mut sizes: Vec<u64> = built.iter().map(|b| b.0).collect();
    sizes.sort_unstable();
    assert_eq!(sizes, [1000, 1001]);
    assert_eq!(
        built.iter().map(|b| b.1).collect::<Vec<_>>(),
        [0x1000, 0x2000]
    );
    let later = ImmediateAcks::after(0x10_0000, 0x1000).acks(&plan);
    let addresses: Vec<u64> = later
        .iter()
        .map(|a| match *a {
            Ack::Built { address, .. } => address,
            _ => 0,
        })
        .collect();
    assert_eq!(addresses, [0x10_1000, 0x10_2000]);
    for a in acks {
        s.ack(a).unwrap();
    }
    assert!(s.blas_address(InstanceKey(0)).is_some());
    assert!(s.blas_address(InstanceKey(1)).is_some());
}

#[test]
fn late_acks_arrive_within_their_delays() {
    let mut s = scheduler();
    let mut late = LateAcks::new(FIF, 0);
    let mut rng = crate::SplitMix64::new(5);
    s.begin_frame(1).unwrap();
    for k in 0..8 {
        s.activate(InstanceKey(k), request(k)).unwrap();
    }
    let plan = s.plan(&BuildBudgets::default()).unwrap();
    late.execute_blas(&plan, &mut rng);
    assert_eq!(late.queue.len(), 8);
    // Nothing arrives before its frame; everything by frame 1 + 3 when all
    // due ones are asked for.
    late.deliver(&mut s, 0, &mut rng, true);
    assert_eq!(late.queue.len(), 8);
    late.deliver(&mut s, 4, &mut rng, true);
    assert!(late.queue.is_empty());
    for k in 0..8 {
        let a = s.blas_address(InstanceKey(k)).unwrap();
        let bytes = late.device.live[&a];
        let estimate = 1000 + u64::from(k);
        assert!(bytes <= estimate && bytes >= estimate * 3 / 4, "{bytes}");
    }
}
