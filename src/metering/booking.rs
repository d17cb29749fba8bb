//! What the account says about a record, and the billing record it may close: plain values that
//! travel with the record (and are kept with it in a state file while unsent). Pure, a leaf:
//! the interval core carries them without knowing how they are made.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

/// What the account said about one record; it travels with the record (and is kept with it in
/// a state file while unsent), so a record sent again carries the same.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Booking {
    /// The tariff in force at the record's start, the one it is booked to.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tariff: Option<String>,
    /// Every tariff in force during the record, when more than one (a merged record, or a
    /// longer period's).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub tariffs: Vec<String>,
    /// The register of `tariff` after this record was booked (records of the shortest period).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub register: Option<Register>,
    /// The billing periods this record closed (one; or also one that closed at the read that
    /// opened the first interval, which closed no record and so goes out with the next).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub billing: Vec<BillingRecord>,
}

/// A tariff register's state as published.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Register {
    /// Pulses booked to the tariff since the register began.
    pub total: i64,
    /// Counts the register's publications; never repeats.
    pub seq: u64,
}

/// Why a billing record covers what it covers.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PeriodStatus {
    /// The whole period, from its start boundary to its end.
    Complete,
    /// The gateway began (or the channel appeared) inside the period: from the first reading.
    Partial,
    /// The read at the period's end was missed: the period runs on to the next boundary that
    /// was read (the records' `merged`), never guessed.
    Merged,
}

/// The largest demand record of a period: its delta and where it lies.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Peak {
    pub delta: i64,
    pub start_ms: i64,
    pub ms: i64,
}

/// A closed billing period of one channel.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct BillingRecord {
    pub start_ms: i64,
    pub end_ms: i64,
    pub total_start: i64,
    pub total_end: i64,
    /// Exactly `total_end - total_start`.
    pub delta: i64,
    /// Pulses per tariff, summing to `delta` (empty without `[tariffs]`).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub by_tariff: BTreeMap<String, i64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub peak: Option<Peak>,
    pub status: PeriodStatus,
    pub seq: u64,
}
