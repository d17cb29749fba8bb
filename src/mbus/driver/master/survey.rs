//! A scan of an M-Bus bus requested over MQTT (`<root>/bus/<bus>/scan`), carried out by the
//! running bus in its idle line time: the requested units are asked as primary addresses, one
//! only when the next poll is due later than the longest the question can take, so the
//! configured meters keep their poll rate; configured primary addresses are not asked. Each
//! meter found is reported on the scan's progress topic as it answers; the result follows.

use tokio::time::Instant;

use tokio::sync::mpsc::Receiver;

use super::device::Address;
use super::link::{Link, char_time};
use super::search::{FoundMeter, Probe, probe_primary};
use crate::bus::driver::Idle;
use crate::command::Reply;
use crate::mbus::config::Line as MbusLine;
use crate::mbus::driver::address::medium_name;
use crate::mbus::driver::channel;
use crate::mbus::driver::frame::MAX_FRAME;
use crate::outcome::{Found, MeterFound, Outcome, ScanOutcome};
use crate::reading::Output;
use crate::scan::{ScanRequest, Survey};

/// What a scan needs of the driver, lent for one step.
pub(super) struct Scanning<'a> {
    pub link: &'a mut Link,
    pub survey: &'a mut Option<Survey>,
    pub requests: &'a mut Option<Receiver<ScanRequest>>,
    /// The configured meters (their primary addresses are not asked).
    pub configured: &'a [Address],
}

/// How a found meter is reported.
pub fn found(m: &FoundMeter, baud: Option<u32>) -> Found {
    Found {
        baud,
        unit: m.primary,
        model: Some(crate::mbus::config::METER_MODEL.to_string()),
        modes: Vec::new(),
        channels: channel::names(&m.telegram.records),
        note: None,
        meter: m.secondary.map(|s| MeterFound {
            id: s.id_text(),
            manufacturer: s.manufacturer_code(),
            version: s.version,
            medium: s.medium,
            medium_name: medium_name(s.medium).to_string(),
        }),
    }
}

/// One step of the bus's scan, if any: takes new requests (one at a time; others are answered
/// "busy") and, when the line is idle long enough, asks one primary address.
pub(super) async fn idle_step(mbus: Scanning<'_>, idle: Idle<'_>) -> bool {
    let configured: Vec<u8> = mbus
        .configured
        .iter()
        .filter_map(|a| match a {
            Address::Primary(a) => Some(*a),
            Address::Secondary(_) => None,
        })
        .collect();
    if let Some(rx) = mbus.requests.as_mut() {
        while let Ok(req) = rx.try_recv() {
            if mbus.survey.is_some() {
                let busy = ScanOutcome::Refused {
                    bus: idle.bus.to_string(),
                    id: req.id.clone(),
                    code: "busy",
                    message: "a scan of this bus is under way".into(),
                };
                send(idle.out, &req.reply, busy);
            } else {
                tracing::info!(
                    bus = idle.bus,
                    addresses = req.units.len(),
                    "M-Bus scan requested; asking primary addresses in idle line time"
                );
                *mbus.survey = Some(Survey::new(req, &configured, Instant::now()));
            }
        }
    }
    let Some(s) = mbus.survey.as_mut() else {
        return false;
    };
    let (baud, readout) = match mbus.link.line() {
        MbusLine::Serial { baud, .. } => (Some(*baud), char_time(*baud, MAX_FRAME + 5)),
        MbusLine::Tcp { .. } => (None, mbus.link.answer_time()),
    };
    // A reset and a readout, each asked twice at worst.
    let cost = (mbus.link.answer_time() * 2 + readout) * 2;
    let mut used = false;
    if let Some(address) = s.next_unit()
        && idle.until.saturating_duration_since(Instant::now()) >= cost
        && !idle.shutdown.is_cancelled()
    {
        used = true;
        let heard = match probe_primary(mbus.link, address).await {
            Ok(Probe::Found(m)) => Some(found(&m, baud)),
            _ => None,
        };
        if let Some(progress) = s.record(heard, idle.bus, Instant::now()) {
            tracing::info!(bus = idle.bus, address, "scan found a meter");
            let _ = idle.out.send(Output::ScanProgress {
                topic: s.progress_topic().to_string(),
                progress: Box::new(progress),
            });
        }
    }
    let now = Instant::now();
    if s.finished(now) {
        tracing::info!(bus = idle.bus, found = s.found_count(), "scan finished");
        send(idle.out, s.reply(), s.result(idle.bus, now));
        *mbus.survey = None;
    }
    used
}

fn send(out: &tokio::sync::mpsc::UnboundedSender<Output>, reply: &Reply, outcome: ScanOutcome) {
    let _ = out.send(Output::CommandResult {
        reply: reply.clone(),
        outcome: Outcome::Scan(outcome),
    });
}
