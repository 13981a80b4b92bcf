//! The tether station over real HTTP on loopback, against a running daemon: the page,
//! the event stream, previews, `/metrics`, the token and path rules, `redo`; and the
//! page itself in headless Chromium, updating without a reload.

use std::collections::HashMap;
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use filmback::daemon::{self, DarkroomLab, Job, JobError, Lab, Processed};

use crate::common::rig::{self, PATIENCE, Rig};

/// A token for the servers that require one.
const TOKEN: &str = "test-token-0123456789";

/// The rig's configuration with the viewer on an ephemeral loopback port and `viewer`
/// added to its table.
fn config(root: &Path, viewer: &str) -> String {
    rig::config_text(root, &format!("[viewer]\nport = 0\n{viewer}\n"))
}

/// Starts a daemon with `lab` under `viewer` settings; returns it with the viewer's
/// address (from the status snapshot, as `filmback status` shows it).
fn start(lab: Arc<dyn Lab>, viewer: &str) -> (Rig, tempfile::TempDir, SocketAddr) {
    let dir = tempfile::tempdir().unwrap();
    let rig = Rig::start_with_text(dir.path(), &config(dir.path(), viewer), lab);
    let address = viewer_address(&rig.state());
    (rig, dir, address)
}

/// Waits for the running daemon's snapshot to name the viewer's address.
fn viewer_address(state: &Path) -> SocketAddr {
    let start = Instant::now();
    loop {
        if let Some(url) = daemon::read_snapshot(state).and_then(|s| s.viewer) {
            let host = url.trim_start_matches("http://").trim_end_matches('/');
            return host.parse().unwrap();
        }
        assert!(
            start.elapsed() < PATIENCE,
            "the viewer's address never appeared"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// A response: status, headers (lower-case names), body.
struct Reply {
    status: u16,
    headers: HashMap<String, String>,
    body: Vec<u8>,
}

/// One HTTP/1.0 request (the connection closes after the reply, whose body needs no
/// chunk decoding); `head` holds extra header lines.
fn request(address: SocketAddr, method: &str, path: &str, head: &[&str]) -> Reply {
    let mut stream = TcpStream::connect(address).unwrap();
    stream.set_read_timeout(Some(PATIENCE)).unwrap();
    let mut text = format!("{method} {path} HTTP/1.0\r\n");
    if !head
        .iter()
        .any(|h| h.to_ascii_lowercase().starts_with("host:"))
    {
        text.push_str(&format!("Host: {address}\r\n"));
    }
    for h in head {
        text.push_str(h);
        text.push_str("\r\n");
    }
    text.push_str("\r\n");
    stream.write_all(text.as_bytes()).unwrap();
    let mut raw = Vec::new();
    stream.read_to_end(&mut raw).unwrap();
    let split = raw
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .expect("a complete head");
    let head = String::from_utf8_lossy(&raw[..split]).into_owned();
    let mut lines = head.lines();
    let status = lines
        .next()
        .unwrap()
        .split(' ')
        .nth(1)
        .unwrap()
        .parse()
        .unwrap();
    let headers = lines
        .filter_map(|l| l.split_once(':'))
        .map(|(k, v)| (k.trim().to_ascii_lowercase(), v.trim().to_string()))
        .collect();
    Reply {
        status,
        headers,
        body: raw[split + 4..].to_vec(),
    }
}

fn get(address: SocketAddr, path: &str) -> Reply {
    request(address, "GET", path, &[])
}

/// A subscriber of `/events`: its events `(kind, JSON)` arrive on a channel with the
/// instant each was read.
fn subscribe(
    address: SocketAddr,
    query: &str,
) -> std::sync::mpsc::Receiver<(String, serde_json::Value, Instant)> {
    let mut stream = TcpStream::connect(address).unwrap();
    write!(
        stream,
        "GET /events{query} HTTP/1.0\r\nHost: {address}\r\nAccept: text/event-stream\r\n\r\n"
    )
    .unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let mut kind = String::new();
        for line in BufReader::new(stream).lines() {
            let Ok(line) = line else { return };
            if let Some(k) = line.strip_prefix("event:") {
                kind = k.trim().to_string();
            } else if let Some(data) = line.strip_prefix("data:") {
                let value = serde_json::from_str(data.trim()).unwrap();
                if tx.send((kind.clone(), value, Instant::now())).is_err() {
                    return;
                }
            }
        }
    });
    rx
}

/// The next event of `kind`, skipping others; panics after [`PATIENCE`].
fn next_event(
    rx: &std::sync::mpsc::Receiver<(String, serde_json::Value, Instant)>,
    kind: &str,
) -> (serde_json::Value, Instant) {
    let deadline = Instant::now() + PATIENCE;
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        let (k, v, at) = rx
            .recv_timeout(left)
            .unwrap_or_else(|_| panic!("no {kind} event"));
        if k == kind {
            return (v, at);
        }
    }
}

/// The value of the sample `name` (with its labels as written) in a metrics text.
fn sample(text: &str, name: &str) -> Option<f64> {
    text.lines()
        .filter(|l| !l.starts_with('#'))
        .find_map(|l| l.strip_prefix(name)?.strip_prefix(' ')?.trim().parse().ok())
}

/// A bracket dropped in: the page is served, the event names its outputs within a second
/// of their publication, the preview decodes, the full file is the output, `/metrics`
/// counts it, and a request naming another host is refused.
#[test]
fn a_bracket_reaches_the_event_stream_previews_and_metrics() {
    let (mut rig, _dir, address) = start(Arc::new(DarkroomLab), "");
    let page = get(address, "/");
    assert_eq!(page.status, 200);
    assert!(String::from_utf8_lossy(&page.body).contains("tether station"));
    let events = subscribe(address, "");
    next_event(&events, "status");
    rig::put(&rig.ingest(), &rig::aeb("Viewer Cam", 40, "VW"));
    let out = rig.out();
    let names = rig::wait_for(&out, "the outputs", |n| n.len() >= 2);
    let published = Instant::now();
    let (record, arrived) = next_event(&events, "developed");
    let latency = arrived.saturating_duration_since(published);
    eprintln!("developed event {latency:?} after the outputs were seen");
    assert!(
        latency < Duration::from_secs(1),
        "event came {latency:?} late"
    );
    assert_eq!(record["stem"], "VW-1");
    assert_eq!(record["kind"], "bracket");
    let mut outputs: Vec<&str> = record["outputs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|o| o["name"].as_str().unwrap())
        .collect();
    outputs.sort_unstable();
    assert_eq!(outputs, names);
    assert_eq!(record["looks"], serde_json::json!(["linear"]));
    assert_eq!(record["frames"].as_array().unwrap().len(), 3);
    let linear = record["outputs"]
        .as_array()
        .unwrap()
        .iter()
        .find(|o| o["look"] == "linear")
        .unwrap();
    let preview = get(address, linear["preview"].as_str().unwrap());
    assert_eq!(preview.status, 200);
    assert_eq!(preview.headers["content-type"], "image/jpeg");
    let picture = image::load_from_memory(&preview.body).unwrap();
    assert_eq!((picture.width(), picture.height()), (rig::W, rig::H));
    let full = get(address, linear["file"].as_str().unwrap());
    assert_eq!(full.status, 200);
    assert_eq!(
        full.body,
        std::fs::read(out.join(linear["name"].as_str().unwrap())).unwrap()
    );
    let thumb = record["frames"][0]["thumb"].as_str().unwrap();
    assert_eq!(get(address, thumb).status, 200);
    // What no frame exposed well (the scene's sun) as an overlay of the preview's shape.
    assert!(record["facts"]["clipped_everywhere"].as_f64().unwrap() > 0.0);
    let overlay = get(address, record["clipped"].as_str().expect("an overlay"));
    assert_eq!(overlay.status, 200);
    assert_eq!(overlay.headers["content-type"], "image/png");
    let overlay = image::load_from_memory(&overlay.body).unwrap().to_rgba8();
    let (w, h) = overlay.dimensions();
    assert!(w.max(h) <= filmback::darkroom::CLIP_MAP_EDGE, "{w}×{h}");
    assert!((f64::from(w) / f64::from(h) - f64::from(rig::W) / f64::from(rig::H)).abs() < 0.05);
    let marked = overlay.pixels().filter(|p| p.0[3] > 0).count();
    assert!(
        marked > 0 && marked < (w * h) as usize / 2,
        "{marked} of {w}×{h} marked"
    );
    assert!(
        record["left_out"].is_null(),
        "a still bracket has no left-out overlay"
    );
    let metrics = get(address, "/metrics");
    assert_eq!(metrics.status, 200);
    let text = String::from_utf8(metrics.body).unwrap();
    assert!(text.trim_end().ends_with("# EOF"), "{text}");
    assert_eq!(
        sample(&text, "filmback_developed_total{kind=\"bracket\"}"),
        Some(1.0),
        "{text}"
    );
    assert_eq!(
        sample(&text, "filmback_viewer_clients"),
        Some(1.0),
        "{text}"
    );
    assert!(
        sample(&text, "filmback_stage_seconds_count{stage=\"merge\"}").is_some(),
        "{text}"
    );
    let foreign = request(address, "GET", "/", &["Host: photos.example.com"]);
    assert_eq!(
        foreign.status, 421,
        "a name other than localhost needs a token"
    );
    rig.stop();
}

/// A bracket with a moving subject links an overlay of where deghosting left frames out:
/// marked along the subject's path, clear away from it.
#[test]
fn a_moving_subject_gets_a_left_out_overlay() {
    let (mut rig, _dir, address) = start(Arc::new(DarkroomLab), "");
    let events = subscribe(address, "");
    next_event(&events, "status");
    rig::put(&rig.ingest(), &rig::aeb_with_subject("Ghost Cam", 45, "GH"));
    let (record, _) = next_event(&events, "developed");
    let share = record["facts"]["deghosted"].as_f64().unwrap();
    assert!(share > 0.02 && share < 0.5, "{share}");
    let overlay = get(address, record["left_out"].as_str().expect("an overlay"));
    assert_eq!(overlay.status, 200);
    assert_eq!(overlay.headers["content-type"], "image/png");
    let overlay = image::load_from_memory(&overlay.body).unwrap().to_rgba8();
    // Under CLIP_MAP_EDGE: one map pixel a frame pixel.
    assert_eq!(overlay.dimensions(), (rig::W, rig::H));
    let alpha = |x: u32, y: u32| overlay.get_pixel(x, y).0[3];
    // The subject in the first and last frames, not in the reference (the middle one).
    assert!(
        alpha(18, 32) > 100 && alpha(78, 32) > 100,
        "{} {}",
        alpha(18, 32),
        alpha(78, 32)
    );
    assert_eq!((alpha(2, 2), alpha(93, 61)), (0, 0), "far from the subject");
    rig.stop();
}

/// The recent brackets of `/api/brackets` (the Session view).
fn session(address: SocketAddr) -> Vec<serde_json::Value> {
    let reply = get(address, "/api/brackets");
    assert_eq!(reply.status, 200);
    let overview: serde_json::Value = serde_json::from_slice(&reply.body).unwrap();
    overview["brackets"].as_array().unwrap().clone()
}

/// A daemon restarted on the same folders shows the brackets it developed before: the
/// kept record (its timings), previews still there at once, a preview that went missing
/// made again without a new development.
#[test]
fn the_session_is_shown_again_after_a_restart() {
    let (mut rig, dir, address) = start(Arc::new(DarkroomLab), "");
    let events = subscribe(address, "");
    rig::put(&rig.ingest(), &rig::aeb("Viewer Cam", 40, "RS"));
    let (record, _) = next_event(&events, "developed");
    rig.stop();
    let linear = record["outputs"]
        .as_array()
        .unwrap()
        .iter()
        .find(|o| o["look"] == "linear")
        .unwrap()["name"]
        .as_str()
        .unwrap()
        .to_string();
    let previews = rig.state().join(daemon::PREVIEW_FOLDER).join("RS-1");
    std::fs::remove_file(previews.join(format!("{linear}.preview.jpg"))).unwrap();
    let mut rig = Rig::start_with_text(dir.path(), &config(dir.path(), ""), Arc::new(DarkroomLab));
    let address = viewer_address(&rig.state());
    let brackets = session(address);
    assert_eq!(brackets.len(), 1, "{brackets:?}");
    assert_eq!(brackets[0]["stem"], "RS-1");
    assert_eq!(brackets[0]["total_ms"], record["total_ms"]);
    let thumb = brackets[0]["frames"][0]["thumb"].as_str().unwrap();
    assert_eq!(get(address, thumb).status, 200);
    let start = Instant::now();
    let preview = loop {
        let brackets = session(address);
        let output = brackets[0]["outputs"]
            .as_array()
            .unwrap()
            .iter()
            .find(|o| o["name"] == linear.as_str())
            .cloned()
            .unwrap();
        if let Some(url) = output["preview"].as_str() {
            break url.to_string();
        }
        assert!(
            start.elapsed() < PATIENCE,
            "the missing preview was not made"
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    let reply = get(address, &preview);
    assert_eq!(reply.status, 200);
    assert!(image::load_from_memory(&reply.body).is_ok());
    rig.stop();
}

/// `[viewer]` is checked as the other sections are: beyond loopback only with a token,
/// tokens long enough, one source of it; a token file's first line is the token, and the
/// configuration's debug form never shows it.
#[test]
fn viewer_settings_are_checked() {
    use filmback::daemon::config::Config;
    let check = |text: &str| Config::from_str(text, Some(Path::new("v.toml")));
    let error = |text: &str| check(text).unwrap_err().to_string();
    assert!(check("[viewer]\nport = 0\n").is_ok());
    let open = error("[viewer]\nbind = \"0.0.0.0\"\n");
    assert!(open.starts_with("v.toml:2:1: viewer.bind:"), "{open}");
    let short = error("[viewer]\nbind = \"0.0.0.0\"\ntoken = \"short\"\n");
    assert!(
        short.contains("viewer.token: a token needs at least 16"),
        "{short}"
    );
    let spaced = error("[viewer]\ntoken = \"has a space in it, sadly\"\n");
    assert!(spaced.contains("without spaces"), "{spaced}");
    assert!(error("[viewer]\nport = 70000\n").contains("0..=65535"));
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("token");
    std::fs::write(&file, format!("{TOKEN}\nignored\n")).unwrap();
    let both = format!(
        "token = \"{TOKEN}\"\ntoken_file = {:?}\n",
        file.display().to_string()
    );
    assert!(error(&format!("[viewer]\n{both}")).contains("not both"));
    let from_file = format!(
        "[viewer]\nbind = \"0.0.0.0\"\ntoken_file = {:?}\n",
        file.display().to_string()
    );
    let config = check(&from_file).unwrap();
    assert_eq!(
        config.viewer.token.as_ref().map(|t| t.expose()),
        Some(TOKEN)
    );
    assert!(
        !format!("{config:?}").contains(TOKEN),
        "the token leaked into Debug"
    );
    let missing = error("[viewer]\ntoken_file = \"/nonexistent/filmback-token\"\n");
    assert!(
        missing.starts_with("/nonexistent/filmback-token: cannot read"),
        "{missing}"
    );
}

/// A lab that publishes one small rendering per job and counts its jobs.
fn counting_lab(calls: Arc<AtomicUsize>) -> impl Fn(&Job) -> Result<Processed, JobError> {
    move |job: &Job| {
        calls.fetch_add(1, Ordering::SeqCst);
        let path = job.out.join(format!("{}.linear.jpg", job.stem));
        let mut bytes = Vec::new();
        image::RgbImage::from_pixel(32, 16, image::Rgb([200, 120, 40]))
            .write_to(
                &mut std::io::Cursor::new(&mut bytes),
                image::ImageFormat::Jpeg,
            )
            .unwrap();
        std::fs::write(&path, bytes).unwrap();
        Ok(Processed {
            outputs: vec![path],
            source: filmback::darkroom::Source::Standard,
            fit: None,
            pooling: None,
            contradicts_cache: false,
            stages: vec![("merge", Duration::from_millis(3))],
            notes: Vec::new(),
            measured: None,
            facts: Default::default(),
            pictures: None,
        })
    }
}

/// With a token configured every request needs it (header or query); files are found
/// only by the station's numbers; `redo` only by POST with its header, and then the
/// bracket is developed again.
#[test]
fn the_token_paths_and_redo_rules_hold() {
    let calls = Arc::new(AtomicUsize::new(0));
    let lab = counting_lab(Arc::clone(&calls));
    let (mut rig, _dir, address) = start(Arc::new(lab), &format!("token = \"{TOKEN}\""));
    let bearer = format!("Authorization: Bearer {TOKEN}");
    let auth = [bearer.as_str()];
    assert_eq!(get(address, "/").status, 401);
    assert_eq!(get(address, "/metrics").status, 401);
    assert_eq!(get(address, "/events").status, 401);
    let wrong = ["Authorization: Bearer test-token-0123456780"];
    assert_eq!(request(address, "GET", "/", &wrong).status, 401);
    assert_eq!(request(address, "GET", "/", &auth).status, 200);
    assert_eq!(get(address, &format!("/?token={TOKEN}")).status, 200);
    let events = subscribe(address, &format!("?token={TOKEN}"));
    next_event(&events, "status");
    rig::put(&rig.ingest(), &rig::aeb("Guard Cam", 50, "GD"));
    let (record, _) = next_event(&events, "developed");
    let id = record["id"].as_u64().unwrap();
    let file = record["outputs"][0]["file"].as_str().unwrap().to_string();
    assert_eq!(request(address, "GET", &file, &auth).status, 200);
    for path in [
        "/file/../../etc/passwd",
        "/file/%2e%2e/%2e%2e",
        "/file/%2e%2e%2f%2e%2e%2fetc%2fpasswd/0",
        "/file//etc/passwd",
        "/file/1/..",
        "/preview/-1/0",
        "/file/999/0",
        &format!("/file/{id}/7"),
        "/etc/passwd",
        "/..%2f..%2fetc%2fpasswd",
    ] {
        let reply = request(address, "GET", path, &auth);
        assert_eq!(reply.status, 404, "{path}");
    }
    let redo = format!("/redo/{id}");
    assert_eq!(request(address, "GET", &redo, &auth).status, 405);
    assert_eq!(
        request(address, "POST", &redo, &["X-Filmback: redo"]).status,
        401
    );
    assert_eq!(request(address, "POST", &redo, &auth).status, 403);
    let header = [bearer.as_str(), "X-Filmback: redo"];
    assert_eq!(request(address, "POST", "/redo/999", &header).status, 404);
    assert_eq!(request(address, "POST", &redo, &header).status, 202);
    let (again, _) = next_event(&events, "developed");
    assert_eq!(again["stem"], record["stem"]);
    assert_eq!(
        calls.load(Ordering::SeqCst),
        2,
        "redo develops the bracket again"
    );
    rig.stop();
}

/// `[hooks] on_developed` runs once per bracket with its outputs as arguments and its
/// stem in the environment.
#[test]
fn the_on_developed_hook_gets_the_outputs() {
    let calls = Arc::new(AtomicUsize::new(0));
    let said = tempfile::tempdir().unwrap();
    let file = said.path().join("hook.txt");
    let hook = format!(
        "[hooks]\non_developed = 'printf \"%s\\n\" \"$FILMBACK_STEM\" \"$@\" > {}'",
        file.display()
    );
    let (mut rig, _dir, _) = start(Arc::new(counting_lab(calls)), &hook);
    rig::put(&rig.ingest(), &rig::aeb("Hook Cam", 60, "HK"));
    let start = Instant::now();
    while !std::fs::read_to_string(&file).is_ok_and(|t| t.ends_with(".jpg\n")) {
        assert!(start.elapsed() < PATIENCE, "the hook never ran");
        std::thread::sleep(Duration::from_millis(20));
    }
    rig.stop();
    let text = std::fs::read_to_string(&file).unwrap();
    let out = rig.out().join("HK-1.linear.jpg");
    assert_eq!(text, format!("HK-1\n{}\n", out.display()));
}

/// A headless Chromium on a page, driven over the DevTools protocol; killed when
/// dropped.
struct Browser {
    child: Child,
    socket: tungstenite::WebSocket<TcpStream>,
    next_id: u64,
    _profile: tempfile::TempDir,
}

impl Browser {
    fn open(binary: &Path, url: &str) -> Browser {
        let profile = tempfile::tempdir().unwrap();
        let mut child = Command::new(binary)
            .args([
                "--headless",
                "--no-sandbox",
                "--disable-gpu",
                "--disable-quic",
                "--no-first-run",
                "--disable-background-networking",
                "--disable-component-update",
                "--disable-sync",
                "--hide-scrollbars",
                "--window-size=1280,800",
                "--remote-debugging-port=0",
            ])
            .arg(format!("--user-data-dir={}", profile.path().display()))
            .arg(url)
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let stderr = BufReader::new(child.stderr.take().unwrap());
        let mut lines = stderr.lines();
        let port: u16 = loop {
            let line = lines
                .next()
                .expect("chromium printed its DevTools address")
                .unwrap();
            if let Some(rest) = line.split("ws://127.0.0.1:").nth(1) {
                break rest.split('/').next().unwrap().parse().unwrap();
            }
        };
        // Chromium keeps writing to stderr; drain it so it never blocks.
        std::thread::spawn(move || lines.for_each(drop));
        let devtools: SocketAddr = ([127, 0, 0, 1], port).into();
        let list = devtools_targets(devtools);
        let page = list
            .as_array()
            .unwrap()
            .iter()
            .find(|t| t["type"] == "page")
            .expect("a page target");
        let ws = page["webSocketDebuggerUrl"].as_str().unwrap();
        let stream = TcpStream::connect(devtools).unwrap();
        let (socket, _) = tungstenite::client(ws, stream).unwrap();
        let mut browser = Browser {
            child,
            socket,
            next_id: 0,
            _profile: profile,
        };
        // The page's own size, whatever the headless window keeps for itself.
        browser.call(
            "Emulation.setDeviceMetricsOverride",
            serde_json::json!({ "width": 1280, "height": 800, "deviceScaleFactor": 1, "mobile": false }),
        );
        browser
    }

    /// Calls a DevTools method and returns its result.
    fn call(&mut self, method: &str, params: serde_json::Value) -> serde_json::Value {
        self.next_id += 1;
        let id = self.next_id;
        let message = serde_json::json!({ "id": id, "method": method, "params": params });
        self.socket
            .send(tungstenite::Message::text(message.to_string()))
            .unwrap();
        loop {
            let reply = self.socket.read().unwrap();
            let Ok(text) = reply.to_text() else { continue };
            let value: serde_json::Value = serde_json::from_str(text).unwrap();
            if value["id"] == id {
                return value["result"].clone();
            }
        }
    }

    /// Evaluates `expression` in the page and returns its value.
    fn eval(&mut self, expression: &str) -> serde_json::Value {
        let r = self.call(
            "Runtime.evaluate",
            serde_json::json!({ "expression": expression, "returnByValue": true }),
        );
        r["result"]["value"].clone()
    }

    /// Waits until `expression` is true in the page.
    fn wait(&mut self, expression: &str) {
        let start = Instant::now();
        while self.eval(expression) != serde_json::Value::Bool(true) {
            assert!(
                start.elapsed() < PATIENCE,
                "the page never had {expression}"
            );
            std::thread::sleep(Duration::from_millis(50));
        }
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The DevTools targets (`GET /json/list`: HTTP/1.1, the reply's length from its
/// `Content-Length`, as this server keeps the connection open).
fn devtools_targets(devtools: SocketAddr) -> serde_json::Value {
    let mut stream = TcpStream::connect(devtools).unwrap();
    stream.set_read_timeout(Some(PATIENCE)).unwrap();
    write!(
        stream,
        "GET /json/list HTTP/1.1\r\nHost: {devtools}\r\n\r\n"
    )
    .unwrap();
    let mut reader = BufReader::new(stream);
    let mut length = 0;
    loop {
        let mut line = String::new();
        reader.read_line(&mut line).unwrap();
        let line = line.trim_end();
        if line.is_empty() {
            break;
        }
        if let Some((name, value)) = line.split_once(':')
            && name.eq_ignore_ascii_case("content-length")
        {
            length = value.trim().parse().unwrap();
        }
    }
    let mut body = vec![0; length];
    reader.read_exact(&mut body).unwrap();
    serde_json::from_slice(&body).unwrap()
}

/// Decodes standard base64 (the DevTools screenshot).
fn base64(text: &str) -> Vec<u8> {
    let value = |c: u8| match c {
        b'A'..=b'Z' => c - b'A',
        b'a'..=b'z' => c - b'a' + 26,
        b'0'..=b'9' => c - b'0' + 52,
        b'+' => 62,
        _ => 63,
    };
    let clean: Vec<u8> = text.bytes().filter(|c| *c != b'=').map(value).collect();
    clean
        .chunks(4)
        .flat_map(|q| {
            let n = q
                .iter()
                .enumerate()
                .fold(0u32, |n, (i, v)| n | u32::from(*v) << (18 - 6 * i));
            let bytes = [(n >> 16) as u8, (n >> 8) as u8, n as u8];
            bytes.into_iter().take(q.len() - 1)
        })
        .collect()
}

/// The page, open in a real browser before the bracket exists, shows it once developed:
/// its name, its rendering (pixels that are not the page's background) — without a
/// reload. `FILMBACK_VIEWER_SCREENSHOT=FILE` keeps the screenshot.
#[test]
fn the_page_in_chromium_shows_a_new_bracket_without_reload() {
    let Some(binary) = crate::common::chromium() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let text = rig::config_text(dir.path(), "[viewer]\nport = 0\n")
        .replace("films = []", "films = [\"velvia50\"]");
    let mut rig = Rig::start_with_text(dir.path(), &text, Arc::new(DarkroomLab));
    let address = viewer_address(&rig.state());
    let mut browser = Browser::open(&binary, &format!("http://{address}/"));
    browser.wait("document.getElementById('live').className === 'live up'");
    browser.eval("window.loadedOnce = 'yes'");
    let shots = filmback::synthetic::demo::aeb("Studio Cam", None, 70);
    let frames = filmback::synthetic::demo::jpegs(480, 320, &shots, 7).unwrap();
    let named: Vec<(String, Vec<u8>)> = frames
        .into_iter()
        .enumerate()
        .map(|(i, b)| (format!("STUDIO-{}.jpg", i + 1), b))
        .collect();
    rig::put(&rig.ingest(), &named);
    browser.wait("document.getElementById('latest-stem').textContent === 'STUDIO-1'");
    browser.wait("(() => { const i = document.getElementById('shot'); return !i.hidden && i.complete && i.naturalWidth === 480; })()");
    assert_eq!(
        browser.eval("window.loadedOnce"),
        "yes",
        "the page was reloaded"
    );
    let looks = browser
        .eval("[...document.querySelectorAll('#looks button')].map(b => b.textContent).join(',')");
    let looks = looks.as_str().unwrap();
    assert!(
        looks.contains("velvia50") && looks.contains("linear"),
        "{looks}"
    );
    let chosen = browser.eval("document.querySelector('#looks button.on').textContent");
    assert!(
        chosen.as_str().unwrap().contains("velvia50"),
        "a film is shown first: {chosen}"
    );
    // Keys switch looks: the next one is the tone map, and the picture follows.
    browser.call(
        "Input.dispatchKeyEvent",
        serde_json::json!({ "type": "keyDown", "key": "ArrowRight", "code": "ArrowRight", "windowsVirtualKeyCode": 39 }),
    );
    browser.wait("document.querySelector('#looks button.on').textContent.includes('linear') && document.getElementById('shot').alt.includes('linear')");
    browser.call(
        "Input.dispatchKeyEvent",
        serde_json::json!({ "type": "keyDown", "key": "ArrowLeft", "code": "ArrowLeft", "windowsVirtualKeyCode": 37 }),
    );
    browser.wait("(() => { const i = document.getElementById('shot'); return i.alt.includes('velvia50') && i.complete && i.naturalWidth === 480; })()");
    // C overlays what no frame exposed well, and hides it again.
    let key_c = serde_json::json!({ "type": "keyDown", "key": "c", "code": "KeyC", "windowsVirtualKeyCode": 67 });
    browser.wait("(() => { const m = document.getElementById('clipmap'); return m.hidden && !!m.getAttribute('src'); })()");
    browser.call("Input.dispatchKeyEvent", key_c.clone());
    browser.wait("(() => { const m = document.getElementById('clipmap'); return !m.hidden && m.complete && m.naturalWidth > 0 && m.getBoundingClientRect().width > 400; })()");
    browser.call("Input.dispatchKeyEvent", key_c);
    browser.wait("document.getElementById('clipmap').hidden");
    // The other views: the body's curve drawn from the cache, the daemon's counts.
    browser.eval("document.querySelector('nav button[data-view=cameras]').click()");
    browser.wait("document.querySelectorAll('#cameras canvas').length === 1 && document.getElementById('cameras').textContent.includes('Studio Cam')");
    browser.eval("document.querySelector('nav button[data-view=service]').click()");
    browser.wait("document.getElementById('service').textContent.includes('STUDIO-1')");
    browser.eval("document.querySelector('nav button[data-view=latest]').click()");
    let shot = browser.call(
        "Page.captureScreenshot",
        serde_json::json!({ "format": "png" }),
    );
    let png = base64(shot["data"].as_str().unwrap());
    let picture = image::load_from_memory(&png).unwrap().to_rgb8();
    assert_eq!(picture.dimensions(), (1280, 800));
    // The rendering fills the stage's middle: not the page's black or panel grey.
    let centre = picture.get_pixel(480, 400);
    let lit = picture
        .enumerate_pixels()
        .filter(|(x, y, p)| *x < 960 && *y > 40 && p.0.iter().any(|c| *c > 40))
        .count();
    assert!(
        lit > 100_000,
        "only {lit} lit pixels in the stage (centre {centre:?})"
    );
    if let Some(keep) = std::env::var_os("FILMBACK_VIEWER_SCREENSHOT") {
        // Kept for the docs: 1024×640, PNG at its best compression (small enough for a
        // repository; Chromium's own PNG is fast, not small).
        use image::codecs::png::{CompressionType, FilterType, PngEncoder};
        let file = std::fs::File::create(keep).unwrap();
        let png = PngEncoder::new_with_quality(file, CompressionType::Best, FilterType::Adaptive);
        let small =
            image::imageops::resize(&picture, 1024, 640, image::imageops::FilterType::Triangle);
        small.write_with_encoder(png).unwrap();
    }
    // A moving subject: G overlays where deghosting left frames out, and hides it again.
    rig::put(
        &rig.ingest(),
        &rig::aeb_with_subject("Studio Cam", 90, "MOVE"),
    );
    browser.wait("document.getElementById('latest-stem').textContent === 'MOVE-1'");
    browser.wait("(() => { const m = document.getElementById('leftoutmap'); return m.hidden && !!m.getAttribute('src') && document.getElementById('ghostwarn').style.display === 'block'; })()");
    // Its warning stands under the clipping warning, and at the stage's top without it.
    browser.wait("(() => { const c = document.getElementById('clipwarn').getBoundingClientRect(), g = document.getElementById('ghostwarn').getBoundingClientRect(); return c.height > 0 && g.top >= c.bottom; })()");
    browser.eval("document.getElementById('clipwarn').style.display = 'none'");
    browser.wait("document.getElementById('ghostwarn').getBoundingClientRect().top - document.getElementById('stage').getBoundingClientRect().top < 15");
    browser.eval("renderLatest()");
    let key_g = serde_json::json!({ "type": "keyDown", "key": "g", "code": "KeyG", "windowsVirtualKeyCode": 71 });
    browser.call("Input.dispatchKeyEvent", key_g.clone());
    browser.wait("(() => { const m = document.getElementById('leftoutmap'); return !m.hidden && m.complete && m.naturalWidth === 96 && document.getElementById('ghostwarn').textContent.includes('G hides'); })()");
    browser.call("Input.dispatchKeyEvent", key_g);
    browser.wait("document.getElementById('leftoutmap').hidden");
    drop(browser);
    rig.stop();
}
