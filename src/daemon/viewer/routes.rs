//! The viewer's routes. Every request passes [`guard`] (token, host); files are found
//! by the numbers of the station's own list, so no part of a request ever becomes a
//! path (an unknown number, `..` or an absolute path is simply not found).

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use axum::Router;
use axum::body::Body;
use axum::error_handling::HandleErrorLayer;
use axum::extract::{DefaultBodyLimit, Path as UrlPath, Query, Request, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::middleware::{self, Next};
use axum::response::{Html, IntoResponse, Json, Response};
use axum::routing::{get, post};
use serde::Serialize;
use tokio::io::AsyncReadExt;
use tower::ServiceBuilder;

use super::{Record, Rejection, Shared, events};
use crate::atomic::{self, Overwrite};
use crate::daemon::cache::{CachedResponse, ResponseCache};
use crate::daemon::{REDO_FOLDER, Snapshot};

/// The page: one HTML file with its script and style, embedded in the binary.
const PAGE: &str = include_str!("page.html");

/// Time to answer a request (the event stream aside, which lasts).
const REQUEST_TIMEOUT: Duration = Duration::from_secs(10);

/// Largest request body, bytes (no route takes one).
const MAX_BODY: usize = 1024;

/// The header a `redo` must carry (`X-Filmback: redo`): a browser sends a custom header
/// across sites only after a preflight this server never grants, so no other site's
/// page can make a visitor's browser redo a bracket.
const REDO_HEADER: &str = "x-filmback";

/// Points on a camera's curve in `/api/cameras`, per channel.
const CURVE_POINTS: usize = 65;

/// The router of every route, guarded and bounded.
pub(crate) fn router(shared: Arc<Shared>) -> Router {
    let timed = Router::new()
        .route("/", get(page))
        .route("/api/brackets", get(brackets))
        .route("/api/cameras", get(cameras))
        .route("/metrics", get(metrics))
        .route("/file/{id}/{k}", get(full_file))
        .route("/preview/{id}/{k}", get(preview))
        .route("/thumb/{id}/{k}", get(thumb))
        .route("/frame/{id}/{k}", get(frame))
        .route("/clipped/{id}", get(clipped))
        .route("/left-out/{id}", get(left_out))
        .route("/redo/{id}", post(redo))
        .layer(
            ServiceBuilder::new()
                .layer(HandleErrorLayer::new(|_: tower::BoxError| async {
                    StatusCode::REQUEST_TIMEOUT
                }))
                .timeout(REQUEST_TIMEOUT),
        );
    Router::new()
        .route("/events", get(event_stream))
        .merge(timed)
        .fallback(|| async { StatusCode::NOT_FOUND })
        .layer(middleware::from_fn_with_state(Arc::clone(&shared), guard))
        .layer(DefaultBodyLimit::max(MAX_BODY))
        .with_state(shared)
}

/// Refuses a request without the token (when one is configured: 401), and, without a
/// token, one whose `Host` is a name other than `localhost` (a page of another site that
/// had its name point at this machine: 421).
async fn guard(State(shared): State<Arc<Shared>>, request: Request, next: Next) -> Response {
    match &shared.token {
        Some(token) if !presented(&request, token.expose()) => {
            return (
                StatusCode::UNAUTHORIZED,
                [(header::WWW_AUTHENTICATE, "Bearer")],
                "a token is required: Authorization: Bearer TOKEN, or ?token=TOKEN\n",
            )
                .into_response();
        }
        Some(_) => {}
        None if !local_host(request.headers()) => {
            return (
                StatusCode::MISDIRECTED_REQUEST,
                "without a token the viewer answers only to localhost or an IP address\n",
            )
                .into_response();
        }
        None => {}
    }
    next.run(request).await
}

/// Whether the request carries `token` in its `Authorization: Bearer` header or its
/// `token` query parameter.
fn presented(request: &Request, token: &str) -> bool {
    let bearer = request
        .headers()
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.strip_prefix("Bearer "))
        .is_some_and(|given| same(given.trim(), token));
    bearer
        || Query::<HashMap<String, String>>::try_from_uri(request.uri())
            .ok()
            .and_then(|q| q.0.get("token").map(|given| same(given, token)))
            .unwrap_or(false)
}

/// Compares two secrets in a time that does not depend on where they differ.
fn same(a: &str, b: &str) -> bool {
    a.len() == b.len()
        && a.bytes()
            .zip(b.bytes())
            .fold(0u8, |acc, (x, y)| acc | (x ^ y))
            == 0
}

/// True when the `Host` header (without its port) is `localhost` or an IP address.
fn local_host(headers: &HeaderMap) -> bool {
    let Some(host) = headers.get(header::HOST).and_then(|h| h.to_str().ok()) else {
        return true;
    };
    let name = match host.strip_prefix('[') {
        Some(v6) => v6.split(']').next().unwrap_or(""),
        None => host.rsplit_once(':').map_or(host, |(name, _)| name),
    };
    name.eq_ignore_ascii_case("localhost") || name.parse::<std::net::IpAddr>().is_ok()
}

async fn page() -> Html<&'static str> {
    Html(PAGE)
}

async fn event_stream(State(shared): State<Arc<Shared>>) -> impl IntoResponse {
    events::stream(shared)
}

/// What the page loads once; events keep it current.
#[derive(Serialize)]
struct Overview {
    /// Recent developments, newest first.
    #[serde(serialize_with = "super::shared_records")]
    brackets: Vec<Arc<Record>>,
    /// Recent rejections, newest first.
    rejected: Vec<Rejection>,
    /// The daemon's latest status.
    status: Option<Snapshot>,
}

async fn brackets(State(shared): State<Arc<Shared>>) -> Json<Overview> {
    let g = shared.gallery();
    Json(Overview {
        brackets: g.records.iter().cloned().collect(),
        rejected: g.rejected.iter().cloned().collect(),
        status: g.status.clone(),
    })
}

/// A camera body's curve for the Cameras view.
#[derive(Serialize)]
struct CameraCurve {
    camera: String,
    brackets: u64,
    updated: u64,
    confidence: Vec<f64>,
    /// Per channel, `g(i/(n−1))` for `i = 0..n` (relative exposure against code).
    curve: Vec<Vec<f64>>,
    /// The pooled brackets: name, own confidence, misfit against the pool (RMS stops).
    pool: Vec<Pooled>,
    measured: bool,
}

#[derive(Serialize)]
struct Pooled {
    name: String,
    at: u64,
    own_confidence: f64,
    own_misfit: f64,
}

fn curve_of(c: &CachedResponse) -> CameraCurve {
    let n = CURVE_POINTS;
    CameraCurve {
        camera: c.camera.to_string(),
        brackets: c.brackets,
        updated: c.updated,
        confidence: c.confidence.clone(),
        curve: (0..c.response.channels())
            .map(|ch| {
                (0..n)
                    .map(|i| c.response.eval(ch, i as f64 / (n - 1) as f64))
                    .collect()
            })
            .collect(),
        pool: c
            .pool
            .iter()
            .map(|b| Pooled {
                name: b.name.clone(),
                at: b.at,
                own_confidence: b.own_confidence,
                own_misfit: b.own_misfit,
            })
            .collect(),
        measured: c.measured.is_some(),
    }
}

async fn cameras(State(shared): State<Arc<Shared>>) -> Response {
    let state = shared.state.clone();
    let listed = tokio::task::spawn_blocking(move || ResponseCache::new(&state).list()).await;
    match listed {
        Ok(Ok(entries)) => {
            let bodies: Vec<CameraCurve> = entries.iter().flatten().map(curve_of).collect();
            Json(bodies).into_response()
        }
        Ok(Err(e)) => (StatusCode::INTERNAL_SERVER_ERROR, format!("{e}\n")).into_response(),
        Err(e) => (StatusCode::INTERNAL_SERVER_ERROR, format!("{e}\n")).into_response(),
    }
}

async fn metrics(State(shared): State<Arc<Shared>>) -> Response {
    match shared.metrics.render() {
        Ok(text) => (
            [(
                header::CONTENT_TYPE,
                "application/openmetrics-text; version=1.0.0; charset=utf-8",
            )],
            text,
        )
            .into_response(),
        Err(_) => StatusCode::INTERNAL_SERVER_ERROR.into_response(),
    }
}

/// Which file of a record a route serves.
#[derive(Clone, Copy)]
enum Print {
    Full,
    Preview,
    Thumb,
    Frame,
    Clipped,
    LeftOut,
}

/// The file numbered `k` of the record numbered `id`, if both exist; the numbers come
/// from the URL as text and anything but two decimal numbers is not found.
fn file_of(shared: &Shared, id: &str, k: &str, print: Print) -> Option<PathBuf> {
    let id: u64 = id.parse().ok()?;
    let k: usize = k.parse().ok()?;
    let record = shared.record(id)?;
    let files = &record.files;
    match print {
        Print::Full => files.outputs.get(k).cloned(),
        Print::Preview => files.previews.get(k)?.as_ref().map(|(p, _)| p.clone()),
        Print::Thumb => files.previews.get(k)?.as_ref().map(|(_, t)| t.clone()),
        Print::Frame => files.frames.get(k)?.clone(),
        Print::Clipped => files.clipped.clone(),
        Print::LeftOut => files.left_out.clone(),
    }
}

async fn full_file(s: State<Arc<Shared>>, p: UrlPath<(String, String)>) -> Response {
    serve(s, p, Print::Full).await
}

async fn preview(s: State<Arc<Shared>>, p: UrlPath<(String, String)>) -> Response {
    serve(s, p, Print::Preview).await
}

async fn thumb(s: State<Arc<Shared>>, p: UrlPath<(String, String)>) -> Response {
    serve(s, p, Print::Thumb).await
}

async fn frame(s: State<Arc<Shared>>, p: UrlPath<(String, String)>) -> Response {
    serve(s, p, Print::Frame).await
}

async fn clipped(State(shared): State<Arc<Shared>>, UrlPath(id): UrlPath<String>) -> Response {
    send(file_of(&shared, &id, "0", Print::Clipped), Print::Clipped).await
}

async fn left_out(State(shared): State<Arc<Shared>>, UrlPath(id): UrlPath<String>) -> Response {
    send(file_of(&shared, &id, "0", Print::LeftOut), Print::LeftOut).await
}

async fn serve(
    State(shared): State<Arc<Shared>>,
    UrlPath((id, k)): UrlPath<(String, String)>,
    print: Print,
) -> Response {
    send(file_of(&shared, &id, &k, print), print).await
}

/// Streams a listed file (previews are small; a full EXR is not read whole).
async fn send(path: Option<PathBuf>, print: Print) -> Response {
    let Some(path) = path else {
        return StatusCode::NOT_FOUND.into_response();
    };
    let Ok(file) = tokio::fs::File::open(&path).await else {
        return (StatusCode::NOT_FOUND, "the file is no longer there\n").into_response();
    };
    let chunks = futures_util::stream::unfold(file, |mut file| async move {
        let mut buf = vec![0u8; 64 * 1024];
        match file.read(&mut buf).await {
            Ok(0) => None,
            Ok(n) => {
                buf.truncate(n);
                Some((Ok::<_, std::io::Error>(buf), file))
            }
            Err(e) => Some((Err(e), file)),
        }
    });
    let mut response = Body::from_stream(chunks).into_response();
    let headers = response.headers_mut();
    headers.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static(media_type(&path)),
    );
    headers.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    if let Print::Full = print
        && let Ok(v) = HeaderValue::from_str(&format!("inline; filename=\"{}\"", plain_name(&path)))
    {
        headers.insert(header::CONTENT_DISPOSITION, v);
    }
    response
}

/// The media type of an output or preview by its extension.
fn media_type(path: &Path) -> &'static str {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    match ext.as_str() {
        "jpg" | "jpeg" => "image/jpeg",
        "png" => "image/png",
        "tif" | "tiff" => "image/tiff",
        "exr" => "image/x-exr",
        "hdr" => "image/vnd.radiance",
        _ => "application/octet-stream",
    }
}

/// A file name safe inside a quoted header value: other characters become `_`.
fn plain_name(path: &Path) -> String {
    path.file_name()
        .map(|n| n.to_string_lossy())
        .unwrap_or_default()
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || "._-+@".contains(c) {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// `POST /redo/{id}` with `X-Filmback: redo`: leaves a request for the daemon to develop
/// that bracket again (as `filmback redo STEM` does); 202 once it is left.
async fn redo(
    State(shared): State<Arc<Shared>>,
    UrlPath(id): UrlPath<String>,
    headers: HeaderMap,
) -> Response {
    if headers.get(REDO_HEADER).is_none_or(|v| v != "redo") {
        return (
            StatusCode::FORBIDDEN,
            "a redo carries the header X-Filmback: redo\n",
        )
            .into_response();
    }
    let Some(record) = id.parse().ok().and_then(|id| shared.record(id)) else {
        return StatusCode::NOT_FOUND.into_response();
    };
    let request = shared.state.join(REDO_FOLDER).join(&record.stem);
    let left = tokio::task::spawn_blocking(move || {
        if let Some(dir) = request.parent() {
            std::fs::create_dir_all(dir).map_err(|source| atomic::PublishError::Io {
                path: dir.to_path_buf(),
                source,
            })?;
        }
        atomic::publish(&request, b"", Overwrite::Replace)
    })
    .await;
    match left {
        Ok(Ok(())) => (
            StatusCode::ACCEPTED,
            Json(serde_json::json!({ "redo": record.stem })),
        )
            .into_response(),
        Ok(Err(e)) => (StatusCode::INTERNAL_SERVER_ERROR, format!("{e}\n")).into_response(),
        Err(e) => (StatusCode::INTERNAL_SERVER_ERROR, format!("{e}\n")).into_response(),
    }
}
