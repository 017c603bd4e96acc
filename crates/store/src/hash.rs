//! Content hashes: SHA-256, written as `sha256:` followed by 64 lowercase hex digits so the
//! algorithm travels with the value and `sha256sum FILE` checks it by hand.

use sha2::{Digest, Sha256};

/// Prefix of every content hash string.
pub const HASH_PREFIX: &str = "sha256:";

/// The raw SHA-256 digest of `data`.
pub fn sha256(data: &[u8]) -> [u8; 32] {
    Sha256::digest(data).into()
}

/// The content hash of `data` as stored in journals and manifests: `sha256:<hex>`.
pub fn content_hash(data: &[u8]) -> String {
    let mut s = String::with_capacity(HASH_PREFIX.len() + 64);
    s.push_str(HASH_PREFIX);
    for b in sha256(data) {
        s.push_str(&format!("{b:02x}"));
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_the_published_test_vectors() {
        // FIPS 180-2 examples.
        assert_eq!(content_hash(b""), "sha256:e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855");
        assert_eq!(content_hash(b"abc"), "sha256:ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad");
    }
}
