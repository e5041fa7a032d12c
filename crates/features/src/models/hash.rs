//! sha256 of files and streams, as lower-case hex (the manifest's spelling).

use std::fs::File;
use std::io::{self, Read, Write};
use std::path::Path;

use sha2::{Digest, Sha256};

use crate::error::{FeaturesError, Result};

/// Lower-case hex of a digest.
pub fn to_hex(bytes: &[u8]) -> String {
    use std::fmt::Write as _;
    bytes.iter().fold(String::with_capacity(64), |mut s, b| {
        let _ = write!(s, "{b:02x}");
        s
    })
}

/// sha256 (hex) and length of a file's content.
pub fn sha256_file(path: &Path) -> Result<(String, u64)> {
    let io_err = |source| FeaturesError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut file = File::open(path).map_err(io_err)?;
    copy_hashing(&mut file, &mut io::sink()).map_err(io_err)
}

/// Copies `reader` into `writer` and returns the sha256 (hex) and length of what went through,
/// so a file is hashed while it is written instead of read back.
pub fn copy_hashing(reader: &mut impl Read, writer: &mut impl Write) -> io::Result<(String, u64)> {
    let mut hasher = Sha256::new();
    let mut buf = vec![0u8; 1 << 16];
    let mut total = 0u64;
    loop {
        let n = match reader.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e),
        };
        hasher.update(&buf[..n]);
        writer.write_all(&buf[..n])?;
        total += n as u64;
    }
    Ok((to_hex(&hasher.finalize()), total))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn known_digests() {
        // FIPS 180-2 test vectors.
        let (h, n) = copy_hashing(&mut &b""[..], &mut io::sink()).unwrap();
        assert_eq!(
            h,
            "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855"
        );
        assert_eq!(n, 0);
        let mut out = Vec::new();
        let (h, n) = copy_hashing(&mut &b"abc"[..], &mut out).unwrap();
        assert_eq!(
            h,
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
        assert_eq!((n, out.as_slice()), (3, &b"abc"[..]));
    }

    #[test]
    fn file_digest_spans_buffer_boundaries_and_detects_one_flipped_bit() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("w.bin");
        let data: Vec<u8> = (0..200_000u32).map(|i| (i * 7 + i / 251) as u8).collect();
        std::fs::write(&path, &data).unwrap();
        let (whole, n) = sha256_file(&path).unwrap();
        assert_eq!(n, data.len() as u64);
        let (streamed, _) = copy_hashing(&mut data.as_slice(), &mut io::sink()).unwrap();
        assert_eq!(whole, streamed);
        for pos in [0, 65_535, 65_536, data.len() - 1] {
            let mut bad = data.clone();
            bad[pos] ^= 1;
            std::fs::write(&path, &bad).unwrap();
            assert_ne!(sha256_file(&path).unwrap().0, whole, "flip at {pos}");
        }
    }

    #[test]
    fn missing_file_is_an_io_error_naming_it() {
        let err = sha256_file(Path::new("/nonexistent/jointloc/w.pth")).unwrap_err();
        assert!(matches!(err, FeaturesError::Io { .. }));
        assert!(err.to_string().contains("/nonexistent/jointloc/w.pth"));
    }
}
