//! `pulsegate raw`: read or write holding registers of any unit, model unknown, for what the
//! profiles do not cover.

use crate::commission::error::CommissionError;
use crate::commission::target::Target;
use crate::modbus::driver::link::Link;

/// Reads `count` registers from `start` at `unit`.
pub(crate) async fn read(
    link: &mut Link,
    target: &Target,
    unit: u8,
    start: u16,
    count: u16,
    answer: std::time::Duration,
) -> Result<Vec<u16>, CommissionError> {
    if count == 0 || count > 125 || u32::from(start) + u32::from(count) > 0x1_0000 {
        return Err(CommissionError::BadInput(format!(
            "read {start} {count}: Modbus reads 1..=125 registers within 0..=65535"
        )));
    }
    let timeout = link.timeout_for(answer, count);
    match link.read(unit, start, count, timeout).await {
        Ok(Ok(words)) => Ok(words),
        Ok(Err(exception)) => Err(CommissionError::Refused {
            unit,
            what: format!("a read of {count} registers at {start}"),
            exception: format!("{exception:?}"),
        }),
        Err(e) => Err(target.error(unit, e)),
    }
}

/// Writes `values` from `address` (one value: FC06, more: FC16) at `unit`.
pub(crate) async fn write(
    link: &mut Link,
    target: &Target,
    unit: u8,
    address: u16,
    values: &[u16],
    answer: std::time::Duration,
) -> Result<(), CommissionError> {
    if values.is_empty()
        || values.len() > 123
        || u32::from(address) + values.len() as u32 > 0x1_0000
    {
        return Err(CommissionError::BadInput(format!(
            "write {address}: Modbus writes 1..=123 registers within 0..=65535"
        )));
    }
    let timeout = link.timeout_for(answer, values.len() as u16);
    let answer = if let [one] = values {
        link.write_register(unit, address, *one, timeout).await
    } else {
        link.write_registers(unit, address, values, timeout).await
    };
    match answer {
        Ok(Ok(())) => Ok(()),
        Ok(Err(exception)) => Err(CommissionError::Refused {
            unit,
            what: format!("a write at {address}"),
            exception: format!("{exception:?}"),
        }),
        Err(e) => Err(target.error(unit, e)),
    }
}

/// Words as a table: address, decimal, hex.
pub fn words_table(start: u16, words: &[u16]) -> String {
    words
        .iter()
        .enumerate()
        .map(|(i, w)| format!("{:>5}  {:>5}  0x{w:04X}\n", usize::from(start) + i, w))
        .collect()
}
