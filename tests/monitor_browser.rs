//! The monitor page in a real browser: the simulated lab runs with `[monitor]` on, headless
//! Chromium (Debian's `chromium`) opens the page, and the test reads the page's state
//! twice through the DevTools protocol: the force plot must have moved on with new data
//! (more updates, later samples, a different picture on the canvas, the line drawn in its
//! colour) and the frame image must have loaded at the frame's size.
//!
//! Without Chromium the test fails under CI (CI=true; .ci/run installs it) and is
//! skipped with a loud message elsewhere. With NANOFORCE_SCREENSHOTS=DIR it also saves
//! DIR/monitor.png (the README's picture).
mod monitor_support;

use std::time::{Duration, Instant};

use monitor_support::*;
use serde_json::Value;

/// The page's own record of what it received and drew (see page.html's `probe`).
fn probe(page: &mut DevTools) -> Value {
    page.eval(
        "(() => { const d = Object.assign({}, document.getElementById('probe').dataset); \
         const c = document.getElementById('force'); \
         const px = c.getContext('2d').getImageData(0, 0, c.width, c.height).data; \
         let blue = 0, sum = 0; \
         for (let i = 0; i < px.length; i += 4) { \
           if (px[i] < 90 && px[i+1] > 90 && px[i+1] < 150 && px[i+2] > 150) blue++; \
           sum = (sum * 31 + px[i] + 7 * px[i+1] + 13 * px[i+2]) % 1000000007; } \
         d.blue = blue; d.canvas = sum; \
         d.state = document.getElementById('state').textContent; \
         return d; })()",
    )
}

fn num(v: &Value, key: &str) -> f64 {
    match &v[key] {
        Value::String(s) => s.parse().unwrap_or(f64::NAN),
        Value::Number(n) => n.as_f64().unwrap_or(f64::NAN),
        _ => f64::NAN,
    }
}

#[test]
fn monitor_page_shows_the_frame_and_a_live_force_plot_in_chromium() {
    let Some(chromium) = chromium() else {
        let msg = "CHROMIUM NOT FOUND: the monitor's browser test did not run \
                   (apt-get install chromium, or set NANOFORCE_CHROMIUM)";
        if std::env::var_os("CI").is_some() {
            panic!("{msg}");
        }
        eprintln!("\n!!!!!!!! {msg} !!!!!!!!\n");
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let config = lab_config(dir.path(), &format!("listen = \"127.0.0.1:{port}\""));
    let screenshots = std::env::var_os("NANOFORCE_SCREENSHOTS");
    // For the README's picture the run goes on into the press.
    let seconds = if screenshots.is_some() { 30.0 } else { 9.0 };
    // The browser starts first: its start-up burst of CPU would otherwise land on the
    // simulated lab's first seconds.
    let browser = Browser::launch(&chromium, "about:blank", 1400, 820);
    let mut page = browser.page();
    let mut daemon = start_daemon(dir.path(), &config, seconds);
    wait_for_monitor(&mut daemon, port);
    let url = format!("http://127.0.0.1:{port}/");
    page.call("Page.navigate", serde_json::json!({ "url": url }));
    // Wait for the first live update and a loaded frame.
    let deadline = Instant::now() + Duration::from_secs(10);
    let first = loop {
        let p = probe(&mut page);
        if num(&p, "updates") >= 3.0 && num(&p, "frameLoads") >= 1.0 {
            break p;
        }
        assert!(Instant::now() < deadline, "the page got no updates: {p}");
        std::thread::sleep(Duration::from_millis(100));
    };
    std::thread::sleep(Duration::from_millis(2500));
    let second = probe(&mut page);

    // Live: about ten updates a second, and the force samples move on in time.
    let updates = num(&second, "updates") - num(&first, "updates");
    assert!(
        updates >= 15.0,
        "{updates} updates in 2.5 s: {first} -> {second}"
    );
    let advanced_s = num(&second, "lastT") - num(&first, "lastT");
    assert!(
        (2.0..4.0).contains(&advanced_s),
        "newest force sample moved {advanced_s} s in 2.5 s"
    );
    // The plot was redrawn with the new data: a different picture, with its line.
    assert_ne!(
        first["canvas"], second["canvas"],
        "the force plot did not change"
    );
    assert!(num(&second, "drawn") > 100.0, "points drawn: {second}");
    assert!(num(&second, "blue") > 300.0, "force line pixels: {second}");
    // The frame shows: the overlay PNG loaded at the simulated SEM's size, and updates.
    // The size is the one the page recorded when the image last loaded: read while the
    // next frame loads, the element's own size is 0x0.
    assert_eq!(second["frameSize"], "640x480", "{second}");
    assert!(
        num(&second, "frameLoads") > num(&first, "frameLoads"),
        "{second}"
    );
    assert_eq!(second["state"], "engaged");

    if let Some(out) = screenshots {
        let pressing = "pts.length > 0 && pts[pts.length - 1][1] > 2000";
        let deadline = Instant::now() + Duration::from_secs(25);
        while page.eval(pressing) != Value::Bool(true) && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(200));
        }
        let shot = page.call(
            "Page.captureScreenshot",
            serde_json::json!({ "format": "png" }),
        );
        let png = base64_decode(shot["data"].as_str().unwrap());
        std::fs::write(std::path::Path::new(&out).join("monitor.png"), png).unwrap();
    }
    drop(page);
    drop(browser);
    let status = daemon.wait().unwrap();
    assert!(status.success(), "the daemon run failed");
}
