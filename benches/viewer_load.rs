//! What the tether station costs the darkroom: throughput of a stream of brackets with the
//! viewer off, on without clients, and on with 20 clients on the event stream, each
//! fetching the new bracket's preview as the page does.
//!
//! `cargo bench --bench viewer_load [-- --mp 12 --brackets 6 --clients 20]`
//!
//! Each run starts a daemon ([`DarkroomLab`], Velvia 50 and linear looks, `jobs = 2`) on a
//! fresh folder, drops `--brackets` three-frame AEBs of `--mp` megapixels at once and
//! times from the drop to the last bracket journaled; it prints brackets per minute and
//! the ratio of each run to the one without the viewer.

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

fn arg(name: &str, default: u32) -> u32 {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
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

/// Runs one stream of brackets; returns the seconds from the drop to the last journaled.
fn run(frames: &[Vec<(String, Vec<u8>)>], viewer: bool, clients: usize) -> f64 {
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
    let seconds = t.elapsed().as_secs_f64();
    let _ = control.blocking_send(Control::Stop);
    let _ = daemon.join();
    if clients > 0 {
        println!(
            "    {clients} clients fetched {:.1} MB of previews",
            fetched.load(Ordering::Relaxed) as f64 / 1e6
        );
    }
    seconds
}

fn main() {
    let mp = arg("--mp", 12);
    let brackets = arg("--brackets", 6);
    let clients = arg("--clients", 20) as usize;
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
    let per_minute = |s: f64| f64::from(brackets) * 60.0 / s;
    let off = run(&frames, false, 0);
    println!(
        "  viewer off:            {off:6.2} s, {:5.1} brackets/min",
        per_minute(off)
    );
    let idle = run(&frames, true, 0);
    println!(
        "  viewer on, no clients: {idle:6.2} s, {:5.1} brackets/min, throughput {:.3} × off",
        per_minute(idle),
        off / idle
    );
    let busy = run(&frames, true, clients);
    println!(
        "  viewer on, {clients} clients: {busy:6.2} s, {:5.1} brackets/min, throughput {:.3} × off, {:.3} × no clients",
        per_minute(busy),
        off / busy,
        idle / busy
    );
}
