//! `btfrig run --plan FILE --out DIR`: a measurement plan on the rig its config names
//! (simulated, emulated firmware, or real serial controllers, checked before anything is
//! created), into a dataset, resumable. Display and wiring only; the work is in
//! `btfrig-measurement`.
//!
//! Exit codes (also in docs/engine.md): 0 the plan is complete (or was already); 1 an error
//! (bad plan, another dataset in `--out`, I/O); 2 bad command-line usage; 3 the run paused on
//! a fault no retry helps (fix the cause, run the same command again to resume); 130
//! interrupted by Ctrl-C (SIGINT), 143 by SIGTERM, after committing the frames in flight
//! (resumable).

use std::io::Write;
use std::process::ExitCode;

use btfrig_measurement::{RunControl, RunEvent, RunOutcome, RunRequest, RunSummary, Signal};

use crate::args::RunArgs;

/// Exit code of a run that paused on a fault no retry helps.
pub const EXIT_PAUSED: u8 = 3;
/// What a paused run adds when a simulated rig's fault scenario caused the fault.
const INJECTED_HINT: &str =
    "(the simulated rig's fault scenario injected this fault; it recurs on every resume unless you add --faults none)";

/// `btfrig run`.
pub fn run(a: &RunArgs) -> anyhow::Result<ExitCode> {
    let text =
        std::fs::read_to_string(&a.plan).map_err(|e| anyhow::anyhow!("cannot read {}: {e}", a.plan.display()))?;
    // `--rig`: the plan's `[rig] config` replaced (a file made absolute), so the dataset
    // records the rig it ran on and the same command resumes it.
    let text = match &a.rig {
        Some(rig) => {
            anyhow::ensure!(
                crate::rig::builtin(rig).is_some() || rig.is_file(),
                "--rig {}: no such rig config file, nor an embedded rig of that name",
                rig.display()
            );
            let cwd = std::env::current_dir().map_err(|e| anyhow::anyhow!("the working directory: {e}"))?;
            crate::demo_cmd::with_overrides(&text, Some(rig), None, &cwd)
                .map_err(|e| anyhow::anyhow!("{}: {e:#}", a.plan.display()))?
        }
        None => text,
    };
    if btfrig_measurement::dome_dry_run::is_dome_plan(&text) {
        return run_dome(a, text);
    }
    let req = RunRequest::from_text(text, &a.plan, &a.out)
        .with_faults(a.faults.clone())
        .with_wall_clock(a.wall_clock)
        .with_light(a.light.as_deref().map(crate::calibrate_light_cmd::load).transpose()?)
        .with_dark_flat(a.dark_flat.as_deref().map(load_dark_flat).transpose()?);
    let model = compress_flag(a.compress.as_deref(), &req.plan_text, &a.plan)?;
    let req = req.with_compressed_model(model);
    let summary = execute(&req)?;
    let nothing_to_do = summary.outcome == RunOutcome::NothingToDo;
    if nothing_to_do {
        println!("{}: all {} captures already done; nothing to do", a.out.display(), summary.captures);
    } else {
        print_summary(&summary);
    }
    if let Some(c) = &summary.compression {
        print_compression(c, nothing_to_do)?;
    }
    if nothing_to_do {
        return Ok(ExitCode::SUCCESS);
    }
    Ok(finish(&summary, &command_line(a)))
}

/// The command that resumes the run of `a`.
fn command_line(a: &RunArgs) -> String {
    let rig = a.rig.as_ref().map_or(String::new(), |r| format!(" --rig {}", r.display()));
    format!("btfrig run --plan {}{rig} --out {}", a.plan.display(), a.out.display())
}

/// `btfrig run` on a dome plan (LED dome or camera array, docs/plan-format.md): collected,
/// demultiplexed and stored view group by view group; resumable per view group. Progress
/// counts steps (a pattern at a rotation, a frame per camera) with an ETA; Ctrl-C stops
/// after the step under way, keeps the committed view groups and exits 130.
fn run_dome(a: &RunArgs, plan_text: String) -> anyhow::Result<ExitCode> {
    let gonio_only = [
        ("--light", a.light.is_some(), "the lamp's light calibration"),
        ("--dark-flat", a.dark_flat.is_some(), "the gonio pipeline's dark/flat correction"),
    ];
    for (flag, given, what) in gonio_only {
        anyhow::ensure!(
            !given,
            "{flag}: {what} is for gonioreflectometer plans; {} is a dome plan (allowed with a dome plan: --faults, --compress)",
            a.plan.display()
        );
    }
    let compressed_model = compress_flag(a.compress.as_deref(), &plan_text, &a.plan)?;
    let req = btfrig_measurement::dome::DomeRunRequest {
        plan_text,
        plan_path: a.plan.clone(),
        out: a.out.clone(),
        faults: a.faults.clone(),
        preview: false,
        compressed_model,
    };
    let control = RunControl::new();
    watch_signals(control.clone());
    let mut progress = Progress { dome: true, ..Progress::default() };
    let result =
        btfrig_measurement::dome::run_controlled(&req, &control, true, &mut |line| println!("{line}"), &mut |e| {
            progress.show(e)
        });
    progress.end_line();
    let s = result?;
    println!("btfrig run: dome plan {} into {}", a.plan.display(), a.out.display());
    print_dome_summary(&s);
    if let Some(c) = &s.compression {
        print_compression(c, false)?;
    }
    let (textures, total) = progress.textures.unwrap_or((s.textures, 0));
    let command = command_line(a);
    match &s.stopped {
        None => return Ok(ExitCode::SUCCESS),
        Some(RunOutcome::Paused { reason, .. }) => {
            // As a gonio run that stops on a fault (`finish`).
            eprintln!("btfrig: the run is PAUSED, not finished ({textures} of {total} textures committed).");
            eprintln!("  reason:  {reason}");
            eprintln!("  dataset: {} (resumable; the report says status \"paused\")", a.out.display());
            if reason.contains("(injected)") {
                eprintln!("  {INJECTED_HINT}");
            }
            eprintln!("Fix the cause and run the same command again to resume:\n  {command}");
            return Ok(ExitCode::from(EXIT_PAUSED));
        }
        Some(_) => {}
    }
    let signal = match &s.stopped {
        Some(RunOutcome::Interrupted(signal)) => *signal,
        _ => Signal::Int,
    };
    eprintln!(
        "btfrig: interrupted after the step under way ({textures} of {total} textures committed; a view group not yet \
         complete is captured again on resume); run the same command again to resume:\n  {command}"
    );
    Ok(ExitCode::from(signal.exit_code()))
}

/// What the runner did with the run's compressed model (`btfrig_measurement::sinks`): the model
/// belongs to the run's outcome, so a rerun of a finished run builds it when the journal
/// does not name it intact (a kill while it was being written). A model that could not be
/// built is an error, after the run's summary.
pub fn print_compression(c: &btfrig_measurement::sinks::CompressionOutcome, nothing_to_do: bool) -> anyhow::Result<()> {
    use btfrig_measurement::sinks::CompressionOutcome;
    match c {
        CompressionOutcome::BuiltEarlier { model } => {
            println!("  compression       {} (built and journaled earlier)", model.display())
        }
        CompressionOutcome::Built { figures, replaced_damaged } => {
            if let Some(what) = replaced_damaged {
                println!("  compression       journaled model damaged ({what}): building it again");
            } else if nothing_to_do {
                println!("  compression       not built yet: building it from the dataset");
            }
            crate::compress_cmd::print_streaming(figures);
        }
        CompressionOutcome::NotFinished => {
            println!("  compression       not built: the run did not finish (resume it, or `btfrig compress` later)")
        }
        CompressionOutcome::Failed(e) => anyhow::bail!(
            "the compressed model was not built: {e} (the dataset is complete; run the same command again to build it)"
        ),
    }
    Ok(())
}

/// The model `--compress` asks for instead of the plan's `outputs.compressed_model` (the
/// runner builds it), checked before anything is captured; `None` without the flag.
pub fn compress_flag(
    flag: Option<&str>,
    plan_text: &str,
    plan_path: &std::path::Path,
) -> anyhow::Result<Option<btfrig_core::plan::CompressedModel>> {
    use btfrig_core::plan::CompressedModel;
    if let Some(m) = flag {
        let model = CompressedModel::from_name(m)
            .ok_or_else(|| anyhow::anyhow!("--compress {m:?}: allowed fmf, pvmf, pcmf, pcmf-shared"))?;
        if model == CompressedModel::PcmfShared {
            // The plan's own key is checked by validation; the flag overrides it, so check here,
            // before anything is captured. A plan that does not validate is refused by the run.
            if let Ok((_, v)) = btfrig_measurement::plan::load_text(plan_text, plan_path) {
                if let Some(why) = v.shared_basis_problem() {
                    let allowed = btfrig_core::plan::SHARED_BASIS_ALLOWED
                        .replace("{k}", &CompressedModel::SHARED_BASIS_TERMS.to_string());
                    anyhow::bail!("--compress \"pcmf-shared\": {why}: allowed {allowed}");
                }
            }
        }
        return Ok(Some(model));
    }
    Ok(None)
}

/// Runs a request with the progress display on stderr and Ctrl-C / SIGTERM wired to a clean
/// stop.
pub fn execute(req: &RunRequest) -> anyhow::Result<RunSummary> {
    let control = RunControl::new();
    watch_signals(control.clone());
    let mut progress = Progress::default();
    let summary = match btfrig_measurement::run(req, &control, &mut |e| progress.show(e)) {
        // Stopped while planning: no dataset exists, nothing to resume; the signal's code.
        Err(e @ btfrig_measurement::RunError::Interrupted(signal)) => {
            progress.end_line();
            eprintln!("btfrig: {e}");
            std::process::exit(i32::from(signal.exit_code()));
        }
        r => r?,
    };
    progress.end_line();
    Ok(summary)
}

/// The message and exit code of a run that did not finish.
pub fn finish(s: &RunSummary, command: &str) -> ExitCode {
    match &s.outcome {
        RunOutcome::Finished | RunOutcome::NothingToDo => ExitCode::SUCCESS,
        RunOutcome::Paused { reason, fault } => {
            eprintln!(
                "btfrig: the run is PAUSED, not finished ({} of {} captures done).",
                s.captures, s.planned_captures
            );
            match fault {
                Some(f) => {
                    eprintln!("  device:  {}", f.device);
                    eprintln!("  step:    {} (light {}, view {})", f.index, f.light, f.view);
                    eprintln!("  error:   {} ({})", f.message, f.kind);
                }
                None => eprintln!("  reason:  {reason}"),
            }
            eprintln!("  dataset: {} (resumable; the report says status \"paused\")", s.dataset.display());
            if fault.as_ref().is_some_and(|f| f.device == "registration") {
                eprintln!(
                    "  (the plan says [registration] on_failure = \"fail\": make the plate's markers visible, or set on_failure = \"nominal\" to go on with the nominal pose, recorded as a fallback; a simulated rig's [hidden_markers] fault recurs on every resume unless you add --faults none)"
                );
            }
            if fault.as_ref().is_some_and(|f| f.message.contains("(injected)")) {
                eprintln!("  {INJECTED_HINT}");
            }
            eprintln!("Fix the cause and run the same command again to resume:\n  {command}");
            ExitCode::from(EXIT_PAUSED)
        }
        RunOutcome::Interrupted(_) | RunOutcome::Aborted => {
            eprintln!(
                "btfrig: interrupted after committing the frames in flight ({} of {} captures done); run the same command again to resume:\n  {command}",
                s.captures, s.planned_captures
            );
            let signal = if let RunOutcome::Interrupted(signal) = s.outcome { signal } else { Signal::Int };
            ExitCode::from(signal.exit_code())
        }
    }
}

/// Reads a dark/flat calibration directory for a run.
pub fn load_dark_flat(dir: &std::path::Path) -> anyhow::Result<btfrig_measurement::DarkFlatInput> {
    let (_, calibration) = btfrig_calibrate::dark_flat::read_calibration(dir)
        .map_err(|e| anyhow::anyhow!("--dark-flat {}: {e}", dir.display()))?;
    Ok(btfrig_measurement::DarkFlatInput {
        source: dir.display().to_string(),
        calibration: std::sync::Arc::new(calibration),
    })
}

/// The one-paragraph human summary.
pub fn print_summary(s: &RunSummary) {
    let stages: Vec<String> = s.stage_s.iter().map(|(k, v)| format!("{k} {v:.2} s")).collect();
    let skipped: u64 = s.skipped.values().sum();
    println!(
        "{}: {} captures ({} this run), {} skipped by the plan, {} retries; rig time {:.0} s, wall {:.1} s; stages: {}; texture rel. RMSE {}; peak memory {}",
        s.dataset.display(),
        s.captures,
        s.captures_this_session,
        skipped,
        s.retries,
        s.hardware_s,
        s.wall_s,
        stages.join(", "),
        s.texture_rel_rmse.map(|r| format!("{r:.4}")).unwrap_or_else(|| "n/a".into()),
        s.peak_rss_mib.map(|m| format!("{m:.0} MiB")).unwrap_or_else(|| "n/a".into())
    );
    println!("{}", registration_line(s));
    if let Some((lo, hi)) = s.lamp.as_ref().and_then(|l| l.factor_range()) {
        println!("lamp factor {lo:.4} .. {hi:.4} (measured on the plate against the light calibration, divided out)");
    }
    if let Some(h) = &s.hdr {
        println!("{}", hdr_line(h));
    }
    if s.unreported_captures > 0 {
        println!(
            "note: {} captures were made by sessions that were killed; their rig and wall time are not in the totals",
            s.unreported_captures
        );
    }
}

/// The HDR figures, e.g. `HDR: captures by exposures 1: 52, 2: 6, 3: 2; brackets took 81 s of
/// rig time, 1290 s less than always bracketing; 0 photosites saturated in every exposure`.
pub fn hdr_line(h: &btfrig_measurement::HdrFigures) -> String {
    let counts: Vec<String> = h.exposures_per_capture.iter().map(|(k, n)| format!("{k}: {n}")).collect();
    format!(
        "HDR: captures by exposures {}; brackets took {:.0} s of rig time, {:.0} s less than always bracketing; {} photosites on the sample saturated in every exposure ({} captures)",
        counts.join(", "),
        h.bracket_s,
        h.time_saved_s,
        h.saturated_photosites,
        h.captures_with_saturation
    )
}

/// How the textures' poses were found, and their error against the truth when known, e.g.
/// `registration: 58 registered, 2 fallbacks; texel error mean 0.003 / max 0.011 (nominal pose 0.052 / 0.140)`.
pub fn registration_line(s: &RunSummary) -> String {
    let mut line = format!("registration: {} registered, {} fallbacks", s.registered, s.fallbacks);
    if s.nominal_by_plan > 0 {
        line += &format!(", {} with the nominal pose by plan", s.nominal_by_plan);
    }
    if let (Some(m), Some(x)) = (s.registration_mean_texel_err, s.registration_max_texel_err) {
        line += &format!("; texel error mean {m:.4} / max {x:.4}");
        if let (Some(nm), Some(nx)) = (s.nominal_mean_texel_err, s.nominal_max_texel_err) {
            line += &format!(" (nominal pose {nm:.4} / {nx:.4})");
        }
    }
    line
}

/// The first SIGINT (Ctrl-C) or SIGTERM stops the run cleanly (the runner commits the frames
/// in flight and writes the report, which names the signal); a second one exits at once with
/// the signal's code (the journal keeps the run resumable anyway).
/// Returns once the handlers are installed, so a signal that arrives later (e.g. during
/// planning) is never the default action's kill.
fn watch_signals(control: RunControl) {
    let (ready_tx, ready_rx) = std::sync::mpsc::channel::<()>();
    std::thread::spawn(move || {
        let Ok(rt) = tokio::runtime::Builder::new_current_thread().enable_all().build() else {
            let _ = ready_tx.send(());
            return;
        };
        rt.block_on(async {
            let mut signals = Signals::install();
            let _ = ready_tx.send(());
            let Some(first) = signals.next().await else { return };
            let what = if first == Signal::Int { "Ctrl-C" } else { first.name() };
            eprintln!("\nbtfrig: {what}: finishing the frames in flight, then stopping ({what} again to quit at once)");
            if let Err(e) = control.interrupt(first) {
                // The planning is cancelled anyway; the engine did not get the stop.
                eprintln!("btfrig: {what}: could not stop the engine: {e}; {what} again to quit at once");
            }
            if let Some(second) = signals.next().await {
                std::process::exit(i32::from(second.exit_code()));
            }
        });
    });
    let _ = ready_rx.recv();
}

/// SIGINT and SIGTERM listeners, registered when made.
struct Signals {
    #[cfg(unix)]
    term: Option<tokio::signal::unix::Signal>,
    #[cfg(unix)]
    int: Option<tokio::signal::unix::Signal>,
}

impl Signals {
    fn install() -> Signals {
        #[cfg(unix)]
        {
            use tokio::signal::unix::{signal, SignalKind};
            Signals { term: signal(SignalKind::terminate()).ok(), int: signal(SignalKind::interrupt()).ok() }
        }
        #[cfg(not(unix))]
        {
            Signals {}
        }
    }

    /// The next SIGINT or SIGTERM; `None` when they cannot be watched.
    async fn next(&mut self) -> Option<Signal> {
        #[cfg(unix)]
        {
            let (Some(term), Some(int)) = (self.term.as_mut(), self.int.as_mut()) else { return None };
            tokio::select! {
                _ = term.recv() => Some(Signal::Term),
                _ = int.recv() => Some(Signal::Int),
            }
        }
        #[cfg(not(unix))]
        {
            tokio::signal::ctrl_c().await.ok().map(|()| Signal::Int)
        }
    }
}

/// The progress line on stderr: captures (a dome run: steps) done/total, ETA, current step.
#[derive(Default)]
struct Progress {
    current: String,
    open_line: bool,
    /// A dome run: progress counts steps (a pattern at a rotation, a frame per camera), and
    /// textures are committed per view group.
    dome: bool,
    /// A dome run's textures in the dataset, and of the whole plan.
    textures: Option<(u64, u64)>,
    /// The run is paused (until `Resumed`).
    paused: bool,
}

impl Progress {
    fn show(&mut self, e: &RunEvent) {
        let mut err = std::io::stderr().lock();
        match e {
            RunEvent::Planning { captures } => {
                let _ = writeln!(err, "planning {captures} captures");
            }
            RunEvent::Started {
                dataset,
                resumed,
                done_before,
                to_do,
                total,
                planned_hardware_s,
                critical_path_s,
                repaired,
            } => {
                if *resumed {
                    let _ = writeln!(
                        err,
                        "resuming the dataset in {}: {done_before} done, {to_do} to do",
                        dataset.display()
                    );
                } else {
                    let _ = writeln!(err, "new dataset in {}", dataset.display());
                }
                if let Some(r) = repaired {
                    let _ = writeln!(err, "repaired on resume: {r}");
                }
                if self.dome {
                    let _ = writeln!(
                        err,
                        "{to_do} steps to do of {total} (a step: one pattern at one rotation, a frame per camera; estimated rig time at least {planned_hardware_s:.0} s)"
                    );
                } else {
                    let _ = writeln!(
                        err,
                        "{to_do} captures to do of {total} (planned hardware time {planned_hardware_s:.0} s, lower bound {critical_path_s:.0} s)"
                    );
                }
            }
            RunEvent::StepDone { light, view, .. } => self.current = format!("light {light} view {view}"),
            RunEvent::DomeStepDone { index, rotation, .. } => {
                self.current = format!("step {index} rotation {rotation}")
            }
            RunEvent::Progress { done, total, eta_s } => {
                let eta = eta_s.map(|s| format!("{s:.0} s")).unwrap_or_else(|| "?".into());
                let _ = match (self.dome, self.textures) {
                    (true, Some((t, n))) => write!(
                        err,
                        "\rsteps {done}/{total}, ETA {eta} (rig time), textures {t}/{n}, last {}   ",
                        self.current
                    ),
                    (true, None) => {
                        write!(err, "\rsteps {done}/{total}, ETA {eta} (rig time), last {}   ", self.current)
                    }
                    (false, _) => {
                        write!(err, "\rcaptures {done}/{total}, ETA {eta} (rig time), last {}   ", self.current)
                    }
                };
                let _ = err.flush();
                self.open_line = true;
            }
            RunEvent::TexturesCommitted { textures, total, .. } => self.textures = Some((*textures, *total)),
            RunEvent::Warning(w) => {
                let _ = writeln!(err, "\nwarning: {w}");
            }
            RunEvent::Paused { reason, .. } => {
                let _ = writeln!(err, "\npaused: {reason}");
                self.paused = true;
            }
            RunEvent::Resumed => {
                let _ = writeln!(err, "resumed");
                self.paused = false;
            }
            RunEvent::Committed { .. } => {}
            // A device fault: the pause line just said why, and the failed step captured nothing.
            RunEvent::Stopping { .. } if self.dome && self.paused => {
                let _ = writeln!(
                    err,
                    "stopping on the failed step: the view groups committed stay, the one under way is captured again on resume"
                );
            }
            RunEvent::Stopping { reason } if self.dome => {
                let _ = writeln!(
                    err,
                    "\nstopping ({reason}) after the step under way: the view groups committed stay, the one under way is captured again on resume"
                );
            }
            RunEvent::Stopping { reason } => {
                let _ = writeln!(err, "\nstopping ({reason}): committing the frames in flight");
            }
        }
    }

    fn end_line(&mut self) {
        if self.open_line {
            eprintln!();
            self.open_line = false;
        }
    }
}

/// The figures of a dome run (`btfrig demo --rig dome|camera-array`, `btfrig run` on a dome
/// plan), one per line.
pub fn print_dome_summary(s: &btfrig_measurement::dome::DomeRunSummary) {
    let lights = if s.light == "flash" { "flashes" } else { "LEDs" };
    let f = |v: Option<f64>| v.map(|r| format!("{r:.3}")).unwrap_or_else(|| "n/a".into());
    println!(
        "  textures          {} ({} {} x {} views), {} frames per camera",
        s.textures, s.leds, lights, s.views, s.frames
    );
    println!("  mode              {}: {}", s.mode, s.multiplex_reason);
    println!(
        "  SNR gain          predicted {:.3}, measured {} (demultiplexed vs single-light frames, against noise-free renders)",
        s.multiplex_gain_predicted,
        f(s.multiplex_gain_measured)
    );
    let of = if s.light == "flash" {
        "frames single-flash capture averages"
    } else {
        "exposure time single-light capture needs"
    };
    println!("  time saved        {:.1} % of the {of} for the same SNR", 100.0 * s.time_saved_fraction);
    println!("  rig time          {:.1} s ({:.1} s exposing)", s.hardware_s, s.exposure_time_s);
    println!(
        "  texture error     {} (single-light references {}): relative RMSE against ground truth",
        f(s.texture_rel_rmse),
        f(s.reference_texture_rel_rmse)
    );
    println!("  group memory      {:.1} MB per view group", s.group_bytes as f64 / 1e6);
    if let Some(k) = s.denoise_terms {
        let n = s.denoise_energy_kept.len().max(1) as f64;
        println!(
            "  denoising         projection onto each view group's own {k}-term light basis: {:.1} % of the energy kept (mean), {:.2} s",
            100.0 * s.denoise_energy_kept.iter().sum::<f64>() / n,
            s.denoise_s
        );
    }
    println!("  wall time         {:.1} s", s.wall_s);
    // Found in the data by the demultiplexer; a device fault is reported apart (paused).
    let label = format!("{} faults", s.light);
    println!("  {label:<18}{}", if s.faults.is_empty() { "none".into() } else { s.faults.join("; ") });
    println!("  warnings          {}", s.warnings.len());
    println!("  dataset           {}", s.dataset.display());
}
