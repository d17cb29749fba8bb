//! What a Modbus server output answers to one request, by the register map and the image as
//! they are: registers, an exception, or a command for the router (a write of a command
//! register, when commands are on). Pure.

use std::time::SystemTime;

use tokio_modbus::{ExceptionCode, Request, Response};

use super::image::{Image, i64_of};
use crate::modbus::config::server::map::offset_of;

/// The most registers one read may ask for (the Modbus application protocol's limit).
pub const MAX_READ: u16 = 125;

/// The most registers one write may carry.
pub const MAX_WRITE: usize = 123;

/// A command a client wrote.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Op {
    Clear,
    Preset(i64),
}

/// A write of a command register: what to do, to which channel, and what to answer once done.
#[derive(Debug, Clone, PartialEq)]
pub struct Command {
    pub unit: u8,
    pub device: String,
    pub channel: String,
    /// The first address of the channel's block.
    pub base: u16,
    pub op: Op,
    /// The answer when it is done.
    pub done: Response,
}

/// What to do with a request.
#[derive(Debug, Clone, PartialEq)]
pub enum Asked {
    Answer(Response),
    Command(Command),
}

/// The answer to `request` for unit `unit`.
pub fn answer(
    image: &Image,
    commands: bool,
    unit: u8,
    request: &Request<'_>,
    now: SystemTime,
) -> Result<Asked, ExceptionCode> {
    let read = |address: u16, count: u16| {
        if !(1..=MAX_READ).contains(&count) {
            return Err(ExceptionCode::IllegalDataValue);
        }
        let device = image
            .units
            .get(&unit)
            .ok_or(ExceptionCode::GatewayTargetDevice)?;
        device
            .read(address, count, now)
            .ok_or(ExceptionCode::IllegalDataAddress)
    };
    match request {
        Request::ReadInputRegisters(a, n) => {
            read(*a, *n).map(|w| Asked::Answer(Response::ReadInputRegisters(w)))
        }
        Request::ReadHoldingRegisters(a, n) => {
            read(*a, *n).map(|w| Asked::Answer(Response::ReadHoldingRegisters(w)))
        }
        Request::WriteSingleRegister(a, v) => {
            write(image, commands, unit, *a, &[*v]).map(|mut c| {
                c.done = Response::WriteSingleRegister(*a, *v);
                Asked::Command(c)
            })
        }
        Request::WriteMultipleRegisters(a, words) => {
            if words.is_empty() || words.len() > MAX_WRITE {
                return Err(ExceptionCode::IllegalDataValue);
            }
            write(image, commands, unit, *a, words).map(|mut c| {
                c.done = Response::WriteMultipleRegisters(*a, words.len() as u16);
                Asked::Command(c)
            })
        }
        _ => Err(ExceptionCode::IllegalFunction),
    }
}

/// A write: `1` to a channel's `clear`, or four registers to its `preset`.
fn write(
    image: &Image,
    commands: bool,
    unit: u8,
    address: u16,
    words: &[u16],
) -> Result<Command, ExceptionCode> {
    if !commands {
        return Err(ExceptionCode::IllegalFunction);
    }
    let device = image
        .units
        .get(&unit)
        .ok_or(ExceptionCode::GatewayTargetDevice)?;
    let (channel, offset) = device
        .map
        .channel_at(address)
        .ok_or(ExceptionCode::IllegalDataAddress)?;
    let op = if Some(offset) == offset_of("clear") {
        match words {
            [1] => Op::Clear,
            _ => return Err(ExceptionCode::IllegalDataValue),
        }
    } else if Some(offset) == offset_of("preset") {
        Op::Preset(i64_of(words).ok_or(ExceptionCode::IllegalDataValue)?)
    } else {
        return Err(ExceptionCode::IllegalDataAddress);
    };
    Ok(Command {
        unit,
        device: device.map.device.clone(),
        channel: channel.to_string(),
        base: address - offset,
        op,
        done: Response::WriteSingleRegister(address, 0),
    })
}

/// The name of an exception, for the metrics.
pub fn exception_name(e: ExceptionCode) -> &'static str {
    match e {
        ExceptionCode::IllegalFunction => "illegal_function",
        ExceptionCode::IllegalDataAddress => "illegal_data_address",
        ExceptionCode::IllegalDataValue => "illegal_data_value",
        ExceptionCode::ServerDeviceFailure => "server_device_failure",
        ExceptionCode::GatewayTargetDevice => "gateway_target_failed",
        ExceptionCode::ServerDeviceBusy => "server_device_busy",
        _ => "other",
    }
}
