//! The pose service's HTTP endpoint (std only, HTTP/1.1, one thread per connection).
//!
//! | Route      | Answer                                                              |
//! |------------|---------------------------------------------------------------------|
//! | `/health`  | JSON: `status` (`ok`, `reconnecting`, `ended`) and every counter of [`StatsSnapshot`]; 503 while the source is reconnecting |
//! | `/metrics` | the same counters in the Prometheus text format                     |
//! | `/latest`  | the last result line (204 before the first)                         |
//! | `/stream`  | every result from now on, JSON Lines, until the client disconnects  |
//!
//! Bound to loopback by default (`tricons serve --listen`); any other address only
//! when the caller allows it ([`HttpServer::start`], `--listen-any`). A slow `/stream`
//! client never slows the pipeline: each client has a bounded queue and lines it cannot
//! take are dropped and counted (`stream_lines_dropped`); a client that stops reading
//! altogether is disconnected once a write to it has blocked for [`WRITE_TIMEOUT`]
//! (`http_slow_clients_dropped`).
//!
//! Hostile clients are bounded too: a request head must arrive whole within
//! [`REQUEST_TIMEOUT`] (else 408, `http_request_timeouts`); at most [`MAX_PENDING`]
//! connections wait for their heads, and a new connection closes the oldest waiting one
//! beyond that (`http_idle_evicted`), so idle clients never keep a request from being
//! read; a slot is taken only once a request has arrived; `/stream` clients take at
//! most [`MAX_STREAM_CLIENTS`] of the [`MAX_CONNECTIONS`] slots, so the rest stay free
//! for `/health` and `/metrics` (over the limits: 429 with `Retry-After`, sent after
//! the request was read, `http_rejected`; never 503, which means "source
//! reconnecting"). The accept loop
//! blocks in `accept` (an idle `/health` answers at once) and shutdown wakes it; every
//! connection thread ends within [`WRITE_TIMEOUT`] of shutdown, whatever its client does.

use super::predictions::FramePredictions;
use super::sink::Sink;
use crate::error::{Error, Result};
use crate::pipeline::{PipelineStats, SourceState, StatsSnapshot};
use std::io::{Read, Write};
use std::net::{Ipv4Addr, Ipv6Addr, SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// Default listen address of `tricons serve`: loopback only.
pub const DEFAULT_LISTEN: &str = "127.0.0.1:7878";
/// Lines queued per `/stream` client before lines are dropped for it.
pub const STREAM_CLIENT_QUEUE: usize = 64;
/// Most connections served at once; more are answered 429.
pub const MAX_CONNECTIONS: usize = 32;
/// Most `/stream` clients at once (the other slots stay free for short requests).
pub const MAX_STREAM_CLIENTS: usize = MAX_CONNECTIONS / 2;
/// Most connections waiting for their request head; a newer one closes the oldest.
pub const MAX_PENDING: usize = 16;
/// How long a client may take to send its whole request head.
pub const REQUEST_TIMEOUT: Duration = Duration::from_secs(2);
/// How long one write to a client may block before the client is disconnected.
pub const WRITE_TIMEOUT: Duration = Duration::from_secs(2);
/// Write deadline while delivering a `/stream` client's last queued lines at shutdown.
const DRAIN_TIMEOUT: Duration = Duration::from_millis(200);
/// Largest request head read.
pub const MAX_REQUEST_BYTES: usize = 8192;
/// How often a `/stream` connection checks for shutdown.
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

/// Whether `addr` may be bound: loopback always, anything else only with `allow_any`.
/// Every address it resolves to is checked (a host name may name several).
pub fn check_listen_address(addr: &str, allow_any: bool) -> Result<Vec<SocketAddr>> {
    use std::net::ToSocketAddrs;
    let resolved: Vec<SocketAddr> =
        addr.to_socket_addrs().map_err(|e| Error::InvalidArgument(format!("listen address {addr:?}: {e}")))?.collect();
    if resolved.is_empty() {
        return Err(Error::InvalidArgument(format!("listen address {addr:?} resolves to nothing")));
    }
    if let Some(open) = resolved.iter().find(|a| !a.ip().is_loopback()) {
        if !allow_any {
            return Err(Error::InvalidArgument(format!(
                "listen address {addr:?} is {open}, not loopback: the service would be reachable from other \
                 machines; pass --listen-any (or \"listen_any\": true in the serve config) to allow it"
            )));
        }
        log::warn!("http: listening on {open}, reachable from other machines (--listen-any)");
    }
    Ok(resolved)
}

impl HttpServer {
    /// Binds `addr` (e.g. `127.0.0.1:7878`; port 0 picks a free one) and serves in the
    /// background. A non-loopback address is refused unless `allow_any`
    /// ([`check_listen_address`]).
    pub fn start(addr: &str, allow_any: bool, stats: Arc<PipelineStats>, hub: Arc<StreamHub>) -> Result<HttpServer> {
        let resolved = check_listen_address(addr, allow_any)?;
        let listener =
            TcpListener::bind(resolved.as_slice()).map_err(|e| Error::io(format!("listen address {addr}"), e))?;
        let local = listener.local_addr().map_err(|e| Error::io(format!("listen address {addr}"), e))?;
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

    /// Stops accepting; `/stream` clients get the lines already queued (as far as they
    /// take them within a short deadline), then EOF. Returns within about
    /// [`WRITE_TIMEOUT`] whatever the clients do.
    pub fn shutdown(mut self) {
        self.stop_now();
    }

    fn stop_now(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            // wake the blocking accept with a connection of our own
            let mut wake = self.addr;
            if wake.ip().is_unspecified() {
                wake.set_ip(if wake.is_ipv4() { Ipv4Addr::LOCALHOST.into() } else { Ipv6Addr::LOCALHOST.into() });
            }
            if let Err(e) = TcpStream::connect_timeout(&wake, Duration::from_secs(1)) {
                log::warn!("http: cannot wake the accept loop at {wake}: {e}");
            }
            let _ = t.join();
        }
    }
}

impl Drop for HttpServer {
    fn drop(&mut self) {
        self.stop_now();
    }
}

/// Connection slots: all of them, and the `/stream` share.
struct Slots {
    active: AtomicUsize,
    streams: AtomicUsize,
}

/// Holds one of a counter's slots until dropped.
struct SlotGuard<'a>(&'a AtomicUsize);

impl Drop for SlotGuard<'_> {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::SeqCst);
    }
}

/// Takes a slot of `counter` if fewer than `max` are taken.
fn take_slot(counter: &AtomicUsize, max: usize) -> Option<SlotGuard<'_>> {
    counter.fetch_update(Ordering::SeqCst, Ordering::SeqCst, |n| (n < max).then_some(n + 1)).ok()?;
    Some(SlotGuard(counter))
}

/// Connections that have not sent their request head yet, oldest first. At most
/// [`MAX_PENDING`]: a new connection closes the oldest one beyond that, so idle clients
/// can hold at most that many threads and never keep a request from being read.
struct Pending {
    conns: Mutex<std::collections::VecDeque<(u64, TcpStream)>>,
}

impl Pending {
    fn lock(&self) -> std::sync::MutexGuard<'_, std::collections::VecDeque<(u64, TcpStream)>> {
        self.conns.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Registers connection `id` (a clone of its socket), closing the oldest pending
    /// one when all [`MAX_PENDING`] places are taken (counted).
    fn admit(&self, id: u64, conn: TcpStream, stats: &PipelineStats) {
        let mut conns = self.lock();
        if conns.len() >= MAX_PENDING
            && let Some((_, oldest)) = conns.pop_front()
        {
            let _ = oldest.shutdown(std::net::Shutdown::Both);
            stats.http_idle_evicted.fetch_add(1, Ordering::Relaxed);
        }
        conns.push_back((id, conn));
    }

    /// Removes `id`; false when it was evicted meanwhile.
    fn finish(&self, id: u64) -> bool {
        let mut conns = self.lock();
        match conns.iter().position(|(i, _)| *i == id) {
            Some(k) => {
                conns.remove(k);
                true
            }
            None => false,
        }
    }

    /// Closes every pending connection (shutdown: nobody waits for their heads).
    fn close_all(&self) {
        for (_, conn) in self.lock().drain(..) {
            let _ = conn.shutdown(std::net::Shutdown::Both);
        }
    }
}

/// What every connection thread shares.
struct Shared {
    stats: Arc<PipelineStats>,
    hub: Arc<StreamHub>,
    stop: Arc<AtomicBool>,
    slots: Slots,
    pending: Pending,
}

fn accept_loop(listener: TcpListener, stats: Arc<PipelineStats>, hub: Arc<StreamHub>, stop: Arc<AtomicBool>) {
    let shared = Arc::new(Shared {
        stats,
        hub,
        stop,
        slots: Slots { active: AtomicUsize::new(0), streams: AtomicUsize::new(0) },
        pending: Pending { conns: Mutex::new(std::collections::VecDeque::new()) },
    });
    let mut handlers: Vec<JoinHandle<()>> = Vec::new();
    let mut next_id = 0u64;
    loop {
        let accepted = listener.accept();
        if shared.stop.load(Ordering::SeqCst) {
            break;
        }
        match accepted {
            Ok((stream, _)) => {
                handlers.retain(|h| !h.is_finished());
                let Ok(registered) = stream.try_clone() else {
                    continue; // out of descriptors: drop this one
                };
                next_id += 1;
                let id = next_id;
                shared.pending.admit(id, registered, &shared.stats);
                let conn = Arc::clone(&shared);
                let spawned = std::thread::Builder::new().name("http-conn".into()).spawn(move || {
                    if let Err(e) = handle(stream, id, &conn) {
                        log::debug!("http: {e}");
                    }
                });
                match spawned {
                    Ok(h) => handlers.push(h),
                    Err(e) => {
                        shared.pending.finish(id);
                        log::warn!("http: cannot start a connection thread: {e}");
                    }
                }
            }
            Err(e) => {
                log::warn!("http: accept failed: {e}");
                std::thread::sleep(POLL);
            }
        }
    }
    shared.pending.close_all();
    for h in handlers {
        let _ = h.join();
    }
}

/// 429 with a retry hint: the slots are taken (503 would read as "source reconnecting").
fn busy(stream: &mut TcpStream, why: &str) -> std::io::Result<()> {
    let body = format!("{why}; retry shortly\n");
    let head = format!(
        "HTTP/1.1 429 Too Many Requests\r\nContent-Type: text/plain\r\nContent-Length: {}\r\nRetry-After: 1\r\nConnection: close\r\n\r\n",
        body.len()
    );
    stream.write_all(head.as_bytes())?;
    stream.write_all(body.as_bytes())?;
    stream.flush()
}

fn respond(stream: &mut TcpStream, status: u16, content_type: &str, body: &[u8]) -> std::io::Result<()> {
    let reason = match status {
        200 => "OK",
        204 => "No Content",
        404 => "Not Found",
        405 => "Method Not Allowed",
        400 => "Bad Request",
        408 => "Request Timeout",
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

/// What a request asks for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Route {
    /// `/`: a line naming the routes.
    Index,
    /// `/health`.
    Health,
    /// `/metrics`.
    Metrics,
    /// `/latest`.
    Latest,
    /// `/stream`.
    Stream,
}

/// Why a request head is refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BadRequest {
    /// Longer than the largest head read (400).
    TooLarge,
    /// A method other than GET (405).
    NotGet,
    /// No such route (404).
    NotFound,
}

/// Whether `head` holds a whole request head (it ends at an empty line).
pub fn head_complete(head: &[u8]) -> bool {
    head.windows(4).any(|w| w == b"\r\n\r\n") || head.windows(2).any(|w| w == b"\n\n")
}

/// The route a request head (its bytes as received, at most [`MAX_REQUEST_BYTES`] of
/// them are accepted) asks for: the request line's method and path, query ignored.
pub fn parse_request(head: &[u8]) -> std::result::Result<Route, BadRequest> {
    if head.len() > MAX_REQUEST_BYTES {
        return Err(BadRequest::TooLarge);
    }
    let text = String::from_utf8_lossy(head);
    let mut parts = text.lines().next().unwrap_or("").split_whitespace();
    let (method, target) = (parts.next().unwrap_or(""), parts.next().unwrap_or(""));
    if method != "GET" {
        return Err(BadRequest::NotGet);
    }
    match target.split('?').next().unwrap_or("") {
        "/" => Ok(Route::Index),
        "/health" => Ok(Route::Health),
        "/metrics" => Ok(Route::Metrics),
        "/latest" => Ok(Route::Latest),
        "/stream" => Ok(Route::Stream),
        _ => Err(BadRequest::NotFound),
    }
}

/// Reads a request head within [`REQUEST_TIMEOUT`] in all (not per read: a client
/// trickling one byte at a time is cut off too). `Ok(None)`: the deadline passed.
fn read_head(stream: &mut TcpStream) -> std::io::Result<Option<Vec<u8>>> {
    let deadline = Instant::now() + REQUEST_TIMEOUT;
    let mut head = Vec::new();
    let mut buf = [0u8; 1024];
    while !head_complete(&head) {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return Ok(None);
        }
        stream.set_read_timeout(Some(left))?;
        let n = match stream.read(&mut buf) {
            Ok(n) => n,
            Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => {
                return Ok(None);
            }
            Err(e) => return Err(e),
        };
        if n == 0 {
            break;
        }
        head.extend_from_slice(&buf[..n]);
        if head.len() > MAX_REQUEST_BYTES {
            break;
        }
    }
    Ok(Some(head))
}

/// Writes all of `bytes` by `deadline` in all (a socket timeout alone is per `write`
/// call, and a client draining a few bytes now and then would reset it forever).
fn write_all_by(stream: &mut TcpStream, mut bytes: &[u8], deadline: Instant) -> std::io::Result<()> {
    use std::io::ErrorKind;
    while !bytes.is_empty() {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return Err(std::io::Error::new(ErrorKind::TimedOut, "write deadline passed"));
        }
        stream.set_write_timeout(Some(left))?;
        match stream.write(bytes) {
            Ok(0) => return Err(ErrorKind::WriteZero.into()),
            Ok(n) => bytes = &bytes[n..],
            Err(e) if e.kind() == ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(())
}

/// One line to a `/stream` client within `timeout`; a client that does not take it in
/// time is counted as dropped (the caller then closes the connection).
fn send_line(stream: &mut TcpStream, line: &str, timeout: Duration, stats: &PipelineStats) -> std::io::Result<()> {
    let mut bytes = Vec::with_capacity(line.len() + 1);
    bytes.extend_from_slice(line.as_bytes());
    bytes.push(b'\n');
    let sent = write_all_by(stream, &bytes, Instant::now() + timeout);
    if let Err(e) = &sent
        && matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut)
    {
        stats.http_slow_clients_dropped.fetch_add(1, Ordering::Relaxed);
        log::info!("http: dropped a /stream client that stopped reading");
    }
    sent
}

fn handle(mut stream: TcpStream, id: u64, shared: &Shared) -> std::io::Result<()> {
    let (stats, hub, stop) = (&*shared.stats, &*shared.hub, &*shared.stop);
    stream.set_write_timeout(Some(WRITE_TIMEOUT))?;
    let head = read_head(&mut stream);
    if !shared.pending.finish(id) {
        return Ok(()); // evicted by newer connections before it sent a request
    }
    let Some(head) = head? else {
        stats.http_request_timeouts.fetch_add(1, Ordering::Relaxed);
        return respond(&mut stream, 408, "text/plain", b"request head not received in time\n");
    };
    // a slot is taken once there is a request to serve (idle clients never hold one)
    let Some(_slot) = take_slot(&shared.slots.active, MAX_CONNECTIONS) else {
        stats.http_rejected.fetch_add(1, Ordering::Relaxed);
        return busy(&mut stream, "too many connections");
    };
    let streams = &shared.slots.streams;
    let route = match parse_request(&head) {
        Ok(route) => route,
        Err(BadRequest::TooLarge) => return respond(&mut stream, 400, "text/plain", b"request too large\n"),
        Err(BadRequest::NotGet) => return respond(&mut stream, 405, "text/plain", b"only GET\n"),
        Err(BadRequest::NotFound) => {
            return respond(&mut stream, 404, "text/plain", b"not found: try /health /metrics /latest /stream\n");
        }
    };
    match route {
        Route::Health => {
            let snap = stats.snapshot();
            let status = if snap.source == SourceState::Reconnecting { 503 } else { 200 };
            respond(&mut stream, status, "application/json", health_json(&snap).as_bytes())
        }
        Route::Metrics => {
            respond(&mut stream, 200, "text/plain; version=0.0.4", stats.snapshot().to_prometheus().as_bytes())
        }
        Route::Latest => match hub.latest() {
            Some(line) => respond(&mut stream, 200, "application/json", format!("{line}\n").as_bytes()),
            None => respond(&mut stream, 204, "application/json", b""),
        },
        Route::Stream => {
            let Some(_slot) = take_slot(streams, MAX_STREAM_CLIENTS) else {
                stats.http_rejected.fetch_add(1, Ordering::Relaxed);
                return busy(&mut stream, "too many /stream clients");
            };
            let rx = hub.subscribe();
            stream.write_all(
                b"HTTP/1.1 200 OK\r\nContent-Type: application/x-ndjson\r\nCache-Control: no-cache\r\nConnection: close\r\n\r\n",
            )?;
            stream.flush()?;
            loop {
                match rx.recv_timeout(POLL) {
                    Ok(line) => send_line(&mut stream, &line, WRITE_TIMEOUT, stats)?,
                    Err(RecvTimeoutError::Timeout) if stop.load(Ordering::SeqCst) => {
                        // Deliver what is queued (a short deadline per line), then end the stream.
                        while let Ok(line) = rx.try_recv() {
                            send_line(&mut stream, &line, DRAIN_TIMEOUT, stats)?;
                        }
                        return stream.flush();
                    }
                    Err(RecvTimeoutError::Timeout) => {}
                    Err(RecvTimeoutError::Disconnected) => return stream.flush(),
                }
            }
        }
        Route::Index => {
            respond(&mut stream, 200, "text/plain", b"tricons pose service: /health /metrics /latest /stream\n")
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn request_heads_route_or_are_refused() {
        assert_eq!(parse_request(b"GET /health HTTP/1.1\r\nHost: x\r\n\r\n"), Ok(Route::Health));
        assert_eq!(parse_request(b"GET /metrics?x=1 HTTP/1.0\n\n"), Ok(Route::Metrics));
        assert_eq!(parse_request(b"GET / HTTP/1.1\r\n\r\n"), Ok(Route::Index));
        assert_eq!(parse_request(b"GET /stream"), Ok(Route::Stream));
        assert_eq!(parse_request(b"GET  /latest  HTTP/1.1\r\n\r\n"), Ok(Route::Latest));
        assert_eq!(parse_request(b"POST /health HTTP/1.1\r\n\r\n"), Err(BadRequest::NotGet));
        assert_eq!(parse_request(b""), Err(BadRequest::NotGet));
        assert_eq!(parse_request(b"\xff\xfe GET"), Err(BadRequest::NotGet));
        assert_eq!(parse_request(b"GET /healthz HTTP/1.1\r\n\r\n"), Err(BadRequest::NotFound));
        assert_eq!(parse_request(b"GET"), Err(BadRequest::NotFound));
        let mut big = b"GET /health HTTP/1.1\r\n".to_vec();
        big.resize(MAX_REQUEST_BYTES + 1, b'a');
        assert_eq!(parse_request(&big), Err(BadRequest::TooLarge));
        assert!(head_complete(b"GET / HTTP/1.1\r\n\r\n") && head_complete(b"GET /\n\n"));
        assert!(!head_complete(b"GET / HTTP/1.1\r\n") && !head_complete(b""));
    }
}
