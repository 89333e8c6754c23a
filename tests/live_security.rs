//! Who may use `orchestrator live`, as the pages of other sites and the programs of this machine
//! meet it: the token printed at start asked on loopback too, a page of another site refused at
//! the socket and the uploads, a name rebound to this machine (DNS rebinding) refused on every
//! route; beyond loopback the same; and a tab beyond `--max-sessions` told the server is full,
//! in a real browser too, which gets back in by the cookie without the token in its URL.

use std::path::PathBuf;

use futures_util::{SinkExt, StreamExt};
use serde_json::{Value, json};
use tokio_tungstenite::tungstenite::client::IntoClientRequest;
use tokio_tungstenite::tungstenite::http::{HeaderName, HeaderValue};
use tokio_tungstenite::tungstenite::{self, Message};

use super::{
    Driver, Server, Socket, body, browser_ready, chromium, eventually, http_response, http_response_with, next, page,
    status, wait_page,
};

/// The server's socket at `path` (its port on loopback), asked for with these headers (Host,
/// Origin): the socket and its first message, or the refusal's status and body.
async fn open(port: u16, path: &str, headers: &[(&str, &str)]) -> Result<(Socket, Value), (u16, String)> {
    let mut request = format!("ws://127.0.0.1:{port}{path}").into_client_request().unwrap();
    for (k, v) in headers {
        request.headers_mut().insert(HeaderName::from_bytes(k.as_bytes()).unwrap(), HeaderValue::from_str(v).unwrap());
    }
    match tokio_tungstenite::connect_async(request).await {
        Ok((mut ws, _)) => {
            let first = next(&mut ws).await;
            Ok((ws, first))
        }
        Err(tungstenite::Error::Http(r)) => {
            let why = String::from_utf8_lossy(r.body().as_deref().unwrap_or_default()).into_owned();
            Err((r.status().as_u16(), why))
        }
        Err(e) => panic!("opening {path}: {e}"),
    }
}

/// A 403 whose body is one line saying `why`.
fn refused(answer: Result<(Socket, Value), (u16, String)>, why: &str) {
    let (code, body) = answer.map(|(_, m)| m.to_string()).expect_err("the socket opened");
    assert!(code == 403 && body.trim().lines().count() == 1 && body.contains(why), "{code}: {body}");
}

/// A POST of a file to a session, with these headers: the status and the body.
fn upload(port: u16, path: &str, headers: &[(&str, &str)]) -> (String, String) {
    let r = http_response_with(port, "POST", path, headers, b"not a motion");
    (status(&r).to_string(), body(r))
}

#[test]
fn on_loopback_the_token_is_asked_and_pages_of_other_sites_and_names_are_refused() {
    let _g = gesthor_tests::serial();
    let tmp = tempfile::tempdir().unwrap();
    let server = Server::start(&tmp.path().join("live"), &["--listen", "127.0.0.1:0"]);
    let port = server.port;
    assert!(server.url.starts_with(&format!("http://localhost:{port}/?token=")), "{}", server.url);
    let (host, own) = (format!("localhost:{port}"), format!("http://localhost:{port}"));
    let evil = format!("evil.example:{port}");

    // without the token: nothing, whatever the route
    for path in ["/", "/sessions"] {
        let r = http_response(port, "GET", path, b"");
        assert!(status(&r) == "403" && body(r.clone()).contains("token"), "{path}: {r}");
    }
    // the page opened with it gets a cookie that lets it in again without it
    let r = http_response(port, "GET", &server.at("/"), b"");
    assert!(status(&r) == "200" && r.contains("GesTHOR live"), "{r}");
    let set = r.lines().find(|l| l.to_ascii_lowercase().starts_with("set-cookie:")).expect("a cookie");
    assert!(set.contains("HttpOnly") && set.contains("SameSite=Strict"), "{set}");
    let cookie = set.split_once(':').unwrap().1.trim().split(';').next().unwrap().to_string();
    let r = http_response_with(port, "GET", "/sessions", &[("Host", &host), ("Cookie", &cookie)], b"");
    assert_eq!(status(&r), "200", "{r}");

    let rt = tokio::runtime::Runtime::new().unwrap();
    rt.block_on(async {
        refused(open(port, "/ws", &[("Host", &host), ("Origin", &own)]).await, "token");
        // a page of another site, or of another server on this machine, has the token: still
        // refused; the cookie does not help it either
        for origin in ["http://evil.example", "http://localhost:1", "null"] {
            refused(open(port, &server.at("/ws"), &[("Host", &host), ("Origin", origin)]).await, "another site");
            refused(open(port, "/ws", &[("Host", &host), ("Origin", origin), ("Cookie", &cookie)]).await, "another");
        }
        // a name rebound to this machine: its page's origin is its own, its Host not the server's
        let rebound = format!("http://{evil}");
        refused(open(port, &server.at("/ws"), &[("Host", &evil), ("Origin", &rebound)]).await, "--allow-host");
        for path in ["/", "/sessions", "/style.css"] {
            let r = http_response_with(port, "GET", &server.at(path), &[("Host", &evil)], b"");
            assert!(status(&r) == "403" && body(r.clone()).contains("--allow-host"), "{path}: {r}");
        }

        // the server's own page, by its loopback names: a session
        for name in ["127.0.0.1", "[::1]"] {
            let r = http_response_with(port, "GET", &server.at("/"), &[("Host", &format!("{name}:{port}"))], b"");
            assert!(status(&r) == "200" && r.contains("GesTHOR live"), "{name}: {r}");
        }
        let (mut ws, hello) = open(port, &server.at("/ws"), &[("Host", &host), ("Origin", &own)]).await.unwrap();
        assert_eq!(hello["type"], "hello", "{hello}");
        let to = |name: &str| format!("/upload?session={}&name={name}", hello["session"].as_str().unwrap());

        // uploads: without the token, or from another site's page, refused; the page's own reaches
        // its session, and the session hears of no other
        let (code, why) = upload(port, &to("untokened.csv"), &[("Host", &host), ("Origin", &own)]);
        assert!(code == "403" && why.contains("token"), "{code}: {why}");
        let (code, why) =
            upload(port, &server.at(&to("evil.csv")), &[("Host", &host), ("Origin", "http://evil.example")]);
        assert!(code == "403" && why.contains("another site"), "{code}: {why}");
        let (code, why) = upload(port, &server.at(&to("notes.csv")), &[("Host", &host), ("Origin", &own)]);
        assert_eq!(code, "202", "{why}");
        let e = next(&mut ws).await;
        assert!(e["type"] == "error" && e["message"].as_str().unwrap().contains("notes.csv"), "{e}");
        ws.close(None).await.unwrap();
    });

    // each refusal is a line of the server's log, naming what it refused
    let log = server.log();
    let line = |a: &str, b: &str| log.lines().any(|l| l.contains("refused") && l.contains(a) && l.contains(b));
    assert!(line("GET /ws", "origin http://evil.example is not"), "{log}");
    assert!(line("GET /ws", "origin http://localhost:1 is not"), "{log}");
    assert!(line("POST /upload", "origin http://evil.example is not"), "{log}");
    assert!(line("GET /sessions", &format!("Host {evil} is not")), "{log}");
    assert!(line("POST /upload", "token"), "{log}");
}

#[test]
fn beyond_loopback_the_socket_and_the_uploads_ask_for_the_token_and_a_known_name() {
    let _g = gesthor_tests::serial();
    let tmp = tempfile::tempdir().unwrap();
    let extra = ["--listen", "0.0.0.0:0", "--insecure", "--allow-host", "gesthor.example"];
    let server = Server::start(&tmp.path().join("live"), &extra);
    let port = server.port;
    // the machine's name, as printed
    let name = server.url.split("://").nth(1).unwrap().split(':').next().unwrap().to_string();
    let rt = tokio::runtime::Runtime::new().unwrap();
    rt.block_on(async {
        for host in [format!("{name}:{port}"), format!("gesthor.example:{port}")] {
            let own = format!("http://{host}");
            let headers = [("Host", host.as_str()), ("Origin", own.as_str())];
            refused(open(port, "/ws", &headers).await, "token");
            let (code, why) = upload(port, "/upload?session=session-001&name=a.csv", &headers);
            assert!(code == "403" && why.contains("token"), "{code}: {why}");
            // with it: the server's own page, by the machine's name or one allowed
            let (mut ws, hello) = open(port, &server.at("/ws"), &headers).await.unwrap();
            assert_eq!(hello["type"], "hello", "{hello}");
            let path = server.at(&format!("/upload?session={}&name=a.csv", hello["session"].as_str().unwrap()));
            assert_eq!(upload(port, &path, &headers).0, "202");
            ws.close(None).await.unwrap();
        }
        let r = http_response_with(port, "GET", &server.at("/"), &[("Host", &format!("evil.example:{port}"))], b"");
        assert_eq!(status(&r), "403", "{r}");
    });
}

#[test]
fn a_tab_beyond_max_sessions_is_told_the_server_is_full_and_starts_nothing() {
    let _g = gesthor_tests::serial();
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("live");
    let server = Server::start(&out, &["--listen", "127.0.0.1:0", "--max-sessions", "1"]);
    let port = server.port;
    let ws_path = server.at("/ws");
    let rt = tokio::runtime::Runtime::new().unwrap();
    let third = rt.block_on(async {
        // the one session, running an episode: its simulator and a policy
        let (mut first, hello) = open(port, &ws_path, &[]).await.unwrap();
        assert_eq!(hello["session"], "session-001", "{hello}");
        first.send(Message::Text(r#"{"type":"start","program":"val:0","checkpoint":0}"#.into())).await.unwrap();
        assert_eq!(next(&mut first).await["type"], "episode");
        assert_eq!(server.learners(), 1);

        // a second tab: told why, in one message, and its socket closes
        let (mut second, full) = open(port, &ws_path, &[]).await.unwrap();
        assert_eq!(full["type"], "full", "{full}");
        assert!(full["message"].as_str().unwrap().contains("runs 1 at once"), "{full}");
        let closed = second.next().await;
        assert!(matches!(closed, None | Some(Ok(Message::Close(_))) | Some(Err(_))), "{closed:?}");
        // ... and nothing started for it
        assert_eq!((server.open_sessions(), server.learners()), (1, 1));

        // the first tab closed, its place is free: the next tab's session is the second
        first.close(None).await.unwrap();
        eventually("the closed tab's session kept running", || server.open_sessions() == 0);
        let (third, hello) = open(port, &ws_path, &[]).await.unwrap();
        assert_eq!(hello["session"], "session-002", "{hello}");
        third
    });
    assert!(server.log().contains("refused a session"), "{}", server.log());
    let sessions: Vec<PathBuf> = std::fs::read_dir(&out).unwrap().flatten().map(|e| e.path()).collect();
    assert_eq!(sessions, [out.join("session-001")], "the session folders");

    if !browser_ready() {
        return;
    }
    // the page says so, where the status is shown; once the place is free it gets in again by
    // the cookie it was given, without the token in its URL
    let driver = Driver::start();
    let bare = format!("http://localhost:{port}/");
    rt.block_on(async {
        let no_camera = tmp.path().join("no-camera.y4m");
        let c = chromium(&driver, &no_camera, &tmp.path().join("profile"), &[]).await;
        c.goto(&server.url).await.unwrap();
        let why = wait_page(&c, "the full server's page never said so", "window.live && window.live.full").await;
        assert!(why.as_str().unwrap().contains("runs 1 at once"), "{why}");
        let shown = page(&c, "document.getElementById('status').textContent").await;
        assert_eq!(shown, why);
        drop(third);
        eventually("the closed tab's session kept running", || server.open_sessions() == 0);
        c.goto(&bare).await.unwrap();
        let session =
            wait_page(&c, "the page without the token got no session", "window.live && window.live.session").await;
        assert_eq!(session, json!("session-003"));
        assert_eq!(page(&c, "window.live.full").await, Value::Null);
        c.close().await.unwrap();
    });
}
