//! The tether station: a page that shows each bracket as it is developed, the event
//! stream other software follows, and Prometheus metrics, served over HTTP beside the
//! darkroom.
//!
//! ```text
//! daemon loop ──developed/rejected/retry/status──► Station (never blocks)
//!                                                    │ developed: previews worker (blocking thread)
//!                                                    ▼
//!                         gallery (recent brackets) + broadcast ──► SSE clients (/events)
//!                                                    ▲
//!                               HTTP (axum on hyper) ┘ page, previews, files, /metrics, redo
//! ```
//!
//! The daemon only hands records to a [`Station`]: an unbounded channel to the previews
//! worker (a few records a minute) and a bounded broadcast channel to the clients, where
//! one that cannot keep up loses events (it is told how many) instead of holding anything
//! up. Previews are made once, after a bracket is published: a downscaled JPEG and a
//! thumbnail per rendering and a thumbnail per frame, in `state/previews/<stem>/`,
//! written atomically. Files are served by the numbers of the station's own list, never
//! by a path from a request.

mod events;
mod listener;
mod metrics;
mod previews;
mod restore;
mod routes;

use std::collections::VecDeque;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};

use serde::{Deserialize, Serialize};
use tokio::sync::{broadcast, mpsc};
use tracing::{info, warn};

use super::Snapshot;
use super::config::{Token, Viewer};
pub(crate) use events::Event;
use metrics::Metrics;
pub(crate) use previews::{PREVIEW_EDGE, THUMB_EDGE};

/// Folder in the state folder holding the previews, one sub-folder per output stem.
pub const PREVIEW_FOLDER: &str = "previews";

/// Brackets the station remembers (the Session view, files served).
const GALLERY: usize = 200;

/// Rejected files the station remembers (the Service view).
const REJECTS: usize = 50;

/// Events buffered per client before a slow one starts losing them.
const EVENT_BUFFER: usize = 64;

/// Why the viewer cannot be served (the daemon goes on without it).
#[derive(Debug, thiserror::Error)]
pub(crate) enum ViewerError {
    /// The configured address cannot be listened on (in use, not this machine's).
    #[error("cannot listen on {address}: {source}")]
    Bind {
        /// The address.
        address: SocketAddr,
        /// What the operating system said.
        source: std::io::Error,
    },
    /// The socket systemd passed (`LISTEN_FDS`) is not a usable TCP listener.
    #[error("the socket passed by systemd (LISTEN_FDS) cannot be used: {source}")]
    Activation {
        /// What went wrong.
        source: std::io::Error,
    },
    /// The socket systemd passed listens beyond loopback and `[viewer]` has no token.
    #[error(
        "the socket passed by systemd listens on {address}, not a loopback address: set [viewer] token or token_file"
    )]
    Exposed {
        /// Where the passed socket listens.
        address: SocketAddr,
    },
}

/// One frame of a developed bracket as the page shows it.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FrameRecord {
    /// File name in the ingest folder.
    pub name: String,
    /// Exposure in stops relative to the darkest frame (`log2(e/e_min)`), when known.
    pub stops: Option<f64>,
    /// URL of its thumbnail, when one could be made (not for camera raws).
    pub thumb: Option<String>,
}

/// One published output as the page shows it.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(crate) struct OutputRecord {
    /// File name in the output folder.
    pub name: String,
    /// The look (`velvia50-t0`, `linear`, …) of a rendering; `None` for the EXR.
    pub look: Option<String>,
    /// True for a film stock's rendering (false for a tone map's and the EXR).
    pub film: bool,
    /// URL of the full-size file.
    pub file: String,
    /// URL of the downscaled preview (long edge [`previews::PREVIEW_EDGE`] px), when made.
    pub preview: Option<String>,
    /// URL of the thumbnail (long edge [`previews::THUMB_EDGE`] px), when made.
    pub thumb: Option<String>,
}

/// A developed bracket or single frame: the `developed` event and an entry of the
/// Session view.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub(crate) struct Record {
    /// The station's number for it (increasing; files are served by it).
    pub id: u64,
    /// Output stem.
    pub stem: String,
    /// The body.
    pub camera: String,
    /// A bracket or a single frame.
    pub kind: Kind,
    /// Unix seconds when it was published.
    pub at: u64,
    /// Its frames in capture order.
    pub frames: Vec<FrameRecord>,
    /// Its outputs in publishing order.
    pub outputs: Vec<OutputRecord>,
    /// The looks rendered, in order.
    pub looks: Vec<String>,
    /// Where the response came from (`fitted`, `pooled`, `cached`, `standard`, `raw`).
    pub response: String,
    /// The bracket's own fit's confidence in `(0, 1]`, when a fit was made.
    pub confidence: Option<f64>,
    /// What the development measured (clipped share, alignment, deghosting).
    pub facts: super::Facts,
    /// URL of the overlay (a PNG at most [`crate::darkroom::CLIP_MAP_EDGE`] px, the
    /// preview's shape) marking what no frame exposed well, when some part was not.
    #[serde(default)]
    pub clipped: Option<String>,
    /// URL of the overlay (the same size) marking where deghosting left frames out, when
    /// it did.
    #[serde(default)]
    pub left_out: Option<String>,
    /// Wall time per stage, milliseconds, in order.
    pub stages: Vec<(String, f64)>,
    /// Wall time of the whole development, milliseconds.
    pub total_ms: f64,
    /// Warnings of the development.
    pub notes: Vec<String>,
    /// Where its files are (never serialised: the page names files by number).
    #[serde(skip)]
    pub(crate) files: Files,
}

/// What a record developed: `bracket` or `single` in JSON and in the metrics' labels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub(crate) enum Kind {
    /// Two or more frames merged.
    Bracket,
    /// One frame rendered alone.
    Single,
}

impl Kind {
    /// The name the JSON and the metrics use.
    pub(crate) fn name(self) -> &'static str {
        match self {
            Kind::Bracket => "bracket",
            Kind::Single => "single",
        }
    }
}

/// The files of a record, by the numbers its URLs carry.
#[derive(Debug, Clone, Default)]
pub(crate) struct Files {
    /// The outputs, in the order of [`Record::outputs`].
    pub outputs: Vec<PathBuf>,
    /// Per output, its preview and thumbnail when made.
    pub previews: Vec<Option<(PathBuf, PathBuf)>>,
    /// Per frame, its thumbnail when made.
    pub frames: Vec<Option<PathBuf>>,
    /// The overlay of what no frame exposed well, when made.
    pub clipped: Option<PathBuf>,
    /// The overlay of where deghosting left frames out, when made.
    pub left_out: Option<PathBuf>,
}

/// A development handed to the station, before its previews exist.
#[derive(Debug)]
pub(crate) struct Published {
    /// The record, its URLs not yet filled in.
    pub record: Record,
    /// The frames' files where they are now (archived or in ingest).
    pub frame_paths: Vec<PathBuf>,
    /// The lab's small copies of the renderings and frames, when it made them (the
    /// previews are otherwise made from the files).
    pub pictures: Option<Arc<super::Pictures>>,
}

/// A rejected file as the Service view lists it.
#[derive(Debug, Clone, Serialize)]
pub(crate) struct Rejection {
    /// The file.
    pub path: String,
    /// Why.
    pub reason: String,
    /// Unix seconds.
    pub at: u64,
}

/// What the station remembers between events.
#[derive(Debug, Default)]
struct Gallery {
    records: VecDeque<Arc<Record>>,
    rejected: VecDeque<Rejection>,
    status: Option<Snapshot>,
    next_id: u64,
}

impl Gallery {
    /// Files a new record first, forgetting the oldest beyond [`GALLERY`].
    fn file(&mut self, record: Arc<Record>) {
        self.records.push_front(record);
        self.records.truncate(GALLERY);
    }

    /// Puts `record` in place of the one of its number, if that is still remembered.
    fn replace(&mut self, record: Arc<Record>) {
        if let Some(slot) = self.records.iter_mut().find(|r| r.id == record.id) {
            *slot = record;
        }
    }
}

/// What the server's handlers and the daemon's handle share.
#[derive(Debug)]
pub(crate) struct Shared {
    gallery: Mutex<Gallery>,
    events: broadcast::Sender<Arc<Event>>,
    metrics: Metrics,
    token: Option<Token>,
    state: PathBuf,
}

impl Shared {
    fn gallery(&self) -> MutexGuard<'_, Gallery> {
        // A panic while holding the lock cannot leave the gallery inconsistent (every
        // change is one push or pop), so a poisoned lock is used as it is.
        self.gallery
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Sends `event` to every client; none listening is not an error.
    fn broadcast(&self, event: Event) {
        let _ = self.events.send(Arc::new(event));
    }

    /// The record numbered `id`, if the station still remembers it.
    fn record(&self, id: u64) -> Option<Arc<Record>> {
        self.gallery()
            .records
            .iter()
            .find(|r| r.id == id)
            .map(Arc::clone)
    }
}

/// The daemon's handle on the viewer: every call returns at once.
#[derive(Debug, Clone)]
pub(crate) struct Station {
    shared: Arc<Shared>,
    developed: mpsc::UnboundedSender<Published>,
    /// Where clients reach it.
    pub address: SocketAddr,
}

impl Station {
    /// Listens as `config` says (or on the socket systemd passed), starts the server and
    /// the previews worker on the current runtime. `state` is the daemon's state folder;
    /// the recent developments of `journal` are shown again (previews still missing are
    /// made by the worker when it has nothing newer to do).
    pub(crate) async fn open(
        config: &Viewer,
        state: &Path,
        journal: &[super::journal::Entry],
    ) -> Result<Station, ViewerError> {
        let listener = listener::listen(config).await?;
        let address = listener.local_addr().map_err(|source| ViewerError::Bind {
            address: config.address,
            source,
        })?;
        if !address.ip().is_loopback() && config.token.is_none() {
            return Err(ViewerError::Exposed { address });
        }
        let (events, _) = broadcast::channel(EVENT_BUFFER);
        let (gallery, unfinished) = restore::gallery(journal, &state.join(PREVIEW_FOLDER)).await;
        let shared = Arc::new(Shared {
            gallery: Mutex::new(gallery),
            events,
            metrics: Metrics::new(),
            token: config.token.clone(),
            state: state.to_path_buf(),
        });
        let (developed, rx) = mpsc::unbounded_channel();
        tokio::spawn(previews::worker(Arc::clone(&shared), rx, unfinished));
        tokio::spawn(listener::serve(
            listener,
            routes::router(Arc::clone(&shared)),
        ));
        info!(url = %format!("http://{address}/"), "viewer serving");
        Ok(Station {
            shared,
            developed,
            address,
        })
    }

    /// A bracket or single was published: its previews are made, then it is announced.
    pub(crate) fn developed(&self, mut published: Published) {
        {
            let mut g = self.shared.gallery();
            g.next_id += 1;
            published.record.id = g.next_id;
        }
        self.shared.metrics.developed(&published.record);
        if self.developed.send(published).is_err() {
            warn!("the viewer's previews worker has stopped; the bracket is not shown");
        }
    }

    /// A file was rejected.
    pub(crate) fn rejected(&self, path: &Path, reason: &str) {
        let rejection = Rejection {
            path: path.display().to_string(),
            reason: reason.to_string(),
            at: super::journal::unix_now(),
        };
        self.shared.metrics.rejected.inc();
        {
            let mut g = self.shared.gallery();
            g.rejected.push_front(rejection.clone());
            g.rejected.truncate(REJECTS);
        }
        self.shared.broadcast(Event::Rejected(rejection));
    }

    /// Something will be tried again.
    pub(crate) fn retry(&self, retry: super::Retry) {
        self.shared.metrics.retries.inc();
        self.shared.broadcast(Event::Retry(retry));
    }

    /// The daemon's status changed (`in_use` bytes of the memory budget held).
    pub(crate) fn status(&self, snapshot: &Snapshot, in_use: u64, budget: u64) {
        self.shared.metrics.status(snapshot, in_use, budget);
        self.shared.gallery().status = Some(snapshot.clone());
        self.shared
            .broadcast(Event::Status(Box::new(snapshot.clone())));
    }
}

/// The look of an output named `<stem>.<look>.jpg` (`None` for other names and the EXR).
fn look_of(stem: &str, name: &str) -> Option<String> {
    let rest = name.strip_prefix(stem)?.strip_prefix('.')?;
    let look = rest
        .strip_suffix(".jpg")
        .or_else(|| rest.strip_suffix(".jpeg"))
        .or_else(|| rest.strip_suffix(".png"))
        .or_else(|| rest.strip_suffix(".tif"))?;
    (!look.is_empty()).then(|| look.to_string())
}

/// The record of a development, before the station numbers it and its previews exist.
pub(crate) fn record_of(
    closed: &super::bracket::Closed,
    dev: &super::Processed,
    stem: &str,
    took: std::time::Duration,
) -> Record {
    let outputs = output_records(stem, &dev.outputs);
    Record {
        id: 0,
        stem: stem.to_string(),
        camera: closed.camera().to_string(),
        kind: match closed {
            super::bracket::Closed::Bracket(_) => Kind::Bracket,
            super::bracket::Closed::Single(..) => Kind::Single,
        },
        at: super::journal::unix_now(),
        frames: frame_records(closed),
        looks: outputs.iter().filter_map(|o| o.look.clone()).collect(),
        outputs,
        response: dev.source.to_string(),
        confidence: dev.fit.as_ref().map(|(_, c)| *c),
        facts: dev.facts.clone(),
        clipped: None,
        left_out: None,
        stages: dev
            .stages
            .iter()
            .map(|(s, d)| ((*s).to_string(), d.as_secs_f64() * 1e3))
            .collect(),
        total_ms: took.as_secs_f64() * 1e3,
        notes: dev.notes.clone(),
        files: Files {
            outputs: dev.outputs.clone(),
            ..Files::default()
        },
    }
}

/// Serialises a shared record as the record itself.
fn shared_record<S: serde::Serializer>(record: &Arc<Record>, s: S) -> Result<S::Ok, S::Error> {
    record.as_ref().serialize(s)
}

/// Serialises shared records as a sequence of the records themselves.
fn shared_records<S: serde::Serializer>(records: &[Arc<Record>], s: S) -> Result<S::Ok, S::Error> {
    s.collect_seq(records.iter().map(AsRef::as_ref))
}

/// The frames of `closed` with their exposures above the darkest, in stops.
fn frame_records(closed: &super::bracket::Closed) -> Vec<FrameRecord> {
    let frames = closed.frames();
    let darkest = frames
        .iter()
        .filter_map(|c| c.exposure)
        .filter(|e| *e > 0.0)
        .fold(f64::INFINITY, f64::min);
    frames
        .iter()
        .map(|c| FrameRecord {
            name: file_name(&c.input.path),
            stops: c
                .exposure
                .filter(|e| *e > 0.0 && darkest.is_finite())
                .map(|e| (e / darkest).log2()),
            thumb: None,
        })
        .collect()
}

/// The outputs named with their looks (URLs are filled in with the previews).
fn output_records(stem: &str, outputs: &[PathBuf]) -> Vec<OutputRecord> {
    outputs
        .iter()
        .map(|p| {
            let name = file_name(p);
            let look = look_of(stem, &name);
            OutputRecord {
                film: look
                    .as_deref()
                    .is_some_and(|l| crate::tonemap::Operator::parse(l).is_none()),
                look,
                name,
                file: String::new(),
                preview: None,
                thumb: None,
            }
        })
        .collect()
}

fn file_name(path: &Path) -> String {
    path.file_name().map_or_else(
        || path.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn looks_come_from_rendering_names_only() {
        assert_eq!(
            look_of("IMG_1", "IMG_1.velvia50-t0.jpg").as_deref(),
            Some("velvia50-t0")
        );
        assert_eq!(
            look_of("IMG_1", "IMG_1.linear.jpg").as_deref(),
            Some("linear")
        );
        assert_eq!(look_of("IMG_1", "IMG_1.exr"), None);
        assert_eq!(look_of("IMG_1", "IMG_12.linear.jpg"), None);
        assert_eq!(look_of("IMG_1", "IMG_1..jpg"), None);
    }
}
