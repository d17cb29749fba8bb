//! An M-Bus bus in words.

use crate::config::model::{Device, Link};

/// An M-Bus bus in words: its line and each meter's address and poll interval (a meter's
/// channels are its answer's records, known when it answers).
pub fn meters(bus: &str, link: &Link, devices: &[Device]) -> String {
    let mut out = format!("bus {bus} ({link}):");
    for d in devices {
        let address = d.address.to_string();
        let picked = d.channels.values().filter(|c| c.record.is_some()).count();
        let records = match picked {
            0 => "every record a channel".to_string(),
            n => format!("{n} records picked"),
        };
        out += &format!(
            "\n  {:<16} {address:<22} every {:<8} {records}",
            d.name,
            humantime::format_duration(d.poll).to_string()
        );
    }
    out
}
