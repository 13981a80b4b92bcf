//! The viewer's socket and connections: the configured address, or the socket systemd
//! passes (`LISTEN_FDS`, from `filmback.socket`), served by hyper with bounded
//! connections and a bounded time to send a request's headers.

use std::sync::Arc;
use std::time::Duration;

use axum::Router;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use tokio::net::TcpListener;
use tokio::sync::Semaphore;
use tracing::{debug, info, warn};

use super::ViewerError;
use crate::daemon::config::Viewer;

/// Connections served at once; the next waits in the kernel's backlog.
const MAX_CONNECTIONS: usize = 64;

/// Time a client has to send a request's headers once it connected (or between
/// requests on a kept-alive connection).
const HEADER_TIMEOUT: Duration = Duration::from_secs(10);

/// The listener: the first socket systemd passed when there is one (`LISTEN_PID` is
/// this process), else a new one bound to `config.address`.
pub(crate) async fn listen(config: &Viewer) -> Result<TcpListener, ViewerError> {
    let activation = |source| ViewerError::Activation { source };
    let mut passed = listenfd::ListenFd::from_env();
    if let Some(std) = passed.take_tcp_listener(0).map_err(activation)? {
        std.set_nonblocking(true).map_err(activation)?;
        info!("viewer: listening on the socket passed by systemd");
        return TcpListener::from_std(std).map_err(activation);
    }
    TcpListener::bind(config.address)
        .await
        .map_err(|source| ViewerError::Bind {
            address: config.address,
            source,
        })
}

/// Accepts connections for as long as the runtime runs, at most [`MAX_CONNECTIONS`] at
/// once, each served by its own task.
pub(crate) async fn serve(listener: TcpListener, app: Router) {
    let slots = Arc::new(Semaphore::new(MAX_CONNECTIONS));
    loop {
        let Ok(slot) = Arc::clone(&slots).acquire_owned().await else {
            return;
        };
        let (stream, peer) = match listener.accept().await {
            Ok(accepted) => accepted,
            Err(e) => {
                // Out of file descriptors and the like: wait instead of spinning.
                warn!(error = %e, "viewer: cannot accept a connection");
                tokio::time::sleep(Duration::from_millis(100)).await;
                continue;
            }
        };
        let service = TowerToHyperService::new(app.clone());
        tokio::spawn(async move {
            let mut http = hyper::server::conn::http1::Builder::new();
            http.timer(TokioTimer::new())
                .header_read_timeout(HEADER_TIMEOUT)
                .max_buf_size(64 * 1024);
            if let Err(e) = http.serve_connection(TokioIo::new(stream), service).await {
                debug!(peer = %peer, error = %e, "viewer connection ended");
            }
            drop(slot);
        });
    }
}
