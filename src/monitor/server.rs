//! A minimal HTTP/1.1 server for the monitor page on the monitor thread's tokio runtime:
//! `GET /` (the page, HTML and JavaScript inline), `GET /frame.png` (the latest overlay)
//! and `GET /events` (Server-Sent Events, one `update` about ten times a second).
//!
//! It protects the daemon rather than the client: every connection has a time limit to
//! send its request; live pages are capped (`max_clients`, then 503) and so are open
//! connections; each page has a small queue, and an update that does not fit is dropped
//! for that page (counted) instead of waiting; a page that stops reading is closed.
//! On loopback, requests must name a loopback host (no DNS rebinding from a web page).
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{mpsc, Semaphore};

/// The page, with its script and styles inline (no CDN, no network).
const PAGE: &str = include_str!("page.html");
/// Updates queued per page before new ones are dropped.
const QUEUE: usize = 8;
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

/// Accepts connections until the task is dropped.
pub async fn accept_loop(listener: TcpListener, hub: Arc<Hub>) {
    // Live pages plus a few short requests (page, frame) at a time.
    let connections = Arc::new(Semaphore::new(hub.max_clients + 8));
    loop {
        let Ok((stream, _)) = listener.accept().await else {
            tokio::time::sleep(Duration::from_millis(50)).await;
            continue;
        };
        let Ok(permit) = connections.clone().try_acquire_owned() else {
            drop(stream);
            continue;
        };
        let hub = hub.clone();
        tokio::spawn(async move {
            let _ = serve(stream, &hub).await;
            drop(permit);
        });
    }
}

/// The request line's method and path, and the Host header.
struct Request {
    method: String,
    path: String,
    host: String,
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
    let text = String::from_utf8_lossy(&buf);
    let mut lines = text.lines();
    let mut first = lines.next()?.split_whitespace();
    let (method, target) = (first.next()?.to_string(), first.next()?);
    let path = target.split('?').next().unwrap_or("/").to_string();
    let host = lines
        .filter_map(|l| l.split_once(':'))
        .find(|(k, _)| k.trim().eq_ignore_ascii_case("host"))
        .map_or(String::new(), |(_, v)| v.trim().to_ascii_lowercase());
    Some(Request { method, path, host })
}

async fn serve(mut stream: TcpStream, hub: &Hub) -> std::io::Result<()> {
    let Ok(Some(request)) = tokio::time::timeout(REQUEST_TIMEOUT, read_request(&mut stream)).await
    else {
        return respond(
            &mut stream,
            "400 Bad Request",
            "text/plain",
            b"bad request\n",
        )
        .await;
    };
    if hub.loopback_only && !is_loopback_host(&request.host) {
        return respond(
            &mut stream,
            "403 Forbidden",
            "text/plain",
            b"loopback only\n",
        )
        .await;
    }
    if request.method != "GET" {
        return respond(
            &mut stream,
            "405 Method Not Allowed",
            "text/plain",
            b"GET only\n",
        )
        .await;
    }
    match request.path.as_str() {
        "/" | "/index.html" => {
            respond(
                &mut stream,
                "200 OK",
                "text/html; charset=utf-8",
                PAGE.as_bytes(),
            )
            .await
        }
        "/frame.png" => {
            let frame = hub.frame_png.lock().ok().and_then(|f| f.clone());
            match frame {
                Some(png) => respond(&mut stream, "200 OK", "image/png", &png).await,
                None => {
                    respond(
                        &mut stream,
                        "404 Not Found",
                        "text/plain",
                        b"no frame yet\n",
                    )
                    .await
                }
            }
        }
        "/events" => events(stream, hub).await,
        _ => respond(&mut stream, "404 Not Found", "text/plain", b"not found\n").await,
    }
}

/// `Host:` names this machine: localhost, 127.x.x.x or [::1] (any port).
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

async fn respond(
    stream: &mut TcpStream,
    status: &str,
    content_type: &str,
    body: &[u8],
) -> std::io::Result<()> {
    let head = format!(
        "HTTP/1.1 {status}\r\nContent-Type: {content_type}\r\nContent-Length: {}\r\n\
         Cache-Control: no-store\r\nX-Content-Type-Options: nosniff\r\nConnection: close\r\n\r\n",
        body.len()
    );
    let write = async {
        stream.write_all(head.as_bytes()).await?;
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
        return respond(
            &mut stream,
            "503 Service Unavailable",
            "text/plain",
            b"too many monitor pages open\n",
        )
        .await;
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
