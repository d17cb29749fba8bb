//! `set_reading` on a bus: the channel's meter offset, set from the total the bus core holds.
//! No module is asked or written, and the total, the deltas and the intervals do not move.

use super::device::DeviceRt;
use crate::command::CommandError;
use crate::decimal::Decimal;
use crate::metering::meter::MeterOffset;

/// Moves `channel`'s published reading to `shown` from now on (the next published reading
/// carries it; the state save after it keeps it across restarts).
pub(super) fn set_reading<P>(
    d: &mut DeviceRt<P>,
    channel: Option<&str>,
    shown: &Decimal,
) -> Result<Option<i64>, CommandError> {
    let name = channel.unwrap_or_default();
    // The config's scale, else the one the driver declared (a meter register's step).
    let declared = d.channels.iter().find(|c| &*c.name == name);
    let configured = d.config.channels.get(name).and_then(|c| c.units.scale);
    if configured.is_none() && declared.is_none() && d.config.channels_from_device() {
        // Its channels are what it answers: unknown until it did, then known.
        return Err(match d.channels.is_empty() {
            true => CommandError::Busy {
                device: d.name.to_string(),
                why: "its channels have not been read yet",
            },
            false => CommandError::UnknownChannel {
                device: d.name.to_string(),
                channel: name.to_string(),
            },
        });
    }
    let scale = configured
        .or_else(|| declared.and_then(|c| c.units.as_ref()?.scale))
        .ok_or_else(|| CommandError::NoScale {
            channel: name.to_string(),
        })?;
    let device = d.name.to_string();
    let Some(ch) = d.channels.iter_mut().find(|c| &*c.name == name) else {
        return Err(CommandError::Busy {
            device,
            why: "its channels have not been read yet",
        });
    };
    let Some(counter) = ch.counter.as_mut() else {
        return Err(CommandError::NoScale {
            channel: name.to_string(),
        });
    };
    let now_ms = crate::reading::unix_ms(std::time::SystemTime::now()) as i64;
    let state = &mut counter.state;
    let offset = MeterOffset::to_show(shown, &scale, state.total, now_ms).ok_or_else(|| {
        CommandError::NotDecimal(format!(
            "{shown} has too many digits to add exactly to the scaled total"
        ))
    })?;
    tracing::info!(device = %d.name, channel = name, reading = %shown, offset = %offset.offset, total = state.total, "meter reading set");
    state.meter = Some(offset);
    Ok(None)
}
