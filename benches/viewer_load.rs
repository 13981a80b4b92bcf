//! What the tether station costs the darkroom: throughput of a stream of brackets with the
//! viewer off, on without clients, and on with 20 clients on the event stream, each
//! fetching the new bracket's preview as the page does.
//!
//! `cargo bench --bench viewer_load [-- --mp 12 --brackets 6 --clients 20]`
//!
//! Each run starts a daemon ([`DarkroomLab`], Velvia 50 and linear looks, `jobs = 2`) on a
//! fresh folder, drops `--brackets` three-frame AEBs of `--mp` megapixels at once and
//! times from the drop to the last bracket journaled; it prints brackets per minute, the
//! CPU time of the whole process per bracket (user + system: the darkroom, the server
//! and, in the last run, the clients' threads), and each run's ratio to the one without
//! the viewer. On a machine shared with other work the CPU time is the steadier measure.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use filmback::daemon::config::Config;
use filmback::daemon::journal::{self, Entry};
use filmback::daemon::{self, Control, DarkroomLab};
use filmback::synthetic::demo;

mod common;

/// One run's measures.
struct Measured {
    /// Wall seconds from the drop to the last bracket journaled.
    wall: f64,
    /// CPU seconds of the process over the same time.
    cpu: f64,
}

fn config(root: &Path, viewer: bool) -> Config {
    let text = format!(
        r#"
[folders]
ingest = "{root}/ingest"
out = "{root}/out"
state = "{root}/state"
[watch]
settle_ms = 100
[bracket]
max_gap_s = 1.0
size = 3
[daemon]
jobs = 2
memory_mb = 16000
[render]
films = ["velvia50"]
tonemaps = ["linear"]
[viewer]
enabled = {viewer}
port = 0
"#,
        root = root.display()
    );
    Config::from_str(&text, None).expect("bench configuration")
}

/// One GET over HTTP/1.0; returns the body's length.
fn fetch(address: SocketAddr, path: &str) -> usize {
    let Ok(mut s) = TcpStream::connect(address) else {
        return 0;
    };
    let _ = write!(s, "GET {path} HTTP/1.0\r\nHost: {address}\r\n\r\n");
    let mut body = Vec::new();
    let _ = s.read_to_end(&mut body);
    body.len()
}

/// A client of the event stream: on each `developed` event it fetches the first look's
/// preview, as the page does. Returns when the stream ends.
fn client(address: SocketAddr, fetched: Arc<AtomicUsize>) {
    let Ok(mut s) = TcpStream::connect(address) else {
        return;
    };
    let _ = write!(s, "GET /events HTTP/1.0\r\nHost: {address}\r\n\r\n");
    let mut developed = false;
    for line in BufReader::new(s).lines() {
        let Ok(line) = line else { return };
        if line == "event: developed" {
            developed = true;
        } else if let Some(data) = line.strip_prefix("data: ").filter(|_| developed) {
            developed = false;
            let record: serde_json::Value = serde_json::from_str(data).unwrap_or_default();
            let preview = record["outputs"]
                .as_array()
                .and_then(|o| o.iter().find_map(|o| o["preview"].as_str()))
                .map(str::to_string);
            if let Some(p) = preview {
                fetched.fetch_add(fetch(address, &p), Ordering::Relaxed);
            }
        }
    }
}

/// Runs one stream of brackets.
fn run(frames: &[Vec<(String, Vec<u8>)>], viewer: bool, clients: usize) -> Measured {
    let dir = tempfile::tempdir().expect("temporary folder");
    let root = dir.path();
    std::fs::create_dir_all(root.join("ingest")).expect("ingest");
    let config = config(root, viewer);
    let (control, rx) = tokio::sync::mpsc::channel(4);
    let daemon = std::thread::spawn(move || {
        let rt = tokio::runtime::Builder::new_multi_thread()
            .enable_all()
            .build()
            .expect("runtime");
        rt.block_on(daemon::run(config, Arc::new(DarkroomLab), rx))
    });
    let state = root.join("state");
    let started = Instant::now();
    let snapshot = loop {
        if let Some(s) = daemon::read_snapshot(&state).filter(|s| s.running) {
            break s;
        }
        assert!(
            started.elapsed() < Duration::from_secs(30),
            "daemon did not start"
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    let fetched = Arc::new(AtomicUsize::new(0));
    if let Some(url) = snapshot.viewer.filter(|_| clients > 0) {
        let address: SocketAddr = url
            .trim_start_matches("http://")
            .trim_end_matches('/')
            .parse()
            .expect("viewer address");
        for _ in 0..clients {
            let f = Arc::clone(&fetched);
            std::thread::spawn(move || client(address, f));
        }
        std::thread::sleep(Duration::from_millis(300));
    }
    let t = Instant::now();
    let cpu = common::cpu_seconds().unwrap_or(0.0);
    for bracket in frames {
        for (name, bytes) in bracket {
            demo::drop_frame(&root.join("ingest"), name, bytes).expect("drop");
        }
    }
    loop {
        let done = journal::read(&state)
            .unwrap_or_default()
            .iter()
            .filter(|e| matches!(e, Entry::Bracket { .. }))
            .count();
        if done >= frames.len() {
            break;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let measured = Measured {
        wall: t.elapsed().as_secs_f64(),
        cpu: common::cpu_seconds().unwrap_or(0.0) - cpu,
    };
    let _ = control.blocking_send(Control::Stop);
    let _ = daemon.join();
    if clients > 0 {
        println!(
            "    {clients} clients fetched {:.1} MB of previews",
            fetched.load(Ordering::Relaxed) as f64 / 1e6
        );
    }
    measured
}

fn main() {
    let mp = common::arg_or("--mp", 12_u32);
    let brackets = common::arg_or("--brackets", 6_u32);
    let clients = common::arg_or("--clients", 20_u32) as usize;
    let width = ((f64::from(mp) * 1e6 * 1.5).sqrt() as u32) & !1;
    let height = (width * 2 / 3) & !1;
    println!("viewer_load: {brackets} brackets of 3 × {width}×{height} JPEGs, jobs = 2");
    let frames: Vec<Vec<(String, Vec<u8>)>> = (0..brackets)
        .map(|b| {
            let shots = demo::aeb("Load Cam", None, 100 + 10 * b);
            demo::jpegs(width, height, &shots, u64::from(b))
                .expect("frames")
                .into_iter()
                .enumerate()
                .map(|(i, bytes)| (format!("L{b:02}-{}.jpg", i + 1), bytes))
                .collect()
        })
        .collect();
    let n = f64::from(brackets);
    let report = |label: &str, m: &Measured, off: Option<&Measured>| {
        let ratio = off.map_or_else(String::new, |o| {
            format!(
                ", throughput {:.3} × off, CPU {:.3} × off",
                o.wall / m.wall,
                m.cpu / o.cpu
            )
        });
        println!(
            "  {label:<22} {:6.2} s, {:5.1} brackets/min, {:5.2} CPU-s a bracket{ratio}",
            m.wall,
            n * 60.0 / m.wall,
            m.cpu / n
        );
    };
    let off = run(&frames, false, 0);
    report("viewer off:", &off, None);
    let idle = run(&frames, true, 0);
    report("viewer on, no clients:", &idle, Some(&off));
    let busy = run(&frames, true, clients);
    report(&format!("viewer on, {clients} clients:"), &busy, Some(&off));
}
