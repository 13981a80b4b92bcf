//! The event stream at `/events`: Server-Sent Events, one JSON object per event, its
//! kind in the SSE `event:` field (docs/service.md, "Events", lists every field).

use std::convert::Infallible;
use std::sync::Arc;
use std::time::Duration;

use axum::response::sse::{self, KeepAlive, Sse};
use futures_util::stream::{self, Stream};
use serde::Serialize;
use tokio::sync::broadcast::error::RecvError;

use super::{Record, Rejection, Shared};
use crate::daemon::{Retry, Snapshot};

/// How often an idle stream sends a comment, so proxies keep it open and a client that
/// went away is noticed.
const KEEP_ALIVE: Duration = Duration::from_secs(15);

/// One event of the stream.
#[derive(Debug, Clone, Serialize)]
#[serde(untagged)]
pub(crate) enum Event {
    /// A bracket or single frame was developed and its previews made.
    Developed(#[serde(serialize_with = "super::shared_record")] Arc<Record>),
    /// A file was set aside as rejected.
    Rejected(Rejection),
    /// A bracket or file will be tried again.
    Retry(Retry),
    /// The daemon's counts changed (the `filmback status` snapshot).
    Status(Box<Snapshot>),
    /// This client was too slow and missed events (the page then reloads the list).
    Lagged {
        /// How many events it missed.
        missed: u64,
    },
}

impl Event {
    /// The SSE `event:` name.
    fn kind(&self) -> &'static str {
        match self {
            Event::Developed(_) => "developed",
            Event::Rejected(_) => "rejected",
            Event::Retry(_) => "retry",
            Event::Status(_) => "status",
            Event::Lagged { .. } => "lagged",
        }
    }

    /// The event as SSE (`event:` kind, `data:` JSON).
    fn to_sse(&self) -> sse::Event {
        let data = serde_json::to_string(self).unwrap_or_else(|e| {
            serde_json::json!({ "error": format!("event not serialisable: {e}") }).to_string()
        });
        sse::Event::default().event(self.kind()).data(data)
    }
}

/// The response of `/events`: the current status first, then every event as it
/// happens. A client that falls more than the buffer behind gets a `lagged` event in
/// place of those it missed; the daemon never waits for it.
pub(crate) fn stream(
    shared: Arc<Shared>,
) -> Sse<impl Stream<Item = Result<sse::Event, Infallible>>> {
    let rx = shared.events.subscribe();
    let first = shared
        .gallery()
        .status
        .clone()
        .map(|s| Event::Status(Box::new(s)));
    let subscriber = Subscriber::new(shared);
    let head = stream::iter(first.map(|e| Ok(e.to_sse())));
    let tail = stream::unfold((rx, subscriber), |(mut rx, subscriber)| async move {
        let event = match rx.recv().await {
            Ok(event) => event.to_sse(),
            Err(RecvError::Lagged(missed)) => {
                subscriber.shared.metrics.lagged.inc_by(missed);
                Event::Lagged { missed }.to_sse()
            }
            Err(RecvError::Closed) => return None,
        };
        Some((Ok(event), (rx, subscriber)))
    });
    Sse::new(futures_util::StreamExt::chain(head, tail))
        .keep_alive(KeepAlive::new().interval(KEEP_ALIVE))
}

/// Counts a connected client in the metrics for as long as its stream lives.
struct Subscriber {
    shared: Arc<Shared>,
}

impl Subscriber {
    fn new(shared: Arc<Shared>) -> Subscriber {
        shared.metrics.subscribers.inc();
        Subscriber { shared }
    }
}

impl Drop for Subscriber {
    fn drop(&mut self) {
        self.shared.metrics.subscribers.dec();
    }
}
