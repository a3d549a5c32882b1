//! A minimal HTTP/1.1 server for the monitor page on the monitor thread's tokio runtime:
//! `GET /` (the page, HTML and JavaScript inline), `GET /frame.png` (the latest overlay)
//! and `GET /events` (Server-Sent Events, one `update` about ten times a second);
//! `HEAD` of each is answered with the head alone.
//!
//! It protects the daemon rather than the client: every connection has
//! [`REQUEST_TIMEOUT`] to send its request head; open connections are capped, and when
//! the cap is reached a new connection closes the oldest one still waiting for its
//! request (idle or trickling a byte at a time), so idle sockets cannot starve the page;
//! only when every open connection is busy is a new one turned away. Accepting never
//! waits. Live pages are capped (`max_clients`, then 503); each page has a small queue,
//! and an update that does not fit is dropped for that page (counted) instead of
//! waiting; a page that stops reading is closed. On loopback, requests must name a
//! loopback host (no DNS rebinding from a web page); a request with two `Host` headers
//! is a 400.
use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{mpsc, Notify};

/// The page, with its script and styles inline (no CDN, no network).
const PAGE: &str = include_str!("page.html");
/// Updates queued per page before new ones are dropped.
const QUEUE: usize = 8;
/// How long a connection has to send its request head.
const REQUEST_TIMEOUT: Duration = Duration::from_secs(5);
const WRITE_TIMEOUT: Duration = Duration::from_secs(2);
const MAX_REQUEST: usize = 8192;

/// What the producer shares with the connections.
pub struct Hub {
    clients: Mutex<Vec<(u64, mpsc::Sender<Arc<str>>)>>,
    frame_png: Mutex<Option<Arc<Vec<u8>>>>,
    hello: Mutex<Arc<str>>,
    next_id: AtomicU64,
    max_clients: usize,
    /// Updates dropped because a page was not keeping up.
    pub dropped_updates: AtomicU64,
    /// Only loopback host names are served (the listener is on loopback).
    loopback_only: bool,
}

impl Hub {
    pub fn new(max_clients: usize, loopback_only: bool) -> Self {
        Hub {
            clients: Mutex::new(Vec::new()),
            frame_png: Mutex::new(None),
            hello: Mutex::new(Arc::from("{}")),
            next_id: AtomicU64::new(1),
            max_clients,
            dropped_updates: AtomicU64::new(0),
            loopback_only,
        }
    }

    /// Live pages now.
    pub fn clients(&self) -> usize {
        self.clients.lock().map_or(0, |c| c.len())
    }

    /// Queues `message` for every page; never waits.
    pub fn broadcast(&self, message: &str) {
        let message: Arc<str> = Arc::from(message);
        if let Ok(mut clients) = self.clients.lock() {
            clients.retain(|(_, tx)| match tx.try_send(message.clone()) {
                Ok(()) => true,
                Err(mpsc::error::TrySendError::Full(_)) => {
                    self.dropped_updates.fetch_add(1, Ordering::Relaxed);
                    true
                }
                Err(mpsc::error::TrySendError::Closed(_)) => false,
            });
        }
    }

    /// The latest overlay picture.
    pub fn set_frame(&self, png: Vec<u8>) {
        if let Ok(mut slot) = self.frame_png.lock() {
            *slot = Some(Arc::new(png));
        }
    }

    /// What a new page gets first (the recent force history).
    pub fn set_hello(&self, message: String) {
        if let Ok(mut slot) = self.hello.lock() {
            *slot = Arc::from(message);
        }
    }

    fn join(&self) -> Option<(u64, mpsc::Receiver<Arc<str>>)> {
        let mut clients = self.clients.lock().ok()?;
        if clients.len() >= self.max_clients {
            return None;
        }
        let (tx, rx) = mpsc::channel(QUEUE);
        let id = self.next_id.fetch_add(1, Ordering::Relaxed);
        clients.push((id, tx));
        Some((id, rx))
    }

    fn leave(&self, id: u64) {
        if let Ok(mut clients) = self.clients.lock() {
            clients.retain(|(k, _)| *k != id);
        }
    }
}

/// Open connections beside the live pages: short requests (page, frame) and those
/// still sending their request.
const SPARE_CONNECTIONS: usize = 8;

/// The open connections, oldest first; at the cap, a new one closes the oldest that is
/// still waiting for its request.
struct Connections {
    open: Mutex<VecDeque<Arc<Connection>>>,
    cap: usize,
    next_id: AtomicU64,
}

/// One open connection as [`Connections`] sees it.
struct Connection {
    id: u64,
    /// Its request head has not arrived yet.
    waiting: AtomicBool,
    /// Told to close (another connection needs its place).
    evict: Notify,
}

/// A connection's place; dropping it frees the place.
struct Slot {
    connections: Arc<Connections>,
    connection: Arc<Connection>,
}

impl Connections {
    fn new(cap: usize) -> Self {
        Connections {
            open: Mutex::new(VecDeque::new()),
            cap,
            next_id: AtomicU64::new(1),
        }
    }

    /// A place for a new connection: free, or taken from the oldest connection still
    /// waiting for its request (closed); None when every open connection is busy.
    fn admit(self: &Arc<Self>) -> Option<Slot> {
        let mut open = self.open.lock().ok()?;
        if open.len() >= self.cap {
            let oldest_waiting = open
                .iter()
                .position(|c| c.waiting.load(Ordering::Relaxed))?;
            if let Some(evicted) = open.remove(oldest_waiting) {
                evicted.evict.notify_one();
            }
        }
        let connection = Arc::new(Connection {
            id: self.next_id.fetch_add(1, Ordering::Relaxed),
            waiting: AtomicBool::new(true),
            evict: Notify::new(),
        });
        open.push_back(connection.clone());
        Some(Slot {
            connections: self.clone(),
            connection,
        })
    }
}

impl Drop for Slot {
    fn drop(&mut self) {
        if let Ok(mut open) = self.connections.open.lock() {
            open.retain(|c| c.id != self.connection.id);
        }
    }
}

/// Accepts connections until the task is dropped; never waits for a place.
pub async fn accept_loop(listener: TcpListener, hub: Arc<Hub>) {
    let connections = Arc::new(Connections::new(hub.max_clients + SPARE_CONNECTIONS));
    loop {
        let Ok((stream, _)) = listener.accept().await else {
            tokio::time::sleep(Duration::from_millis(50)).await;
            continue;
        };
        let Some(slot) = connections.admit() else {
            drop(stream);
            continue;
        };
        let hub = hub.clone();
        tokio::spawn(async move {
            let _ = serve(stream, &hub, &slot).await;
            drop(slot);
        });
    }
}

/// The request line's method and path, and the Host header.
#[derive(Debug, PartialEq)]
struct Request {
    method: String,
    path: String,
    host: String,
    /// How many `Host` headers the request had.
    hosts: usize,
}

async fn read_request(stream: &mut TcpStream) -> Option<Request> {
    let mut buf = Vec::with_capacity(1024);
    let mut chunk = [0u8; 1024];
    while !buf.windows(4).any(|w| w == b"\r\n\r\n") {
        let n = stream.read(&mut chunk).await.ok()?;
        if n == 0 || buf.len() + n > MAX_REQUEST {
            return None;
        }
        buf.extend_from_slice(&chunk[..n]);
    }
    parse_request(&buf)
}

/// The request head at the start of `bytes` (up to its blank line).
fn parse_request(bytes: &[u8]) -> Option<Request> {
    let text = String::from_utf8_lossy(bytes);
    let head = text.split("\r\n\r\n").next()?;
    let mut lines = head.lines();
    let mut first = lines.next()?.split_whitespace();
    let (method, target) = (first.next()?.to_string(), first.next()?);
    let path = target.split('?').next().unwrap_or("/").to_string();
    let hosts: Vec<String> = lines
        .filter_map(|l| l.split_once(':'))
        .filter(|(k, _)| k.trim().eq_ignore_ascii_case("host"))
        .map(|(_, v)| v.trim().to_ascii_lowercase())
        .collect();
    Some(Request {
        method,
        path,
        host: hosts.first().cloned().unwrap_or_default(),
        hosts: hosts.len(),
    })
}

async fn serve(mut stream: TcpStream, hub: &Hub, slot: &Slot) -> std::io::Result<()> {
    let read = tokio::time::timeout(REQUEST_TIMEOUT, read_request(&mut stream));
    let request = tokio::select! {
        request = read => request,
        // Its place went to a newer connection: close without a word.
        () = slot.connection.evict.notified() => return Ok(()),
    };
    slot.connection.waiting.store(false, Ordering::Relaxed);
    let Ok(Some(request)) = request else {
        return respond(&mut stream, &BAD_REQUEST, b"bad request\n").await;
    };
    if request.hosts > 1 {
        return respond(&mut stream, &BAD_REQUEST, b"more than one Host header\n").await;
    }
    if hub.loopback_only && !is_loopback_host(&request.host) {
        let head = Head::new("403 Forbidden", "text/plain");
        return respond(&mut stream, &head, b"loopback only\n").await;
    }
    let head_only = match request.method.as_str() {
        "GET" => false,
        "HEAD" => true,
        _ => {
            let head = Head {
                allow: true,
                ..Head::new("405 Method Not Allowed", "text/plain")
            };
            return respond(&mut stream, &head, b"GET or HEAD only\n").await;
        }
    };
    let ok = |content_type| Head {
        head_only,
        ..Head::new("200 OK", content_type)
    };
    let not_found = Head {
        head_only,
        ..Head::new("404 Not Found", "text/plain")
    };
    match request.path.as_str() {
        "/" | "/index.html" => {
            let head = ok("text/html; charset=utf-8");
            respond(&mut stream, &head, PAGE.as_bytes()).await
        }
        "/frame.png" => {
            let frame = hub.frame_png.lock().ok().and_then(|f| f.clone());
            match frame {
                Some(png) => respond(&mut stream, &ok("image/png"), &png).await,
                None => respond(&mut stream, &not_found, b"no frame yet\n").await,
            }
        }
        "/events" if head_only => respond(&mut stream, &ok("text/event-stream"), b"").await,
        "/events" => events(stream, hub).await,
        _ => respond(&mut stream, &not_found, b"not found\n").await,
    }
}

/// The status line and headers of a response.
struct Head {
    status: &'static str,
    content_type: &'static str,
    /// A `HEAD` request: the head alone, its Content-Length that of the body.
    head_only: bool,
    /// Add `Allow: GET, HEAD` (a 405).
    allow: bool,
}

impl Head {
    const fn new(status: &'static str, content_type: &'static str) -> Self {
        Head {
            status,
            content_type,
            head_only: false,
            allow: false,
        }
    }
}

const BAD_REQUEST: Head = Head::new("400 Bad Request", "text/plain");

/// `Host:` names this machine: localhost, 127.x.x.x or `[::1]` (any port).
fn is_loopback_host(host: &str) -> bool {
    let name = match host.strip_prefix('[') {
        Some(rest) => rest.split(']').next().unwrap_or(""),
        None => host.split(':').next().unwrap_or(""),
    };
    name == "localhost"
        || name == "::1"
        || name
            .parse::<std::net::Ipv4Addr>()
            .is_ok_and(|ip| ip.is_loopback())
}

async fn respond(stream: &mut TcpStream, head: &Head, body: &[u8]) -> std::io::Result<()> {
    let text = format!(
        "HTTP/1.1 {}\r\nContent-Type: {}\r\nContent-Length: {}\r\n{}\
         Cache-Control: no-store\r\nX-Content-Type-Options: nosniff\r\nConnection: close\r\n\r\n",
        head.status,
        head.content_type,
        body.len(),
        if head.allow {
            "Allow: GET, HEAD\r\n"
        } else {
            ""
        },
    );
    let body = if head.head_only { &[][..] } else { body };
    let write = async {
        stream.write_all(text.as_bytes()).await?;
        stream.write_all(body).await?;
        stream.shutdown().await
    };
    tokio::time::timeout(WRITE_TIMEOUT, write)
        .await
        .unwrap_or(Ok(()))
}

/// One live page: its queue drained into the socket until it goes away.
async fn events(mut stream: TcpStream, hub: &Hub) -> std::io::Result<()> {
    let Some((id, mut rx)) = hub.join() else {
        let head = Head::new("503 Service Unavailable", "text/plain");
        return respond(&mut stream, &head, b"too many monitor pages open\n").await;
    };
    let hello = hub
        .hello
        .lock()
        .map(|h| h.clone())
        .unwrap_or_else(|_| Arc::from("{}"));
    let head = "HTTP/1.1 200 OK\r\nContent-Type: text/event-stream\r\nCache-Control: no-store\r\n\
                Connection: keep-alive\r\n\r\n";
    let result = async {
        send(
            &mut stream,
            &format!("{head}event: hello\ndata: {hello}\n\n"),
        )
        .await?;
        while let Some(message) = rx.recv().await {
            send(&mut stream, &format!("event: update\ndata: {message}\n\n")).await?;
        }
        Ok(())
    }
    .await;
    hub.leave(id);
    result
}

/// Writes within [`WRITE_TIMEOUT`]; a page that stops reading is dropped.
async fn send(stream: &mut TcpStream, text: &str) -> std::io::Result<()> {
    match tokio::time::timeout(WRITE_TIMEOUT, stream.write_all(text.as_bytes())).await {
        Ok(result) => result,
        Err(_) => Err(std::io::Error::new(
            std::io::ErrorKind::TimedOut,
            "monitor page not reading",
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn loopback_host_names() {
        for ok in [
            "127.0.0.1:8080",
            "localhost:1",
            "localhost",
            "[::1]:9000",
            "127.1.2.3",
        ] {
            assert!(is_loopback_host(ok), "{ok}");
        }
        for bad in [
            "evil.example:8080",
            "10.0.0.1:80",
            "",
            "[fe80::1]:80",
            "localhost.evil",
        ] {
            assert!(!is_loopback_host(bad), "{bad}");
        }
    }

    #[test]
    fn requests_with_two_hosts_are_told_apart() {
        let one = parse_request(b"HEAD /x?y=1 HTTP/1.1\r\nHost: LocalHost:80\r\n\r\nHost: b\r\n")
            .unwrap();
        assert_eq!(
            one,
            Request {
                method: "HEAD".into(),
                path: "/x".into(),
                host: "localhost:80".into(),
                hosts: 1,
            },
            "lines after the head are not headers"
        );
        let two = parse_request(b"GET / HTTP/1.1\r\nHost: localhost\r\nhost: evil.example\r\n\r\n")
            .unwrap();
        assert_eq!(two.hosts, 2);
        assert!(parse_request(b"\r\n\r\n").is_none());
    }

    #[test]
    fn a_full_house_closes_its_oldest_waiting_connection() {
        let connections = Arc::new(Connections::new(3));
        let slots: Vec<Slot> = (0..3).map(|_| connections.admit().unwrap()).collect();
        // The oldest is busy (its request arrived); the second oldest is waiting.
        slots[0].connection.waiting.store(false, Ordering::Relaxed);
        let fourth = connections
            .admit()
            .expect("a waiting connection makes room");
        let ids =
            |c: &Connections| -> Vec<u64> { c.open.lock().unwrap().iter().map(|c| c.id).collect() };
        assert_eq!(ids(&connections), [1, 3, 4]);
        // The evicted one is told (the notification waits for it if it is not listening).
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        let told = runtime.block_on(async {
            let notified = slots[1].connection.evict.notified();
            tokio::time::timeout(Duration::from_millis(100), notified).await
        });
        assert!(told.is_ok(), "the second connection was told to close");
        drop(slots);
        assert_eq!(ids(&connections), [4], "dropped slots free their places");
        // Every place busy: a new connection is turned away.
        fourth.connection.waiting.store(false, Ordering::Relaxed);
        let busy: Vec<Slot> = (0..2).map(|_| connections.admit().unwrap()).collect();
        for slot in &busy {
            slot.connection.waiting.store(false, Ordering::Relaxed);
        }
        assert!(connections.admit().is_none());
    }

    #[test]
    fn clients_are_capped_and_slow_ones_lose_updates() {
        let hub = Hub::new(2, true);
        let (a, mut rx_a) = hub.join().unwrap();
        let (_b, _rx_b) = hub.join().unwrap();
        assert!(hub.join().is_none(), "a third page is refused");
        for k in 0..QUEUE + 5 {
            hub.broadcast(&format!("{k}"));
        }
        // Each page holds QUEUE updates; the rest were dropped, not waited for.
        assert_eq!(hub.dropped_updates.load(Ordering::Relaxed), 2 * 5);
        assert_eq!(rx_a.try_recv().unwrap().as_ref(), "0");
        hub.leave(a);
        assert_eq!(hub.clients(), 1);
        assert!(hub.join().is_some(), "a place is free again");
    }
}
