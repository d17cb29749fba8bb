//! Admission of commands per device: a token bucket for the rate and a bound on how many wait for
//! the bus. Pure: instants come in. A burst of commands (a script gone wrong, an attacker with
//! publish rights) is answered at once with `busy` instead of queueing without bound, so it costs
//! the gateway neither memory nor the line time the polls need.

use std::collections::HashMap;

use tokio::time::Instant;

use crate::command::CommandError;

/// Commands a device takes in a burst, and how fast the bucket refills.
pub const BURST: f64 = 10.0;
pub const PER_SECOND: f64 = 5.0;
/// Commands of one device waiting for (or on) the bus at once.
pub const MAX_QUEUED: usize = 8;

#[derive(Debug, Clone, Copy)]
struct Bucket {
    tokens: f64,
    at: Instant,
    queued: usize,
}

/// The admission state of every device that received a command.
#[derive(Debug, Default)]
pub struct Admission {
    devices: HashMap<String, Bucket>,
}

impl Admission {
    /// Takes a command for `device` at `now`, or says why not. Call [`Admission::done`] when an
    /// admitted command has its outcome. Only configured devices come here, so the map is
    /// bounded by the config.
    pub fn admit(&mut self, device: &str, now: Instant) -> Result<(), CommandError> {
        let b = self.devices.entry(device.to_string()).or_insert(Bucket {
            tokens: BURST,
            at: now,
            queued: 0,
        });
        let refill = now.saturating_duration_since(b.at).as_secs_f64() * PER_SECOND;
        b.tokens = (b.tokens + refill).min(BURST);
        b.at = now;
        if b.queued >= MAX_QUEUED {
            return Err(CommandError::Busy {
                device: device.into(),
                why: "8 commands are already waiting for it",
            });
        }
        if b.tokens < 1.0 {
            return Err(CommandError::Busy {
                device: device.into(),
                why: "more than 5 commands a second",
            });
        }
        b.tokens -= 1.0;
        b.queued += 1;
        Ok(())
    }

    /// An admitted command of `device` has its outcome.
    pub fn done(&mut self, device: &str) {
        if let Some(b) = self.devices.get_mut(device) {
            b.queued = b.queued.saturating_sub(1);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn a_burst_beyond_the_bucket_is_refused_as_busy() {
        let mut a = Admission::default();
        let t = Instant::now();
        let admitted = (0..1000)
            .filter(|_| {
                let ok = a.admit("press", t).is_ok();
                if ok {
                    a.done("press");
                }
                ok
            })
            .count();
        assert_eq!(admitted, BURST as usize);
        assert_eq!(
            a.admit("press", t).unwrap_err().code(),
            "busy",
            "the excess is answered, not queued"
        );
        assert!(
            a.admit("press", t + Duration::from_secs(1)).is_ok(),
            "refilled"
        );
    }

    #[test]
    fn no_more_than_eight_commands_of_a_device_wait_at_once() {
        let mut a = Admission::default();
        let mut t = Instant::now();
        for _ in 0..MAX_QUEUED {
            t += Duration::from_secs(1);
            a.admit("press", t).unwrap();
        }
        t += Duration::from_secs(10);
        assert!(a.admit("press", t).is_err(), "queue full");
        assert!(
            a.admit("other", t).is_ok(),
            "other devices are not affected"
        );
        a.done("press");
        assert!(a.admit("press", t).is_ok());
    }
}
