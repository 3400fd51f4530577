//! The HTTP endpoint against hostile and unlucky clients: a `/stream` client that stops
//! reading, idle and trickling connections, too many `/stream` clients, and addresses
//! other than loopback. Every loop here is bounded in count and time; every address is
//! loopback (the non-loopback ones are only checked, never bound).

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use tricons::output::FramePredictions;
use tricons::output::http::{
    HttpServer, HubSink, MAX_CONNECTIONS, MAX_PENDING, MAX_STREAM_CLIENTS, REQUEST_TIMEOUT, StreamHub, WRITE_TIMEOUT,
    check_listen_address,
};
use tricons::output::sink::Sink;
use tricons::pipeline::PipelineStats;

fn server() -> (HttpServer, Arc<PipelineStats>, Arc<StreamHub>) {
    let stats = Arc::new(PipelineStats::new());
    let hub = Arc::new(StreamHub::new(Arc::clone(&stats)));
    let server = HttpServer::start("127.0.0.1:0", false, Arc::clone(&stats), Arc::clone(&hub)).unwrap();
    (server, stats, hub)
}

/// The status line of a GET, read with a deadline.
fn status_of(addr: SocketAddr, path: &str) -> String {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    // a server refusing the connection may answer and close before the request is sent
    let _ = write!(s, "GET {path} HTTP/1.1\r\nHost: x\r\n\r\n");
    let mut text = String::new();
    let _ = s.read_to_string(&mut text);
    text.lines().next().unwrap_or("").to_string()
}

/// A `/stream` client that has its 200 head (so it is subscribed) and will read no more.
fn stuck_stream_client(addr: SocketAddr) -> TcpStream {
    let mut stuck = TcpStream::connect(addr).unwrap();
    write!(stuck, "GET /stream HTTP/1.1\r\n\r\n").unwrap();
    let mut head = [0u8; 15];
    stuck.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    stuck.read_exact(&mut head).unwrap();
    assert_eq!(&head, b"HTTP/1.1 200 OK");
    stuck
}

/// Shuts the server down and checks it took about WRITE_TIMEOUT at most.
fn shutdown_within_bound(server: HttpServer) {
    let started = Instant::now();
    server.shutdown();
    assert!(started.elapsed() < WRITE_TIMEOUT * 2, "shutdown took {:?}", started.elapsed());
}

/// Polls `cond` every 20 ms for at most `limit`.
fn wait_for(limit: Duration, mut cond: impl FnMut() -> bool) -> bool {
    let end = Instant::now() + limit;
    while Instant::now() < end {
        if cond() {
            return true;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    cond()
}

/// A client that subscribes to `/stream` and then never reads is disconnected once a
/// write to it blocks for WRITE_TIMEOUT (counted), and shutdown does not wait for it.
#[test]
fn a_stream_client_that_stops_reading_is_dropped_and_does_not_block_shutdown() {
    let (server, stats, hub) = server();
    let addr = server.local_addr();
    let stuck = stuck_stream_client(addr);
    // 256 KiB lines until the socket buffers are full and a write times out (bounded: 400 lines, 100 MiB)
    let line = "x".repeat(256 * 1024);
    let mut sink = HubSink(Arc::clone(&hub));
    let frame = FramePredictions::default();
    let dropped = |s: &PipelineStats| s.http_slow_clients_dropped.load(Ordering::Relaxed);
    for _ in 0..400 {
        sink.publish(&frame, &line).unwrap();
        std::thread::sleep(Duration::from_millis(10));
        if dropped(&stats) > 0 {
            break;
        }
    }
    assert!(wait_for(WRITE_TIMEOUT * 3, || dropped(&stats) == 1), "the stuck client was not dropped");
    assert!(status_of(addr, "/metrics").contains("200"));
    shutdown_within_bound(server);
    drop(stuck);
}

/// Shutdown while a `/stream` client is blocked mid-write (its buffers full, never read)
/// completes within about WRITE_TIMEOUT, not when the client decides.
#[test]
fn shutdown_is_bounded_while_a_stream_write_is_blocked() {
    let (server, _stats, hub) = server();
    let addr = server.local_addr();
    let stuck = stuck_stream_client(addr);
    let line = "y".repeat(1024 * 1024);
    let mut sink = HubSink(Arc::clone(&hub));
    for _ in 0..40 {
        sink.publish(&FramePredictions::default(), &line).unwrap();
    }
    std::thread::sleep(Duration::from_millis(100));
    shutdown_within_bound(server);
    drop(stuck);
}

/// Connections that send nothing never hold a slot: at most MAX_PENDING of them wait for
/// a request head, each newer connection closes the oldest waiting one (counted), so
/// `/health` is answered at once however many idle clients there are; the idle clients
/// still waiting at the end get 408 after REQUEST_TIMEOUT, the evicted ones EOF.
#[test]
fn idle_connections_cannot_hold_the_slots() {
    let (server, stats, _hub) = server();
    let addr = server.local_addr();
    let n_idle = 3 * MAX_CONNECTIONS;
    let idle: Vec<TcpStream> = (0..n_idle).map(|_| TcpStream::connect(addr).unwrap()).collect();
    // every /health after the flood is answered 200 (never 429 or 503), well before any
    // idle client could have timed out
    let started = Instant::now();
    for _ in 0..5 {
        let status = status_of(addr, "/health");
        assert!(status.starts_with("HTTP/1.1 200"), "{status}");
    }
    assert!(started.elapsed() < REQUEST_TIMEOUT, "/health waited for the idle clients");
    assert_eq!(stats.http_rejected.load(Ordering::Relaxed), 0);
    // the first /health found every waiting place taken and evicted one more idle
    // connection; the later ones found the place it left
    let evicted = || stats.http_idle_evicted.load(Ordering::Relaxed);
    assert!(wait_for(Duration::from_secs(5), || evicted() == (n_idle + 1 - MAX_PENDING) as u64), "{}", evicted());
    let timeouts = || stats.http_request_timeouts.load(Ordering::Relaxed);
    assert!(
        wait_for(REQUEST_TIMEOUT * 3, || timeouts() == (MAX_PENDING - 1) as u64),
        "{} request timeouts counted, {} expected",
        timeouts(),
        MAX_PENDING - 1
    );
    let (mut timed_out, mut closed) = (0, 0);
    for mut c in idle {
        c.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
        let mut text = String::new();
        let _ = c.read_to_string(&mut text);
        if text.starts_with("HTTP/1.1 408") {
            timed_out += 1;
        } else {
            assert_eq!(text, "", "an evicted connection is closed unanswered");
            closed += 1;
        }
    }
    assert_eq!((timed_out, closed), (MAX_PENDING - 1, n_idle + 1 - MAX_PENDING));
    server.shutdown();
}

/// A client trickling its request one byte at a time is cut off at REQUEST_TIMEOUT in
/// all, not per byte.
#[test]
fn a_trickling_request_is_cut_off_at_the_deadline() {
    let (server, stats, _hub) = server();
    let mut c = TcpStream::connect(server.local_addr()).unwrap();
    let started = Instant::now();
    let mut cut_off = false;
    for b in b"GET /health HTTP/1.1\r\nHost: a-very-long-host-name-sent-slowly\r\n\r\n" {
        if c.write_all(&[*b]).is_err() {
            cut_off = true;
            break;
        }
        std::thread::sleep(Duration::from_millis(100));
        if started.elapsed() > REQUEST_TIMEOUT * 3 {
            break;
        }
    }
    c.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    let mut text = String::new();
    let _ = c.read_to_string(&mut text);
    assert!(cut_off || text.starts_with("HTTP/1.1 408"), "{text}");
    assert_eq!(stats.http_request_timeouts.load(Ordering::Relaxed), 1);
    server.shutdown();
}

/// `/stream` clients take at most MAX_STREAM_CLIENTS slots; the next one gets 429 and
/// short requests still get an answer.
#[test]
fn stream_clients_leave_slots_for_health() {
    let (server, stats, _hub) = server();
    let addr = server.local_addr();
    let streams: Vec<TcpStream> = (0..MAX_STREAM_CLIENTS)
        .map(|_| {
            let mut s = TcpStream::connect(addr).unwrap();
            write!(s, "GET /stream HTTP/1.1\r\n\r\n").unwrap();
            s
        })
        .collect();
    // every stream client got its 200 head
    for s in &streams {
        let mut s = s.try_clone().unwrap();
        s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
        let mut head = [0u8; 15];
        s.read_exact(&mut head).unwrap();
        assert_eq!(&head, b"HTTP/1.1 200 OK");
    }
    assert!(status_of(addr, "/stream").starts_with("HTTP/1.1 429"));
    assert_eq!(stats.http_rejected.load(Ordering::Relaxed), 1);
    assert!(status_of(addr, "/health").starts_with("HTTP/1.1 200"));
    drop(streams);
    server.shutdown();
}

#[test]
fn only_loopback_binds_unless_allowed() {
    for ok in ["127.0.0.1:0", "[::1]:7878", "localhost:7878"] {
        assert!(check_listen_address(ok, false).is_ok(), "{ok}");
    }
    for open in ["0.0.0.0:7878", "[::]:7878", "0:7878", "192.0.2.7:80"] {
        let err = check_listen_address(open, false).unwrap_err().to_string();
        assert!(err.contains("--listen-any") && err.contains("not loopback"), "{open}: {err}");
        assert!(check_listen_address(open, true).is_ok(), "{open} with --listen-any");
    }
    assert!(check_listen_address("not an address", true).is_err());
}
