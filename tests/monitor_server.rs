//! The monitor's HTTP side against a running simulated lab, over raw sockets: the page is
//! self-contained, the frame is a PNG of the SEM's size, other host names are refused,
//! live pages are capped (503 past `max_clients`), a page that never reads does not
//! slow the others, and a closed page frees its place. Afterwards the recording has
//! overlay thumbnails and `nanoforce report` shows them with the run's loop figures.
//! With two probes in view the page's frame names each, with its numbers.
mod monitor_support;

use std::io::{Read, Write};
use std::net::TcpStream;
use std::process::Command;
use std::time::{Duration, Instant};

use monitor_support::*;

/// Opens `/events` and returns the stream after its response head.
fn open_events(port: u16) -> (TcpStream, String) {
    let mut s = TcpStream::connect(("127.0.0.1", port)).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    write!(s, "GET /events HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n").unwrap();
    let mut head = Vec::new();
    let mut byte = [0u8; 1];
    while !head.ends_with(b"\r\n\r\n") && s.read(&mut byte).unwrap_or(0) == 1 {
        head.push(byte[0]);
    }
    (s, String::from_utf8_lossy(&head).to_string())
}

/// Counts `update` events read from `s` during `span`.
fn count_updates(s: &mut TcpStream, span: Duration) -> usize {
    let deadline = Instant::now() + span;
    let mut text = Vec::new();
    let mut buf = [0u8; 65536];
    while Instant::now() < deadline {
        match s.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => text.extend_from_slice(&buf[..n]),
            Err(_) => break,
        }
    }
    String::from_utf8_lossy(&text)
        .matches("event: update\n")
        .count()
}

#[test]
fn monitor_serves_caps_pages_and_keeps_thumbnails() {
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let config = lab_config(
        dir.path(),
        &format!("listen = \"127.0.0.1:{port}\"\nmax_clients = 2\nthumbnail_every_s = 1.0"),
    );
    let mut daemon = start_daemon(dir.path(), &config, 7.0);
    wait_for_monitor(&mut daemon, port);

    let (head, page) = http_get(port, "/", &format!("127.0.0.1:{port}"));
    let page = String::from_utf8_lossy(&page);
    assert!(head.starts_with("HTTP/1.1 200"), "{head}");
    assert!(page.contains("new EventSource(\"/events\")"));
    assert!(
        !page.contains("http://") && !page.contains("https://"),
        "no CDN"
    );

    let (head, _) = http_get(port, "/", "evil.example:80");
    assert!(
        head.starts_with("HTTP/1.1 403"),
        "DNS rebinding guard: {head}"
    );
    let (head, _) = http_get(port, "/nothing", "localhost");
    assert!(head.starts_with("HTTP/1.1 404"), "{head}");

    // Two pages: one reads, one never does; a third is refused.
    let (mut reader, head) = open_events(port);
    assert!(
        head.starts_with("HTTP/1.1 200") && head.contains("text/event-stream"),
        "{head}"
    );
    let (stalled, _) = open_events(port);
    let (_, head) = open_events(port);
    assert!(head.starts_with("HTTP/1.1 503"), "third page: {head}");
    let updates = count_updates(&mut reader, Duration::from_secs(2));
    assert!(
        updates >= 15,
        "{updates} updates in 2 s beside a stalled page"
    );

    let (head, png) = http_get(port, "/frame.png", "localhost");
    assert!(head.contains("image/png"), "{head}");
    let frame = image::load_from_memory(&png).unwrap();
    assert_eq!((frame.width(), frame.height()), (640, 480));

    // Closing a page frees its place.
    drop(reader);
    drop(stalled);
    let deadline = Instant::now() + Duration::from_secs(3);
    loop {
        let (_, head) = open_events(port);
        if head.starts_with("HTTP/1.1 200") {
            break;
        }
        assert!(Instant::now() < deadline, "places never freed: {head}");
        std::thread::sleep(Duration::from_millis(200));
    }

    let status = daemon.wait().unwrap();
    assert!(status.success());
    let sessions = dir.path().join("state/sessions");
    let session = std::fs::read_dir(&sessions)
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    let thumbs = std::fs::read_dir(session.join("thumbnails"))
        .unwrap()
        .count();
    assert!(
        (4..=9).contains(&thumbs),
        "{thumbs} thumbnails in a 7 s run at 1/s"
    );

    let out = Command::new(BIN)
        .arg("report")
        .arg(&session)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let html = std::fs::read_to_string(session.join("report/report.html")).unwrap();
    assert!(html.contains("Recorded by nanoforce run"));
    assert!(html.contains("<td>Haptic loop</td>") && html.contains("Force error"));
    assert!(html.matches("data:image/png;base64,").count() >= 3 + 4);
}

/// Keeps `n` idle connections to `port` open until `stop`: one the server closes is
/// opened again at once (an attacker holding places). Returns how many it opened.
fn hold_idle_connections(
    port: u16,
    n: usize,
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
) -> std::thread::JoinHandle<usize> {
    std::thread::spawn(move || {
        let connect = || {
            let s = TcpStream::connect(("127.0.0.1", port)).ok()?;
            s.set_nonblocking(true).ok()?;
            Some(s)
        };
        let mut open: Vec<Option<TcpStream>> = (0..n).map(|_| connect()).collect();
        let mut opened = n;
        let mut buf = [0u8; 256];
        while !stop.load(std::sync::atomic::Ordering::Relaxed) {
            for slot in &mut open {
                let closed = match slot {
                    Some(s) => match s.read(&mut buf) {
                        Ok(_) => true,
                        Err(e) => e.kind() != std::io::ErrorKind::WouldBlock,
                    },
                    None => true,
                };
                if closed {
                    *slot = connect();
                    opened += 1;
                }
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        opened
    })
}

/// Idle sockets and a slowloris (a byte a second) cannot starve the page: with more idle
/// connections held open than the server keeps (each one the server closes is opened
/// again), 24 requests in a row are all answered, each within two seconds. Two `Host`
/// headers are a 400; `HEAD` gets the head alone; other methods a 405.
#[test]
fn idle_connections_do_not_starve_the_page() {
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let config = lab_config(dir.path(), &format!("listen = \"127.0.0.1:{port}\""));
    let mut daemon = start_daemon(dir.path(), &config, 20.0);
    wait_for_monitor(&mut daemon, port);
    let host = format!("127.0.0.1:{port}");

    // 16 idle connections: more than the 4 pages + 8 spare places the server keeps.
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let attacker = hold_idle_connections(port, 16, stop.clone());
    let slowloris = {
        let request = format!(
            "GET / HTTP/1.1\r\nHost: {host}\r\nX-Padding: {}",
            "a".repeat(60)
        );
        std::thread::spawn(move || {
            let Ok(mut s) = TcpStream::connect(("127.0.0.1", port)) else {
                return 0;
            };
            let mut sent = 0;
            for byte in request.bytes().take(12) {
                if s.write_all(&[byte]).is_err() {
                    break;
                }
                sent += 1;
                std::thread::sleep(Duration::from_secs(1));
            }
            sent
        })
    };
    std::thread::sleep(Duration::from_millis(500));
    let started = Instant::now();
    let mut slowest = Duration::ZERO;
    let mut answered = 0;
    for _ in 0..24 {
        let t = Instant::now();
        let (head, body) = http_raw(
            port,
            &format!("GET / HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n"),
            Duration::from_secs(3),
        );
        if head.starts_with("HTTP/1.1 200") && body.len() > 1000 {
            answered += 1;
        }
        slowest = slowest.max(t.elapsed());
    }
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    let opened = attacker.join().unwrap();
    eprintln!(
        "{answered} of 24 requests answered beside 16 held idle connections ({opened} opened) \
         and a slowloris: {:?} in all, slowest {slowest:?}",
        started.elapsed()
    );
    assert_eq!(answered, 24, "requests answered beside idle connections");
    assert!(
        slowest < Duration::from_secs(2),
        "slowest of 24 requests: {slowest:?}"
    );
    let _ = slowloris.join();

    let (head, _) = http_raw(
        port,
        &format!("GET / HTTP/1.1\r\nHost: {host}\r\nHost: evil.example\r\n\r\n"),
        Duration::from_secs(3),
    );
    assert!(head.starts_with("HTTP/1.1 400"), "two Host headers: {head}");
    let (head, body) = http_raw(
        port,
        &format!("HEAD / HTTP/1.1\r\nHost: {host}\r\n\r\n"),
        Duration::from_secs(3),
    );
    let length = head
        .lines()
        .find_map(|l| l.strip_prefix("Content-Length: "))
        .and_then(|v| v.trim().parse::<usize>().ok());
    assert!(head.starts_with("HTTP/1.1 200"), "HEAD: {head}");
    assert!(
        length.is_some_and(|n| n > 1000),
        "HEAD: the page's length: {head}"
    );
    assert!(body.is_empty(), "HEAD: no body, got {} bytes", body.len());
    let (head, _) = http_raw(
        port,
        &format!("POST / HTTP/1.1\r\nHost: {host}\r\n\r\n"),
        Duration::from_secs(3),
    );
    assert!(
        head.starts_with("HTTP/1.1 405") && head.contains("Allow: GET, HEAD"),
        "{head}"
    );
    let _ = daemon.kill();
    let _ = daemon.wait();
}

/// A page served beyond loopback (`allow_remote`) is announced as a warning.
#[test]
fn allow_remote_is_a_warning() {
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let config = lab_config(
        dir.path(),
        &format!("listen = \"0.0.0.0:{port}\"\nallow_remote = true"),
    );
    let daemon = start_daemon(dir.path(), &config, 1.0);
    let out = daemon.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    let line = err
        .lines()
        .find(|l| l.contains("monitor page"))
        .unwrap_or_else(|| panic!("no monitor line: {err}"));
    assert!(
        line.contains("WARN") && line.contains("allow_remote"),
        "{line}"
    );
}

/// The lab of two probes (config/sim-two-probes.toml) with its page on `port`: each
/// update's frame names both probes with their numbers and marks the felt one.
#[test]
fn the_page_shows_every_probe() {
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let two = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("config/sim-two-probes.toml"),
    )
    .unwrap();
    let config = dir.path().join("two.toml");
    std::fs::write(
        &config,
        format!("{two}\n[monitor]\nlisten = \"127.0.0.1:{port}\"\n"),
    )
    .unwrap();
    let mut daemon = start_daemon(dir.path(), &config, 5.0);
    wait_for_monitor(&mut daemon, port);
    let (mut events, head) = open_events(port);
    assert!(head.starts_with("HTTP/1.1 200"), "{head}");
    let deadline = Instant::now() + Duration::from_secs(4);
    let mut text = String::new();
    let mut buf = [0u8; 65536];
    let frame = loop {
        assert!(Instant::now() < deadline, "no update with a frame: {text}");
        let n = events.read(&mut buf).unwrap_or(0);
        text.push_str(&String::from_utf8_lossy(&buf[..n]));
        let found = text
            .lines()
            .filter_map(|l| l.strip_prefix("data: "))
            .filter_map(|d| serde_json::from_str::<serde_json::Value>(d).ok())
            .find_map(|u| Some(u["frame"].clone()).filter(|f| f["probes"].is_array()));
        if let Some(frame) = found {
            break frame;
        }
    };
    let probes = frame["probes"].as_array().unwrap();
    let names: Vec<&str> = probes.iter().filter_map(|p| p["name"].as_str()).collect();
    assert_eq!(names, ["left", "right"], "{frame}");
    let felt: Vec<bool> = probes.iter().map(|p| p["active"] == true).collect();
    assert_eq!(felt, [true, false], "the first probe is felt: {frame}");
    assert!(
        probes.iter().all(|p| p["confidence"].is_number()),
        "{frame}"
    );
    assert_eq!(
        frame["detected"], probes[0]["detected"],
        "the top level is the first's"
    );
    drop(events);
    assert!(daemon.wait().unwrap().success());
}
