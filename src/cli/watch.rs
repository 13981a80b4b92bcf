//! `filmback watch [--config FILE] [--ingest DIR] [--out DIR] [--state DIR] [--demo]`.

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::time::Duration;

use anyhow::Context;
use filmback::daemon::config::Config;
use filmback::daemon::journal::Entry;
use filmback::daemon::{self, Control, DarkroomLab};
use filmback::synthetic::demo;
use tokio::signal::unix::{SignalKind, signal};
use tokio::sync::mpsc;
use tracing::{error, info};

/// Arguments of `filmback watch`.
#[derive(Debug, Clone, clap::Args)]
pub struct Args {
    /// Configuration file (TOML); without it the built-in defaults apply.
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Ingest folder (overrides the file).
    #[arg(long, value_name = "DIR")]
    ingest: Option<PathBuf>,
    /// Output folder (overrides the file).
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    /// State folder: journal, response cache, status (overrides the file).
    #[arg(long, value_name = "DIR")]
    state: Option<PathBuf>,
    /// Demonstration: after start, print the viewer's address, drop a synthetic
    /// three-frame bracket with EXIF into the ingest folder (as a tethering tool would) and
    /// print the outputs once it is developed; the daemon goes on watching until Ctrl-C.
    #[arg(long)]
    demo: bool,
}

impl Args {
    /// The file (or defaults) with the command-line folders on top.
    fn config(&self) -> anyhow::Result<Config> {
        let mut config = match &self.config {
            Some(path) => Config::load(path)?,
            None => Config::defaults(),
        };
        if let Some(d) = &self.ingest {
            config.folders.ingest.clone_from(d);
        }
        if let Some(d) = &self.out {
            config.folders.out.clone_from(d);
        }
        if let Some(d) = &self.state {
            config.folders.state.clone_from(d);
        }
        let label = match &self.config {
            Some(p) => format!("{} with command-line folders", p.display()),
            None => "command line".to_string(),
        };
        config.check_folders(Path::new(&label))?;
        Ok(config)
    }
}

/// Standard error, one log event per line whatever it contains: control characters in
/// an event (a file name with a newline, an EXIF field with a carriage return) are
/// written as `\n`, `\r`, `\t` or `\xNN`, so no name can forge or split a log line.
/// The event's own final newline, and the escape character of colours on a terminal,
/// pass through.
struct OneLine {
    colour: bool,
}

impl std::io::Write for OneLine {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let body = buf.strip_suffix(b"\n").unwrap_or(buf);
        let mut line = Vec::with_capacity(buf.len() + 8);
        for &b in body {
            match b {
                b'\n' => line.extend_from_slice(b"\\n"),
                b'\r' => line.extend_from_slice(b"\\r"),
                b'\t' => line.extend_from_slice(b"\\t"),
                0x1b if self.colour => line.push(b),
                0..=0x1f | 0x7f => line.extend_from_slice(format!("\\x{b:02x}").as_bytes()),
                _ => line.push(b),
            }
        }
        if body.len() < buf.len() {
            line.push(b'\n');
        }
        std::io::stderr().lock().write_all(&line)?;
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        std::io::stderr().flush()
    }
}

/// Human-readable logs on a terminal; plain lines (no colour, no timestamp: journald
/// stamps them) when systemd captures stderr (`JOURNAL_STREAM` set). Every event is one
/// line ([`OneLine`]).
fn init_tracing() {
    use std::io::IsTerminal;
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let journald = std::env::var_os("JOURNAL_STREAM").is_some();
    let colour = !journald && std::io::stderr().is_terminal();
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(move || OneLine { colour })
        .with_target(false)
        .with_ansi(colour);
    if journald {
        builder.without_time().init();
    } else {
        builder.init();
    }
}

/// Runs the daemon until SIGTERM or SIGINT.
pub fn run(args: Args) -> anyhow::Result<ExitCode> {
    let config = args.config()?;
    init_tracing();
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    let result = runtime.block_on(async {
        let (tx, rx) = mpsc::channel(4);
        let signals = forward_signals(tx, args.clone())?;
        tokio::spawn(signals);
        if args.demo {
            let (ingest, state) = (config.folders.ingest.clone(), config.folders.state.clone());
            tokio::spawn(async move {
                if let Err(e) = demo_bracket(&ingest, &state).await {
                    error!(error = %super::chain_text(&e), "demo");
                }
            });
        }
        daemon::run(config, Arc::new(DarkroomLab), rx).await?;
        Ok::<_, anyhow::Error>(())
    });
    // Brackets abandoned at stop keep their blocking threads; don't wait for them.
    runtime.shutdown_timeout(Duration::from_millis(500));
    result?;
    Ok(ExitCode::SUCCESS)
}

/// SIGTERM/SIGINT stop the daemon; SIGHUP re-reads the configuration and applies it
/// only if it is valid (otherwise the old one is kept and the error logged).
fn forward_signals(
    tx: mpsc::Sender<Control>,
    args: Args,
) -> anyhow::Result<impl std::future::Future<Output = ()>> {
    let mut term = signal(SignalKind::terminate()).context("cannot handle SIGTERM")?;
    let mut int = signal(SignalKind::interrupt()).context("cannot handle SIGINT")?;
    let mut hup = signal(SignalKind::hangup()).context("cannot handle SIGHUP")?;
    Ok(async move {
        loop {
            tokio::select! {
                _ = term.recv() => { info!("SIGTERM"); break; }
                _ = int.recv() => { info!("SIGINT"); break; }
                _ = hup.recv() => {
                    let _ = sd_notify::notify(&[sd_notify::NotifyState::Reloading]);
                    match args.config() {
                        Ok(c) => { let _ = tx.send(Control::Reload(Box::new(c))).await; }
                        Err(e) => error!(error = %super::chain_text(&e), "new configuration rejected; keeping the running one"),
                    }
                    let _ = sd_notify::notify(&[sd_notify::NotifyState::Ready]);
                }
            }
        }
        let _ = tx.send(Control::Stop).await;
    })
}

/// The viewer's address as the running daemon's status snapshot gives it (after start,
/// within 5 s), or `None` when it is not served.
async fn viewer_url(state: &Path) -> Option<String> {
    let deadline = tokio::time::Instant::now() + Duration::from_secs(5);
    while tokio::time::Instant::now() < deadline {
        if let Some(snapshot) = daemon::read_snapshot(state).filter(|s| s.running) {
            return snapshot.viewer;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    None
}

/// The demonstration: drops one synthetic bracket (three 1200×800 JPEGs with EXIF,
/// −2/0/+2 EV) into the ingest folder the way a tethering tool does (written under a
/// temporary name, then renamed), waits for the daemon's journal to settle it and prints
/// what was written.
async fn demo_bracket(ingest: &Path, state: &Path) -> anyhow::Result<()> {
    tokio::time::sleep(Duration::from_millis(500)).await;
    if let Some(url) = viewer_url(state).await {
        println!("the tether station: open {url} to see the demo bracket arrive");
    }
    let stamp = filmback::daemon::journal::unix_now();
    let shots = demo::aeb("Demo Camera", Some("0001"), (stamp % 3600) as u32);
    // One scene every time (its file names still carry the time, so runs do not collide).
    let (width, height) = demo::SIZE;
    let jpegs =
        tokio::task::spawn_blocking(move || demo::jpegs(width, height, &shots, demo::SCENE))
            .await
            .context("demo bracket")?
            .context("cannot make the demo bracket")?;
    let mut names = Vec::new();
    for (i, bytes) in jpegs.iter().enumerate() {
        let name = format!("demo-{stamp}-{}.jpg", i + 1);
        let path = demo::drop_frame(ingest, &name, bytes)
            .with_context(|| format!("cannot write the demo frame {name}"))?;
        info!(file = %path.display(), "demo frame dropped");
        names.push(name);
        tokio::time::sleep(Duration::from_millis(300)).await;
    }
    let ours = |inputs: Vec<&filmback::daemon::bracket::Input>| {
        inputs.iter().any(|i| {
            i.path
                .file_name()
                .is_some_and(|n| names.iter().any(|m| n == m.as_str()))
        })
    };
    let deadline = tokio::time::Instant::now() + Duration::from_secs(120);
    while tokio::time::Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(250)).await;
        let Ok(entries) = filmback::daemon::journal::read(state) else {
            continue;
        };
        let Some(entry) = entries.iter().rev().find(|e| ours(e.inputs())) else {
            continue;
        };
        return match entry {
            Entry::Bracket {
                outputs, response, ..
            } => {
                println!("demo bracket developed (response: {response}):");
                for o in outputs {
                    println!("  {}", o.display());
                }
                println!("still watching {} (Ctrl-C to stop)", ingest.display());
                Ok(())
            }
            other => anyhow::bail!("the demo bracket was not developed: {other:?}"),
        };
    }
    anyhow::bail!("the demo bracket was not developed within 120 s")
}
