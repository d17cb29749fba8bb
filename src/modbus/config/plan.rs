//! The poll planner: the registers a device poll needs → as few reads as the wire favours.
//!
//! Pure. A read costs its frame overhead (request, answer header and CRC, two silent intervals,
//! the device's turnaround), and bridging a gap of `g` unused registers costs `2g` characters of
//! answer. Boundaries are chosen by dynamic programming over the sorted values, never inside a
//! 32-bit value, never across a hole the device refused (exception 02), at most 125 registers,
//! or fewer when the line is noisy (a limit from `modbus::driver::sizing`; a single value is never split).

use std::ops::Range;
use std::time::Duration;

use crate::profile::Register;

/// The most registers one FC03 read may return (Modbus spec).
pub const MAX_READ: u16 = 125;

/// One holding-register read.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Block {
    pub start: u16,
    pub len: u16,
}

impl Block {
    pub fn end(&self) -> u16 {
        self.start + self.len
    }

    /// Whether the block covers `r` whole.
    pub fn covers(&self, r: &Register) -> bool {
        r.address >= self.start && r.end() <= self.end()
    }

    /// The unused registers inside this block, given the values it carries.
    pub fn gaps(&self, values: &[Register]) -> Vec<Range<u16>> {
        let mut spans: Vec<Range<u16>> = values
            .iter()
            .filter(|r| self.covers(r))
            .map(|r| r.address..r.end())
            .collect();
        spans.sort_by_key(|s| s.start);
        let mut out = Vec::new();
        let mut at = self.start;
        for s in spans {
            if s.start > at {
                out.push(at..s.start);
            }
            at = at.max(s.end);
        }
        out
    }
}

/// The device turnaround assumed before it is measured (the planner, `check` and `plan`; the bus
/// measures it at run time).
pub const DEFAULT_TURNAROUND: Duration = Duration::from_millis(2);

/// Bytes of a read request and of a write's answer on RTU: address, function, two words, CRC.
pub const REQUEST_BYTES: usize = 8;
/// Bytes of a read's answer around its registers: address, function, byte count, CRC.
pub const ANSWER_OVERHEAD_BYTES: usize = 5;
/// Bytes of an exception answer: address, function | 0x80, code, CRC.
pub const EXCEPTION_BYTES: usize = 5;

/// Bytes of the answer to a read of `registers` registers.
pub fn read_answer_bytes(registers: u16) -> usize {
    ANSWER_OVERHEAD_BYTES + 2 * usize::from(registers)
}

/// Characters of one read of `registers` registers on the wire: the request and the answer.
/// With the constants above, the one place for Modbus RTU frame sizes (the planner's prices,
/// the line's timing and the port's reads of an answer all use them).
pub fn read_chars(registers: u16) -> f64 {
    (REQUEST_BYTES + read_answer_bytes(registers)) as f64
}

/// The reads of one device's poll, as a value: built when the registers change (a work-mode
/// change), when a hole is learned or the wire's prices change; executed by the driver as it
/// is; `check` and `plan` print the same value ([`PollPlan::describe`]).
#[derive(Debug, Clone, PartialEq)]
pub struct PollPlan {
    pub registers: Vec<Register>,
    pub blocks: Vec<Block>,
    /// What it was built for: holes known, the wire's prices, the longest read allowed.
    holes: usize,
    wire: Wire,
    limit: u16,
}

impl PollPlan {
    pub fn new(registers: &[Register], holes: &[Range<u16>], wire: &Wire) -> PollPlan {
        PollPlan::within(registers, holes, wire, MAX_READ)
    }

    /// A plan whose reads are at most `limit` registers long (a value longer than that is
    /// still read whole, alone).
    pub fn within(
        registers: &[Register],
        holes: &[Range<u16>],
        wire: &Wire,
        limit: u16,
    ) -> PollPlan {
        PollPlan {
            registers: registers.to_vec(),
            blocks: plan_reads_within(registers, holes, wire, limit),
            holes: holes.len(),
            wire: *wire,
            limit,
        }
    }

    /// Still the plan for these registers, holes and prices (at the full read length).
    pub fn fits(&self, registers: &[Register], holes: usize, wire: &Wire) -> bool {
        self.fits_within(registers, holes, wire, MAX_READ)
    }

    /// Still the plan for these registers, holes, prices and longest read.
    pub fn fits_within(
        &self,
        registers: &[Register],
        holes: usize,
        wire: &Wire,
        limit: u16,
    ) -> bool {
        self.registers == registers
            && self.holes == holes
            && self.wire == *wire
            && self.limit == limit
    }

    /// The longest read of the plan, in registers.
    pub fn longest(&self) -> u16 {
        self.blocks.iter().map(|b| b.len).max().unwrap_or(0)
    }

    /// Registers read per poll (the plan may bridge gaps).
    pub fn registers_read(&self) -> u16 {
        self.blocks.iter().map(|b| b.len).sum()
    }

    /// `2 request(s) [0+10, 20+4], 14 registers`.
    pub fn describe(&self) -> String {
        let reads: Vec<String> = self
            .blocks
            .iter()
            .map(|b| format!("{}+{}", b.start, b.len))
            .collect();
        format!(
            "{} request(s) [{}], {} registers",
            self.blocks.len(),
            reads.join(", "),
            self.registers_read()
        )
    }
}

/// How the wire prices a read, in characters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Wire {
    /// Characters a separate read costs beyond its data: frames, silences, turnaround.
    pub request_overhead: f64,
}

impl Wire {
    /// RTU at `timing`, with the device's turnaround.
    pub fn rtu(timing: &LineTiming, turnaround: Duration) -> Wire {
        let silences =
            2.0 * timing.silent_interval().as_secs_f64() / timing.char_time().as_secs_f64();
        let turnaround = turnaround.as_secs_f64() / timing.char_time().as_secs_f64();
        Wire {
            request_overhead: read_chars(0) + silences + turnaround,
        }
    }

    /// Modbus TCP: a round trip is cheap in bytes but not in time; price it as ~40 bytes.
    pub fn tcp() -> Wire {
        Wire {
            request_overhead: 12.0 + 9.0 + 20.0,
        }
    }

    /// How a read is priced on a line of `timing` (RTU) or none (TCP) before any device's
    /// turnaround is measured: with [`DEFAULT_TURNAROUND`]. The one place for this rule: the
    /// bus, `pulsegate check` and the commissioning reads all price reads so.
    pub fn for_line(timing: Option<&LineTiming>) -> Wire {
        timing.map_or_else(Wire::tcp, |t| Wire::rtu(t, DEFAULT_TURNAROUND))
    }
}

/// Bits one character takes on a serial line: start bit, 8 data bits, the parity bit if any,
/// and the stop bits. The one place for this rule (the config's line timing and the open port's
/// both ask it).
pub fn bits_per_char(parity: bool, stop_bits: u8) -> u32 {
    1 + 8 + u32::from(parity) + u32::from(stop_bits)
}

/// Character timing of a serial line.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LineTiming {
    pub baud: u32,
    /// Bits per character: start + 8 data + parity + stop.
    pub bits_per_char: u32,
    /// Extra quiet time after the Modbus silent interval.
    pub guard: Duration,
}

impl LineTiming {
    /// Time on the wire of one character.
    pub fn char_time(&self) -> Duration {
        Duration::from_secs_f64(f64::from(self.bits_per_char) / f64::from(self.baud))
    }

    /// The RTU inter-frame silence: 3.5 characters, fixed at 1.75 ms above 19200 baud
    /// (Modbus over serial line, 2.5.1.1), plus the configured guard.
    pub fn silent_interval(&self) -> Duration {
        let t35 = if self.baud > 19200 {
            Duration::from_micros(1750)
        } else {
            self.char_time().mul_f64(3.5)
        };
        t35 + self.guard
    }

    /// Time on the wire of `chars` characters.
    pub fn chars(&self, chars: f64) -> Duration {
        self.char_time().mul_f64(chars)
    }

    /// Time on the wire of `chars` whole characters, to the nanosecond (the port's deadlines).
    pub fn frame_time(&self, chars: usize) -> Duration {
        Duration::from_nanos(
            chars as u64 * u64::from(self.bits_per_char) * 1_000_000_000 / u64::from(self.baud),
        )
    }

    /// Time on the wire of a read of `registers` registers: request and answer.
    pub fn read_time(&self, registers: u16) -> Duration {
        self.chars(read_chars(registers))
    }
}

/// How long to wait for the answer to a read of `registers` registers: the device's `answer`
/// time plus the time request and answer take on the line (`timing`; none on TCP). The one
/// place for this rule: the bus's polls and the commissioning commands both ask it.
pub fn read_timeout(answer: Duration, timing: Option<&LineTiming>, registers: u16) -> Duration {
    answer + timing.map(|t| t.read_time(registers)).unwrap_or_default()
}

/// Splits the values of one device poll into reads. `holes` are ranges the device refused.
pub fn plan_reads(values: &[Register], holes: &[Range<u16>], wire: &Wire) -> Vec<Block> {
    plan_reads_within(values, holes, wire, MAX_READ)
}

/// [`plan_reads`] with reads of at most `limit` registers, except that a value longer than
/// `limit` is read whole on its own (a 32-bit value is never split, even at a limit of 1).
pub fn plan_reads_within(
    values: &[Register],
    holes: &[Range<u16>],
    wire: &Wire,
    limit: u16,
) -> Vec<Block> {
    let mut spans: Vec<Range<u16>> = values.iter().map(|r| r.address..r.end()).collect();
    spans.sort_by_key(|s| (s.start, s.end));
    // Merge overlapping values (the same register asked twice) so no value is split.
    let mut merged: Vec<Range<u16>> = Vec::new();
    for s in spans {
        match merged.last_mut() {
            Some(last) if s.start < last.end => last.end = last.end.max(s.end),
            _ => merged.push(s),
        }
    }
    let n = merged.len();
    if n == 0 {
        return Vec::new();
    }
    let crosses_hole =
        |gap: Range<u16>| holes.iter().any(|h| h.start < gap.end && gap.start < h.end);
    // best[j]: (cost, reads, previous split) for the first j spans.
    let mut best: Vec<(f64, usize, usize)> = vec![(f64::INFINITY, usize::MAX, 0); n + 1];
    best[0] = (0.0, 0, 0);
    for j in 1..=n {
        for i in (1..=j).rev() {
            let start = merged[i - 1].start;
            let end = merged[j - 1].end;
            let len = end - start;
            if len > MAX_READ || (i < j && len > limit) {
                break;
            }
            if i < j && crosses_hole(merged[i - 1].end..merged[i].start) {
                // The gap between span i-1 and i would be inside the block: widening further
                // left only keeps it inside.
                break;
            }
            let (prev_cost, prev_reads, _) = best[i - 1];
            let cost = prev_cost + wire.request_overhead + 2.0 * f64::from(end - start);
            let reads = prev_reads + 1;
            if cost < best[j].0 - 1e-9 || ((cost - best[j].0).abs() <= 1e-9 && reads < best[j].1) {
                best[j] = (cost, reads, i - 1);
            }
        }
    }
    let mut blocks = Vec::new();
    let mut j = n;
    while j > 0 {
        let i = best[j].2;
        let start = merged[i].start;
        blocks.push(Block {
            start,
            len: merged[j - 1].end - start,
        });
        j = i;
    }
    blocks.reverse();
    blocks
}

/// Estimated time on an RTU line of one poll made of `blocks`, with the device's turnaround.
pub fn line_time(blocks: &[Block], timing: &LineTiming, turnaround: Duration) -> Duration {
    blocks
        .iter()
        .map(|b| timing.chars(read_chars(b.len)) + timing.silent_interval() * 2 + turnaround)
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::profile::ValueType;

    fn u32_at(address: u16) -> Register {
        Register {
            address,
            ty: ValueType::U32,
        }
    }

    fn wire(overhead: f64) -> Wire {
        Wire {
            request_overhead: overhead,
        }
    }

    #[test]
    fn a_poll_plan_is_kept_until_its_registers_holes_or_prices_change() {
        let v = [u32_at(16), u32_at(128)];
        let plan = PollPlan::new(&v, &[], &wire(20.0));
        assert_eq!(plan.describe(), "2 request(s) [16+2, 128+2], 4 registers");
        assert!(plan.fits(&v, 0, &wire(20.0)));
        assert!(!plan.fits(&v[..1], 0, &wire(20.0)), "another work mode");
        assert!(!plan.fits(&v, 1, &wire(20.0)), "a hole learned");
        assert!(!plan.fits(&v, 0, &wire(400.0)), "the wire priced anew");
        let bridged = PollPlan::new(&v, &[], &wire(400.0));
        assert_eq!(bridged.describe(), "1 request(s) [16+114], 114 registers");
    }

    #[test]
    fn a_modbus_read_of_n_registers_is_13_plus_2n_characters() {
        // Request 01 03 00 10 00 02 CRC CRC (8); answer 01 03 04 + 4 data + CRC CRC (5 + 4).
        assert_eq!(read_chars(2), 17.0);
        assert_eq!(read_chars(0), 13.0);
    }

    #[test]
    fn adjacent_values_are_read_in_one_request() {
        let v = [u32_at(16), u32_at(18), u32_at(20), u32_at(22)];
        assert_eq!(
            plan_reads(&v, &[], &wire(20.0)),
            vec![Block { start: 16, len: 8 }]
        );
    }

    #[test]
    fn a_gap_is_bridged_only_when_cheaper_than_a_new_request() {
        // Gap of 4 registers costs 8 characters: cheaper than a 20-character request.
        let v = [u32_at(16), u32_at(22)];
        assert_eq!(
            plan_reads(&v, &[], &wire(20.0)),
            vec![Block { start: 16, len: 8 }]
        );
        // Gap of 104 registers costs 208 characters: two requests.
        let v = [u32_at(16), u32_at(128)];
        assert_eq!(
            plan_reads(&v, &[], &wire(20.0)),
            vec![Block { start: 16, len: 2 }, Block { start: 128, len: 2 }]
        );
        // The same 4-register gap with a very cheap request is not bridged.
        let v = [u32_at(16), u32_at(22)];
        assert_eq!(plan_reads(&v, &[], &wire(4.0)).len(), 2);
    }

    #[test]
    fn a_known_hole_is_never_bridged() {
        let v = [u32_at(16), u32_at(22)];
        #[allow(clippy::single_range_in_vec_init)] // one hole, as a list
        let holes = vec![19..21];
        assert_eq!(
            plan_reads(&v, &holes, &wire(1000.0)),
            vec![Block { start: 16, len: 2 }, Block { start: 22, len: 2 }]
        );
    }

    #[test]
    fn no_read_is_longer_than_125_registers() {
        let v: Vec<Register> = (0..100).map(|i| u32_at(i * 2)).collect();
        let blocks = plan_reads(&v, &[], &wire(1000.0));
        assert!(blocks.iter().all(|b| b.len <= MAX_READ));
        assert_eq!(blocks.iter().map(|b| b.len).sum::<u16>(), 200);
    }

    #[test]
    fn a_32_bit_value_is_never_split_across_reads() {
        // 62 u32 values fill 124 registers; the 63rd would make 126, so it goes whole.
        let v: Vec<Register> = (0..63).map(|i| u32_at(i * 2)).collect();
        let blocks = plan_reads(&v, &[], &wire(1000.0));
        for r in &v {
            assert!(blocks.iter().any(|b| b.covers(r)), "{r:?} is split");
        }
    }

    #[test]
    fn a_limit_splits_a_block_without_splitting_a_value() {
        // 4 u32 values side by side: one read of 8 at full length.
        let v = [u32_at(16), u32_at(18), u32_at(20), u32_at(22)];
        let at = |limit| plan_reads_within(&v, &[], &wire(1000.0), limit);
        assert_eq!(at(MAX_READ), vec![Block { start: 16, len: 8 }]);
        assert_eq!(
            at(4),
            vec![Block { start: 16, len: 4 }, Block { start: 20, len: 4 }]
        );
        // A limit of 3 cannot take two values: one value a read.
        assert_eq!(at(3).len(), 4);
        // Nor can a limit of 1 split a 32-bit value: it is read whole, alone.
        assert_eq!(at(1), at(2));
        assert!(at(1).iter().all(|b| b.len == 2));
    }

    #[test]
    fn a_plan_within_a_limit_is_another_plan() {
        let v = [u32_at(16), u32_at(18)];
        let plan = PollPlan::within(&v, &[], &wire(20.0), 2);
        assert_eq!(plan.describe(), "2 request(s) [16+2, 18+2], 4 registers");
        assert_eq!(plan.longest(), 2);
        assert!(plan.fits_within(&v, 0, &wire(20.0), 2));
        assert!(
            !plan.fits(&v, 0, &wire(20.0)),
            "the full length is another plan"
        );
    }

    #[test]
    fn the_same_register_asked_twice_is_read_once() {
        let v = [u32_at(16), u32_at(16)];
        assert_eq!(
            plan_reads(&v, &[], &wire(20.0)),
            vec![Block { start: 16, len: 2 }]
        );
    }

    #[test]
    fn gaps_lists_the_bridged_registers() {
        let v = [u32_at(16), u32_at(22)];
        assert_eq!(Block { start: 16, len: 8 }.gaps(&v), vec![18..22]);
    }

    #[test]
    fn the_silent_interval_is_fixed_above_19200_baud() {
        let t = |baud| LineTiming {
            baud,
            bits_per_char: 10,
            guard: Duration::ZERO,
        };
        assert_eq!(t(115200).silent_interval(), Duration::from_micros(1750));
        let at_9600 = t(9600).silent_interval().as_secs_f64();
        assert!((at_9600 - 3.5 * 10.0 / 9600.0).abs() < 1e-6, "{at_9600}");
    }
}
