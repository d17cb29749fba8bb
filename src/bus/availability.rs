//! Device availability: online at the first good answer, offline after `offline_after`
//! consecutive failures, then probed with backoff. Logged once per change, not per poll.

use std::time::Duration;

use tokio::sync::mpsc::UnboundedSender;

use super::device::{DeviceRt, PollError};
use crate::config::Bus;
use crate::reading::Output;

/// The device answered a whole poll.
pub(super) fn answered(d: &mut DeviceRt, bus: &str, out: &UnboundedSender<Output>) {
    d.failures = 0;
    d.backoff.reset();
    if d.last_error.take().is_some() && d.online == Some(true) {
        tracing::info!(bus, device = %d.name, "device answering again");
    }
    if d.online != Some(true) {
        if d.online == Some(false) {
            tracing::info!(bus, device = %d.name, "device back online");
        }
        d.online = Some(true);
        let _ = out.send(Output::DeviceStatus {
            device: d.name.clone(),
            online: true,
        });
    }
}

/// A poll failed. Returns how long to wait before probing the device again when it is (now)
/// offline; `None` to keep its schedule. While the line itself is down (adapter gone), offline
/// devices are probed every `backoff_min` so the bus is back within seconds of the line.
pub(super) fn failed(
    d: &mut DeviceRt,
    e: &PollError,
    bus: &Bus,
    line_fault: bool,
    bus_name: &str,
    out: &UnboundedSender<Output>,
) -> Option<Duration> {
    let message = e.to_string();
    let new_error = d.last_error.as_deref() != Some(message.as_str());
    if new_error {
        tracing::warn!(bus = bus_name, device = %d.name, unit = d.unit, "{message}");
        d.last_error = Some(message);
    }
    if e.device_answered() {
        // It is there (an exception, a garbled answer on a noisy line): not a step towards
        // offline. A module that starts refusing registers it answered before may be another
        // module, or have restarted in another work mode: identity and modes are read again
        // (once per new refusal, so a device that keeps refusing costs no extra reads).
        if new_error && matches!(e, PollError::Refused { .. }) && d.discovered() {
            d.module_restarted();
        }
        d.failures = 0;
        return None;
    }
    d.failures += 1;
    if d.failures < bus.offline_after {
        return None;
    }
    if d.online != Some(false) {
        tracing::warn!(bus = bus_name, device = %d.name, failures = d.failures, "device offline");
        d.online = Some(false);
        d.mark_gap();
        // Whatever answers at this address next may be another module.
        d.identify_due = true;
        let _ = out.send(Output::DeviceStatus {
            device: d.name.clone(),
            online: false,
        });
    }
    Some(if line_fault {
        bus.backoff_min
    } else {
        d.backoff.next_wait()
    })
}

/// The module is not the configured model: out of service with status `wrong_model` (logged and
/// published once per change); its counters' next deltas cover the time out of service.
pub(super) fn wrong_model(d: &mut DeviceRt, why: String, bus: &str, out: &UnboundedSender<Output>) {
    if d.wrong_model.as_deref() == Some(why.as_str()) {
        return;
    }
    tracing::error!(bus, device = %d.name, unit = d.unit, "module taken out of service: {why}");
    d.wrong_model = Some(why);
    d.metrics.wrong_model(true);
    d.online = None;
    d.failures = 0;
    d.mark_gap();
    let _ = out.send(Output::DeviceProblem {
        device: d.name.clone(),
        status: "wrong_model",
    });
}

/// A quadrature pair's mode words disagree (or agree again): status `mode_mismatch` while they
/// do, `online` again after.
pub(super) fn mode_mismatch(d: &mut DeviceRt, out: &UnboundedSender<Output>) {
    let Some(now) = d.take_mismatch_change() else {
        return;
    };
    let status = match now {
        Some(_) => Output::DeviceProblem {
            device: d.name.clone(),
            status: "mode_mismatch",
        },
        None => Output::DeviceStatus {
            device: d.name.clone(),
            online: true,
        },
    };
    let _ = out.send(status);
}
