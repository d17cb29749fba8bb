//! Carrying out a clear or preset on a device: book what was counted before, write, read back,
//! and rebase the counters so the write itself never moves a total.

use std::collections::BTreeSet;

use tokio::time::Instant;
use tokio_modbus::ExceptionCode;

use super::device::{ModbusDevice, Snapshot};
use super::link::Link;
use crate::bus::device::DeviceRt;
use crate::bus::driver::Executed;
use crate::command::{CommandError, Op, Request};
use crate::decode::{decode, encode_int};
use crate::event::Event;
use crate::profile::Register;
use crate::reading::Reading;

fn write_failed(e: impl std::fmt::Display) -> CommandError {
    CommandError::WriteFailed(e.to_string())
}

fn exception(e: ExceptionCode) -> CommandError {
    CommandError::WriteFailed(format!("the module refused the write: {e:?}"))
}

impl DeviceRt<ModbusDevice> {
    /// Carries out `req` on this (discovered) device.
    pub async fn execute(&mut self, link: &mut Link, req: &Request) -> Executed {
        let mut readings = Vec::new();
        let result = self.execute_inner(link, req, &mut readings).await;
        Executed { readings, result }
    }

    async fn execute_inner(
        &mut self,
        link: &mut Link,
        req: &Request,
        readings: &mut Vec<Reading>,
    ) -> Result<Option<i64>, CommandError> {
        let targets = self.targets_of(req)?;
        // 1. Book what was counted up to now.
        let counts: Vec<Register> = targets
            .iter()
            .map(|&i| self.channels[i].spec.count)
            .collect();
        let before = self
            .read_registers(link, &counts, &|| false)
            .await
            .map_err(|e| write_failed(format!("reading before the write: {e}")))?;
        for &i in &targets {
            let order = self.profile.word_order;
            let ch = &mut self.channels[i];
            if let Some((w, at)) = before.get(&ch.spec.count) {
                let count = decode(w, ch.spec.count.ty, order).as_i64();
                let Some(update) = ch.counter.update(count, at.stamp) else {
                    continue;
                };
                readings.push(ch.reading(&self.name, at.wall, count, None, None, update));
            }
        }
        // 2. Write.
        let written = Instant::now();
        let expected = self.write(link, req, &targets).await?;
        // 3. Read back and rebase.
        let after = self
            .read_registers(link, &counts, &|| false)
            .await
            .map_err(|e| write_failed(format!("reading back: {e}")))?;
        let elapsed_ms = written.elapsed().as_millis() as u64;
        self.rebase(req, &targets, &after, expected, elapsed_ms, readings)
    }

    /// The channels `req` acts on; a preset out of the channel's range is refused here.
    fn targets_of(&self, req: &Request) -> Result<Vec<usize>, CommandError> {
        let targets: Vec<usize> = match &req.channel {
            Some(name) => {
                let i = self
                    .channels
                    .iter()
                    .position(|c| &*c.name == name)
                    .ok_or_else(|| CommandError::UnknownChannel {
                        device: self.name.to_string(),
                        channel: name.clone(),
                    })?;
                vec![i]
            }
            None => (0..self.channels.len()).collect(),
        };
        if let Op::Preset(v) = req.op {
            let ch = &self.channels[targets[0]];
            if !ch.spec.accepts_preset(v) {
                return Err(CommandError::OutOfRange {
                    channel: ch.name.to_string(),
                    value: v,
                });
            }
        }
        Ok(targets)
    }

    /// Writes the preset or the clears; returns the count expected afterwards.
    async fn write(
        &mut self,
        link: &mut Link,
        req: &Request,
        targets: &[usize],
    ) -> Result<i64, CommandError> {
        match req.op {
            Op::Preset(v) => {
                let ch = &self.channels[targets[0]];
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
                Ok(v)
            }
            Op::Clear | Op::ClearAll => {
                self.write_clears(link, targets, req.op == Op::ClearAll)
                    .await?;
                Ok(0)
            }
            // The bus core sets meter readings itself; nothing of it is ever written.
            Op::SetReading(_) => Err(CommandError::WriteFailed(
                "set_reading writes nothing to a module".into(),
            )),
        }
    }

    /// Rebases the counters on what was read back (`after`), booking the pulses counted
    /// between the write and the read-back; a count that is not what was written is an error.
    fn rebase(
        &mut self,
        req: &Request,
        targets: &[usize],
        after: &Snapshot,
        expected: i64,
        elapsed_ms: u64,
        readings: &mut Vec<Reading>,
    ) -> Result<Option<i64>, CommandError> {
        let event = if matches!(req.op, Op::Preset(_)) {
            Event::Preset
        } else {
            Event::Cleared
        };
        let mut mismatch = None;
        let mut single = None;
        for &i in targets {
            let order = self.profile.word_order;
            let ch = &mut self.channels[i];
            let Some((w, at)) = after.get(&ch.spec.count) else {
                continue;
            };
            let got = decode(w, ch.spec.count.ty, order).as_i64();
            // Pulses keep coming while we write: allow what the input can count meanwhile.
            let slack = ch.counter.spec.plausible(elapsed_ms);
            let update = if (got - expected).abs() > slack {
                // The write did not take as asked: book nothing, go on from what is there.
                mismatch.get_or_insert(CommandError::ReadBack { expected, got });
                ch.counter.rebase(got, at.stamp, event)
            } else {
                // Pulses counted between the write and the read-back are booked.
                ch.counter.rebase_from(expected, got, at.stamp, event)
            };
            readings.push(ch.reading(&self.name, at.wall, got, None, None, update));
            single = Some(got);
        }
        match mismatch {
            Some(e) => Err(e),
            None => Ok(if targets.len() == 1 { single } else { None }),
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
                .filter_map(|&i| self.channels[i].spec.clear_all)
                .collect();
            for code in codes {
                link.write_register(self.proto.unit, code.register, code.code, timeout)
                    .await
                    .map_err(write_failed)?
                    .map_err(exception)?;
                done.extend(
                    targets
                        .iter()
                        .filter(|&&i| self.channels[i].spec.clear_all == Some(code)),
                );
            }
        }
        for &i in targets.iter().filter(|i| !done.contains(i)) {
            let clear = self.channels[i].spec.clear.clone();
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
