//! The pose service's HTTP endpoint (std only, HTTP/1.1, one thread per connection).
//!
//! | Route      | Answer                                                              |
//! |------------|---------------------------------------------------------------------|
//! | `/health`  | JSON: `status` (`ok`, `reconnecting`, `ended`) and every counter of [`StatsSnapshot`]; 503 while the source is reconnecting |
//! | `/metrics` | the same counters in the Prometheus text format                     |
//! | `/latest`  | the last result line (204 before the first)                         |
//! | `/stream`  | every result from now on, JSON Lines, until the client disconnects  |
//!
//! Bound to loopback by default (`tricons serve --listen`). A slow `/stream`
//! client never slows the pipeline: each client has a bounded queue and lines
//! it cannot take are dropped and counted (`stream_lines_dropped`).

use super::predictions::FramePredictions;
use super::sink::Sink;
use crate::error::{Error, Result};
use crate::pipeline::{PipelineStats, SourceState, StatsSnapshot};
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

/// Default listen address of `tricons serve`: loopback only.
pub const DEFAULT_LISTEN: &str = "127.0.0.1:7878";
/// Lines queued per `/stream` client before lines are dropped for it.
pub const STREAM_CLIENT_QUEUE: usize = 64;
/// Most connections served at once; more are answered 503.
pub const MAX_CONNECTIONS: usize = 32;
/// How long a client may take to send its request.
const REQUEST_TIMEOUT: Duration = Duration::from_secs(2);
/// Largest request head read.
const MAX_REQUEST_BYTES: usize = 8192;
/// How often idle loops check for shutdown.
const POLL: Duration = Duration::from_millis(50);

/// Fans results out to `/stream` clients and keeps the latest for `/latest`.
pub struct StreamHub {
    stats: Arc<PipelineStats>,
    latest: Mutex<Option<Arc<str>>>,
    clients: Mutex<Vec<SyncSender<Arc<str>>>>,
}

impl StreamHub {
    /// A hub counting dropped lines in `stats`.
    pub fn new(stats: Arc<PipelineStats>) -> StreamHub {
        StreamHub { stats, latest: Mutex::new(None), clients: Mutex::new(Vec::new()) }
    }

    fn subscribe(&self) -> Receiver<Arc<str>> {
        let (tx, rx) = std::sync::mpsc::sync_channel(STREAM_CLIENT_QUEUE);
        self.clients.lock().unwrap_or_else(|p| p.into_inner()).push(tx);
        rx
    }

    fn latest(&self) -> Option<Arc<str>> {
        self.latest.lock().unwrap_or_else(|p| p.into_inner()).clone()
    }

    fn broadcast(&self, line: &str) {
        let line: Arc<str> = Arc::from(line);
        *self.latest.lock().unwrap_or_else(|p| p.into_inner()) = Some(Arc::clone(&line));
        self.clients.lock().unwrap_or_else(|p| p.into_inner()).retain(|tx| match tx.try_send(Arc::clone(&line)) {
            Ok(()) => true,
            Err(TrySendError::Full(_)) => {
                self.stats.stream_lines_dropped.fetch_add(1, Ordering::Relaxed);
                true
            }
            Err(TrySendError::Disconnected(_)) => false,
        });
    }
}

/// The hub as a pipeline output.
pub struct HubSink(pub Arc<StreamHub>);

impl Sink for HubSink {
    fn describe(&self) -> String {
        "http stream".into()
    }
    fn publish(&mut self, _frame: &FramePredictions, line: &str) -> Result<()> {
        self.0.broadcast(line);
        Ok(())
    }
    fn flush(&mut self) -> Result<()> {
        Ok(())
    }
}

/// A running HTTP endpoint; [`shutdown`](HttpServer::shutdown) (or drop) stops it.
pub struct HttpServer {
    addr: SocketAddr,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl HttpServer {
    /// Binds `addr` (e.g. `127.0.0.1:7878`; port 0 picks a free one) and serves in the background.
    pub fn start(addr: &str, stats: Arc<PipelineStats>, hub: Arc<StreamHub>) -> Result<HttpServer> {
        let listener = TcpListener::bind(addr).map_err(|e| Error::io(format!("listen address {addr}"), e))?;
        let local = listener.local_addr().map_err(|e| Error::io(format!("listen address {addr}"), e))?;
        listener.set_nonblocking(true).map_err(|e| Error::io(format!("listen address {addr}"), e))?;
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let stop = Arc::clone(&stop);
            std::thread::Builder::new()
                .name("http".into())
                .spawn(move || accept_loop(listener, stats, hub, stop))
                .map_err(|e| Error::io(format!("listen address {addr}"), e))?
        };
        Ok(HttpServer { addr: local, stop, thread: Some(thread) })
    }

    /// The bound address.
    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    /// Stops accepting; `/stream` clients get the lines already queued, then EOF.
    pub fn shutdown(mut self) {
        self.stop_now();
    }

    fn stop_now(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl Drop for HttpServer {
    fn drop(&mut self) {
        self.stop_now();
    }
}

fn accept_loop(listener: TcpListener, stats: Arc<PipelineStats>, hub: Arc<StreamHub>, stop: Arc<AtomicBool>) {
    let active = Arc::new(AtomicUsize::new(0));
    let mut handlers: Vec<JoinHandle<()>> = Vec::new();
    while !stop.load(Ordering::SeqCst) {
        match listener.accept() {
            Ok((mut stream, _)) => {
                handlers.retain(|h| !h.is_finished());
                if active.load(Ordering::SeqCst) >= MAX_CONNECTIONS {
                    let _ = respond(&mut stream, 503, "text/plain", b"too many connections\n");
                    continue;
                }
                active.fetch_add(1, Ordering::SeqCst);
                let (stats, hub, stop, active) =
                    (Arc::clone(&stats), Arc::clone(&hub), Arc::clone(&stop), Arc::clone(&active));
                let spawned = std::thread::Builder::new().name("http-conn".into()).spawn(move || {
                    if let Err(e) = handle(stream, &stats, &hub, &stop) {
                        log::debug!("http: {e}");
                    }
                    active.fetch_sub(1, Ordering::SeqCst);
                });
                match spawned {
                    Ok(h) => handlers.push(h),
                    Err(e) => log::warn!("http: cannot start a connection thread: {e}"),
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => std::thread::sleep(POLL),
            Err(e) => {
                log::warn!("http: accept failed: {e}");
                std::thread::sleep(POLL);
            }
        }
    }
    for h in handlers {
        let _ = h.join();
    }
}

fn respond(stream: &mut TcpStream, status: u16, content_type: &str, body: &[u8]) -> std::io::Result<()> {
    let reason = match status {
        200 => "OK",
        204 => "No Content",
        404 => "Not Found",
        405 => "Method Not Allowed",
        400 => "Bad Request",
        _ => "Service Unavailable",
    };
    let head = format!(
        "HTTP/1.1 {status} {reason}\r\nContent-Type: {content_type}\r\nContent-Length: {}\r\nConnection: close\r\n\r\n",
        body.len()
    );
    stream.write_all(head.as_bytes())?;
    stream.write_all(body)?;
    stream.flush()
}

/// `/health`'s body: the status word and the snapshot's fields.
pub fn health_json(snapshot: &StatsSnapshot) -> String {
    let status = match snapshot.source {
        SourceState::Running => "ok",
        SourceState::Reconnecting => "reconnecting",
        SourceState::Ended => "ended",
    };
    let mut value = serde_json::to_value(snapshot).unwrap_or_default();
    if let Some(map) = value.as_object_mut() {
        map.insert("status".into(), status.into());
    }
    let mut s = serde_json::to_string_pretty(&value).unwrap_or_default();
    s.push('\n');
    s
}

fn handle(mut stream: TcpStream, stats: &PipelineStats, hub: &StreamHub, stop: &AtomicBool) -> std::io::Result<()> {
    stream.set_nonblocking(false)?;
    stream.set_read_timeout(Some(REQUEST_TIMEOUT))?;
    let mut head = Vec::new();
    let mut buf = [0u8; 1024];
    while !head.windows(4).any(|w| w == b"\r\n\r\n") && !head.windows(2).any(|w| w == b"\n\n") {
        let n = stream.read(&mut buf)?;
        if n == 0 {
            break;
        }
        head.extend_from_slice(&buf[..n]);
        if head.len() > MAX_REQUEST_BYTES {
            return respond(&mut stream, 400, "text/plain", b"request too large\n");
        }
    }
    let text = String::from_utf8_lossy(&head);
    let mut parts = text.lines().next().unwrap_or("").split_whitespace();
    let (method, target) = (parts.next().unwrap_or(""), parts.next().unwrap_or(""));
    let path = target.split('?').next().unwrap_or("");
    if method != "GET" {
        return respond(&mut stream, 405, "text/plain", b"only GET\n");
    }
    match path {
        "/health" => {
            let snap = stats.snapshot();
            let status = if snap.source == SourceState::Reconnecting { 503 } else { 200 };
            respond(&mut stream, status, "application/json", health_json(&snap).as_bytes())
        }
        "/metrics" => {
            respond(&mut stream, 200, "text/plain; version=0.0.4", stats.snapshot().to_prometheus().as_bytes())
        }
        "/latest" => match hub.latest() {
            Some(line) => respond(&mut stream, 200, "application/json", format!("{line}\n").as_bytes()),
            None => respond(&mut stream, 204, "application/json", b""),
        },
        "/stream" => {
            let rx = hub.subscribe();
            stream.write_all(
                b"HTTP/1.1 200 OK\r\nContent-Type: application/x-ndjson\r\nCache-Control: no-cache\r\nConnection: close\r\n\r\n",
            )?;
            stream.flush()?;
            loop {
                match rx.recv_timeout(POLL) {
                    Ok(line) => {
                        stream.write_all(line.as_bytes())?;
                        stream.write_all(b"\n")?;
                        stream.flush()?;
                    }
                    Err(RecvTimeoutError::Timeout) if stop.load(Ordering::SeqCst) => {
                        // Deliver what is queued, then end the stream.
                        while let Ok(line) = rx.try_recv() {
                            stream.write_all(line.as_bytes())?;
                            stream.write_all(b"\n")?;
                        }
                        return stream.flush();
                    }
                    Err(RecvTimeoutError::Timeout) => {}
                    Err(RecvTimeoutError::Disconnected) => return stream.flush(),
                }
            }
        }
        "/" => respond(&mut stream, 200, "text/plain", b"tricons pose service: /health /metrics /latest /stream\n"),
        _ => respond(&mut stream, 404, "text/plain", b"not found: try /health /metrics /latest /stream\n"),
    }
}
