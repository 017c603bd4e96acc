//! Checksums used by the framed protocols.

/// CRC-16/CCITT-FALSE (polynomial 0x1021, initial 0xFFFF, no reflection, no final XOR);
/// the check value of `b"123456789"` is 0x29B1.
pub fn crc16_ccitt(data: &[u8]) -> u16 {
    let mut crc: u16 = 0xFFFF;
    for &b in data {
        crc ^= u16::from(b) << 8;
        for _ in 0..8 {
            crc = if crc & 0x8000 != 0 { (crc << 1) ^ 0x1021 } else { crc << 1 };
        }
    }
    crc
}

/// XOR of all bytes (the NMEA 0183 sentence checksum).
pub fn xor8(data: &[u8]) -> u8 {
    data.iter().fold(0, |a, &b| a ^ b)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn published_check_values() {
        assert_eq!(crc16_ccitt(b"123456789"), 0x29B1);
        assert_eq!(crc16_ccitt(b""), 0xFFFF);
        // NMEA example: $GPGLL,5300.97914,N,00259.98174,E,125926,A*28
        assert_eq!(xor8(b"GPGLL,5300.97914,N,00259.98174,E,125926,A"), 0x28);
    }
}
