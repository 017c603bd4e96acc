//! GenICam backend.
