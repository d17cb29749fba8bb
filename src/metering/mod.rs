//! Metering: clock-aligned interval records and meter readings. Pure.
//!
//! A pulse counter keeps counting while the gateway is away, so the consumption between two
//! boundary reads is exact whatever happened between them. [`interval`] turns a channel's
//! booked reads into records of its configured periods ([`period`]), on boundaries of the local
//! clock of `gateway.timezone` ([`clock`]); [`meter`] keeps the offset that makes a channel's
//! published `reading` match its meter's display; [`tariff`] says which time-of-use tariff
//! each record belongs to.

pub mod account;
pub mod billing;
pub mod booking;
pub mod clock;
pub mod demand;
pub mod interval;
pub mod meter;
pub mod obis;
pub mod period;
pub mod tariff;

pub use clock::Clock;
pub use interval::{IntervalState, Read, Record, Status};
pub use period::Period;
