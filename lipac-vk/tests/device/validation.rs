//! The debug messenger records errors, so the "no validation errors" checks
//! of the other tests can fail.

use crate::common::*;
use ash::vk;

pub fn messenger_records_error_messages() {
    let h = headless("messenger_records_error_messages");
    if vulkan_required() {
        assert!(
            h.validation_enabled(),
            "LIPAC_REQUIRE_VULKAN=1 needs the validation layer"
        );
    }
    // The harness runs this only with VK_EXT_debug_utils.
    assert!(h.records_messages(), "no VK_EXT_debug_utils");
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

pub fn validation_layer_errors_are_recorded() {
    let h = headless("validation_layer_errors_are_recorded");
    // The harness runs this only with the validation layer.
    assert!(
        h.validation_enabled(),
        "VK_LAYER_KHRONOS_validation not enabled"
    );
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
