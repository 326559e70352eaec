use super::*;

#[test]
fn align_up_rounds() {
    assert_eq!(align_up(0, 256), Some(0));
    assert_eq!(align_up(1, 256), Some(256));
    assert_eq!(align_up(256, 256), Some(256));
    assert_eq!(align_up(257, 8), Some(264));
    assert_eq!(align_up(5, 0), Some(5));
    assert_eq!(align_up(u64::MAX, 2), None);
}

#[test]
fn allocations_that_break_the_contract_are_refused() {
    let req = vk::MemoryRequirements {
        size: 1000,
        alignment: 256,
        memory_type_bits: 1,
    };
    let good = |offset, size, mapped: bool| DeviceAllocation {
        memory: vk::DeviceMemory::from_raw(7),
        offset,
        size,
        mapped: mapped.then(std::ptr::NonNull::<u8>::dangling),
        id: 0,
    };
    let host = MemoryLocation::CpuToGpu;
    assert_eq!(
        check_allocation(&good(512, 1000, true), &req, host, "b"),
        Ok(())
    );
    assert_eq!(
        check_allocation(&good(0, 1000, false), &req, MemoryLocation::GpuOnly, "b"),
        Ok(())
    );
    for bad in [
        good(100, 1000, true),
        good(0, 999, true),
        good(0, 1000, false),
    ] {
        assert!(matches!(
            check_allocation(&bad, &req, host, "b"),
            Err(VkError::Allocator(_))
        ));
    }
    let mut null = good(0, 1000, true);
    null.memory = vk::DeviceMemory::null();
    assert!(check_allocation(&null, &req, host, "b").is_err());
}
