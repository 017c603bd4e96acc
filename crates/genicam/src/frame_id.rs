//! GigE Vision 1.x block ids are 16 bits: 1..=65535, then 1 again (0 is never sent), and
//! Aravis's fake cameras start near the top on purpose. [`FrameIdUnwrapper`] turns them into
//! one increasing sequence and says how many ids were skipped (frames the camera sent that
//! never arrived, or that it never sent).

/// The largest id before the wrap.
const WRAP: u64 = 65_535;

/// Unwraps 16-bit frame ids into a `u64` sequence.
#[derive(Debug, Clone, Default)]
pub struct FrameIdUnwrapper {
    last: Option<(u64, u64)>,
    /// The first sequence number after a reset (sequences never go back).
    floor: u64,
}

impl FrameIdUnwrapper {
    /// A new unwrapper: the first id seen is its own sequence number.
    pub fn new() -> Self {
        FrameIdUnwrapper::default()
    }

    /// Forgets the last id (after a reconnect the camera starts a new count); the next id
    /// continues the sequence.
    pub fn reset(&mut self) {
        if let Some((_, seq)) = self.last.take() {
            self.floor = seq + 1;
        }
    }

    /// The sequence number of `raw` (the first id maps to itself) and how many ids lie
    /// between it and the previous one (0 when consecutive). An id equal to the previous one
    /// counts as a full turn of 65535 ids, which at any real frame rate cannot happen between
    /// two pops; it is reported as such rather than hidden.
    pub fn next(&mut self, raw: u64) -> (u64, u64) {
        let raw = raw & 0xffff;
        let (seq, skipped) = match self.last {
            None if self.floor == 0 => (raw, 0),
            None => (self.floor, 0),
            Some((last_raw, last_seq)) => {
                let step = if raw > last_raw { raw - last_raw } else { WRAP - last_raw + raw };
                // Ids 0 and the wrap: 65535 -> 1 is one step (0 is not used by GigE Vision).
                let step = if raw == 0 { step.max(1) } else { step };
                (last_seq + step, step - 1)
            }
        };
        self.last = Some((raw, seq));
        (seq, skipped)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wraps_from_65535_to_1_without_a_gap() {
        let mut u = FrameIdUnwrapper::new();
        assert_eq!(u.next(65_533), (65_533, 0));
        assert_eq!(u.next(65_534), (65_534, 0));
        assert_eq!(u.next(65_535), (65_535, 0));
        assert_eq!(u.next(1), (65_536, 0));
        assert_eq!(u.next(2), (65_537, 0));
        // Two frames lost across the wrap.
        let mut u = FrameIdUnwrapper::new();
        u.next(65_534);
        assert_eq!(u.next(2), (65_537, 2));
    }

    #[test]
    fn gaps_are_counted_and_reset_starts_afresh() {
        let mut u = FrameIdUnwrapper::new();
        u.next(10);
        assert_eq!(u.next(13), (13, 2));
        u.reset();
        assert_eq!(u.next(500), (14, 0));
        assert_eq!(u.next(501), (15, 0));
    }
}
