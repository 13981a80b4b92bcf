//! `/metrics`: the daemon's counters, gauges and stage histograms in the OpenMetrics
//! text format (which Prometheus scrapes), through `prometheus-client`.

use prometheus_client::encoding::text::encode;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::metrics::histogram::{Histogram, exponential_buckets};
use prometheus_client::registry::Registry;

use super::Record;
use crate::daemon::Snapshot;

/// A metric's labels: `(name, value)` pairs.
type Labels = Vec<(String, String)>;

/// Buckets of a stage's duration, seconds: 5 ms doubling to about 82 s (15 buckets).
fn stage_histogram() -> Histogram {
    Histogram::new(exponential_buckets(0.005, 2.0, 15))
}

/// Everything `/metrics` shows (names and meanings in docs/service.md, "Metrics").
#[derive(Debug)]
pub(crate) struct Metrics {
    registry: Registry,
    developed: Family<Labels, Counter>,
    /// Files rejected.
    pub rejected: Counter,
    /// Retries scheduled (outputs not written, files not readable, frames missing).
    pub retries: Counter,
    stages: Family<Labels, Histogram, fn() -> Histogram>,
    total: Histogram,
    responses: Family<Labels, Counter>,
    queued: Gauge,
    in_flight: Gauge,
    memory_in_use: Gauge,
    memory_budget: Gauge,
    /// Clients connected to `/events`.
    pub subscribers: Gauge,
    /// Events dropped for clients that could not keep up.
    pub lagged: Counter,
}

impl Metrics {
    /// Registers every metric under the `filmback_` prefix.
    pub(crate) fn new() -> Metrics {
        let mut registry = Registry::with_prefix("filmback");
        let m = Metrics {
            developed: Family::default(),
            rejected: Counter::default(),
            retries: Counter::default(),
            stages: Family::new_with_constructor(stage_histogram),
            total: stage_histogram(),
            responses: Family::default(),
            queued: Gauge::default(),
            in_flight: Gauge::default(),
            memory_in_use: Gauge::default(),
            memory_budget: Gauge::default(),
            subscribers: Gauge::default(),
            lagged: Counter::default(),
            registry: Registry::default(),
        };
        m.register(&mut registry);
        Metrics { registry, ..m }
    }

    /// Registers every metric in `r` under its name and help text.
    fn register(&self, r: &mut Registry) {
        r.register(
            "developed",
            "Brackets and single frames developed, by kind",
            self.developed.clone(),
        );
        r.register(
            "rejected",
            "Files set aside as rejected",
            self.rejected.clone(),
        );
        r.register(
            "retries",
            "Retries scheduled (outputs not written, files unreadable, frames missing)",
            self.retries.clone(),
        );
        r.register(
            "stage_seconds",
            "Wall time of each stage of a development, seconds",
            self.stages.clone(),
        );
        r.register(
            "develop_seconds",
            "Wall time of a whole development, seconds",
            self.total.clone(),
        );
        r.register("responses", "Developments by the origin of the response used (fitted, pooled, cached, standard, raw)", self.responses.clone());
        r.register(
            "queue_depth",
            "Closed brackets waiting for a job",
            self.queued.clone(),
        );
        r.register(
            "in_flight",
            "Brackets developing now",
            self.in_flight.clone(),
        );
        r.register(
            "memory_in_use_bytes",
            "Memory budget held by the brackets developing, bytes",
            self.memory_in_use.clone(),
        );
        r.register(
            "memory_budget_bytes",
            "The memory budget ([daemon] memory_mb), bytes",
            self.memory_budget.clone(),
        );
        r.register(
            "viewer_clients",
            "Clients connected to the event stream",
            self.subscribers.clone(),
        );
        r.register(
            "viewer_events_dropped",
            "Events a slow client missed",
            self.lagged.clone(),
        );
    }

    /// Counts a development: its kind, the response's origin and its stages' times.
    pub(crate) fn developed(&self, record: &Record) {
        let label = |k: &str, v: &str| vec![(k.to_string(), v.to_string())];
        self.developed
            .get_or_create(&label("kind", record.kind.name()))
            .inc();
        self.responses
            .get_or_create(&label("source", &record.response))
            .inc();
        for (stage, ms) in &record.stages {
            self.stages
                .get_or_create(&label("stage", stage))
                .observe(ms / 1e3);
        }
        self.total.observe(record.total_ms / 1e3);
    }

    /// Takes the gauges from a status snapshot and the memory budget's use, bytes.
    pub(crate) fn status(&self, snapshot: &Snapshot, in_use: u64, budget: u64) {
        let int = |n: u64| i64::try_from(n).unwrap_or(i64::MAX);
        self.queued.set(int(snapshot.queued as u64));
        self.in_flight.set(int(snapshot.in_flight as u64));
        self.memory_in_use.set(int(in_use));
        self.memory_budget.set(int(budget));
    }

    /// The text exposition of every metric.
    pub(crate) fn render(&self) -> Result<String, std::fmt::Error> {
        let mut text = String::new();
        encode(&mut text, &self.registry)?;
        Ok(text)
    }
}
