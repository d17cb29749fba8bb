//! Commissioning a Modbus line: find the units that answer and their models (`scan.rs`, with
//! a config snippet of what answered: `snippet.rs`), read one module as the gateway would
//! (`read.rs`), clear or preset a channel, change the settings its datasheet documents
//! (`setup.rs`), and read or write raw registers (`raw.rs`), over the driver's link
//! (`line.rs`: the line a command names).

pub(crate) mod commands;
mod line;
pub(crate) mod raw;
pub(crate) mod read;
pub(crate) mod scan;
pub(crate) mod setup;
pub(crate) mod snippet;
