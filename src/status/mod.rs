//! The status page's data: a board fed with every event the outputs get (`board.rs`, pure),
//! its snapshot as the API's JSON (`view.rs`), a channel's rate history (`history.rs`), the
//! event log (`log.rs`), and the shell that reads the running gateway's health and metrics
//! into a snapshot (`live.rs`).

pub mod board;
pub mod history;
pub mod live;
pub mod log;
pub mod view;

pub use board::{Board, Measured};
pub use live::{FRESH, Live};

#[cfg(test)]
mod tests;
