//! The dry-run summary printed by `btfrig plan show`.

use std::fmt;

use crate::expand::SkipKind;

/// Bytes each capture leaves on disk; the caller knows the formats and sizes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DiskEstimate {
    /// Raw frame bytes per capture (0 when raw frames are not kept).
    pub raw_bytes_per_capture: u64,
    /// Rectified texture bytes per capture (0 when none are written).
    pub texture_bytes_per_capture: u64,
}

impl DiskEstimate {
    /// Total bytes for `captures` captures.
    pub fn total_bytes(&self, captures: usize) -> u64 {
        captures as u64 * (self.raw_bytes_per_capture + self.texture_bytes_per_capture)
    }
}

/// `seconds` as `h:mm:ss` (hours may exceed 24), rounded to the nearest second.
pub fn format_hms(seconds: f64) -> String {
    let s = seconds.max(0.0).round() as u64;
    format!("{}:{:02}:{:02}", s / 3600, s / 60 % 60, s % 60)
}

/// Bytes in binary units with three significant-ish digits.
fn format_bytes(b: u64) -> String {
    const UNITS: [&str; 5] = ["B", "KiB", "MiB", "GiB", "TiB"];
    let mut v = b as f64;
    let mut u = 0;
    while v >= 1024.0 && u + 1 < UNITS.len() {
        v /= 1024.0;
        u += 1;
    }
    if u == 0 {
        format!("{b} B")
    } else {
        format!("{v:.2} {}", UNITS[u])
    }
}

/// What a plan will do, before doing it.
#[derive(Debug, Clone, PartialEq)]
pub struct DryRun {
    /// Name of the light sampling.
    pub lights: String,
    /// Name of the view sampling.
    pub views: String,
    /// Pairs requested.
    pub requested: usize,
    /// Captures that will be made.
    pub captures: usize,
    /// Skips per kind, non-zero kinds only, in [`SkipKind::all`] order.
    pub skipped: Vec<(SkipKind, usize)>,
    /// Estimated hardware time of the optimised order, seconds.
    pub hardware_s: f64,
    /// Hardware time of the naive nested-loop order, seconds.
    pub naive_order_hardware_s: f64,
    /// Lower bound on the hardware time of any order, seconds.
    pub critical_path_s: f64,
    /// Sum of move durations (mostly hidden under transfers), seconds.
    pub motion_s: f64,
    /// Sum of commands, latencies, exposures and read-outs, seconds.
    pub capture_s: f64,
    /// Sum of transfers, seconds.
    pub transfer_s: f64,
    /// Camera waiting for motion, seconds.
    pub idle_s: f64,
    /// Bytes per capture on disk.
    pub disk: DiskEstimate,
}

impl DryRun {
    /// Estimated disk space, bytes.
    pub fn disk_bytes(&self) -> u64 {
        self.disk.total_bytes(self.captures)
    }

    /// Total number of skipped pairs.
    pub fn skipped_total(&self) -> usize {
        self.skipped.iter().map(|(_, n)| n).sum()
    }
}

impl fmt::Display for DryRun {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let pct = |x: f64| if self.hardware_s > 0.0 { 100.0 * x / self.hardware_s } else { 0.0 };
        writeln!(f, "lights x views   {} x {} ({} pairs requested)", self.lights, self.views, self.requested)?;
        writeln!(f, "captures         {}", self.captures)?;
        writeln!(f, "skipped          {}", self.skipped_total())?;
        for (k, n) in &self.skipped {
            writeln!(f, "  {:<22} {n}", k.label())?;
        }
        writeln!(f, "estimated time   {} ({:.0} s)", format_hms(self.hardware_s), self.hardware_s)?;
        writeln!(f, "  capture        {:.0} s ({:.1} %)", self.capture_s, pct(self.capture_s))?;
        writeln!(f, "  transfer       {:.0} s ({:.1} %)", self.transfer_s, pct(self.transfer_s))?;
        writeln!(f, "  waiting motion {:.0} s ({:.1} %)", self.idle_s, pct(self.idle_s))?;
        writeln!(f, "  motion total   {:.0} s (overlaps transfers)", self.motion_s)?;
        let vs = if self.naive_order_hardware_s > 0.0 {
            100.0 * (self.naive_order_hardware_s / self.hardware_s.max(f64::MIN_POSITIVE) - 1.0)
        } else {
            0.0
        };
        writeln!(
            f,
            "naive order      {} ({:.0} s, {vs:+.1} % vs optimised)",
            format_hms(self.naive_order_hardware_s),
            self.naive_order_hardware_s
        )?;
        let gap = if self.critical_path_s > 0.0 { 100.0 * (self.hardware_s / self.critical_path_s - 1.0) } else { 0.0 };
        writeln!(
            f,
            "lower bound      {} ({:.0} s; optimised is {gap:.2} % above)",
            format_hms(self.critical_path_s),
            self.critical_path_s
        )?;
        write!(
            f,
            "disk             {} ({} raw + {} texture per capture)",
            format_bytes(self.disk_bytes()),
            format_bytes(self.disk.raw_bytes_per_capture),
            format_bytes(self.disk.texture_bytes_per_capture)
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hms_and_bytes() {
        assert_eq!(format_hms(0.0), "0:00:00");
        assert_eq!(format_hms(59.6), "0:01:00");
        assert_eq!(format_hms(37_000.0), "10:16:40");
        assert_eq!(format_hms(90_061.0), "25:01:01");
        assert_eq!(format_bytes(512), "512 B");
        assert_eq!(format_bytes(3 * 1024 * 1024), "3.00 MiB");
        assert_eq!(DiskEstimate { raw_bytes_per_capture: 10, texture_bytes_per_capture: 5 }.total_bytes(4), 60);
    }
}
