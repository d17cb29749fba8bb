//! A Modbus bus in words: each device's reads, registers and line time per poll, and the share
//! of the line its intervals need.

use std::fmt::Write;
use std::time::Duration;

use super::Line;
use super::plan::{DEFAULT_TURNAROUND, PollPlan, Wire, line_time};
use crate::config::model::Bus;
use crate::profile::Register;

/// Assumed device turnaround when estimating line time (the bus measures it at run time).
const TURNAROUND: Duration = DEFAULT_TURNAROUND;

/// One line per device with its reads, registers and line time per poll, and per bus the share
/// of the line its intervals need (a warning when above 100%). Work modes are not known before
/// the modules answer, so each group is taken in its first mode.
pub fn bus(bus: &Bus, line: &Line) -> String {
    let mut out = String::new();
    let timing = line.timing(bus.guard);
    let link = &bus.link;
    let _ = writeln!(out, "bus {} ({link}):", bus.name);
    let wire = Wire::for_line(timing.as_ref());
    let mut load = 0.0;
    for d in &bus.devices {
        let modes: Vec<u16> = vec![0; d.profile.mode_registers().len()];
        let channels = d.profile.channels(&modes).unwrap_or_default();
        let values: Vec<Register> = channels.iter().flat_map(|c| c.polled()).collect();
        // The same value the bus builds and executes for this mode.
        let plan = PollPlan::new(&values, &[], &wire);
        let time = timing.map(|t| line_time(&plan.blocks, &t, TURNAROUND));
        if let Some(t) = time {
            load += t.as_secs_f64() / d.poll.as_secs_f64();
        }
        let _ = writeln!(
            out,
            "  {:<16} unit {:>3} {:<10} every {:<8} {}, {} channels{}",
            d.name,
            d.unit,
            d.profile.model,
            humantime::format_duration(d.poll).to_string(),
            plan.describe(),
            channels.len(),
            time.map(|t| format!(", {:.1} ms on the line", t.as_secs_f64() * 1000.0))
                .unwrap_or_default(),
        );
    }
    if timing.is_some() {
        let _ = writeln!(out, "  line use at these intervals: {:.0}%", load * 100.0);
        if load > 1.0 {
            let _ = writeln!(
                out,
                "  WARNING: bus {} cannot meet its poll intervals at this baud rate",
                bus.name
            );
        }
    }
    out
}
