//! Wired M-Bus (EN 13757-2 link layer, EN 13757-3 application layer), pure: no I/O, no
//! runtime. What an M-Bus driver stands on:
//!
//! - [`frame`]: frames read from a byte buffer (how many bytes a frame took, or how many more
//!   it needs) and the master's frames built (SND_NKE, REQ_UD2 with the FCB rule, select by
//!   secondary address, application reset);
//! - [`address`]: secondary addresses and select masks with wildcards;
//! - [`telegram`]: an answer's CI field, [`header`] and records ([`error`] why not) ([`dif`], [`vif`], [`vife`],
//!   [`vif_table`], [`quantity`], [`value`], [`record`]; [`fixed`] for CI 0x73);
//! - [`channel`]: default channel names, and which records are counted registers.
//!
//! The record layer is our own (docs/mbus.md says why the m-bus-parser crate is not used).
//! On it stands [`master`]: the driver under the bus core (the line, each meter's readout,
//! records as channels and samples, the wildcard search); only it does I/O.

pub mod address;
pub mod channel;
pub mod dif;
pub mod error;
pub mod fixed;
pub mod frame;
pub mod header;
pub mod master;
pub mod quantity;
pub mod record;
pub mod telegram;
pub mod value;
pub mod vif;
pub mod vif_table;
pub mod vife;

pub use address::{SecondaryAddress, SecondaryMask};
pub use error::DecodeError;
pub use frame::{Frame, FrameError, Scan};
pub use record::Record;
pub use telegram::{Telegram, decode, decode_frame};
