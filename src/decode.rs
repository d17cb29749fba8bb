//! Words off the wire → typed values, by the profile's type and word order.

use crate::profile::{ValueType, WordOrder};

/// A decoded register value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Value {
    Int(i64),
    Float(f64),
}

impl Value {
    /// The value as an integer count; floats are rounded (never used for counts by the seeds).
    pub fn as_i64(self) -> i64 {
        match self {
            Value::Int(v) => v,
            Value::Float(f) => f.round() as i64,
        }
    }

    /// The value as a float.
    pub fn as_f64(self) -> f64 {
        match self {
            Value::Int(v) => v as f64,
            Value::Float(f) => f,
        }
    }
}

/// Joins two registers into one 32-bit word in the profile's order.
fn join(words: &[u16], order: WordOrder) -> u32 {
    let (hi, lo) = match order {
        WordOrder::HighFirst => (words[0], words[1]),
        WordOrder::LowFirst => (words[1], words[0]),
    };
    (u32::from(hi) << 16) | u32::from(lo)
}

/// Decodes `ty` from the start of `words`. `words` must hold at least `ty.words()` registers:
/// the plan guarantees it, and [`decode_checked`] is the form for untrusted input.
pub fn decode(words: &[u16], ty: ValueType, order: WordOrder) -> Value {
    match ty {
        ValueType::U16 => Value::Int(i64::from(words[0])),
        ValueType::I16 => Value::Int(i64::from(words[0] as i16)),
        ValueType::U32 => Value::Int(i64::from(join(words, order))),
        ValueType::I32 => Value::Int(i64::from(join(words, order) as i32)),
        ValueType::F32 => Value::Float(f64::from(f32::from_bits(join(words, order)))),
    }
}

/// Like [`decode`], but `None` when `words` is too short.
pub fn decode_checked(words: &[u16], ty: ValueType, order: WordOrder) -> Option<Value> {
    (words.len() >= usize::from(ty.words())).then(|| decode(words, ty, order))
}

/// Encodes an integer for a preset write; `None` when it does not fit the type.
pub fn encode_int(value: i64, ty: ValueType, order: WordOrder) -> Option<Vec<u16>> {
    let bits: u32 = match ty {
        ValueType::U16 => return u16::try_from(value).ok().map(|v| vec![v]),
        ValueType::I16 => return i16::try_from(value).ok().map(|v| vec![v as u16]),
        ValueType::U32 => u32::try_from(value).ok()?,
        ValueType::I32 => i32::try_from(value).ok()? as u32,
        ValueType::F32 => return None,
    };
    let (hi, lo) = ((bits >> 16) as u16, bits as u16);
    Some(match order {
        WordOrder::HighFirst => vec![hi, lo],
        WordOrder::LowFirst => vec![lo, hi],
    })
}

/// Words of an IEEE 754 float register in `order` (the simulator's frequency registers).
pub fn encode_f32(value: f32, order: WordOrder) -> Vec<u16> {
    let bits = value.to_bits();
    let (hi, lo) = ((bits >> 16) as u16, bits as u16);
    match order {
        WordOrder::HighFirst => vec![hi, lo],
        WordOrder::LowFirst => vec![lo, hi],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_float_is_encoded_in_the_word_order_the_decoder_reads() {
        // 1000.0 is 0x447A0000 in IEEE 754 single precision.
        assert_eq!(encode_f32(1000.0, WordOrder::HighFirst), [0x447A, 0x0000]);
        assert_eq!(encode_f32(1000.0, WordOrder::LowFirst), [0x0000, 0x447A]);
        let words = encode_f32(-12.5, WordOrder::LowFirst);
        let back = decode(&words, ValueType::F32, WordOrder::LowFirst).as_f64();
        assert_eq!(back, -12.5);
    }

    /// Registers of a read answer frame: address, function, byte count, data, CRC.
    fn frame_words(frame: &[u8]) -> Vec<u16> {
        let n = usize::from(frame[2]);
        frame[3..3 + n]
            .chunks(2)
            .map(|b| u16::from_be_bytes([b[0], b[1]]))
            .collect()
    }

    const YL67_ANSWER: [u8; 9] = [0x01, 0x03, 0x04, 0xCA, 0x90, 0xFF, 0xFF, 0xC4, 0x76];

    #[test]
    fn the_datasheet_answer_is_encoder_count_minus_13680() {
        let w = frame_words(&YL67_ANSWER);
        assert_eq!(
            decode(&w, ValueType::I32, WordOrder::LowFirst),
            Value::Int(-13680)
        );
    }

    #[test]
    fn the_same_words_as_a_di_count_are_4294953616() {
        let w = frame_words(&YL67_ANSWER);
        assert_eq!(
            decode(&w, ValueType::U32, WordOrder::LowFirst),
            Value::Int(4_294_953_616)
        );
    }

    #[test]
    fn the_datasheet_answer_frame_has_a_valid_crc() {
        // CRC-16/MODBUS over everything but the CRC, sent low byte first.
        let mut crc: u16 = 0xFFFF;
        for &b in &YL67_ANSWER[..7] {
            crc ^= u16::from(b);
            for _ in 0..8 {
                crc = if crc & 1 != 0 {
                    (crc >> 1) ^ 0xA001
                } else {
                    crc >> 1
                };
            }
        }
        assert_eq!(crc.to_le_bytes(), [YL67_ANSWER[7], YL67_ANSWER[8]]);
    }

    #[test]
    fn zh_yx1600_reads_high_word_first() {
        assert_eq!(
            decode(&[0x0001, 0x86A0], ValueType::I32, WordOrder::HighFirst),
            Value::Int(100_000)
        );
        assert_eq!(
            decode(&[0xFFFF, 0xFFFF], ValueType::I32, WordOrder::HighFirst),
            Value::Int(-1)
        );
    }

    #[test]
    fn sixteen_bit_values_ignore_word_order() {
        assert_eq!(
            decode(&[0xFFFE], ValueType::I16, WordOrder::LowFirst),
            Value::Int(-2)
        );
        assert_eq!(
            decode(&[0xFFFE], ValueType::U16, WordOrder::HighFirst),
            Value::Int(65534)
        );
    }

    #[test]
    fn floats_follow_the_word_order() {
        let bits = 1000.5f32.to_bits();
        let (hi, lo) = ((bits >> 16) as u16, bits as u16);
        assert_eq!(
            decode(&[lo, hi], ValueType::F32, WordOrder::LowFirst),
            Value::Float(1000.5)
        );
        assert_eq!(
            decode(&[hi, lo], ValueType::F32, WordOrder::HighFirst),
            Value::Float(1000.5)
        );
    }

    #[test]
    fn encode_is_the_inverse_of_decode() {
        for order in [WordOrder::LowFirst, WordOrder::HighFirst] {
            for (v, ty) in [
                (-13680, ValueType::I32),
                (4_294_953_616, ValueType::U32),
                (i64::from(i32::MIN), ValueType::I32),
                (65535, ValueType::U16),
            ] {
                let words = encode_int(v, ty, order).unwrap();
                assert_eq!(decode(&words, ty, order), Value::Int(v));
            }
        }
    }

    #[test]
    fn encode_refuses_values_outside_the_type() {
        assert_eq!(encode_int(-1, ValueType::U32, WordOrder::LowFirst), None);
        assert_eq!(
            encode_int(1 << 31, ValueType::I32, WordOrder::LowFirst),
            None
        );
        assert_eq!(
            encode_int(1 << 32, ValueType::U32, WordOrder::LowFirst),
            None
        );
    }

    #[test]
    fn short_input_is_refused_not_a_panic() {
        assert_eq!(
            decode_checked(&[1], ValueType::U32, WordOrder::LowFirst),
            None
        );
    }
}
