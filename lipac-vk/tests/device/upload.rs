//! `RecordUploader` (upload_records.comp) equals
//! `lipac_core::culling::apply_uploads` bit for bit on random records,
//! ranges, overrides, rate floors and hitbox extents, over several rounds
//! on the same GPU buffers.

use crate::common::*;
use ash::vk;
use lipac_core::culling::{apply_uploads, Uploads};
use lipac_core::hitbox_extents::HitboxExtent;
use lipac_core::layout::{
    instance_bits, HitboxRecord, InstanceArrays, InstanceBounds, InstanceHot, InstanceRecord,
    InstanceState, InstanceTlas,
};
use lipac_test_support::{Rng64, SplitMix64 as Rng};
use lipac_vk::{
    Buffer, InstanceBuffers, MemoryLocation, OneShot, RecordUploader, UploadStats, UploadTargets,
};

/// Records of random bits: every state value incl. 3, NaN/inf floats, any
/// BLAS address.
fn random_records<T: bytemuck::Pod>(rng: &mut Rng, n: usize) -> Vec<T> {
    let mut v = vec![T::zeroed(); n];
    for w in bytemuck::cast_slice_mut::<T, u32>(&mut v) {
        *w = rng.next_u64() as u32;
    }
    v
}

fn random_uploads(rng: &mut Rng, slots: u32, hitboxes: u32) -> Uploads {
    let mut records = Vec::new();
    // Mostly sorted disjoint ranges (what the registry hands out), plus
    // overlapping, empty, reversed and out-of-range ones.
    let mut at = rng.below_u32(8);
    while at < slots {
        let len = 1 + rng.below_u32(12);
        records.push(at..(at + len).min(slots));
        at += len + rng.below_u32(40);
    }
    for _ in 0..rng.below_u32(4) {
        let a = rng.below_u32(slots + 20);
        let b = rng.below_u32(slots + 20);
        records.push(a..b);
    }
    let n_states = rng.below_u32(slots / 2 + 1);
    let state_overrides = (0..n_states)
        .map(|_| {
            let state = match rng.below_u32(3) {
                0 => InstanceState::Inactive,
                1 => InstanceState::Omitted,
                _ => InstanceState::Active,
            };
            // Duplicates (small range) and slots past the buffer.
            (rng.below_u32(slots + 8), state)
        })
        .collect();
    let n_hitboxes = rng.below_u32(hitboxes + 1);
    let hitbox_overrides = (0..n_hitboxes)
        .map(|_| (rng.below_u32(hitboxes + 4), rng.below_u32(2) == 1))
        .collect();
    // Floors of any size (a GPU rate above or below them), duplicates and
    // keys past the buffers.
    let mut floors = |n: u32, keys: u32| -> Vec<(u32, u32)> {
        (0..rng.below_u32(n + 1))
            .map(|_| (rng.below_u32(keys + 4), rng.next_u64() as u32))
            .collect()
    };
    let hitbox_rate_floors = floors(hitboxes, hitboxes);
    let instance_rate_floors = floors(slots / 2, slots);
    // Extents: odd heights (±0, ±inf, ordinary; the CPU never stores NaN),
    // any cost word, duplicates (the last wins) and indices past the buffer.
    let heights = [
        0.0,
        -0.0,
        f32::INFINITY,
        f32::NEG_INFINITY,
        -3.5,
        1.0e30,
        7.25,
    ];
    let hitbox_extents = (0..rng.below_u32(hitboxes + 1))
        .map(|_| {
            let mut h = || heights[rng.below_u32(heights.len() as u32) as usize];
            let (min_y, max_y) = (h(), h());
            let index = rng.below_u32(hitboxes + 4);
            let cost = rng.next_u64() as u32;
            (index, HitboxExtent { min_y, max_y, cost })
        })
        .collect();
    Uploads {
        hitbox_extents,
        records,
        state_overrides,
        hitbox_overrides,
        hitbox_rate_floors,
        instance_rate_floors,
    }
}

pub fn gpu_upload_equals_apply_uploads() {
    let h = headless("gpu_upload_equals_apply_uploads");
    let ctx = h.context();
    let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
    let mut one_shot = OneShot::new(ctx).unwrap();
    let uploader = RecordUploader::new(ctx).unwrap();
    let mut rng = Rng::new(0x5EED);
    for (slots, hitboxes) in [(1u32, 1u32), (37, 5), (3000, 257)] {
        // The GPU arrays start as independent random bits.
        let n = slots as usize;
        let mut gpu_copy = InstanceArrays::from_parts(
            random_records(&mut rng, n),
            random_records(&mut rng, n),
            random_records(&mut rng, n),
        )
        .unwrap();
        let mut gpu_hitboxes: Vec<HitboxRecord> = random_records(&mut rng, hitboxes as usize);
        let mut gpu_rates: Vec<u32> = random_records(&mut rng, n);
        let host =
            |data: &[u8]| Buffer::with_data(ctx, storage, MemoryLocation::GpuToCpu, data).unwrap();
        let hot = host(bytemuck::cast_slice(gpu_copy.hot()));
        let tlas = host(bytemuck::cast_slice(gpu_copy.tlas()));
        let bounds = host(bytemuck::cast_slice(gpu_copy.bounds()));
        let hitbox_buf = host(bytemuck::cast_slice(&gpu_hitboxes));
        let rates_buf = host(bytemuck::cast_slice(&gpu_rates));
        let mut bindings = uploader
            .bind(&UploadTargets {
                instances: InstanceBuffers {
                    hot: &hot,
                    tlas: &tlas,
                    bounds: &bounds,
                },
                hitboxes: &hitbox_buf,
                instance_rates: &rates_buf,
            })
            .unwrap();
        assert_eq!(
            (bindings.slot_capacity(), bindings.hitbox_capacity()),
            (slots, hitboxes)
        );
        for round in 0..4 {
            let cpu_records = InstanceArrays::from_records(&random_records::<InstanceRecord>(
                &mut rng,
                slots as usize,
            ));
            let uploads = if round == 3 {
                Uploads::default()
            } else {
                random_uploads(&mut rng, slots, hitboxes)
            };
            let before = gpu_copy.clone();
            apply_uploads(
                &uploads,
                &cpu_records,
                &mut gpu_copy,
                &mut gpu_rates,
                &mut gpu_hitboxes,
            );
            let stats = one_shot
                .run(|rec| uploader.record(rec, &mut bindings, &uploads, &cpu_records))
                .unwrap();
            let got = InstanceArrays::from_parts(
                hot.read::<InstanceHot>(0, n).unwrap(),
                tlas.read::<InstanceTlas>(0, n).unwrap(),
                bounds.read::<InstanceBounds>(0, n).unwrap(),
            )
            .unwrap();
            let got_hitboxes: Vec<HitboxRecord> = hitbox_buf.read(0, hitboxes as usize).unwrap();
            let got_rates: Vec<u32> = rates_buf.read(0, n).unwrap();
            let what = format!("{slots} slots, {hitboxes} hitboxes, round {round}");
            for (i, (g, w)) in got.hot().iter().zip(gpu_copy.hot()).enumerate() {
                assert_eq!(g, w, "{what}: hot {i}");
            }
            for (i, (g, w)) in got.tlas().iter().zip(gpu_copy.tlas()).enumerate() {
                assert_eq!(
                    bytemuck::bytes_of(g),
                    bytemuck::bytes_of(w),
                    "{what}: TLAS record {i}: {g:?} vs {w:?}"
                );
            }
            for (i, (g, w)) in got.bounds().iter().zip(gpu_copy.bounds()).enumerate() {
                assert_eq!(
                    bytemuck::bytes_of(g),
                    bytemuck::bytes_of(w),
                    "{what}: bounds {i}: {g:?} vs {w:?}"
                );
            }
            for (i, (g, w)) in got_hitboxes.iter().zip(&gpu_hitboxes).enumerate() {
                assert_eq!(
                    bytemuck::bytes_of(g),
                    bytemuck::bytes_of(w),
                    "{what}: hitbox {i}"
                );
            }
            assert_eq!(got_rates, gpu_rates, "{what}: rates");
            // The uploads did something, and the state bits were kept where
            // no override names the slot.
            if round < 3 && slots > 1 {
                assert!(stats.records > 0, "{what}");
                let in_range: std::collections::HashSet<u32> = uploads
                    .hitbox_extents
                    .iter()
                    .map(|e| e.0)
                    .filter(|&i| i < hitboxes)
                    .collect();
                assert_eq!(stats.extents as usize, in_range.len(), "{what}: extents");
                let overridden: std::collections::HashSet<u32> =
                    uploads.state_overrides.iter().map(|o| o.0).collect();
                let mut kept = 0;
                for (s, (g, b)) in got.hot().iter().zip(before.hot()).enumerate() {
                    if !overridden.contains(&(s as u32)) {
                        assert_eq!(
                            g.packed & instance_bits::STATE_MASK,
                            b.packed & instance_bits::STATE_MASK,
                            "{what}: slot {s}"
                        );
                        kept += 1;
                    }
                }
                assert!(kept > 0, "{what}");
            } else if round == 3 {
                assert_eq!(stats, UploadStats::default());
            }
        }
    }
    assert_no_validation_errors(&h);
}

pub fn upload_targets_are_checked() {
    let h = headless("upload_targets_are_checked");
    let ctx = h.context();
    let storage = vk::BufferUsageFlags::STORAGE_BUFFER;
    let uploader = RecordUploader::new(ctx).unwrap();
    let small = Buffer::new(ctx, 16, storage, MemoryLocation::GpuOnly).unwrap();
    let hitboxes = Buffer::new(ctx, 120, storage, MemoryLocation::GpuOnly).unwrap();
    let slots10 = |b| Buffer::new(ctx, b, storage, MemoryLocation::GpuOnly).unwrap();
    let (hot, tlas, bounds) = (slots10(80), slots10(640), slots10(280));
    let rates = slots10(40);
    // 36 bytes hold 9 rates, not the 10 slots' rates.
    let few_rates = slots10(36);
    assert!(matches!(
        uploader.bind(&UploadTargets {
            instances: InstanceBuffers {
                hot: &hot,
                tlas: &tlas,
                bounds: &bounds,
            },
            hitboxes: &hitboxes,
            instance_rates: &few_rates,
        }),
        Err(lipac_vk::VkError::InvalidArgument(_))
    ));
    // 16 bytes hold no 64-byte TLAS record.
    assert!(uploader
        .bind(&UploadTargets {
            instances: InstanceBuffers {
                hot: &hot,
                tlas: &small,
                bounds: &bounds,
            },
            hitboxes: &hitboxes,
            instance_rates: &rates,
        })
        .is_err());
    let no_storage = Buffer::new(
        ctx,
        960,
        vk::BufferUsageFlags::TRANSFER_DST,
        MemoryLocation::GpuOnly,
    )
    .unwrap();
    assert!(matches!(
        uploader.bind(&UploadTargets {
            instances: InstanceBuffers {
                hot: &hot,
                tlas: &tlas,
                bounds: &no_storage,
            },
            hitboxes: &hitboxes,
            instance_rates: &rates,
        }),
        Err(lipac_vk::VkError::MissingUsage(_))
    ));
    // A range inside the CPU records but past the GPU buffer is refused.
    let mut bindings = uploader
        .bind(&UploadTargets {
            instances: InstanceBuffers {
                hot: &hot,
                tlas: &tlas,
                bounds: &bounds,
            },
            hitboxes: &hitboxes,
            instance_rates: &rates,
        })
        .unwrap();
    assert_eq!(bindings.slot_capacity(), 10);
    let records = InstanceArrays::from_records(&[InstanceRecord::default(); 20]);
    let uploads = Uploads {
        records: vec![5..15, 15..15],
        ..Uploads::default()
    };
    let mut one_shot = OneShot::new(ctx).unwrap();
    let refused = one_shot.run(|rec| uploader.record(rec, &mut bindings, &uploads, &records));
    assert!(matches!(
        refused,
        Err(lipac_vk::VkError::InvalidArgument(_))
    ));
    drop((bindings, hot, tlas, bounds, rates, few_rates));
    assert_no_validation_errors(&h);
}
