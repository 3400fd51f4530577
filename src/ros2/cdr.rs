//! CDR payloads of ROS 2 messages: a 4-byte encapsulation header (`00 01 00 00` for little
//! endian, `00 00 00 00` for big endian) and the classic CDR body, aligned from the byte
//! after the header. The body codec is `cdr-encoding` (RustDDS's own).

use crate::error::{Error, Result};
use serde::{Deserialize, Serialize};

/// The encapsulation header of a little-endian classic CDR payload.
pub const CDR_LE: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// Serialises `message` as a little-endian CDR payload with its header.
pub fn encode<T: Serialize>(message: &T) -> Result<Vec<u8>> {
    let mut out = Vec::with_capacity(256);
    out.extend_from_slice(&CDR_LE);
    cdr_encoding::to_writer::<T, byteorder::LittleEndian, _>(&mut out, message)
        .map_err(|e| Error::InvalidArgument(format!("CDR encoding failed: {e}")))?;
    Ok(out)
}

/// Reads a CDR payload (either byte order). `what` names the message in errors (the bag and
/// topic). At most 3 bytes of padding may follow the message.
pub fn decode<'de, T: Deserialize<'de>>(payload: &'de [u8], what: &str) -> Result<T> {
    let (value, trailing) = decode_start(payload, what)?;
    if trailing > 3 {
        return Err(Error::InvalidArgument(format!("{what}: {trailing} bytes follow the message")));
    }
    Ok(value)
}

/// Reads the start of a CDR payload as `T` (e.g. the `Header` that begins most messages),
/// ignoring what follows.
pub fn decode_prefix<'de, T: Deserialize<'de>>(payload: &'de [u8], what: &str) -> Result<T> {
    decode_start(payload, what).map(|(value, _)| value)
}

/// `T` from the start of the payload's body, and how many body bytes follow it.
fn decode_start<'de, T: Deserialize<'de>>(payload: &'de [u8], what: &str) -> Result<(T, usize)> {
    let bad = |msg: String| Error::InvalidArgument(format!("{what}: {msg}"));
    if payload.len() < 4 {
        return Err(bad(format!("a CDR payload of {} bytes has no encapsulation header", payload.len())));
    }
    let body = &payload[4..];
    let (value, used) = match [payload[0], payload[1]] {
        [0, 1] => cdr_encoding::from_bytes::<T, byteorder::LittleEndian>(body),
        [0, 0] => cdr_encoding::from_bytes::<T, byteorder::BigEndian>(body),
        r => {
            return Err(bad(format!(
                "encapsulation {:02x}{:02x} is not classic CDR (XCDR2 and parameter lists are not read)",
                r[0], r[1]
            )));
        }
    }
    .map_err(|e| bad(format!("not the expected message ({e})")))?;
    Ok((value, body.len().saturating_sub(used)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ros2::msg::{Header, Image, Time};
    use std::borrow::Cow;

    /// The layout of a small Image, byte by byte: strings carry their NUL, `uint8[]` a count,
    /// alignment counts from after the header.
    #[test]
    fn an_image_has_the_ros_wire_layout() {
        let img = Image {
            header: Header { stamp: Time { sec: 1, nanosec: 2 }, frame_id: "c".into() },
            height: 1,
            width: 2,
            encoding: "mono8".into(),
            is_bigendian: 0,
            step: 2,
            data: Cow::Borrowed(&[7, 9]),
        };
        let bytes = encode(&img).unwrap();
        #[rustfmt::skip]
        let want: Vec<u8> = vec![
            0, 1, 0, 0,
            1, 0, 0, 0, 2, 0, 0, 0,           // stamp
            2, 0, 0, 0, b'c', 0, 0, 0,        // frame_id "c\0" + pad to 4
            1, 0, 0, 0, 2, 0, 0, 0,           // height, width
            6, 0, 0, 0, b'm', b'o', b'n', b'o', b'8', 0, // "mono8\0"
            0,                                // is_bigendian
            0,                                // pad to 4
            2, 0, 0, 0,                       // step
            2, 0, 0, 0, 7, 9,                 // data
        ];
        assert_eq!(bytes, want);
        let back: Image = decode(&bytes, "test").unwrap();
        assert_eq!(back, img);
        assert!(matches!(back.data, Cow::Borrowed(_)), "image data is read without a copy");
    }

    #[test]
    fn bad_payloads_are_errors_naming_the_message() {
        let ok = encode(&Time { sec: 3, nanosec: 4 }).unwrap();
        for (bytes, needle) in [
            (vec![0u8, 1], "no encapsulation header"),
            (vec![0, 7, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8], "not classic CDR"),
            (ok[..7].to_vec(), "not the expected message"),
            ([ok.clone(), vec![0; 8]].concat(), "bytes follow"),
        ] {
            let err = decode::<Time>(&bytes, "bag.mcap /t").unwrap_err().to_string();
            assert!(err.contains("bag.mcap /t") && err.contains(needle), "{err}");
        }
        assert_eq!(decode::<Time>(&ok, "t").unwrap(), Time { sec: 3, nanosec: 4 });
    }
}
