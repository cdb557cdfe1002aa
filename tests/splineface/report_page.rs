//! `report.html` in a real browser: the demo's page opened by headless Chromium, driven over
//! WebDriver (Debian's `chromium` and `chromium-driver`; `.ci/run` installs them). Ignored
//! by default: it needs those two programs.
//!
//! The page records its own load (script and console errors, images that did not load, how
//! much of the viewer's picture is not background) into `#self-check`; the test also reads
//! the browser's log and takes a screenshot of its own, and looks at the viewer's pixels in
//! it.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::{Value, json};

const CHROMIUM: &str = "/usr/bin/chromium";
const CHROMEDRIVER: &str = "/usr/bin/chromedriver";

/// A WebDriver session on a chromedriver of our own; both end when it is dropped.
struct Browser {
    driver: Child,
    port: u16,
    session: String,
}

/// One HTTP/1.1 request to `127.0.0.1:port` (`Connection: close`): the response's JSON body.
fn http(port: u16, method: &str, path: &str, body: Option<&Value>) -> Result<Value, String> {
    let mut stream = TcpStream::connect(("127.0.0.1", port)).map_err(|e| e.to_string())?;
    stream
        .set_read_timeout(Some(Duration::from_secs(120)))
        .map_err(|e| e.to_string())?;
    let body = body.map(Value::to_string).unwrap_or_default();
    let request = format!(
        "{method} {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nContent-Type: application/json\r\n\
         Content-Length: {}\r\nConnection: close\r\n\r\n{body}",
        body.len()
    );
    stream.write_all(request.as_bytes()).map_err(|e| e.to_string())?;
    // Read the headers, then exactly the body they announce (chromedriver keeps the
    // connection open whatever the request asks).
    let mut response = Vec::new();
    let mut buffer = [0u8; 65536];
    let split = loop {
        if let Some(split) = response.windows(4).position(|w| w == b"\r\n\r\n") {
            break split;
        }
        let n = stream.read(&mut buffer).map_err(|e| e.to_string())?;
        if n == 0 {
            return Err("the connection closed before the headers' end".into());
        }
        response.extend_from_slice(&buffer[..n]);
    };
    let headers = String::from_utf8_lossy(&response[..split]).to_ascii_lowercase();
    let mut content = response[split + 4..].to_vec();
    let length = headers
        .lines()
        .find_map(|l| l.strip_prefix("content-length:"))
        .and_then(|v| v.trim().parse::<usize>().ok());
    let chunked = headers.contains("transfer-encoding: chunked");
    loop {
        let complete = match length {
            Some(length) => content.len() >= length,
            None if chunked => content.ends_with(b"0\r\n\r\n"),
            None => false,
        };
        if complete {
            break;
        }
        let n = stream.read(&mut buffer).map_err(|e| e.to_string())?;
        if n == 0 {
            break;
        }
        content.extend_from_slice(&buffer[..n]);
    }
    if chunked {
        let mut joined = Vec::new();
        let mut rest = content.as_slice();
        loop {
            let line_end = rest.windows(2).position(|w| w == b"\r\n").ok_or("bad chunk")?;
            let size = usize::from_str_radix(String::from_utf8_lossy(&rest[..line_end]).trim(), 16)
                .map_err(|e| e.to_string())?;
            if size == 0 {
                break;
            }
            joined.extend_from_slice(&rest[line_end + 2..line_end + 2 + size]);
            rest = &rest[line_end + 2 + size + 2..];
        }
        content = joined;
    }
    serde_json::from_slice(&content).map_err(|e| format!("{e}: {}", String::from_utf8_lossy(&content)))
}

impl Browser {
    fn start() -> Browser {
        let port = {
            let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
            listener.local_addr().unwrap().port()
        };
        let driver = Command::new(CHROMEDRIVER)
            .arg(format!("--port={port}"))
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("chromedriver starts (apt-get install chromium chromium-driver)");
        let start = Instant::now();
        while http(port, "GET", "/status", None).is_err() {
            assert!(
                start.elapsed() < Duration::from_secs(30),
                "chromedriver did not answer"
            );
            std::thread::sleep(Duration::from_millis(100));
        }
        let profile = std::env::temp_dir().join(format!("splineface-chromium-{}", std::process::id()));
        let capabilities = json!({ "capabilities": { "alwaysMatch": {
            "browserName": "chrome",
            "goog:loggingPrefs": { "browser": "ALL" },
            "goog:chromeOptions": {
                "binary": CHROMIUM,
                "args": [
                    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                    "--disable-background-networking", "--disable-component-update", "--disable-sync",
                    // WebGL in software: SwiftShader through ANGLE.
                    "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                    "--window-size=1280,1000",
                    format!("--user-data-dir={}", profile.display()),
                ],
            },
        }}});
        let answer = http(port, "POST", "/session", Some(&capabilities)).unwrap();
        let session = answer["value"]["sessionId"]
            .as_str()
            .unwrap_or_else(|| panic!("no session: {answer}"))
            .to_owned();
        Browser {
            driver,
            port,
            session,
        }
    }

    fn call(&self, method: &str, path: &str, body: Option<Value>) -> Value {
        let path = format!("/session/{}{path}", self.session);
        let answer = http(self.port, method, &path, body.as_ref()).unwrap();
        assert!(
            answer["value"].get("error").is_none(),
            "{method} {path}: {answer}"
        );
        answer["value"].clone()
    }

    fn run(&self, script: &str) -> Value {
        self.call(
            "POST",
            "/execute/sync",
            Some(json!({ "script": script, "args": [] })),
        )
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        let _ = http(self.port, "DELETE", &format!("/session/{}", self.session), None);
        let _ = self.driver.kill();
        let _ = self.driver.wait();
    }
}

fn demo_page() -> PathBuf {
    let dir = std::env::temp_dir().join(format!("splineface-report-page-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let run = Command::new(env!("CARGO_BIN_EXE_splineface"))
        .args(["demo", "--photos", "4", "--out"])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    dir.join("report.html")
}

/// The share of a region's pixels that differ clearly from its corner pixel.
fn not_background(image: &image::RgbImage, [x, y, w, h]: [u32; 4]) -> f64 {
    let corner = image.get_pixel(x + 2, y + 2);
    let mut differ = 0usize;
    for py in y..(y + h).min(image.height()) {
        for px in x..(x + w).min(image.width()) {
            let p = image.get_pixel(px, py);
            let d: i32 = (0..3)
                .map(|c| (i32::from(p[c]) - i32::from(corner[c])).abs())
                .sum();
            differ += usize::from(d > 24);
        }
    }
    differ as f64 / f64::from(w * h)
}

fn open(browser: &Browser, page: &Path) -> Value {
    browser.call(
        "POST",
        "/url",
        Some(json!({ "url": format!("file://{}", page.display()) })),
    );
    let start = Instant::now();
    loop {
        let answer = browser.run(
            "const e = document.getElementById('self-check'); return e.dataset.done ? e.textContent : null;",
        );
        if let Some(text) = answer.as_str() {
            return serde_json::from_str(text).unwrap();
        }
        assert!(
            start.elapsed() < Duration::from_secs(90),
            "the page's self-check did not finish"
        );
        std::thread::sleep(Duration::from_millis(250));
    }
}

#[test]
#[ignore = "needs Chromium and ChromeDriver (apt-get install chromium chromium-driver; .ci/run does)"]
fn the_demo_report_page_loads_and_draws_the_face_in_chromium() {
    let page = demo_page();
    let browser = Browser::start();
    let check = open(&browser, &page);

    // The page's own record of its load. Warnings are allowed: on a loaded machine the
    // viewer warns that an animation frame came late ("rAF timed out"), which is no fault.
    assert_eq!(check["errors"], json!([]), "errors while loading: {check}");
    assert_eq!(check["broken"], json!([]), "images that did not load: {check}");
    // The demo's page has overlays (4), RASL's six pictures, the texture's three, the depth's
    // two, the preview and the comparison's three.
    assert!(check["images"].as_u64().unwrap() >= 18, "{check}");
    assert_eq!(check["viewer"]["loaded"], json!(true), "{check}");
    assert_eq!(check["viewer"]["textured"], json!(true), "{check}");
    let drawn = check["viewer"]["drawn"].as_f64().unwrap();
    assert!(drawn > 0.15, "the viewer's picture is {drawn} face: {check}");

    // The browser's own log: no error from any source.
    let log = browser.call("POST", "/se/log", Some(json!({ "type": "browser" })));
    for entry in log.as_array().unwrap() {
        assert_ne!(entry["level"], "SEVERE", "browser log: {entry}");
    }

    // A screenshot of our own: the viewer's box holds a face, not only its background.
    let rect = browser.run(
        "const r = document.getElementById('viewer').getBoundingClientRect(); return [r.x, r.y, r.width, r.height];",
    );
    let rect: Vec<u32> = rect
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap().round() as u32)
        .collect();
    let shot = browser.call("GET", "/screenshot", None);
    let png = base64::decode(shot.as_str().unwrap()).unwrap();
    let screenshot = image::load_from_memory(&png).unwrap().to_rgb8();
    let face = not_background(&screenshot, [rect[0], rect[1], rect[2], rect[3]]);
    assert!(face > 0.15, "the viewer shows {face} face in the screenshot");

    // Shaded: the switch takes the texture off and the face is still drawn.
    let shaded = browser.run(
        "document.querySelector('#look input[value=shaded]').click(); \
         const m = document.getElementById('viewer').model.materials[0]; \
         return m.pbrMetallicRoughness.baseColorTexture.texture === null;",
    );
    assert_eq!(shaded, json!(true));
}

#[test]
#[ignore = "needs Chromium and ChromeDriver (apt-get install chromium chromium-driver; .ci/run does)"]
fn a_report_page_with_almost_no_outputs_still_opens_cleanly() {
    // Only a report.json with a dropped photo: no face, no pictures.
    let files = vec![(
        PathBuf::from("report.json"),
        serde_json::to_vec(&json!({
            "photos_used": ["a"],
            "photos_dropped": [{ "name": "b", "reason": "its <landmarks> disagree" }],
        }))
        .unwrap(),
    )];
    let html = splineface::report::report_page(
        &files,
        &splineface::report::PageOptions {
            title: "almost nothing".into(),
            reconstruction: PathBuf::new(),
            comparison: None,
        },
    );
    let dir = std::env::temp_dir().join(format!("splineface-report-bare-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let page = dir.join("report.html");
    std::fs::write(&page, html).unwrap();
    let browser = Browser::start();
    let check = open(&browser, &page);
    assert_eq!(check["errors"], json!([]), "{check}");
    assert_eq!(check["viewer"], Value::Null, "{check}");
    let text = browser.run("return document.body.innerText;");
    let text = text.as_str().unwrap();
    assert!(text.contains("its <landmarks> disagree"), "{text}");
    assert!(text.contains("No face.glb"), "{text}");
}
