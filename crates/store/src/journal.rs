//! The append-only journal: one record per finished (or skipped) step, each fsync'd before
//! the step counts as done.
//!
//! Framing (one record a line, so the file is readable with `less`):
//!
//! ```text
//! LLLLLLLL CCCCCCCCCCCCCCCC {json}\n
//! ```
//!
//! `L` is the byte length of `{json}` in 8 lowercase hex digits, `C` the first 8 bytes of the
//! SHA-256 of `{json}` in 16 hex digits. A record that is incomplete or fails its checksum
//! and is followed by no valid record is a torn tail (the power went during the append):
//! [`Journal::open`] cuts it away and reports it. A bad record followed by a valid one is
//! damage in the middle and an error naming its byte offset.
//!
//! Version 2 adds the manifest's hash to the header (so a changed manifest is noticed), the
//! `retake` record (a done step whose files resume found damaged: it counts as not done
//! again, and a later `step` record of it is allowed) and the `model` record (a compressed
//! model the run built, written next to the dataset). Version 3 adds the `frames` record (the
//! raw frames of a view group: a dome's pattern frames of one camera at one rotation) and the
//! `retake_frames` record (a view group's raw frames found damaged on a resume).

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::error::StoreError;
use crate::hash::sha256;
use crate::storage::{parent, Storage};
use crate::{FileRecord, StepHdr, StepId, StepRegistration, StepTiming};

/// `format` field of the header record.
pub const JOURNAL_FORMAT: &str = "btfrig-journal";
/// Version of the record schema.
pub const JOURNAL_VERSION: u32 = 3;
const PREFIX: usize = 8 + 1 + 16 + 1;

/// One journal record.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum Record {
    /// First record: what the journal belongs to.
    Header {
        /// Always [`JOURNAL_FORMAT`].
        format: String,
        /// [`JOURNAL_VERSION`] at the time of writing.
        version: u32,
        /// Content hash of the plan the dataset measures.
        plan_hash: String,
        /// [`crate::manifest_hash`] of the manifest as created (absent in version 1 journals:
        /// their manifest is not checked).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        manifest_hash: Option<String>,
    },
    /// A finished step and the files it wrote (already durable when this was appended).
    Step(StepRecord),
    /// A step the run decided not to capture, with the reason.
    Skip {
        /// The step.
        step: StepId,
        /// Why it was skipped.
        reason: String,
    },
    /// A done step whose files were found damaged when the run was resumed: it is not done
    /// any more and is captured again (its files are deleted after this record is durable).
    Retake {
        /// The step.
        step: StepId,
        /// What was found (`textures/l000_v003.exr: missing`).
        reason: String,
    },
    /// A compressed model the run built, durable (written, fsync'd, renamed) before this
    /// record was appended.
    Model(ModelRecord),
    /// The raw frames of a view group, durable before this record was appended. A dome run
    /// appends it before the first texture of the view, so no texture is journaled without the
    /// frames it was made from.
    Frames(FramesRecord),
    /// A view group whose raw frames were found damaged when the run was resumed: they are not
    /// kept any more (deleted after this record is durable) and the group is captured again.
    RetakeFrames {
        /// The view.
        view: u32,
        /// What was found (`raw/v003_p001.exr: missing`).
        reason: String,
    },
}

/// The journal record of a view group's raw frames.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FramesRecord {
    /// The view (index into `samplings.view`).
    pub view: u32,
    /// The frames in pattern order (`raw/v003_p000.exr`, `raw/v003_p001.exr`, ...), with size
    /// and content hash.
    pub files: Vec<FileRecord>,
}

/// The journal record of a compressed model a run built (`btfrig run --compress`).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelRecord {
    /// The model's label (`fmf`, `pcmf-w64`, ...): a rerun asking for this model builds none.
    pub method: String,
    /// The file's name in the directory that holds the dataset (`run1.fmf.btfm`).
    pub file: String,
    /// Its size, bytes.
    pub size: u64,
    /// Its content hash.
    pub hash: String,
}

/// The journal record of a finished step.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StepRecord {
    /// The step.
    pub step: StepId,
    /// Files it wrote, with size and content hash.
    pub files: Vec<FileRecord>,
    /// Attempts it took (1 = no retry).
    pub attempts: u32,
    /// Its timing.
    pub timing: StepTiming,
    /// How its sample pose was found (absent in journals written before registration, and
    /// for steps that wrote no texture).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub registration: Option<StepRegistration>,
    /// Its exposures when the plan has HDR on (absent otherwise and in older journals).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hdr: Option<StepHdr>,
}

/// Frames one record: length, checksum, JSON, newline.
pub fn encode_record(record: &Record) -> Vec<u8> {
    let json = serde_json::to_vec(record).expect("journal records serialise");
    let sum = &sha256(&json)[..8];
    let mut out = format!("{:08x} ", json.len()).into_bytes();
    for b in sum {
        out.extend_from_slice(format!("{b:02x}").as_bytes());
    }
    out.push(b' ');
    out.extend_from_slice(&json);
    out.push(b'\n');
    out
}

enum Bad {
    /// The file ends inside the record.
    Incomplete,
    /// The record is complete but wrong.
    Invalid(String),
}

fn parse_hex(b: &[u8]) -> Option<u64> {
    if b.iter().all(|c| c.is_ascii_digit() || (b'a'..=b'f').contains(c)) {
        u64::from_str_radix(std::str::from_utf8(b).ok()?, 16).ok()
    } else {
        None
    }
}

fn parse_at(bytes: &[u8], off: usize) -> Result<(Record, usize), Bad> {
    let rest = &bytes[off..];
    if rest.len() < PREFIX {
        // A prefix of a valid header could still be a torn record; anything else is damage.
        return Err(Bad::Incomplete);
    }
    let len = parse_hex(&rest[..8]).ok_or_else(|| Bad::Invalid("length field is not 8 hex digits".into()))? as usize;
    let sum = parse_hex(&rest[9..25]).ok_or_else(|| Bad::Invalid("checksum field is not 16 hex digits".into()))?;
    if rest[8] != b' ' || rest[25] != b' ' {
        return Err(Bad::Invalid("fields not separated by single spaces".into()));
    }
    let total = PREFIX + len + 1;
    if rest.len() < total {
        return Err(Bad::Incomplete);
    }
    let json = &rest[PREFIX..PREFIX + len];
    if rest[total - 1] != b'\n' {
        return Err(Bad::Invalid("record does not end in a newline".into()));
    }
    let want = u64::from_be_bytes(sha256(json)[..8].try_into().expect("8 bytes"));
    if want != sum {
        return Err(Bad::Invalid(format!("checksum {sum:016x} does not match the content ({want:016x})")));
    }
    let record = serde_json::from_slice(json).map_err(|e| Bad::Invalid(format!("record JSON: {e}")))?;
    Ok((record, total))
}

/// A torn or corrupt last record, cut away (or to be cut away) on open.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TornTail {
    /// Byte offset where the bad tail starts (the journal's valid length).
    pub offset: u64,
    /// Bytes in the tail.
    pub bytes: u64,
    /// What was wrong with it.
    pub reason: String,
}

impl std::fmt::Display for TornTail {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "torn journal tail at byte {}: {} bytes ({})", self.offset, self.bytes, self.reason)
    }
}

/// What a journal holds, read without changing it.
#[derive(Debug, Clone, Default)]
pub struct Replay {
    /// Plan hash from the header (`None` for an empty journal).
    pub plan_hash: Option<String>,
    /// Manifest hash from the header (`None`: an empty or version 1 journal).
    pub manifest_hash: Option<String>,
    /// Finished steps.
    pub done: BTreeMap<StepId, StepRecord>,
    /// Skipped steps and why.
    pub skipped: BTreeMap<StepId, String>,
    /// Steps retaken (found damaged on a resume), with what was found, in journal order.
    pub retaken: Vec<(StepId, String)>,
    /// Compressed models built, in journal order.
    pub models: Vec<ModelRecord>,
    /// Raw frames kept per view group, by view.
    pub frames: BTreeMap<u32, FramesRecord>,
    /// Length of the valid prefix.
    pub valid_len: u64,
    /// The bad tail, if any.
    pub torn_tail: Option<TornTail>,
}

/// Parses journal bytes. A bad tail is returned in [`Replay::torn_tail`]; damage followed by
/// valid records, a missing header or a step recorded twice is an error naming the offset.
pub fn replay(path: &str, bytes: &[u8]) -> Result<Replay, StoreError> {
    let mut r = Replay::default();
    let mut off = 0usize;
    while off < bytes.len() {
        let (record, len) = match parse_at(bytes, off) {
            Ok(x) => x,
            Err(bad) => {
                let reason = match bad {
                    Bad::Incomplete => "incomplete record".to_string(),
                    Bad::Invalid(m) => m,
                };
                // Damage, not a torn append, if any valid record starts at a later line.
                let later =
                    (off + 1..bytes.len()).filter(|&p| bytes[p - 1] == b'\n').any(|p| parse_at(bytes, p).is_ok());
                if later {
                    return Err(StoreError::JournalCorrupt { path: path.into(), offset: off as u64, reason });
                }
                r.torn_tail = Some(TornTail { offset: off as u64, bytes: (bytes.len() - off) as u64, reason });
                break;
            }
        };
        let corrupt = |reason: String| StoreError::JournalCorrupt { path: path.into(), offset: off as u64, reason };
        match record {
            Record::Header { format, version, plan_hash, manifest_hash } => {
                if off != 0 {
                    return Err(corrupt("second header record".into()));
                }
                if format != JOURNAL_FORMAT || version > JOURNAL_VERSION {
                    return Err(corrupt(format!(
                        "header says {format:?} version {version}; this build reads {JOURNAL_FORMAT:?} up to version {JOURNAL_VERSION}"
                    )));
                }
                r.plan_hash = Some(plan_hash);
                r.manifest_hash = manifest_hash;
            }
            _ if off == 0 => return Err(corrupt("first record is not the header".into())),
            Record::Step(s) => {
                if r.done.contains_key(&s.step) || r.skipped.contains_key(&s.step) {
                    return Err(corrupt(format!("step {} recorded twice", s.step)));
                }
                r.done.insert(s.step, s);
            }
            Record::Skip { step, reason } => {
                if r.done.contains_key(&step) || r.skipped.contains_key(&step) {
                    return Err(corrupt(format!("step {step} recorded twice")));
                }
                r.skipped.insert(step, reason);
            }
            Record::Retake { step, reason } => {
                if r.done.remove(&step).is_none() {
                    return Err(corrupt(format!("step {step} retaken but not done")));
                }
                r.retaken.push((step, reason));
            }
            Record::Model(m) => r.models.push(m),
            Record::Frames(f) => {
                if r.frames.contains_key(&f.view) {
                    return Err(corrupt(format!("raw frames of view {} recorded twice", f.view)));
                }
                r.frames.insert(f.view, f);
            }
            Record::RetakeFrames { view, .. } => {
                if r.frames.remove(&view).is_none() {
                    return Err(corrupt(format!("raw frames of view {view} retaken but not recorded")));
                }
            }
        }
        off += len;
    }
    r.valid_len = off as u64;
    Ok(r)
}

/// An open journal: its path and what it holds. Appends go through the [`Storage`] passed in.
#[derive(Debug, Clone)]
pub struct Journal {
    path: String,
    state: Replay,
}

impl Journal {
    /// Creates a journal holding only the header, durable (file and directory entry) on return.
    pub fn create<S: Storage + ?Sized>(
        storage: &S,
        path: &str,
        plan_hash: &str,
        manifest_hash: Option<&str>,
    ) -> Result<Journal, StoreError> {
        let io = |op: &'static str, p: &str| {
            let p = storage.display(p);
            move |source| StoreError::Io { op, path: p, source }
        };
        let header = Record::Header {
            format: JOURNAL_FORMAT.into(),
            version: JOURNAL_VERSION,
            plan_hash: plan_hash.into(),
            manifest_hash: manifest_hash.map(str::to_string),
        };
        let bytes = encode_record(&header);
        storage.create(path).map_err(io("create", path))?;
        storage.append(path, &bytes).map_err(io("append", path))?;
        storage.fsync(path).map_err(io("fsync", path))?;
        storage.fsync(parent(path)).map_err(io("fsync", parent(path)))?;
        let state = Replay {
            plan_hash: Some(plan_hash.into()),
            manifest_hash: manifest_hash.map(str::to_string),
            valid_len: bytes.len() as u64,
            ..Replay::default()
        };
        Ok(Journal { path: path.into(), state })
    }

    /// Opens an existing journal for appending: replays it, checks the plan hash, and cuts a
    /// torn tail away (durably), returning it so the caller can report it.
    /// A journal with not even its header intact is created afresh, with `manifest_hash`.
    pub fn open<S: Storage + ?Sized>(
        storage: &S,
        path: &str,
        plan_hash: &str,
        manifest_hash: Option<&str>,
    ) -> Result<(Journal, Option<TornTail>), StoreError> {
        let bytes =
            storage.read(path).map_err(|source| StoreError::Io { op: "read", path: storage.display(path), source })?;
        let mut state = replay(&storage.display(path), &bytes)?;
        if state.valid_len == 0 {
            // Not even the header survived: nothing was journaled, start afresh.
            let torn = state.torn_tail.take();
            return Ok((Journal::create(storage, path, plan_hash, manifest_hash)?, torn));
        }
        if state.plan_hash.as_deref() != Some(plan_hash) {
            return Err(StoreError::PlanMismatch {
                path: storage.display(path),
                found: state.plan_hash.clone().unwrap_or_default(),
                expected: plan_hash.into(),
            });
        }
        let torn = state.torn_tail.take();
        if torn.is_some() {
            let io = |op: &'static str| {
                let p = storage.display(path);
                move |source| StoreError::Io { op, path: p, source }
            };
            storage.truncate(path, state.valid_len).map_err(io("truncate"))?;
            storage.fsync(path).map_err(io("fsync"))?;
        }
        Ok((Journal { path: path.into(), state }, torn))
    }

    /// Appends a record and fsyncs it; only then is it added to the in-memory state.
    pub fn append<S: Storage + ?Sized>(&mut self, storage: &S, record: Record) -> Result<(), StoreError> {
        let io = |op: &'static str| {
            let p = storage.display(&self.path);
            move |source| StoreError::Io { op, path: p, source }
        };
        let bytes = encode_record(&record);
        storage.append(&self.path, &bytes).map_err(io("append"))?;
        storage.fsync(&self.path).map_err(io("fsync"))?;
        self.state.valid_len += bytes.len() as u64;
        match record {
            Record::Step(s) => {
                self.state.done.insert(s.step, s);
            }
            Record::Skip { step, reason } => {
                self.state.skipped.insert(step, reason);
            }
            Record::Retake { step, reason } => {
                self.state.done.remove(&step);
                self.state.retaken.push((step, reason));
            }
            Record::Model(m) => self.state.models.push(m),
            Record::Frames(f) => {
                self.state.frames.insert(f.view, f);
            }
            Record::RetakeFrames { view, .. } => {
                self.state.frames.remove(&view);
            }
            Record::Header { .. } => {}
        }
        Ok(())
    }

    /// What the journal holds.
    pub fn state(&self) -> &Replay {
        &self.state
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn step(l: u32, v: u32) -> Record {
        Record::Step(StepRecord {
            step: StepId { light: l, view: v },
            files: vec![FileRecord { path: format!("textures/{l}_{v}.exr"), size: 10, hash: "sha256:ab".into() }],
            attempts: 1,
            timing: StepTiming::default(),
            registration: None,
            hdr: None,
        })
    }

    fn journal(n: u32) -> (Vec<u8>, Vec<usize>) {
        let mut bytes = encode_record(&Record::Header {
            format: JOURNAL_FORMAT.into(),
            version: 1,
            plan_hash: "p".into(),
            manifest_hash: None,
        });
        let mut starts = vec![0];
        for i in 0..n {
            starts.push(bytes.len());
            bytes.extend(encode_record(&step(i, i + 1)));
        }
        (bytes, starts)
    }

    #[test]
    fn the_registration_field_is_optional_and_round_trips() {
        // A step record as journaled before registration existed still parses.
        let old = r#"{"type":"step","step":{"light":1,"view":2},"files":[],"attempts":1,"timing":{"started_unix_s":1.0,"wall_s":0.5,"hardware_s":null}}"#;
        match serde_json::from_str::<Record>(old).unwrap() {
            Record::Step(r) => assert_eq!(r.registration, None),
            other => panic!("{other:?}"),
        }
        let reg = crate::StepRegistration {
            pose: crate::PoseSource::NominalFallback,
            markers: vec![],
            rms_px: None,
            texel_sigma: None,
            reason: Some("registration needs at least 3 good markers, found 0".into()),
            search: Some(Box::new(crate::StepSearch {
                windows: 12,
                searched_fraction: 1.3,
                whole_frame: true,
                fallback: Some("no-pose".into()),
                fallback_detail: Some("no pose from the windows".into()),
                detect_s: 0.5,
                whole_frame_s: Some(0.4),
                reference_s: 0.0,
            })),
        };
        let Record::Step(mut r) = step(1, 2) else { unreachable!() };
        r.registration = Some(reg.clone());
        let json = serde_json::to_string(&Record::Step(r)).unwrap();
        assert!(json.contains(r#""pose":"nominal-fallback""#), "{json}");
        match serde_json::from_str::<Record>(&json).unwrap() {
            Record::Step(back) => assert_eq!(back.registration, Some(reg)),
            other => panic!("{other:?}"),
        }
        // Without registration the record is byte-for-byte what older versions wrote.
        assert!(!serde_json::to_string(&step(1, 2)).unwrap().contains("registration"));
    }

    #[test]
    fn round_trip_and_every_truncation_is_a_torn_tail() {
        let (bytes, starts) = journal(3);
        let r = replay("j", &bytes).unwrap();
        assert_eq!(r.done.len(), 3);
        assert_eq!(r.valid_len, bytes.len() as u64);
        assert!(r.torn_tail.is_none());
        for cut in 0..bytes.len() {
            let r = replay("j", &bytes[..cut]).unwrap();
            let whole = starts.iter().filter(|&&s| s < cut).count();
            let expect_valid = *starts.iter().rev().find(|&&s| s <= cut).unwrap();
            assert_eq!(r.valid_len as usize, expect_valid, "cut {cut}");
            assert_eq!(r.torn_tail.is_some(), cut != expect_valid, "cut {cut}");
            // Records fully before the cut survive; the one cut is not counted.
            let complete = if starts.contains(&cut) { whole } else { whole - 1 };
            assert_eq!(r.done.len(), complete.saturating_sub(1), "cut {cut}");
        }
    }

    #[test]
    fn damage_in_the_middle_names_its_offset_and_at_the_end_is_a_tail() {
        let (bytes, starts) = journal(3);
        for (k, &s) in starts.iter().enumerate() {
            for at in [s, s + 3, s + 12, s + 30] {
                let mut b = bytes.clone();
                b[at] ^= 0x01;
                match replay("j", &b) {
                    Err(StoreError::JournalCorrupt { offset, .. }) => {
                        assert!(k < starts.len() - 1, "last record must be a tail");
                        assert_eq!(offset, s as u64);
                    }
                    Ok(r) => {
                        assert_eq!(k, starts.len() - 1, "record {k} damaged at {at} read as a tail");
                        assert_eq!(r.torn_tail.unwrap().offset, s as u64);
                        assert_eq!(r.done.len(), 2);
                    }
                    Err(e) => panic!("{e}"),
                }
            }
        }
    }

    #[test]
    fn a_retake_makes_a_step_not_done_and_allows_one_more_record() {
        let (mut bytes, _) = journal(2);
        let again = |bytes: &[u8]| replay("j", bytes);
        let retake = |l: u32, v: u32| {
            encode_record(&Record::Retake { step: StepId { light: l, view: v }, reason: "x: missing".into() })
        };
        bytes.extend(retake(0, 1));
        let r = again(&bytes).unwrap();
        assert!(!r.done.contains_key(&StepId { light: 0, view: 1 }));
        assert_eq!(r.retaken, vec![(StepId { light: 0, view: 1 }, "x: missing".to_string())]);
        bytes.extend(encode_record(&step(0, 1)));
        assert!(again(&bytes).unwrap().done.contains_key(&StepId { light: 0, view: 1 }));
        // A third record of it without another retake, or a retake of a step not done, is damage.
        let mut twice = bytes.clone();
        twice.extend(encode_record(&step(0, 1)));
        assert!(matches!(again(&twice), Err(StoreError::JournalCorrupt { .. })));
        let mut not_done = bytes.clone();
        not_done.extend(retake(7, 7));
        match again(&not_done) {
            Err(StoreError::JournalCorrupt { reason, .. }) => assert!(reason.contains("not done"), "{reason}"),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn a_step_recorded_twice_is_an_error() {
        let (mut bytes, _) = journal(2);
        let at = bytes.len();
        bytes.extend(encode_record(&step(0, 1)));
        match replay("j", &bytes) {
            Err(StoreError::JournalCorrupt { offset, reason, .. }) => {
                assert_eq!(offset, at as u64);
                assert!(reason.contains("twice"), "{reason}");
            }
            other => panic!("{other:?}"),
        }
    }
}
