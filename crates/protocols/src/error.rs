//! Errors shared by every codec.

/// Bytes that do not form a valid message. The decoder has already skipped them: the next
/// call goes on with what follows.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    /// A line or frame longer than the protocol allows; discarded up to the next line end
    /// (or, binary, past its sync bytes).
    #[error("{what} longer than the limit of {limit} bytes, discarded")]
    Oversized {
        /// `line` or `frame`.
        what: &'static str,
        /// The limit, bytes.
        limit: usize,
    },
    /// A complete line or frame that is not a valid message.
    #[error("malformed {what}: {detail} (in {text:?})")]
    Malformed {
        /// Which message or part.
        what: &'static str,
        /// Why.
        detail: String,
        /// The offending text (lossy, at most 80 characters).
        text: String,
    },
    /// The checksum sent does not match the one computed.
    #[error("checksum mismatch: received {received:#06x}, computed {computed:#06x}")]
    Checksum {
        /// Checksum in the message.
        received: u32,
        /// Checksum of the received bytes.
        computed: u32,
    },
    /// Bytes between messages that belong to none (skipped while searching for a sync).
    #[error("skipped {count} bytes of garbage before a frame")]
    Garbage {
        /// How many.
        count: usize,
    },
}

impl DecodeError {
    /// A [`DecodeError::Malformed`] quoting (a prefix of) the offending bytes.
    pub fn malformed(what: &'static str, detail: impl Into<String>, bytes: &[u8]) -> Self {
        let mut text = String::from_utf8_lossy(bytes).into_owned();
        if text.chars().count() > 80 {
            text = text.chars().take(80).collect::<String>() + "...";
        }
        DecodeError::Malformed { what, detail: detail.into(), text }
    }
}

/// A message that cannot be put on the wire as given.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum EncodeError {
    /// A number that is NaN or infinite, or too large for the protocol.
    #[error("{field} = {value} cannot be sent (allowed: {allowed})")]
    Value {
        /// Which field.
        field: &'static str,
        /// Its value, as text.
        value: String,
        /// What the protocol allows.
        allowed: &'static str,
    },
    /// A text field with characters the framing reserves.
    #[error("{field} = {value:?} contains characters the protocol reserves (allowed: {allowed})")]
    Text {
        /// Which field.
        field: &'static str,
        /// Its value.
        value: String,
        /// What the protocol allows.
        allowed: &'static str,
    },
    /// The encoded message would exceed the protocol's limit.
    #[error("{what} of {len} bytes exceeds the limit of {limit} bytes")]
    TooLong {
        /// `line` or `frame`.
        what: &'static str,
        /// Its encoded length.
        len: usize,
        /// The limit.
        limit: usize,
    },
}
