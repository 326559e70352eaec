use super::*;

#[test]
fn prefers_async_compute_family() {
    let g = vk::QueueFlags::GRAPHICS | vk::QueueFlags::COMPUTE | vk::QueueFlags::TRANSFER;
    let c = vk::QueueFlags::COMPUTE | vk::QueueFlags::TRANSFER;
    let t = vk::QueueFlags::TRANSFER;
    let fams = [(0, g), (1, c), (2, t)];
    assert_eq!(pick_family(fams.iter().copied()), Some(1));
    assert_eq!(pick_family([(0, t), (1, g)].iter().copied()), Some(1));
    assert_eq!(pick_family([(0, t)].iter().copied()), None);
}
