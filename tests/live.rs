//! `orchestrator live` as a person meets it: in a real browser (Debian's Chromium over
//! chromedriver, driven by fantoccini) whose fake camera plays our own avatar performing a GOND
//! referencing gesture (filmed by `gesture film`), two checkpoints side by side, a filmed wave
//! that calls the intervention gesture; and at the socket: bad frames, a bad program, a closed
//! tab; the listening rules (HTTPS with a pinned certificate), a bad checkpoint; and who may use
//! the server (`live_security.rs`).

#[path = "live_security.rs"]
mod security;

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use gesthor_tests::{bin, capture_ready, dataset};
use rustls::client::danger::{HandshakeSignatureValid, ServerCertVerified, ServerCertVerifier};
use rustls::crypto::{CryptoProvider, verify_tls12_signature, verify_tls13_signature};
use rustls::pki_types::{CertificateDer, ServerName, UnixTime};
use rustls::{DigitallySignedStruct, SignatureScheme};
use serde_json::{Value, json};
use sha2::{Digest, Sha256};
use tokio_tungstenite::tungstenite::Message;
use worker::dataset::{Dataset, Verify};
use worker::gesture::Motion;
use worker::gesture::capture::{arm_activity, pointing_line};
use worker::humanoid::{Humanoid, Side};
use worker::program::Program;
use worker::scene::Split;

pub(crate) type Socket = tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

/// The server's next message.
pub(crate) async fn next(ws: &mut Socket) -> Value {
    loop {
        match ws.next().await.expect("the socket closed").expect("the socket failed") {
            Message::Text(t) => return serde_json::from_str(t.as_str()).unwrap(),
            _ => continue,
        }
    }
}

/// A small trained +Both checkpoint (a run directory), made once for the module.
fn trained_run() -> PathBuf {
    static RUN: OnceLock<(tempfile::TempDir, PathBuf)> = OnceLock::new();
    RUN.get_or_init(|| {
        let tmp = tempfile::tempdir().unwrap();
        let cfg = gesthor_tests::small_ppo_config(tmp.path(), "");
        let run = tmp.path().join("run");
        let o = Command::new(bin("orchestrator"))
            .args(["up", "--config", &cfg.display().to_string(), "--run-dir", &run.display().to_string()])
            .args(["--workers", "1", "--frames", "64"])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        (tmp, run)
    })
    .1
    .clone()
}

/// A running `orchestrator live` on a free port; killed when dropped, its log (stderr) shown
/// with the test's output.
pub(crate) struct Server {
    child: Child,
    pub(crate) url: String,
    pub(crate) port: u16,
    /// The token of the printed URL.
    pub(crate) token: Option<String>,
    /// The certificate's SHA-256 as printed, when it serves HTTPS.
    fingerprint: Option<String>,
    log: tempfile::NamedTempFile,
}

impl Server {
    pub(crate) fn start(out: &Path, extra: &[&str]) -> Server {
        let log = tempfile::NamedTempFile::new().unwrap();
        let mut child = Command::new(bin("orchestrator"))
            .args(["live", "--checkpoint", &trained_run().display().to_string()])
            .args(["--dataset", &dataset().display().to_string(), "--out", &out.display().to_string()])
            .args(extra)
            .stdout(Stdio::piped())
            .stderr(log.reopen().unwrap())
            .spawn()
            .unwrap();
        let mut said = BufReader::new(child.stdout.take().unwrap());
        let mut line = String::new();
        said.read_line(&mut line).unwrap();
        let url = line.split_whitespace().find(|w| w.contains("://")).unwrap_or_else(|| panic!("{line}"));
        let (scheme, rest) = url.split_once("://").unwrap();
        let port = rest.split(['/', ':']).nth(1).unwrap().parse().unwrap();
        // over HTTPS, a second line: the certificate's fingerprint
        let fingerprint = (scheme == "https").then(|| {
            let mut line = String::new();
            said.read_line(&mut line).unwrap();
            assert!(line.contains("SHA-256 fingerprint"), "{line}");
            line.split_whitespace().last().unwrap().to_string()
        });
        let token = url.split_once("?token=").map(|(_, t)| t.to_string());
        Server { child, url: url.to_string(), port, token, fingerprint, log }
    }

    /// `path` with the token the server printed, as its page asks.
    pub(crate) fn at(&self, path: &str) -> String {
        match &self.token {
            Some(t) => format!("{path}{}token={t}", if path.contains('?') { '&' } else { '?' }),
            None => path.to_string(),
        }
    }

    /// What the server has written to stderr so far.
    pub(crate) fn log(&self) -> String {
        std::fs::read_to_string(self.log.path()).unwrap()
    }

    /// How many sessions have a simulator running.
    pub(crate) fn open_sessions(&self) -> u64 {
        let body = http_get(self.port, &self.at("/sessions"));
        serde_json::from_str::<Value>(&body).unwrap()["open"].as_u64().unwrap()
    }

    /// The server's `learner` children (one per checkpoint a session started).
    pub(crate) fn learners(&self) -> usize {
        children(self.child.id()).iter().filter(|c| c.as_str() == "learner").count()
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        // captured by the test harness: shown when the test fails
        eprint!("{}", self.log());
    }
}

/// The command names of `pid`'s children.
fn children(pid: u32) -> Vec<String> {
    let mut out = Vec::new();
    for e in std::fs::read_dir("/proc").unwrap().flatten() {
        let Ok(stat) = std::fs::read_to_string(e.path().join("stat")) else { continue };
        // pid (comm) state ppid ...
        let Some((head, rest)) = stat.rsplit_once(") ") else { continue };
        let ppid: u32 = rest.split_whitespace().nth(1).and_then(|p| p.parse().ok()).unwrap_or(0);
        if ppid == pid {
            out.push(head.split_once(" (").map(|(_, c)| c.to_string()).unwrap_or_default());
        }
    }
    out
}

/// The body of a GET on loopback.
fn http_get(port: u16, path: &str) -> String {
    body(http_response(port, "GET", path, b""))
}

/// What a request in plain HTTP on loopback is answered with (whatever came before an error).
pub(crate) fn http_response(port: u16, method: &str, path: &str, body: &[u8]) -> String {
    http_response_with(port, method, path, &[("Host", "localhost")], body)
}

/// [`http_response`] with these headers.
pub(crate) fn http_response_with(port: u16, method: &str, path: &str, headers: &[(&str, &str)], body: &[u8]) -> String {
    let mut s = TcpStream::connect(("127.0.0.1", port)).unwrap();
    let headers: String = headers.iter().map(|(k, v)| format!("{k}: {v}\r\n")).collect();
    // a server that refuses the request (plain HTTP to an HTTPS listener) may close the
    // connection before the request is written: a broken pipe is its answer, not a failure
    let sent = write!(s, "{method} {path} HTTP/1.0\r\n{headers}Content-Length: {}\r\n\r\n", body.len())
        .and_then(|()| s.write_all(body));
    if let Err(e) = sent {
        let refused = matches!(e.kind(), std::io::ErrorKind::BrokenPipe | std::io::ErrorKind::ConnectionReset);
        assert!(refused, "writing the request: {e}");
    }
    let mut bytes = Vec::new();
    let _ = s.read_to_end(&mut bytes);
    String::from_utf8_lossy(&bytes).into_owned()
}

/// The body of an HTTP response.
pub(crate) fn body(response: String) -> String {
    response.split_once("\r\n\r\n").map(|(_, b)| b.to_string()).unwrap_or(response)
}

/// The status code of an HTTP response.
pub(crate) fn status(response: &str) -> &str {
    response.split_whitespace().nth(1).unwrap_or_default()
}

/// A TLS client's check of the server's certificate: only the one whose SHA-256 is the
/// fingerprint printed is accepted (as a person comparing the browser's warning would).
#[derive(Debug)]
struct Pinned {
    fingerprint: String,
    provider: Arc<CryptoProvider>,
}

impl ServerCertVerifier for Pinned {
    fn verify_server_cert(
        &self,
        end_entity: &CertificateDer<'_>,
        _: &[CertificateDer<'_>],
        _: &ServerName<'_>,
        _: &[u8],
        _: UnixTime,
    ) -> Result<ServerCertVerified, rustls::Error> {
        if sha256_colons(end_entity) == self.fingerprint {
            Ok(ServerCertVerified::assertion())
        } else {
            Err(rustls::Error::General("not the certificate whose fingerprint was printed".into()))
        }
    }

    fn verify_tls12_signature(
        &self,
        message: &[u8],
        cert: &CertificateDer<'_>,
        dss: &DigitallySignedStruct,
    ) -> Result<HandshakeSignatureValid, rustls::Error> {
        verify_tls12_signature(message, cert, dss, &self.provider.signature_verification_algorithms)
    }

    fn verify_tls13_signature(
        &self,
        message: &[u8],
        cert: &CertificateDer<'_>,
        dss: &DigitallySignedStruct,
    ) -> Result<HandshakeSignatureValid, rustls::Error> {
        verify_tls13_signature(message, cert, dss, &self.provider.signature_verification_algorithms)
    }

    fn supported_verify_schemes(&self) -> Vec<SignatureScheme> {
        self.provider.signature_verification_algorithms.supported_schemes()
    }
}

/// SHA-256 as browsers show it: `AB:CD:…`.
fn sha256_colons(der: &[u8]) -> String {
    Sha256::digest(der).iter().map(|b| format!("{b:02X}")).collect::<Vec<_>>().join(":")
}

/// What a GET over HTTPS on loopback is answered with (status line and all), through a client
/// that trusts only the certificate of `fingerprint`; an error when the handshake fails.
async fn https_get(port: u16, fingerprint: &str, path: &str) -> std::io::Result<String> {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let pinned = Pinned { fingerprint: fingerprint.to_string(), provider: provider.clone() };
    let config = rustls::ClientConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .unwrap()
        .dangerous()
        .with_custom_certificate_verifier(Arc::new(pinned))
        .with_no_client_auth();
    let tcp = tokio::net::TcpStream::connect(("127.0.0.1", port)).await?;
    let name = ServerName::try_from("localhost").unwrap();
    let mut tls = tokio_rustls::TlsConnector::from(Arc::new(config)).connect(name, tcp).await?;
    tls.write_all(format!("GET {path} HTTP/1.0\r\nHost: localhost\r\n\r\n").as_bytes()).await?;
    let mut bytes = Vec::new();
    // a server that closes without TLS's goodbye has still said all it had to
    if let Err(e) = tls.read_to_end(&mut bytes).await
        && (e.kind() != std::io::ErrorKind::UnexpectedEof || bytes.is_empty())
    {
        return Err(e);
    }
    Ok(String::from_utf8_lossy(&bytes).into_owned())
}

/// Waits for `what` to hold, failing with `why` if it never does (a guard against a hang, not
/// a speed bound: a busy two-core machine gets minutes).
fn eventually(why: &str, mut what: impl FnMut() -> bool) {
    let t = Instant::now();
    while !what() {
        assert!(t.elapsed() < Duration::from_secs(180), "{why}");
        std::thread::sleep(Duration::from_millis(200));
    }
}

/// Whether Chromium and chromedriver are here; under CI, or where setup.sh installed them, they must be.
pub(crate) fn browser_ready() -> bool {
    let found = ["/usr/bin/chromium", "/usr/bin/chromedriver"].iter().all(|p| Path::new(p).is_file());
    let required =
        std::env::var_os("CI").is_some() || std::env::var("GESTHOR_BROWSER_REQUIRED").is_ok_and(|v| v == "1");
    if !found && required {
        panic!("chromium or chromedriver is missing, but CI or scripts/setup.sh installs them");
    }
    if !found {
        eprintln!("skipped: no chromium and chromedriver (scripts/setup.sh installs them)");
    }
    found
}

/// The fake camera's video: our avatar performing val:1's referencing gesture (`gesture film`),
/// or intervention gesture `intervention`, each frame on a grey 320×240 canvas, as YUV4MPEG2
/// (I420, which Chromium reads). Chromium plays it at 30 frames a second, over and over.
pub(crate) fn filmed_y4m(dir: &Path, intervention: Option<usize>) -> PathBuf {
    let frames = dir.join("film");
    let k = intervention.map(|k| vec!["--intervention".to_string(), k.to_string()]).unwrap_or_default();
    let o = Command::new(bin("orchestrator"))
        .args(["gesture", "film", "val:1", "--dataset", &dataset().display().to_string()])
        .args(["--size", "240", "--out", &frames.display().to_string()])
        .args(k)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let path = dir.join("cam.y4m");
    let mut y4m = b"YUV4MPEG2 W320 H240 F30:1 Ip A1:1 C420\n".to_vec();
    for t in 0..100 {
        let img = image::open(frames.join(format!("{t:03}.png"))).unwrap().to_rgb8();
        let rgb = |x: u32, y: u32| {
            let p = if (40..280).contains(&x) { img.get_pixel(x - 40, y).0 } else { [128; 3] };
            p.map(f32::from)
        };
        y4m.extend_from_slice(b"FRAME\n");
        let (mut u, mut v) = (Vec::new(), Vec::new());
        for y in 0..240 {
            for x in 0..320 {
                let [r, g, b] = rgb(x, y);
                y4m.push((16.0 + 0.257 * r + 0.504 * g + 0.098 * b).round() as u8);
            }
        }
        for y in (0..240).step_by(2) {
            for x in (0..320).step_by(2) {
                let [r, g, b] = rgb(x, y);
                u.push((128.0 - 0.148 * r - 0.291 * g + 0.439 * b).round() as u8);
                v.push((128.0 + 0.439 * r - 0.368 * g - 0.071 * b).round() as u8);
            }
        }
        y4m.extend(u);
        y4m.extend(v);
    }
    std::fs::write(&path, y4m).unwrap();
    path
}

/// The gesturing arm of program `i` in the dataset at `dir` and its shoulder → wrist line
/// during the hold (where the arm's activity is within 80% of its peak, as `bench capture`
/// reads it), in the program's own skeleton's axes.
fn held_arm(dir: &Path, i: usize) -> (Side, [f32; 3]) {
    let ds = Dataset::open(dir, Verify::Quick).unwrap();
    let file = ds.require(Split::Val).unwrap();
    let p = Program::from_record(i as u64, &file.record(i)).unwrap();
    let motion = Motion::from_flat(&file.motion(i)).unwrap();
    let human = Humanoid::seeded(p.seed);
    let sk = human.skeleton();
    let (side, act) = arm_activity(sk, &motion);
    let act = &act[if side == Side::Left { 0 } else { 1 }];
    let peak = act.iter().copied().fold(0.0f32, f32::max);
    let line = (0..act.len())
        .filter(|&t| act[t] >= 0.8 * peak)
        .map(|t| pointing_line(sk, motion.frame(t), side))
        .reduce(|a, b| a + b)
        .unwrap()
        .normalize();
    (side, [line.x, line.y, line.z])
}

/// chromedriver on a free port; killed when dropped.
pub(crate) struct Driver(Child, u16);

impl Driver {
    pub(crate) fn start() -> Driver {
        let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
        let child = Command::new("/usr/bin/chromedriver")
            .arg(format!("--port={port}"))
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        eventually("chromedriver never listened", || TcpStream::connect(("127.0.0.1", port)).is_ok());
        Driver(child, port)
    }
}

impl Drop for Driver {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Headless Chromium through `driver`, its fake camera playing `cam`, in a profile of its own,
/// with `extra` flags.
pub(crate) async fn chromium(driver: &Driver, cam: &Path, profile: &Path, extra: &[&str]) -> fantoccini::Client {
    let (cam, profile) = (
        format!("--use-file-for-fake-video-capture={}", cam.display()),
        format!("--user-data-dir={}", profile.display()),
    );
    let mut args = vec![
        "--headless=new",
        "--no-sandbox",
        "--use-fake-ui-for-media-stream",
        "--use-fake-device-for-media-stream",
        &cam,
        "--disable-gpu",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--no-first-run",
        "--window-size=1400,1050",
        &profile,
    ];
    args.extend(extra);
    let mut caps = serde_json::Map::new();
    caps.insert("goog:chromeOptions".into(), json!({"binary": "/usr/bin/chromium", "args": args}));
    fantoccini::ClientBuilder::new(hyper_util::client::legacy::connect::HttpConnector::new())
        .capabilities(caps)
        .connect(&format!("http://127.0.0.1:{}", driver.1))
        .await
        .expect("chromedriver starts Chromium")
}

/// Evaluates `js` (an expression) in the page.
pub(crate) async fn page(c: &fantoccini::Client, js: &str) -> Value {
    c.execute(&format!("return {js};"), vec![]).await.unwrap()
}

pub(crate) async fn wait_page(c: &fantoccini::Client, why: &str, js: &str) -> Value {
    let t = Instant::now();
    loop {
        let v = page(c, js).await;
        if !v.is_null() && v != json!(false) {
            return v;
        }
        let errors = page(c, "window.live && window.live.errors").await;
        assert!(t.elapsed() < Duration::from_secs(180), "{why} (the page's errors: {errors})");
        tokio::time::sleep(Duration::from_millis(250)).await;
    }
}

pub(crate) async fn click(c: &fantoccini::Client, id: &str) {
    c.find(fantoccini::Locator::Id(id)).await.unwrap().click().await.unwrap();
}

#[test]
fn a_person_gestures_at_the_robot_through_the_webcam_in_a_real_browser() {
    if !browser_ready() || !capture_ready() {
        return;
    }
    let _g = gesthor_tests::serial();
    let tmp = tempfile::tempdir().unwrap();
    let cam = filmed_y4m(tmp.path(), None);
    let out = tmp.path().join("live");
    let server = Server::start(&out, &["--listen", "127.0.0.1:0"]);
    let driver = Driver::start();
    let profile = tmp.path().join("profile");
    let rt = tokio::runtime::Runtime::new().unwrap();
    let (record, person_record) = rt.block_on(async {
        let c = chromium(&driver, &cam, &profile, &[]).await;
        c.goto(&server.url).await.unwrap();
        wait_page(&c, "the page never got its session", "window.live && window.live.session").await;

        // the camera's frames reach the landmark model, and a gesture is captured from them
        click(&c, "camera").await;
        wait_page(&c, "the webcam's frames were not read", "window.live.framesSeen >= 10").await;
        click(&c, "capture").await;
        let captured = wait_page(&c, "no gesture was captured from the webcam", "window.live.captured").await;
        assert!(captured["person_frames"].as_u64().unwrap() * 2 >= captured["frames"].as_u64().unwrap(), "{captured}");

        // an episode on the captured gesture, run at speed to its end
        page(&c, "(document.getElementById('gesture').value = 'webcam', document.getElementById('index').value = '1')").await;
        click(&c, "start").await;
        wait_page(&c, "the episode did not start", "window.live.episode").await;
        page(&c, "(document.getElementById('speed').value = '30', true)").await;
        click(&c, "run").await;
        wait_page(&c, "the episode never ended", "window.live.ended").await;
        let end = page(&c, "window.live.sides[0].end").await;
        let path = page(&c, "window.live.sides[0].path").await;
        let steps = path.as_array().unwrap();
        assert_eq!(steps.len() as u64, end["steps"].as_u64().unwrap(), "one step shown per action taken");
        assert!(steps.iter().any(|p| p != &steps[0]), "the robot never moved: {path}");
        assert_eq!(page(&c, "document.querySelectorAll('#episodes tr').length").await, json!(1));

        // two checkpoints side by side on the program's own gesture (here the same one twice:
        // two policies, two simulators); the person calls the intervention gesture with the
        // key, and both robots see it at the same step, beside the rule's call
        let shown = |k: usize| format!("document.querySelector('#side-{k} .shown').textContent");
        page(&c, "(document.getElementById('gesture').value = 'program', document.getElementById('interventions').value = 'person', document.getElementById('versus').value = '0')").await;
        click(&c, "start").await;
        let sides = wait_page(&c, "the side-by-side episode did not start", "window.live.episode && window.live.episode.sides.length == 2 && window.live.episode.sides").await;
        assert_eq!((sides[0]["number"].as_u64(), sides[1]["number"].as_u64()), (Some(2), Some(3)), "{sides}");
        click(&c, "step").await;
        wait_page(&c, "no first step", "window.live.sides.every(s => s.steps == 1)").await;
        for k in 0..2 {
            assert_eq!(page(&c, &shown(k)).await, json!("referencing"));
        }
        click(&c, "intervene").await;
        click(&c, "step").await;
        click(&c, "step").await;
        wait_page(&c, "no third step", "window.live.sides.every(s => s.steps == 3)").await;
        for k in 0..2 {
            assert_eq!(page(&c, &shown(k)).await, json!("intervention"), "side {k}");
        }
        // both robots' views and policies are on the page
        let views = "[...document.querySelectorAll('.side .rgb, .side .depth')].filter(i => i.naturalWidth > 0).length";
        wait_page(&c, "the two robots' views were not shown", &format!("{views} == 4")).await;
        assert_eq!(page(&c, "document.querySelectorAll('.side .bar').length").await, json!(8));
        click(&c, "run").await;
        wait_page(&c, "the side-by-side episode never ended", "window.live.ended").await;
        let ends = page(&c, "window.live.sides.map(s => s.end)").await;
        let lengths = page(&c, "window.live.sides.map(s => s.path.length)").await;
        for k in 0..2 {
            assert_eq!(lengths[k], ends[k]["steps"], "side {k}: one step shown per action taken");
        }
        assert_eq!(page(&c, "document.querySelectorAll('#episodes tr').length").await, json!(3));
        // the camera was on all along: a pointing arm holds still, it does not wave
        let seen = page(&c, "[window.live.framesSeen, window.live.wavingFrames]").await;
        assert_eq!(seen[1], json!(0), "[frames read, read as a wave]: {seen}");
        assert_eq!(page(&c, "window.live.errors").await, json!([]), "the page's errors");
        c.close().await.unwrap();
        let record = |e: &Value| PathBuf::from(e["record"].as_str().unwrap());
        (record(&end), [record(&ends[0]), record(&ends[1])])
    });

    // the arm captured from the webcam points where the filmed one did, within the closed
    // loop's error (`gesture capture` on the same film, tests/capture.rs): the webcam's frames
    // are timed by their arrival, so the holds are compared, not frame by frame
    let (filmed_side, filmed) = held_arm(&dataset(), 1);
    let (captured_side, captured) = held_arm(&record.join("dataset"), 0);
    assert_eq!(captured_side, filmed_side, "the captured arm is the filmed one");
    let cos: f32 = filmed.iter().zip(&captured).map(|(a, b)| a * b).sum();
    let deg = f64::from(cos.clamp(-1.0, 1.0).acos().to_degrees());
    assert!(deg < crate::capture::BOUND_DEG, "the captured arm's hold is {deg:.1}° from the filmed one's");

    // every record replays to the same path and the same gestures; each side is an episode of
    // its own that names the one beside it
    for r in [&record, &person_record[0], &person_record[1]] {
        let o = Command::new(bin("orchestrator")).args(["live", "replay", &r.display().to_string()]).output().unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        assert!(String::from_utf8_lossy(&o.stdout).contains("the same path"));
        assert!(r.join("dataset/manifest.json").is_file() && r.join("episode.json").is_file());
    }
    for (r, beside) in person_record.iter().zip([3, 2]) {
        let steps = std::fs::read_to_string(r.join("steps.jsonl")).unwrap();
        assert!(steps.lines().any(|l| l.contains("\"shown\":2")), "the person's call is recorded");
        let episode: Value = serde_json::from_str(&std::fs::read_to_string(r.join("episode.json")).unwrap()).unwrap();
        assert_eq!(episode["beside"], beside, "{}", r.display());
    }
    // the closed tab freed its session
    eventually("the closed tab's session kept running", || server.open_sessions() == 0);
}

/// The intervention gesture filmed for the wave test: its right hand, 27 cm above the shoulder,
/// swings sideways over 25 cm. Of the 20, K = 0–5 and 17 read as a wave (the landmark model on
/// the film at 10 and 30 frames a second: in 37–68% of 1.5 s windows; K = 1 in the most), the
/// others raise no hand above the shoulder or swing it by 5 cm at most, and the referencing
/// film in no window. A wave is read from the last 1.5 s or the last 6 frames read, whichever
/// holds more (`webcam::remember`), so a busy machine reading few frames a second reads it too;
/// the capture tests that also run the landmark model take the serial lock.
const WAVE: usize = 1;

#[test]
fn a_filmed_wave_at_the_webcam_calls_the_intervention_gesture_in_a_real_browser() {
    if !browser_ready() || !capture_ready() {
        return;
    }
    let _g = gesthor_tests::serial();
    let tmp = tempfile::tempdir().unwrap();
    let cam = filmed_y4m(tmp.path(), Some(WAVE));
    let server = Server::start(&tmp.path().join("live"), &["--listen", "127.0.0.1:0"]);
    let driver = Driver::start();
    let rt = tokio::runtime::Runtime::new().unwrap();
    let record = rt.block_on(async {
        let c = chromium(&driver, &cam, &tmp.path().join("profile"), &[]).await;
        c.goto(&server.url).await.unwrap();
        wait_page(&c, "the page never got its session", "window.live && window.live.session").await;
        // an episode whose interventions are the person's: before the camera, the robot is
        // shown the program's referencing gesture
        let shown = "document.querySelector('#side-0 .shown').textContent";
        page(&c, "(document.getElementById('gesture').value = 'program', document.getElementById('interventions').value = 'person', document.getElementById('index').value = '1')").await;
        click(&c, "start").await;
        wait_page(&c, "the episode did not start", "window.live.episode").await;
        click(&c, "step").await;
        wait_page(&c, "no first step", "window.live.sides[0].steps == 1").await;
        assert_eq!(page(&c, shown).await, json!("referencing"));

        // the camera on: the filmed wave is read as one, and no key is pressed
        let t = Instant::now();
        click(&c, "camera").await;
        wait_page(&c, "the filmed wave was never read as a wave", "window.live.wavingFrames >= 1").await;
        let seen = page(&c, "window.live.framesSeen").await.as_f64().unwrap();
        eprintln!("a wave read after {seen} webcam frames in {:.1} s", t.elapsed().as_secs_f64());
        let t = Instant::now();
        // the call reaches the robot at the next observation, as the key's does
        click(&c, "step").await;
        click(&c, "step").await;
        wait_page(&c, "no third step", "window.live.sides[0].steps == 3").await;
        assert_eq!(page(&c, shown).await, json!("intervention"));
        page(&c, "(document.getElementById('speed').value = '30', true)").await;
        click(&c, "run").await;
        wait_page(&c, "the episode never ended", "window.live.ended").await;
        let read = page(&c, "window.live.framesSeen").await.as_f64().unwrap() - seen;
        eprintln!("then {read} frames read in {:.1} s of the episode", t.elapsed().as_secs_f64());
        let errors = page(&c, "window.live.errors").await;
        assert_eq!(errors, json!([]), "the page's errors");
        let end = page(&c, "window.live.sides[0].end").await;
        c.close().await.unwrap();
        PathBuf::from(end["record"].as_str().unwrap())
    });
    // the record has the call, from the third step on, and replays to the same path
    let steps = std::fs::read_to_string(record.join("steps.jsonl")).unwrap();
    let shown: Vec<bool> = steps.lines().map(|l| l.contains("\"shown\":2")).collect();
    assert_eq!(shown[..3], [false, false, true], "{steps}");
    let o = Command::new(bin("orchestrator")).args(["live", "replay", &record.display().to_string()]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stdout).contains("the same path"));
}

#[test]
fn bad_frames_and_programs_get_one_error_each_and_a_closed_tab_frees_its_session() {
    let _g = gesthor_tests::serial();
    let tmp = tempfile::tempdir().unwrap();
    let server = Server::start(&tmp.path().join("live"), &["--listen", "127.0.0.1:0"]);
    assert!(http_get(server.port, &server.at("/")).contains("GesTHOR live"));
    let rt = tokio::runtime::Runtime::new().unwrap();
    rt.block_on(async {
        let ws_url = format!("ws://127.0.0.1:{}{}", server.port, server.at("/ws"));
        let (mut ws, _) = tokio_tungstenite::connect_async(ws_url).await.unwrap();
        let hello = next(&mut ws).await;
        assert_eq!(hello["type"], "hello", "{hello}");
        let error = |m: Value| {
            assert_eq!(m["type"], "error", "{m}");
            m["message"].as_str().unwrap().to_string()
        };
        let refused = |m: Value| {
            assert_eq!(m["type"], "frame_refused", "{m}");
            m["message"].as_str().unwrap().to_string()
        };
        ws.send(Message::Binary(b"GIF89a not a jpeg".to_vec().into())).await.unwrap();
        assert!(refused(next(&mut ws).await).contains("not a JPEG"));
        let mut big = vec![0u8; 600 * 1024];
        big[..3].copy_from_slice(&[0xFF, 0xD8, 0xFF]);
        ws.send(Message::Binary(big.into())).await.unwrap();
        assert!(refused(next(&mut ws).await).contains("at most"));
        ws.send(Message::Text(r#"{"type":"launch"}"#.into())).await.unwrap();
        assert!(error(next(&mut ws).await).contains("does not know"));
        ws.send(Message::Text(r#"{"type":"start","program":"val:99999","checkpoint":0}"#.into())).await.unwrap();
        assert!(error(next(&mut ws).await).contains("val:99999"));
        if capture_ready() {
            // two frames at once: the second comes before the first was answered
            let png = tmp.path().join("grey.png");
            image::RgbImage::from_pixel(240, 240, image::Rgb([90, 90, 90])).save(&png).unwrap();
            let jpeg = orchestrator::commands::bench::live::webcam_jpeg(&png).unwrap();
            ws.send(Message::Binary(jpeg.clone().into())).await.unwrap();
            ws.send(Message::Binary(jpeg.into())).await.unwrap();
            let (a, b) = (next(&mut ws).await, next(&mut ws).await);
            assert!(refused(a).contains("before the last one was answered"));
            assert_eq!(b["type"], "frame_seen", "{b}");
        }
        ws.send(Message::Text(r#"{"type":"start","program":"val:0","checkpoint":0,"versus":5}"#.into())).await.unwrap();
        assert!(error(next(&mut ws).await).contains("versus 5"));
        // the session goes on: two robots side by side, a step each
        ws.send(Message::Text(r#"{"type":"start","program":"val:0","checkpoint":0,"versus":0}"#.into())).await.unwrap();
        let episode = next(&mut ws).await;
        assert_eq!(episode["type"], "episode");
        assert_eq!(episode["sides"].as_array().unwrap().len(), 2, "{}", episode["sides"]);
        ws.send(Message::Text(r#"{"type":"step"}"#.into())).await.unwrap();
        let (a, b) = (next(&mut ws).await, next(&mut ws).await);
        assert_eq!((a["type"].as_str(), b["type"].as_str()), (Some("step"), Some("step")));
        assert_eq!((a["side"].as_u64(), b["side"].as_u64()), (Some(0), Some(1)));
        assert_eq!(server.open_sessions(), 1);
        assert_eq!(server.learners(), 2);
        ws.close(None).await.unwrap();
    });
    eventually("the closed tab's session kept running", || server.open_sessions() == 0);
    eventually("the closed tab's policy kept running", || server.learners() == 0);
}

#[test]
fn listening_beyond_loopback_asks_for_a_token_over_https_and_bad_files_are_named() {
    let tmp = tempfile::tempdir().unwrap();
    let rt = tokio::runtime::Runtime::new().unwrap();
    // beyond loopback: HTTPS with a certificate made at start, the token in the printed URL
    let server = Server::start(&tmp.path().join("live"), &["--listen", "0.0.0.0:0"]);
    assert!(server.url.starts_with("https://") && server.url.contains("?token="), "{}", server.url);
    let fingerprint = server.fingerprint.clone().unwrap();
    rt.block_on(async {
        let page = https_get(server.port, &fingerprint, &server.at("/")).await.unwrap();
        assert!(status(&page) == "200" && page.contains("GesTHOR live"), "{page}");
        for path in ["/", "/sessions", "/?token=0123"] {
            let refused = https_get(server.port, &fingerprint, path).await.unwrap();
            assert!(status(&refused) == "403" && refused.contains("token"), "{path}: {refused}");
        }
        // a client that expects another certificate does not get through
        assert!(https_get(server.port, &sha256_colons(b"another certificate"), "/").await.is_err());
    });
    // plain HTTP to the HTTPS port gets no page
    assert!(!http_response(server.port, "GET", &server.at("/"), b"").contains("GesTHOR live"));
    drop(server);

    // --insecure: plain HTTP beyond loopback, still with the token
    let server = Server::start(&tmp.path().join("live"), &["--listen", "0.0.0.0:0", "--insecure"]);
    assert!(server.url.starts_with("http://") && server.url.contains("?token="), "{}", server.url);
    assert!(server.fingerprint.is_none());
    assert!(http_get(server.port, "/").contains("token"));
    assert!(http_get(server.port, "/sessions").contains("token"));
    assert!(http_get(server.port, &server.at("/")).contains("GesTHOR live"));
    drop(server);

    // a certificate and key of one's own, on loopback: HTTPS with them, the token as always
    let names = vec!["localhost".to_string()];
    let key = rcgen::KeyPair::generate().unwrap();
    let cert = rcgen::CertificateParams::new(names).unwrap().self_signed(&key).unwrap();
    let (cert_pem, key_pem) = (tmp.path().join("cert.pem"), tmp.path().join("key.pem"));
    std::fs::write(&cert_pem, cert.pem()).unwrap();
    std::fs::write(&key_pem, key.serialize_pem()).unwrap();
    let (c, k) = (cert_pem.display().to_string(), key_pem.display().to_string());
    let server =
        Server::start(&tmp.path().join("live"), &["--listen", "127.0.0.1:0", "--tls-cert", &c, "--tls-key", &k]);
    assert!(server.url.starts_with("https://localhost:") && server.url.contains("?token="), "{}", server.url);
    assert_eq!(server.fingerprint.as_deref(), Some(sha256_colons(cert.der()).as_str()));
    let page = rt.block_on(https_get(server.port, &sha256_colons(cert.der()), &server.at("/"))).unwrap();
    assert!(page.contains("GesTHOR live"), "{page}");
    drop(server);

    // a missing or garbled certificate or key: one line naming the file and its flag
    let garbled = tmp.path().join("garbled.pem");
    std::fs::write(&garbled, "-----BEGIN CERTIFICATE-----\nnot base64 at all!\n-----END CERTIFICATE-----\n").unwrap();
    let missing = tmp.path().join("missing.pem").display().to_string();
    let g = garbled.display().to_string();
    for (args, named) in [
        (["--tls-cert", &missing, "--tls-key", &k], ("--tls-cert", "missing.pem")),
        (["--tls-cert", &g, "--tls-key", &k], ("--tls-cert", "garbled.pem")),
        (["--tls-cert", &c, "--tls-key", &c], ("--tls-key", "cert.pem")),
        (["--tls-cert", &c, "--tls-key", &missing], ("--tls-key", "missing.pem")),
    ] {
        let o = Command::new(bin("orchestrator"))
            .args(["live", "--checkpoint", &trained_run().display().to_string(), "--listen", "0.0.0.0:0"])
            .args(["--dataset", &dataset().display().to_string()])
            .args(args)
            .output()
            .unwrap();
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success() && e.contains(named.0) && e.contains(named.1), "{args:?}: {e}");
        assert_eq!(e.trim().lines().count(), 1, "{e}");
    }

    // a run whose checkpoint is not one: the learner cannot load it
    let run = tmp.path().join("badrun");
    std::fs::create_dir_all(run.join("checkpoints")).unwrap();
    std::fs::copy(trained_run().join("config.toml"), run.join("config.toml")).unwrap();
    let bad = run.join("checkpoints/bad.safetensors");
    std::fs::write(&bad, b"not a checkpoint").unwrap();
    let o = Command::new(bin("orchestrator"))
        .args(["live", "--checkpoint", &bad.display().to_string(), "--dataset", &dataset().display().to_string()])
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && e.contains("bad.safetensors") && e.trim().lines().count() == 1, "{e}");
}
