use super::*;
use crate::mbus::driver::address::SecondaryMask;

/// `68 03 03 68 08 01 70 79 16`: an application error frame from the corpus.
const CONTROL: [u8; 9] = [0x68, 0x03, 0x03, 0x68, 0x08, 0x01, 0x70, 0x79, 0x16];

#[test]
fn the_single_character_is_an_ack_of_one_byte() {
    assert_eq!(
        scan(&[0xE5, 0x10]).unwrap(),
        Scan::Frame {
            frame: Frame::Ack,
            consumed: 1
        }
    );
}

#[test]
fn a_short_frame_reads_control_and_address() {
    let bytes = [0x10, 0x7B, 0x05, 0x80, 0x16];
    assert_eq!(
        parse(&bytes).unwrap(),
        Frame::Short {
            control: 0x7B,
            address: 5
        }
    );
}

#[test]
fn a_partial_frame_says_how_many_more_bytes_it_needs() {
    assert_eq!(scan(&[]).unwrap(), Scan::Need(1));
    assert_eq!(scan(&[0x10, 0x7B]).unwrap(), Scan::Need(3));
    assert_eq!(scan(&[0x68]).unwrap(), Scan::Need(3));
    assert_eq!(scan(&CONTROL[..4]).unwrap(), Scan::Need(5));
    assert_eq!(scan(&CONTROL[..8]).unwrap(), Scan::Need(1));
    assert_eq!(
        scan(&CONTROL).unwrap(),
        Scan::Frame {
            frame: Frame::Control {
                control: 0x08,
                address: 1,
                ci: 0x70
            },
            consumed: 9
        }
    );
}

#[test]
fn a_long_frame_that_says_255_needs_no_more_than_261_bytes() {
    assert_eq!(
        scan(&[0x68, 0xFF, 0xFF, 0x68]).unwrap(),
        Scan::Need(MAX_FRAME - 4)
    );
}

#[test]
fn broken_frames_name_their_fault() {
    let mut bad_sum = CONTROL;
    bad_sum[7] = 0x7A;
    assert_eq!(
        parse(&bad_sum).unwrap_err(),
        ParseError::Frame(FrameError::BadChecksum {
            expected: 0x79,
            found: 0x7A
        })
    );
    let mut bad_stop = CONTROL;
    bad_stop[8] = 0x17;
    assert_eq!(
        parse(&bad_stop).unwrap_err(),
        FrameError::BadStop(0x17).into()
    );
    assert_eq!(
        scan(&[0x68, 0x03, 0x04]).unwrap_err(),
        FrameError::LengthMismatch(3, 4)
    );
    assert_eq!(scan(&[0x00]).unwrap_err(), FrameError::Garbage(0));
    assert_eq!(
        scan(&[0x68, 0x02, 0x02, 0x68]).unwrap_err(),
        FrameError::TooShort(2)
    );
    assert_eq!(
        scan(&[0x68, 0x03, 0x03, 0x10]).unwrap_err(),
        FrameError::BadSecondStart(0x10)
    );
    assert_eq!(
        parse(&[0xE5, 0xE5]).unwrap_err(),
        FrameError::Trailing(1).into()
    );
    assert_eq!(parse(&CONTROL[..6]).unwrap_err(), ParseError::Incomplete(3));
}

#[test]
fn master_frames_are_the_standards_bytes() {
    assert_eq!(snd_nke(1), [0x10, 0x40, 0x01, 0x41, 0x16]);
    assert_eq!(req_ud2(1, false), [0x10, 0x5B, 0x01, 0x5C, 0x16]);
    assert_eq!(req_ud2(0xFE, true), [0x10, 0x7B, 0xFE, 0x79, 0x16]);
    let mask = SecondaryMask::from_id("14491001").unwrap();
    assert_eq!(
        select(&mask),
        [
            0x68, 0x0B, 0x0B, 0x68, 0x73, 0xFD, 0x52, 0x01, 0x10, 0x49, 0x14, 0xFF, 0xFF, 0xFF,
            0xFF, 0x2C, 0x16
        ]
    );
    assert_eq!(
        application_reset(3),
        [0x68, 0x03, 0x03, 0x68, 0x53, 0x03, 0x50, 0xA6, 0x16]
    );
}

#[test]
fn a_frame_reads_back_what_it_encodes() {
    let frame = Frame::Long {
        control: 0x08,
        address: 7,
        ci: 0x72,
        data: vec![1, 2, 3],
    };
    assert_eq!(parse(&frame.encode()).unwrap(), frame);
}

#[test]
fn the_fcb_starts_set_after_a_reset_and_toggles_on_each_answer() {
    let mut fcb = Fcb::after_reset();
    assert_eq!(fcb.request(5)[1], 0x7B);
    // No answer: the same bit again.
    assert_eq!(fcb.request(5)[1], 0x7B);
    fcb.answered();
    assert_eq!(fcb.request(5)[1], 0x5B);
    fcb.answered();
    assert!(fcb.bit());
}
