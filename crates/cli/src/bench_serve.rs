//! `btfrig bench serve`: a simulated run through `btfrig serve`, alternately without load
//! and with a second process sending status requests at a fixed rate; prints the requests'
//! latency percentiles and the run's wall time with and without load, side by side.
//!
//! The load is open-loop: request k is due at k / rate seconds and its latency is measured
//! from when it was due, so a stalled server cannot hide its stall by slowing the sender
//! (coordinated omission). Requests use keep-alive HTTP/1.1 connections, one per sender thread.

use std::io::{BufRead, BufReader, Read};
use std::process::{Command, Stdio};
use std::time::Duration;

use anyhow::{bail, Context};
use btfrig_bench::serve::{cpu_s, run_once, send_open_loop, LoadStats, AUTH, TOKEN};

/// `btfrig bench serve`.
#[derive(Debug, clap::Args)]
pub struct BenchServeArgs {
    /// Status requests per second from the second process.
    #[arg(long, default_value_t = 200.0)]
    pub rate: f64,
    /// Captures per run (the embedded demo plan, capped).
    #[arg(long, default_value_t = 30)]
    pub captures: usize,
    /// Pairs of runs (without load, with load), alternated so drift hits both alike.
    #[arg(long, default_value_t = 3)]
    pub pairs: usize,
    /// Endpoint the load requests.
    #[arg(long, default_value = "/api/v1/runs/current")]
    pub path: String,
    /// Print one JSON object instead of the table.
    #[arg(long)]
    pub json: bool,
}

/// `btfrig bench serve-load` (the second process).
#[derive(Debug, clap::Args)]
pub struct ServeLoadArgs {
    /// The daemon's port on 127.0.0.1.
    #[arg(long)]
    pub port: u16,
    /// Bearer token.
    #[arg(long)]
    pub token: String,
    /// Requests per second.
    #[arg(long)]
    pub rate: f64,
    /// Endpoint.
    #[arg(long)]
    pub path: String,
    /// Sender threads (connections). One suffices at hundreds per second (each request takes
    /// well under a millisecond) and costs the machine least.
    #[arg(long, default_value_t = 1)]
    pub connections: usize,
}

/// Runs the benchmark.
pub fn bench(a: &BenchServeArgs) -> anyhow::Result<()> {
    if !(a.rate > 0.0 && a.rate <= 5000.0) {
        bail!("--rate {}: give a rate in (0, 5000] requests per second", a.rate);
    }
    if a.captures == 0 || a.pairs == 0 {
        bail!("--captures and --pairs must be at least 1");
    }
    let dir = std::env::temp_dir().join(format!("btfrig-bench-serve-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let auth = dir.join("auth.toml");
    std::fs::write(&auth, AUTH)?;
    let exe = std::env::current_exe()?;
    let mut daemon = Command::new(&exe)
        .args(["serve", "--listen", "127.0.0.1:0", "--data"])
        .arg(dir.join("data"))
        .arg("--auth")
        .arg(&auth)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .context("starting btfrig serve")?;
    let result = (|| {
        let mut line = String::new();
        BufReader::new(daemon.stdout.take().context("daemon stdout")?).read_line(&mut line)?;
        let port: u16 = line
            .trim()
            .rsplit(':')
            .next()
            .and_then(|p| p.parse().ok())
            .with_context(|| format!("daemon said {line:?}"))?;
        let plan = include_str!("../../../rig-configs/plans/demo.toml")
            .replace("max_captures = 60", &format!("max_captures = {}", a.captures));
        let mut rows = Vec::new();
        for pair in 0..a.pairs {
            for loaded in [false, true] {
                let load = if loaded {
                    Some(
                        Command::new(&exe)
                            .args(["bench", "serve-load", "--port", &port.to_string(), "--token", TOKEN])
                            .args(["--rate", &a.rate.to_string(), "--path", &a.path])
                            .stdin(Stdio::piped())
                            .stdout(Stdio::piped())
                            .spawn()
                            .context("starting the load process")?,
                    )
                } else {
                    None
                };
                let wall = run_once(port, &plan, &format!("bench-{pair}-{}", if loaded { "load" } else { "idle" }))?;
                let stats = match load {
                    Some(mut child) => {
                        drop(child.stdin.take()); // EOF: stop and report
                        let out = child.wait_with_output()?;
                        let v: serde_json::Value = serde_json::from_slice(&out.stdout)
                            .with_context(|| format!("load process said {:?}", String::from_utf8_lossy(&out.stdout)))?;
                        Some(v)
                    }
                    None => None,
                };
                rows.push((loaded, wall, stats));
            }
        }
        // CPU per request with no run: the daemon's share and the load process's own.
        let daemon_pid = daemon.id().to_string();
        let before = cpu_s(&daemon_pid);
        let mut child = Command::new(&exe)
            .args(["bench", "serve-load", "--port", &port.to_string(), "--token", TOKEN])
            .args(["--rate", &a.rate.to_string(), "--path", &a.path])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()?;
        std::thread::sleep(Duration::from_secs(5));
        drop(child.stdin.take());
        let out = child.wait_with_output()?;
        let idle_load: serde_json::Value = serde_json::from_slice(&out.stdout)?;
        let daemon_cpu = before.zip(cpu_s(&daemon_pid)).map(|(b, e)| e - b);
        let n = idle_load["requests"].as_f64().unwrap_or(0.0).max(1.0);
        let cpu = (daemon_cpu.map(|c| c / n * 1e6), idle_load["cpu_s"].as_f64().map(|c| c / n * 1e6));
        Ok::<_, anyhow::Error>((rows, cpu))
    })();
    let _ = daemon.kill();
    let _ = daemon.wait();
    let _ = std::fs::remove_dir_all(&dir);
    let (rows, (daemon_us, client_us)) = result?;
    let idle: Vec<f64> = rows.iter().filter(|r| !r.0).map(|r| r.1).collect();
    let busy: Vec<f64> = rows.iter().filter(|r| r.0).map(|r| r.1).collect();
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    // Each loaded run against the idle run just before it, then the median: drift of the
    // machine's load between pairs cancels.
    let mut ratios: Vec<f64> = idle.iter().zip(&busy).map(|(i, b)| b / i - 1.0).collect();
    ratios.sort_by(|a, b| a.total_cmp(b));
    let slowdown = ratios[ratios.len() / 2];
    let loads: Vec<&serde_json::Value> = rows.iter().filter_map(|r| r.2.as_ref()).collect();
    let worst_p99 = loads.iter().filter_map(|v| v["p99_ms"].as_f64()).fold(0.0, f64::max);
    let errors: u64 = loads.iter().filter_map(|v| v["errors"].as_u64()).sum();
    if a.json {
        println!(
            "{}",
            serde_json::json!({
                "rate": a.rate, "captures": a.captures, "pairs": a.pairs,
                "run_wall_s_idle": idle, "run_wall_s_loaded": busy,
                "slowdown": slowdown, "slowdown_per_pair": ratios,
                "daemon_cpu_us_per_request": daemon_us, "load_cpu_us_per_request": client_us, "p99_ms_worst": worst_p99, "load": loads, "errors": errors,
            })
        );
        return Ok(());
    }
    println!(
        "bench serve: {} captures per run (demo plan), {} requests/s to {} from a second process, {} pairs",
        a.captures, a.rate, a.path, a.pairs
    );
    println!(
        "{:<6} {:>10} {:>9} {:>9} {:>9} {:>9} {:>9} {:>7}",
        "run", "wall s", "requests", "rate/s", "p50 ms", "p99 ms", "max ms", "errors"
    );
    for (loaded, wall, stats) in &rows {
        match stats {
            Some(v) => println!(
                "{:<6} {:>10.2} {:>9} {:>9.1} {:>9.2} {:>9.2} {:>9.2} {:>7}",
                "load",
                wall,
                v["requests"],
                v["rate"].as_f64().unwrap_or(0.0),
                v["p50_ms"].as_f64().unwrap_or(f64::NAN),
                v["p99_ms"].as_f64().unwrap_or(f64::NAN),
                v["max_ms"].as_f64().unwrap_or(f64::NAN),
                v["errors"]
            ),
            None => {
                let _ = loaded;
                println!("{:<6} {:>10.2}", "idle", wall)
            }
        }
    }
    let us = |v: Option<f64>| v.map_or("?".to_string(), |v| format!("{v:.0}"));
    println!(
        "CPU per status request (no run): daemon {} us, load process {} us; at {} requests/s that is {:.2} % of the 2 cores",
        us(daemon_us),
        us(client_us),
        a.rate,
        (daemon_us.unwrap_or(0.0) + client_us.unwrap_or(0.0)) * a.rate / 1e6 / 2.0 * 100.0
    );
    println!(
        "p99 latency (worst run) {worst_p99:.2} ms (target < 20); run slowdown under load {:+.2} % (median of the pairs {}; mean wall {:.2} s vs {:.2} s; target < 2 %); {errors} failed requests",
        100.0 * slowdown,
        ratios.iter().map(|r| format!("{:+.2} %", 100.0 * r)).collect::<Vec<_>>().join(", "),
        mean(&busy),
        mean(&idle)
    );
    Ok(())
}

/// The load process: sends until stdin closes, then prints its statistics as JSON.
pub fn load(a: &ServeLoadArgs) -> anyhow::Result<()> {
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let s = stop.clone();
    std::thread::spawn(move || {
        let mut sink = Vec::new();
        let _ = std::io::stdin().read_to_end(&mut sink);
        s.store(true, std::sync::atomic::Ordering::Relaxed);
    });
    let LoadStats { latencies_ms: lat, errors, seconds: secs } =
        send_open_loop(a.port, &a.token, &a.path, a.rate, a.connections, &stop)?;
    let pct = |p: f64| if lat.is_empty() { f64::NAN } else { lat[((lat.len() - 1) as f64 * p).round() as usize] };
    println!(
        "{}",
        serde_json::json!({
            "requests": lat.len(), "errors": errors, "seconds": secs, "rate": lat.len() as f64 / secs,
            "p50_ms": pct(0.5), "p90_ms": pct(0.9), "p99_ms": pct(0.99), "max_ms": lat.last().copied(),
            "cpu_s": cpu_s("self"),
        })
    );
    Ok(())
}
