//! Names that become topic levels, checked where the config names them.

use super::walk::{Errors, Table};

/// A device name becomes a topic level: refused when it cannot be one.
pub(crate) fn device_name(t: &Table<'_>, path: &str, name: &str, errs: &mut Errors) {
    if !crate::topics::is_topic_safe(name) || matches!(name, "status" | "bus" | "cmd" | "gateway") {
        errs.push(
            path,
            t.origin(),
            "device name must be letters, digits, '-' or '_' and not status, bus, cmd or gateway \
             (it is a topic level)",
        );
    }
}
