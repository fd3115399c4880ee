//! Consistent Overhead Byte Stuffing (COBS, Cheshire and Baker, 1999), the link's
//! framing: checked, without a path to a panic.
//!
//! An encoded frame is a sequence of blocks. Each block starts with a code byte `c`
//! (1..=255) followed by `c - 1` data bytes, none of them `0x00`; a block with `c < 255`
//! stands for its data followed by one `0x00`, except the last block of the frame, whose
//! zero is not part of the data. A block with `c = 255` holds 254 data bytes and no zero.
//! So the encoded frame contains no `0x00` at all, and `0x00` can delimit frames.
//!
//! Every index here goes through `get`/`get_mut`, so a malformed input or a short
//! buffer is an error the caller sees, never a bounds-check panic: the firmware images
//! link no panic machinery (`.ci/no-panic`), and the `cobs` crate's in-place decoder
//! (0.5) indexes its buffer directly. The encoding is the `cobs` crate's, byte for byte
//! (a frame that ends with a full 254-byte block gets no extra empty block); the tests
//! compare the two.

/// The largest data length of one block (bytes): its code byte is `0xFF`.
const BLOCK_DATA_MAX: u8 = 0xFE;

/// Encodes `data` into `out` (no delimiter is added). Returns the encoded length:
/// `data.len() + 1` for data shorter than 254 bytes, at most
/// `data.len() + data.len() / 254 + 1`. `None` when `out` is too short; `out` is then
/// partly written.
pub fn encode(data: &[u8], out: &mut [u8]) -> Option<usize> {
    // Index of the current block's code byte, the block's code so far (data bytes + 1),
    // and the next free output index.
    let mut code_at = 0usize;
    let mut code = 1u8;
    let mut next = 1usize;
    let last = data.len().checked_sub(1);
    for (i, &byte) in data.iter().enumerate() {
        if byte == 0 {
            *out.get_mut(code_at)? = code;
            code_at = next;
            next = next.checked_add(1)?;
            code = 1;
            continue;
        }
        *out.get_mut(next)? = byte;
        next = next.checked_add(1)?;
        code = code.saturating_add(1);
        // A full block closes at once, unless the data ends with it: then the final
        // write below closes it and no empty block follows.
        if code == BLOCK_DATA_MAX + 1 && Some(i) != last {
            *out.get_mut(code_at)? = code;
            code_at = next;
            next = next.checked_add(1)?;
            code = 1;
        }
    }
    *out.get_mut(code_at)? = code;
    Some(next)
}

/// Decodes one encoded frame (without its delimiter) in place: on success the first
/// `n` bytes of `buf` hold the data and `Some(n)` is returned. `None` for an invalid
/// encoding: an empty frame, a `0x00` anywhere, or a block longer than what is left.
/// Time is linear in `buf.len()`.
pub fn decode_in_place(buf: &mut [u8]) -> Option<usize> {
    let len = buf.len();
    if len == 0 {
        return None;
    }
    // Decoding never writes ahead of what it reads: a block of `c` encoded bytes
    // decodes to at most `c` bytes (its `c - 1` data bytes and one zero).
    let mut read = 0usize;
    let mut write = 0usize;
    while read < len {
        let code = *buf.get(read)?;
        if code == 0 {
            return None;
        }
        read += 1;
        let data_len = usize::from(code - 1);
        if data_len > len - read {
            return None;
        }
        for _ in 0..data_len {
            let byte = *buf.get(read)?;
            if byte == 0 {
                return None;
            }
            *buf.get_mut(write)? = byte;
            read += 1;
            write += 1;
        }
        if code != BLOCK_DATA_MAX + 1 && read < len {
            *buf.get_mut(write)? = 0;
            write += 1;
        }
    }
    Some(write)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Encodes and checks against `expected`, then decodes back.
    fn check(data: &[u8], expected: &[u8]) {
        let mut out = [0u8; 600];
        let n = encode(data, &mut out).expect("fits");
        assert_eq!(&out[..n], expected, "encoding of {data:?}");
        let mut buf = out;
        let m = decode_in_place(&mut buf[..n]).expect("valid");
        assert_eq!(&buf[..m], data);
    }

    /// `n` non-zero bytes 1, 2, .., wrapping past 255 to 1, written into `buf` at `at`.
    fn ramp(buf: &mut [u8], at: usize, n: usize) {
        for (k, b) in buf[at..at + n].iter_mut().enumerate() {
            *b = (k % 255 + 1) as u8;
        }
    }

    #[test]
    fn known_vectors() {
        // The examples of the COBS paper and of its common descriptions.
        check(&[], &[0x01]);
        check(&[0x00], &[0x01, 0x01]);
        check(&[0x00, 0x00], &[0x01, 0x01, 0x01]);
        check(&[0x00, 0x11, 0x00], &[0x01, 0x02, 0x11, 0x01]);
        check(&[0x11, 0x22, 0x00, 0x33], &[0x03, 0x11, 0x22, 0x02, 0x33]);
        check(&[0x11, 0x22, 0x33, 0x44], &[0x05, 0x11, 0x22, 0x33, 0x44]);
        check(&[0x11, 0x00, 0x00, 0x00], &[0x02, 0x11, 0x01, 0x01, 0x01]);
        let (mut d, mut e) = ([0u8; 300], [0u8; 300]);
        // 254 non-zero bytes: one full block, no empty block after it.
        ramp(&mut d, 0, 254);
        e[0] = 0xFF;
        ramp(&mut e, 1, 254);
        check(&d[..254], &e[..255]);
        // 255 non-zero bytes: a full block and a block of one.
        ramp(&mut d, 0, 255);
        e[255..257].copy_from_slice(&[0x02, 0xFF]);
        check(&d[..255], &e[..257]);
        // 254 non-zero bytes, then a zero: the full block, an empty block for the zero,
        // and the final empty block.
        d[254] = 0;
        e[255..257].copy_from_slice(&[0x01, 0x01]);
        check(&d[..255], &e[..257]);
        // A zero, then 254 non-zero bytes.
        d[0] = 0;
        ramp(&mut d, 1, 254);
        e[..2].copy_from_slice(&[0x01, 0xFF]);
        ramp(&mut e, 2, 254);
        check(&d[..255], &e[..256]);
    }

    #[test]
    fn invalid_encodings_are_refused() {
        for bad in [
            &[][..],
            &[0x00],
            &[0x02],
            &[0x03, 0x11],
            &[0x02, 0x00],
            &[0x02, 0x11, 0x00, 0x01],
            &[0x05, 0x11, 0x22, 0x33],
            &[0xFF, 0x11],
        ] {
            let mut buf = [0u8; 8];
            let buf = &mut buf[..bad.len()];
            buf.copy_from_slice(bad);
            assert_eq!(decode_in_place(buf), None, "{bad:?}");
        }
    }

    #[test]
    fn a_short_output_is_an_error() {
        let data = [0x11, 0x22, 0x00, 0x33];
        for len in 0..5 {
            assert_eq!(encode(&data, &mut [0u8; 8][..len]), None, "{len}");
        }
        assert_eq!(encode(&data, &mut [0u8; 5]), Some(5));
    }

    #[test]
    fn every_short_frame_round_trips_and_the_length_is_one_more() {
        // All 3-byte frames over an alphabet with the interesting bytes.
        let alphabet = [0x00, 0x01, 0x02, 0x7F, 0xFE, 0xFF];
        for &a in &alphabet {
            for &b in &alphabet {
                for &c in &alphabet {
                    let data = [a, b, c];
                    let mut out = [0u8; 8];
                    let n = encode(&data, &mut out).unwrap();
                    assert_eq!(n, 4);
                    assert!(!out[..n].contains(&0));
                    let m = decode_in_place(&mut out[..n]).unwrap();
                    assert_eq!(&out[..m], &data);
                }
            }
        }
    }
}
