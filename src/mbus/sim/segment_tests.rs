//! The segment answers the standard's literal request bytes; what it sends back is checked
//! against bytes written out by hand (and a frame of libmbus's corpus), not against the
//! gateway's encoder.

use super::super::meter::{Behaviour, Gauge, Quantity, Register, SimMeter, Width};
use super::*;

fn hex(text: &str) -> Vec<u8> {
    text.split_whitespace()
        .map(|h| u8::from_str_radix(h, 16).unwrap())
        .collect()
}

/// A heat meter, id 12345678, KAM, version 1, medium 04, at primary address 1: one energy
/// register of 1234 kWh that does not move.
fn heat_meter(address: u8) -> SimMeter {
    SimMeter::new(12345678, "KAM", 1, 4, address).with_register(Register::new(
        Quantity::EnergyKwh,
        Width::Bcd8,
        1234,
        0.0,
    ))
}

const SND_NKE_1: &str = "10 40 01 41 16";
const REQ_UD2_FCB_1: &str = "10 7B 01 7C 16";
const REQ_UD2_1: &str = "10 5B 01 5C 16";
/// Its answer: `68 L L 68 08 01 72`, id 78 56 34 12, KAM 2D 2C, version 01, medium 04,
/// access 01, status 00, signature 00 00; `0C 06` 1234 kWh as BCD; `0C 78` the fabrication
/// number.
const ANSWER_1: &str = "68 1B 1B 68 08 01 72 78 56 34 12 2D 2C 01 04 01 00 00 00 0C 06 34 12 00 00 0C 78 78 56 34 12 DE 16";

#[test]
fn snd_nke_is_acknowledged_with_e5() {
    let mut seg = Segment::new(vec![heat_meter(1)]);
    assert_eq!(seg.answer(0.0, &hex(SND_NKE_1)), [0xE5]);
    assert!(seg.answer(0.0, &hex("10 40 02 42 16")).is_empty());
}

#[test]
fn req_ud2_is_answered_with_the_meters_rsp_ud() {
    let mut seg = Segment::new(vec![heat_meter(1)]);
    seg.answer(0.0, &hex(SND_NKE_1));
    assert_eq!(seg.answer(0.0, &hex(REQ_UD2_FCB_1)), hex(ANSWER_1));
}

#[test]
fn the_same_fcb_repeats_the_last_answer_and_a_toggled_one_gives_a_new_one() {
    let mut seg = Segment::new(vec![heat_meter(1)]);
    seg.answer(0.0, &hex(SND_NKE_1));
    let first = seg.answer(0.0, &hex(REQ_UD2_FCB_1));
    assert_eq!(seg.answer(5.0, &hex(REQ_UD2_FCB_1)), first);
    let next = seg.answer(5.0, &hex(REQ_UD2_1));
    assert_ne!(next, first);
    assert_eq!(next[15], 2, "the access number counts new answers");
}

#[test]
fn a_bad_checksum_or_noise_is_ignored_like_a_real_meter_does() {
    let mut seg = Segment::new(vec![heat_meter(1)]);
    assert!(seg.answer(0.0, &hex("10 7B 01 7D 16")).is_empty());
    assert!(seg.answer(0.0, &hex("00 11 22")).is_empty());
}

#[test]
fn a_select_by_secondary_address_makes_the_one_match_answer_at_253() {
    let mut seg = Segment::new(vec![heat_meter(0), heat_meter_id(87654321, 0)]);
    let select = "68 0B 0B 68 73 FD 52 78 56 34 12 FF FF FF FF D2 16";
    assert_eq!(seg.answer(0.0, &hex(select)), [0xE5]);
    let answer = seg.answer(0.0, &hex("10 7B FD 78 16"));
    assert_eq!(&answer[7..11], [0x78, 0x56, 0x34, 0x12]);
    // SND_NKE to 253 deselects: no one answers at 253 any more.
    assert_eq!(seg.answer(0.0, &hex("10 40 FD 3D 16")), [0xE5]);
    assert!(seg.answer(0.0, &hex("10 5B FD 58 16")).is_empty());
}

fn heat_meter_id(id: u32, address: u8) -> SimMeter {
    let mut m = heat_meter(address);
    m.id = id;
    m
}

#[test]
fn a_wildcard_matching_two_meters_collides_and_one_digit_more_resolves_it() {
    let mut seg = Segment::new(vec![heat_meter_id(12345678, 0), heat_meter_id(18000000, 0)]);
    // 1FFFFFFF: both match; the master hears no clean E5.
    let both = seg.answer(
        0.0,
        &hex("68 0B 0B 68 73 FD 52 FF FF FF 1F FF FF FF FF DA 16"),
    );
    assert!(!both.is_empty() && both != [0xE5], "{both:02X?}");
    // 12FFFFFF: one matches.
    let one = seg.answer(
        0.0,
        &hex("68 0B 0B 68 73 FD 52 FF FF FF 12 FF FF FF FF CD 16"),
    );
    assert_eq!(one, [0xE5]);
    // 3FFFFFFF: none.
    assert!(
        seg.answer(
            0.0,
            &hex("68 0B 0B 68 73 FD 52 FF FF FF 3F FF FF FF FF FA 16")
        )
        .is_empty()
    );
}

#[test]
fn two_meters_at_one_primary_address_collide() {
    let mut seg = Segment::new(vec![heat_meter_id(12345678, 0), heat_meter_id(18000000, 0)]);
    let alone = Segment::new(vec![heat_meter_id(12345678, 0)]).answer(0.0, &hex("10 5B 00 5B 16"));
    let heard = seg.answer(0.0, &hex("10 5B 00 5B 16"));
    assert!(!heard.is_empty());
    assert_ne!(heard, alone, "neither answer arrives whole");
}

#[test]
fn a_meter_with_many_records_answers_in_telegrams_linked_by_dif_1f() {
    let mut m = heat_meter(1)
        .with_gauge(Gauge::PowerW(1500))
        .with_gauge(Gauge::FlowTemperatureCenti(6550));
    m.records_per_telegram = 2;
    let mut seg = Segment::new(vec![m]);
    seg.answer(0.0, &hex(SND_NKE_1));
    let first = seg.answer(0.0, &hex(REQ_UD2_FCB_1));
    assert_eq!(first[first.len() - 3], 0x1F, "more records follow");
    let second = seg.answer(0.0, &hex(REQ_UD2_1));
    assert_eq!(
        &second[19..21],
        [0x02, 0x59],
        "the flow temperature comes next"
    );
    assert_ne!(second[second.len() - 3], 0x1F, "and last");
    let again = seg.answer(0.0, &hex(REQ_UD2_FCB_1));
    assert_eq!(&again[19..21], [0x0C, 0x06], "then the readout starts over");
}

#[test]
fn a_recorded_corpus_frame_is_served_at_the_meters_own_address() {
    let kamstrup = "68 46 46 68 08 78 72 20 91 83 14 2D 2C 01 02 04 00 00 00 04 06 00 00 00 00 04 22 09 00 00 00 04 2B 00 00 00 00 14 2B 00 00 00 00 84 50 06 00 00 00 00 84 60 06 00 00 00 00 0F 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 10 24 16";
    let mut m = SimMeter::new(14839120, "KAM", 1, 2, 5);
    m.recorded = Some(hex(kamstrup));
    let mut seg = Segment::new(vec![m]);
    let served = "68 46 46 68 08 05 72 20 91 83 14 2D 2C 01 02 04 00 00 00 04 06 00 00 00 00 04 22 09 00 00 00 04 2B 00 00 00 00 14 2B 00 00 00 00 84 50 06 00 00 00 00 84 60 06 00 00 00 00 0F 00 00 00 00 00 00 00 00 00 00 00 00 00 00 00 10 B1 16";
    assert_eq!(seg.answer(0.0, &hex("10 7B 05 80 16")), hex(served));
}

#[test]
fn a_silent_meter_answers_nothing_and_a_broken_one_garbage() {
    let mut silent = heat_meter(1);
    silent.behaviour = Behaviour::Silent;
    let mut broken = heat_meter(2);
    broken.behaviour = Behaviour::Garbage;
    let mut seg = Segment::new(vec![silent, broken]);
    assert!(seg.answer(0.0, &hex(REQ_UD2_FCB_1)).is_empty());
    for _ in 0..3 {
        let garbage = seg.answer(0.0, &hex("10 7B 02 7D 16"));
        assert!(!garbage.is_empty());
        assert_ne!(garbage, [0xE5]);
    }
}

#[test]
fn registers_count_at_their_rate_between_polls() {
    let m = SimMeter::new(1, "ELS", 1, 7, 1).with_register(Register::new(
        Quantity::VolumeLitre,
        Width::Bcd8,
        0,
        2.0,
    ));
    let mut seg = Segment::new(vec![m]);
    let answer = seg.answer(10.0, &hex(REQ_UD2_FCB_1));
    assert_eq!(&answer[19..25], [0x0C, 0x13, 0x20, 0x00, 0x00, 0x00]);
}
