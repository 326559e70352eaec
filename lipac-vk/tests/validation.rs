//! The debug messenger records errors, so the "no validation errors" checks
//! of the other tests can fail.

mod common;

use ash::vk;
use common::*;

#[test]
fn messenger_records_error_messages() {
    let Some(h) = headless("messenger_records_error_messages") else {
        return;
    };
    if vulkan_required() {
        assert!(
            h.validation_enabled(),
            "LIPAC_REQUIRE_VULKAN=1 needs the validation layer"
        );
    }
    if !h.records_messages() {
        eprintln!("SKIPPED messenger_records_error_messages: no VK_EXT_debug_utils");
        return;
    }
    assert_no_validation_errors(&h);
    assert!(h.submit_debug_message(
        vk::DebugUtilsMessageSeverityFlagsEXT::WARNING,
        c"just a warning"
    ));
    assert!(
        h.validation_errors().is_empty(),
        "warnings are not recorded as errors"
    );
    assert!(h.submit_debug_message(
        vk::DebugUtilsMessageSeverityFlagsEXT::ERROR,
        c"injected error"
    ));
    assert_eq!(h.validation_errors(), vec!["injected error".to_owned()]);
}

#[test]
fn validation_layer_errors_are_recorded() {
    let Some(h) = headless("validation_layer_errors_are_recorded") else {
        return;
    };
    if !h.validation_enabled() {
        eprintln!("SKIPPED validation_layer_errors_are_recorded: VK_LAYER_KHRONOS_validation not installed");
        return;
    }
    let ctx = h.context();
    // A buffer of size 0 breaks VUID-VkBufferCreateInfo-size-00912; the layer
    // reports it before the driver sees the call (which drivers accept or
    // refuse with an error; both are fine here).
    let info = vk::BufferCreateInfo::default()
        .size(0)
        .usage(vk::BufferUsageFlags::STORAGE_BUFFER)
        .sharing_mode(vk::SharingMode::EXCLUSIVE);
    // SAFETY: deliberate invalid usage on a valid device; whatever handle comes
    // back is destroyed at once (destroying a null handle is a no-op).
    unsafe {
        if let Ok(b) = ctx.device().create_buffer(&info, None) {
            ctx.device().destroy_buffer(b, None);
        }
    }
    let errors = h.validation_errors();
    assert!(
        errors.iter().any(|e| e.contains("00912")),
        "expected VUID-VkBufferCreateInfo-size-00912, got {errors:?}"
    );
}
