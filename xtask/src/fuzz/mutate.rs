//! Mutations of real files: what a cut download, a flipped bit, a hand edit, a spreadsheet or
//! the wrong tool does to a file. Each mutation is drawn from a seeded stream and described in
//! words, so that a failing case can be named and replayed.

use formats::SplitMix64;

/// What a file is, for the mutations that know about formats.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Shape {
    Binary,
    /// Text with numbers in it (JSON, CSV, OBJ, ASCII STL): numbers are swapped for edge cases.
    Text,
    /// PNG: after mutating, chunk checksums are usually recomputed, so that the decoder gets past
    /// them to the chunks' contents (a damaged file with valid checksums is what a buggy
    /// writer makes).
    Png,
}

/// Numbers and words a hand edit or a foreign tool puts where a number was.
const TOKENS: &[&str] = &[
    "0",
    "-1",
    "1",
    "-0",
    "nan",
    "NaN",
    "inf",
    "-inf",
    "1e309",
    "-1e309",
    "1e-320",
    "4294967295",
    "4294967296",
    "18446744073709551616",
    "2147483647",
    "-2147483648",
    "1e30",
    "0.5",
    "",
    "null",
    "true",
    "\"\"",
    "[]",
    "{}",
    "[[[[[[[[[[[[[[[[[[[[[[[[",
    "\"x\"",
    "1,5",
    "99999999999",
];

/// Bytes that mean something to some format.
const BYTES: &[u8] = &[
    0, 1, 0x7f, 0x80, 0xff, b'0', b'9', b'-', b'.', b'e', b'"', b',', b'{', b'}', b'[', b']', b'\n', b'\r', b' ', b':',
    b'/',
];

/// Integers that break size fields: zero, one, sign bits, all ones, just past 16 bits.
const WORDS: &[u32] = &[0, 1, 2, 0x7fff_ffff, 0x8000_0000, 0xffff_ffff, 0x1_0000, 0xffff, 0x4000];

/// One to four mutations of `seed` (`others`: the target's other real files, for splicing),
/// and what they were.
pub fn mutate(rng: &mut SplitMix64, seed: &[u8], others: &[Vec<u8>], shape: Shape) -> (Vec<u8>, Vec<String>) {
    let mut data = seed.to_vec();
    // Mostly one mutation: a file that is nearly right reaches deepest into a parser.
    let count = [1, 1, 1, 2, 2, 3, 4][rng.below(7)];
    let mut log: Vec<String> = (0..count).map(|_| mutate_once(rng, &mut data, others, shape)).collect();
    if shape == Shape::Png && rng.unit() < 0.75 {
        fix_png_checksums(&mut data);
        log.push("PNG checksums recomputed".into());
    }
    (data, log)
}

fn mutate_once(rng: &mut SplitMix64, data: &mut Vec<u8>, others: &[Vec<u8>], shape: Shape) -> String {
    let len = data.len();
    // Text gets its numbers replaced more often than anything else.
    let op = if shape == Shape::Text && rng.unit() < 0.4 { 7 } else { rng.below(9) };
    if len == 0 && op != 5 && op != 8 {
        data.extend_from_slice(TOKENS[rng.below(TOKENS.len())].as_bytes());
        return "empty file given a token".into();
    }
    match op {
        0 => {
            let (i, bit) = (rng.below(len), rng.below(8));
            data[i] ^= 1 << bit;
            format!("bit {bit} of byte {i} flipped")
        }
        1 => {
            let (i, v) = (rng.below(len), BYTES[rng.below(BYTES.len())]);
            data[i] = v;
            format!("byte {i} set to {v:#04x}")
        }
        2 => {
            // Cuts near the end (an interrupted copy) and anywhere.
            let at = if rng.unit() < 0.5 { len - rng.below(len.min(64) + 1) } else { rng.below(len + 1) };
            data.truncate(at);
            format!("cut to {at} bytes")
        }
        3 => {
            let (a, n) = range(rng, len);
            data.drain(a..a + n);
            format!("bytes {a}..{} deleted", a + n)
        }
        4 => {
            let (a, n) = range(rng, len);
            let copy = data[a..a + n].to_vec();
            let at = rng.below(len + 1);
            data.splice(at..at, copy);
            format!("bytes {a}..{} repeated at {at}", a + n)
        }
        5 => {
            let n = 1 + rng.below(16);
            let at = rng.below(len + 1);
            let bytes: Vec<u8> = (0..n).map(|_| rng.next_u64() as u8).collect();
            data.splice(at..at, bytes);
            format!("{n} random bytes inserted at {at}")
        }
        6 if len >= 4 => {
            let (i, v) = (rng.below(len - 3), WORDS[rng.below(WORDS.len())]);
            let big_endian = rng.unit() < 0.5;
            let bytes = if big_endian { v.to_be_bytes() } else { v.to_le_bytes() };
            data[i..i + 4].copy_from_slice(&bytes);
            format!("u32 at {i} set to {v:#x} ({})", if big_endian { "big-endian" } else { "little-endian" })
        }
        7 => replace_number(rng, data),
        _ => splice(rng, data, others),
    }
}

/// A start and a length within `len` (> 0): mostly short, sometimes up to half the file.
fn range(rng: &mut SplitMix64, len: usize) -> (usize, usize) {
    let max = if rng.unit() < 0.8 { len.min(64) } else { (len / 2).max(1) };
    let n = 1 + rng.below(max);
    (rng.below(len - n + 1), n)
}

/// Replaces the first number at or after a random place with a token.
fn replace_number(rng: &mut SplitMix64, data: &mut Vec<u8>) -> String {
    let token = TOKENS[rng.below(TOKENS.len())];
    let from = rng.below(data.len());
    let is_num = |b: u8| b.is_ascii_digit() || matches!(b, b'-' | b'+' | b'.' | b'e' | b'E');
    let Some(start) = data[from..].iter().position(|b| b.is_ascii_digit()).map(|k| from + k) else {
        data.splice(from..from, token.bytes());
        return format!("{token:?} inserted at {from}");
    };
    let start = (0..start).rev().take_while(|&k| is_num(data[k])).last().unwrap_or(start);
    let end = data[start..].iter().position(|&b| !is_num(b)).map_or(data.len(), |k| start + k);
    data.splice(start..end, token.bytes());
    format!("number at {start} replaced with {token:?}")
}

/// Replaces a range with a range of another real file of the same kind.
fn splice(rng: &mut SplitMix64, data: &mut Vec<u8>, others: &[Vec<u8>]) -> String {
    if others.is_empty() {
        return "no other file to splice".into();
    }
    let donor = &others[rng.below(others.len())];
    if donor.is_empty() || data.is_empty() {
        data.extend_from_slice(donor);
        return "another file appended".into();
    }
    let (a, n) = range(rng, donor.len());
    let at = rng.below(data.len());
    let end = (at + n).min(data.len());
    data.splice(at..end, donor[a..a + n].iter().copied());
    format!("bytes {at}..{end} replaced with another file's {a}..{}", a + n)
}

/// Recomputes the CRC of every whole chunk of a PNG (stops at the first that does not fit).
pub fn fix_png_checksums(data: &mut [u8]) {
    let mut at = 8;
    while at + 12 <= data.len() {
        let n = u32::from_be_bytes(data[at..at + 4].try_into().expect("4 bytes")) as usize;
        let Some(end) = (at + 8).checked_add(n).filter(|&e| e + 4 <= data.len()) else { break };
        let crc = crc32(&data[at + 4..end]);
        data[end..end + 4].copy_from_slice(&crc.to_be_bytes());
        at = end + 4;
    }
}

/// CRC-32 (IEEE, reflected), as PNG chunks use it.
pub fn crc32(bytes: &[u8]) -> u32 {
    const TABLE: [u32; 256] = {
        let mut table = [0u32; 256];
        let mut i = 0;
        while i < 256 {
            let mut c = i as u32;
            let mut k = 0;
            while k < 8 {
                c = if c & 1 != 0 { 0xedb8_8320 ^ (c >> 1) } else { c >> 1 };
                k += 1;
            }
            table[i] = c;
            i += 1;
        }
        table
    };
    !bytes.iter().fold(!0u32, |c, &b| TABLE[((c ^ b as u32) & 0xff) as usize] ^ (c >> 8))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc_matches_the_png_specification() {
        // The IEEE CRC-32 check value, and a real chunk: an encoder's IEND.
        assert_eq!(crc32(b"123456789"), 0xcbf4_3926);
        assert_eq!(crc32(b"IEND"), 0xae42_6082);
        let img = image::RgbImage::from_pixel(3, 2, image::Rgb([10, 200, 30]));
        let mut png = sensor::frame::encode_png_rgb(&img);
        let original = png.clone();
        let n = png.len();
        png[n - 1] ^= 0xff;
        fix_png_checksums(&mut png);
        assert_eq!(png, original, "a damaged checksum is recomputed to the encoder's");
    }

    #[test]
    fn mutations_are_seeded_and_change_the_file() {
        let seed = br#"{"radius_mm": 25.0, "crop_size_px": 570}"#.to_vec();
        let others = vec![seed.clone()];
        let run = |k: u64| mutate(&mut SplitMix64::for_item(7, k), &seed, &others, Shape::Text);
        let mut changed = 0;
        for k in 0..200 {
            let (a, log) = run(k);
            assert_eq!((a.clone(), log.clone()), run(k), "case {k} replays");
            assert!(!log.is_empty());
            changed += (a != seed) as usize;
        }
        assert!(changed > 180, "only {changed} of 200 cases changed the file");
    }
}
