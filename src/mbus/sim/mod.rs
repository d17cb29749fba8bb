//! The simulator's M-Bus segment: meters built from the standard's tables with their own small
//! wire code ([`wire`], not the gateway's decoder), counting registers that roll over at their
//! width ([`meter`]), and a pure segment model ([`segment`]: request bytes in, what the master
//! hears out, collisions included). [`shell`] serves a segment on TCP (as M-Bus-to-Ethernet
//! converters pass raw frames) and on a pseudo-terminal at 2400 8E1.

pub mod config;
pub mod gateway;
pub mod meter;
pub mod plant;
pub mod segment;
pub mod shell;
pub mod wire;

pub use meter::{Behaviour, Gauge, Quantity, Register, SimMeter, Width};
pub use plant::{PlantSegment, Segments};
pub use segment::Segment;
