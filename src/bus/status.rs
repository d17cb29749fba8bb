//! The shell around a device's availability (`availability.rs`, the state machine): what a
//! poll's outcome means for the device, said once per change: log lines, status outputs, gaps
//! in its counters.

use std::time::Duration;

use tokio::sync::mpsc::UnboundedSender;
use tokio::time::Instant;

use super::availability::Transition;
use super::device::{DeviceRt, PollError};
use super::driver::DeviceState;
use crate::reading::Output;

/// The device answered a whole poll.
pub(super) fn answered<P>(d: &mut DeviceRt<P>, bus: &str, out: &UnboundedSender<Output>) {
    for t in d.availability.answered() {
        match t {
            Transition::Recovered => {
                if d.availability.may_log_recovery() {
                    tracing::info!(bus, device = %d.name, "device answering again");
                }
            }
            Transition::Online { back } => {
                if back {
                    tracing::info!(bus, device = %d.name, "device back online");
                }
                let _ = out.send(Output::DeviceStatus {
                    device: d.name.clone(),
                    online: true,
                });
            }
            Transition::Error(_) | Transition::Offline { .. } => {}
        }
    }
}

/// A poll failed. Returns how long to wait before probing the device again when it is (now)
/// offline; `None` to keep its schedule.
pub(super) fn failed<P: DeviceState>(
    d: &mut DeviceRt<P>,
    e: &PollError<P::Error>,
    line_fault: bool,
    bus: &str,
    out: &UnboundedSender<Output>,
) -> Option<Duration> {
    let verdict = d
        .availability
        .failed(e.to_string(), e.device_answered(), line_fault);
    for t in verdict.transitions {
        match t {
            Transition::Error(message) => {
                match d.availability.may_log_error(Instant::now()) {
                    Some(0) => {
                        tracing::warn!(bus, device = %d.name, unit = d.config.unit, "{message}")
                    }
                    Some(more) => tracing::warn!(
                        bus, device = %d.name, unit = d.config.unit,
                        "{message} ({more} more errors since the last line, not logged one by one)"
                    ),
                    None => {}
                }
                d.proto.poll_failed(e);
            }
            Transition::Offline { failures } => {
                tracing::warn!(bus, device = %d.name, failures, "device offline");
                d.mark_gap();
                d.proto.went_offline();
                let _ = out.send(Output::DeviceStatus {
                    device: d.name.clone(),
                    online: false,
                });
            }
            Transition::Recovered | Transition::Online { .. } => {}
        }
    }
    verdict.wait
}

/// The device is not the configured one (Modbus: another model): out of service with status
/// `wrong_model`, the word the topics and metrics have always used (logged and
/// published once per change); its counters' next deltas cover the time out of service.
pub(super) fn out_of_service<P>(
    d: &mut DeviceRt<P>,
    why: String,
    bus: &str,
    out: &UnboundedSender<Output>,
) {
    if d.out_of_service.as_deref() == Some(why.as_str()) {
        return;
    }
    tracing::error!(bus, device = %d.name, unit = d.config.unit, "module taken out of service: {why}");
    d.out_of_service = Some(why);
    d.metrics.wrong_model(true);
    d.availability.out_of_service();
    d.mark_gap();
    let _ = out.send(Output::DeviceProblem {
        device: d.name.clone(),
        status: "wrong_model",
    });
}

/// A problem of the device's own began or ended (Modbus: a quadrature pair's mode words
/// disagree): its status while it lasts, `online` again after.
pub(super) fn status_change<P: DeviceState>(d: &mut DeviceRt<P>, out: &UnboundedSender<Output>) {
    let Some(now) = d.proto.status_change() else {
        return;
    };
    let status = match now {
        Some(status) => Output::DeviceProblem {
            device: d.name.clone(),
            status,
        },
        None => Output::DeviceStatus {
            device: d.name.clone(),
            online: true,
        },
    };
    let _ = out.send(status);
}
