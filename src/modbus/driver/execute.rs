//! Carrying out a clear or preset on a device: read the counts before, write, read back. The
//! bus core books it (`bus/book.rs`): what was counted before, then the counters rebased on the
//! read-back, so the write itself never moves a total.

use std::collections::BTreeSet;

use tokio::time::Instant;
use tokio_modbus::ExceptionCode;

use super::device::{ModbusDevice, Snapshot};
use super::link::Link;
use crate::bus::device::DeviceRt;
use crate::bus::driver::{Executed, Written, Wrote};
use crate::command::{CommandError, Op, Request};
use crate::decode::{decode, encode_int};
use crate::profile::Register;
use crate::sample::Sample;

fn write_failed(e: impl std::fmt::Display) -> CommandError {
    CommandError::WriteFailed(e.to_string())
}

fn exception(e: ExceptionCode) -> CommandError {
    CommandError::WriteFailed(format!("the module refused the write: {e:?}"))
}

impl DeviceRt<ModbusDevice> {
    /// Carries out `req` on this (discovered) device: what it read before, wrote and read back.
    pub async fn execute(&mut self, link: &mut Link, req: &Request) -> Executed {
        let mut executed = Executed::default();
        executed.failed = self.execute_inner(link, req, &mut executed).await.err();
        executed
    }

    async fn execute_inner(
        &mut self,
        link: &mut Link,
        req: &Request,
        out: &mut Executed,
    ) -> Result<(), CommandError> {
        let targets = self.targets_of(req)?;
        // 1. Read what was counted up to now (the core books it).
        let counts: Vec<Register> = targets
            .iter()
            .map(|&i| self.proto.channels[i].spec.count)
            .collect();
        let before = self
            .read_registers(link, &counts, &|| false)
            .await
            .map_err(|e| write_failed(format!("reading before the write: {e}")))?;
        out.before = targets
            .iter()
            .filter_map(|&i| self.sample_of(&before, i))
            .collect();
        // 2. Write.
        let written = Instant::now();
        let wrote = self.write(link, req, &targets).await?;
        // 3. Read back (the core rebases the counters on it).
        let after = self
            .read_registers(link, &counts, &|| false)
            .await
            .map_err(|e| write_failed(format!("reading back: {e}")))?;
        let elapsed_ms = written.elapsed().as_millis() as u64;
        out.written = targets
            .iter()
            .map(|&i| Written {
                channel: i,
                wrote,
                read_back: self.sample_of(&after, i),
                elapsed_ms,
            })
            .collect();
        Ok(())
    }

    /// Channel `i`'s count in `snapshot`, if it was read.
    fn sample_of(&self, snapshot: &Snapshot, i: usize) -> Option<Sample> {
        let ch = &self.proto.channels[i];
        let (words, at) = snapshot.get(&ch.spec.count)?;
        let count = decode(words, ch.spec.count.ty, self.profile.word_order).as_i64();
        Some(Sample::count(i, at, count, ch.wrap))
    }

    /// The channels `req` acts on; a preset out of the channel's range is refused here.
    fn targets_of(&self, req: &Request) -> Result<Vec<usize>, CommandError> {
        let targets: Vec<usize> = match &req.channel {
            Some(name) => {
                let i = self
                    .proto
                    .channels
                    .iter()
                    .position(|c| &*c.name == name)
                    .ok_or_else(|| CommandError::UnknownChannel {
                        device: self.name.to_string(),
                        channel: name.clone(),
                    })?;
                vec![i]
            }
            None => (0..self.proto.channels.len()).collect(),
        };
        if let Op::Preset(v) = req.op {
            let ch = &self.proto.channels[targets[0]];
            if !ch.spec.accepts_preset(v) {
                return Err(CommandError::OutOfRange {
                    channel: ch.name.to_string(),
                    value: v,
                });
            }
        }
        Ok(targets)
    }

    /// Writes the preset or the clears; returns what was written.
    async fn write(
        &mut self,
        link: &mut Link,
        req: &Request,
        targets: &[usize],
    ) -> Result<Wrote, CommandError> {
        match req.op {
            Op::Preset(v) => {
                let ch = &self.proto.channels[targets[0]];
                let words =
                    encode_int(v, ch.spec.count.ty, self.profile.word_order).ok_or_else(|| {
                        CommandError::OutOfRange {
                            channel: ch.name.to_string(),
                            value: v,
                        }
                    })?;
                let timeout = self.timeout_for(link, 0);
                link.write_registers(self.proto.unit, ch.spec.count.address, &words, timeout)
                    .await
                    .map_err(write_failed)?
                    .map_err(exception)?;
                Ok(Wrote::Preset(v))
            }
            Op::Clear | Op::ClearAll => {
                self.write_clears(link, targets, req.op == Op::ClearAll)
                    .await?;
                Ok(Wrote::Cleared)
            }
            // The bus core sets meter readings itself; nothing of it is ever written.
            Op::SetReading(_) => Err(CommandError::WriteFailed(
                "set_reading writes nothing to a module".into(),
            )),
        }
    }

    /// Clears `targets`: with the mode's clear-all code where `all` and the profile has one,
    /// channel by channel otherwise.
    async fn write_clears(
        &mut self,
        link: &mut Link,
        targets: &[usize],
        all: bool,
    ) -> Result<(), CommandError> {
        let timeout = self.timeout_for(link, 1);
        let mut done: BTreeSet<usize> = BTreeSet::new();
        if all {
            let codes: BTreeSet<_> = targets
                .iter()
                .filter_map(|&i| self.proto.channels[i].spec.clear_all)
                .collect();
            for code in codes {
                link.write_register(self.proto.unit, code.register, code.code, timeout)
                    .await
                    .map_err(write_failed)?
                    .map_err(exception)?;
                done.extend(
                    targets
                        .iter()
                        .filter(|&&i| self.proto.channels[i].spec.clear_all == Some(code)),
                );
            }
        }
        for &i in targets.iter().filter(|i| !done.contains(i)) {
            let clear = self.proto.channels[i].spec.clear.clone();
            if clear.restart.is_empty() {
                link.write_register(self.proto.unit, clear.register, clear.code, timeout)
                    .await
                    .map_err(write_failed)?
                    .map_err(exception)?;
            } else {
                // The register also runs the counter: note its state (up, down, paused or
                // stopped), clear (which stops it), and put it back in that state.
                let state = link
                    .read(self.proto.unit, clear.register, 1, timeout)
                    .await
                    .map_err(write_failed)?
                    .map_err(exception)?;
                link.write_register(self.proto.unit, clear.register, clear.code, timeout)
                    .await
                    .map_err(write_failed)?
                    .map_err(exception)?;
                if state[0] != clear.code {
                    link.write_register(self.proto.unit, clear.register, state[0], timeout)
                        .await
                        .map_err(write_failed)?
                        .map_err(exception)?;
                }
            }
        }
        Ok(())
    }
}
