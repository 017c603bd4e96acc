//! Firmware emulators: a device-trait object (in tests, a simulated device) served over a
//! pseudo-terminal in a real protocol, with hooks to inject link faults.

pub mod grbl;
