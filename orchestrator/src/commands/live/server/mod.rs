//! The HTTP side of `orchestrator live`: the page's three files (built into the binary), the
//! WebSocket each tab opens, a tab's uploads, and how many sessions are open; every route behind
//! [`access`]'s checks. Each socket gets a session on a thread of its own ([`super::session`]),
//! as many at once as the server runs; the socket task only carries messages both ways, and an
//! upload reaches the session by its name.

pub mod access;

use std::collections::HashMap;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use axum::Router;
use axum::body::Bytes;
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::{DefaultBodyLimit, Query, State};
use axum::http::{StatusCode, header};
use axum::middleware::from_fn_with_state;
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use serde::Deserialize;

use access::Access;

use super::gesture::MAX_UPLOAD_BYTES;
use super::session::{self, Input, Shared};
use super::wire::{CheckpointInfo, ToPage, ToServer};

const INDEX: &str = include_str!("../page/index.html");
const APP: &str = include_str!("../page/app.js");
const STYLE: &str = include_str!("../page/style.css");

/// What every request sees.
pub struct App {
    pub shared: Arc<Shared>,
    /// Sessions whose simulator is still running.
    pub open: AtomicUsize,
    /// Sessions run at once, at most (`--max-sessions`).
    max_sessions: usize,
    started: AtomicUsize,
    /// Each open session's input, by name: where its tab's uploads go.
    inputs: Mutex<HashMap<String, std::sync::mpsc::Sender<Input>>>,
}

impl App {
    pub fn new(shared: Arc<Shared>, max_sessions: usize) -> App {
        App {
            shared,
            open: AtomicUsize::new(0),
            max_sessions,
            started: AtomicUsize::new(0),
            inputs: Mutex::new(HashMap::new()),
        }
    }
}

pub fn router(app: Arc<App>, access: Access) -> Router {
    Router::new()
        .route("/", get(|| async { ([(header::CONTENT_TYPE, "text/html; charset=utf-8")], INDEX) }))
        .route("/app.js", get(|| async { ([(header::CONTENT_TYPE, "text/javascript")], APP) }))
        .route("/style.css", get(|| async { ([(header::CONTENT_TYPE, "text/css")], STYLE) }))
        .route("/sessions", get(sessions))
        .route("/ws", get(socket))
        .route("/upload", post(upload).layer(DefaultBodyLimit::max(MAX_UPLOAD_BYTES)))
        .layer(from_fn_with_state(Arc::new(access), access::check))
        .with_state(app)
}

async fn sessions(State(app): State<Arc<App>>) -> Response {
    format!("{{\"open\":{}}}", app.open.load(Ordering::SeqCst)).into_response()
}

#[derive(Deserialize)]
struct UploadTo {
    session: String,
    name: String,
}

/// A file for a session's person's gesture (`POST /upload?session=S&name=N`, the file as the
/// body): accepted here, read by the session, answered on its socket.
async fn upload(State(app): State<Arc<App>>, Query(q): Query<UploadTo>, body: Bytes) -> Response {
    let input = app.inputs.lock().expect("not poisoned").get(&q.session).cloned();
    let Some(input) = input else {
        return (StatusCode::NOT_FOUND, format!("no session {} is open\n", q.session)).into_response();
    };
    match input.send(Input::Upload { name: q.name, bytes: body.to_vec() }) {
        Ok(()) => {
            (StatusCode::ACCEPTED, "read by the session: its answer comes on the page's socket\n").into_response()
        }
        Err(_) => (StatusCode::NOT_FOUND, format!("session {} has closed\n", q.session)).into_response(),
    }
}

async fn socket(ws: WebSocketUpgrade, State(app): State<Arc<App>>) -> Response {
    ws.on_upgrade(move |s| carry(s, app))
}

/// A free `session-NNN` folder name under the output folder.
fn session_id(app: &App) -> String {
    loop {
        let n = app.started.fetch_add(1, Ordering::SeqCst) + 1;
        let id = format!("session-{n:03}");
        if !app.shared.out.join(&id).exists() {
            return id;
        }
    }
}

/// Takes one of the sessions the server runs at once, if one is free.
fn reserve(app: &App) -> bool {
    app.open.fetch_update(Ordering::SeqCst, Ordering::SeqCst, |n| (n < app.max_sessions).then_some(n + 1)).is_ok()
}

/// Tells a tab that no session is free for it, and closes its socket.
async fn full(mut socket: WebSocket, max: usize) {
    eprintln!("live: a tab was refused a session: {max} are open, as many as --max-sessions allows");
    let message =
        format!("no session is free: the server runs {max} at once, all in use; close another tab of it or try later");
    if send(&mut socket, &ToPage::Full { message }).await.is_ok() {
        let _ = socket.send(Message::Close(None)).await;
    }
}

/// What a tab may choose, for its session `id`.
fn hello(shared: &Shared, id: &str) -> ToPage {
    ToPage::Hello {
        checkpoints: shared
            .checkpoints
            .iter()
            .map(|c| CheckpointInfo {
                name: c.name.clone(),
                method: c.cfg.run.method.label().to_string(),
                size: [c.cfg.env.width, c.cfg.env.height],
            })
            .collect(),
        splits: shared.dataset.manifest.splits.iter().map(|(name, e)| (name.clone(), e.programs as usize)).collect(),
        rooms: shared.rooms.clone(),
        session: id.to_string(),
    }
}

/// Carries one tab's messages to its session and back, until either side closes.
async fn carry(mut socket: WebSocket, app: Arc<App>) {
    if !reserve(&app) {
        return full(socket, app.max_sessions).await;
    }
    let id = session_id(&app);
    let hello = hello(&app.shared, &id);
    let (to_page, mut from_session) = tokio::sync::mpsc::unbounded_channel();
    let (to_session, from_page) = std::sync::mpsc::channel();
    app.inputs.lock().expect("not poisoned").insert(id.clone(), to_session.clone());
    let (s, a, name) = (app.shared.clone(), app.clone(), id.clone());
    let spawned = std::thread::Builder::new().name(id.clone()).spawn(move || {
        session::run(s, id, from_page, to_page);
        // the session and all it started are gone
        a.open.fetch_sub(1, Ordering::SeqCst);
    });
    if spawned.is_err() {
        app.open.fetch_sub(1, Ordering::SeqCst);
        app.inputs.lock().expect("not poisoned").remove(&name);
        return;
    }
    carry_messages(&mut socket, &hello, &to_session, &mut from_session).await;
    // the tab is gone: its session ends once no upload holds its input either
    app.inputs.lock().expect("not poisoned").remove(&name);
}

/// The socket's part of [`carry`]: until the tab or the session closes.
async fn carry_messages(
    socket: &mut WebSocket,
    hello: &ToPage,
    to_session: &std::sync::mpsc::Sender<Input>,
    from_session: &mut tokio::sync::mpsc::UnboundedReceiver<ToPage>,
) {
    if send(socket, hello).await.is_err() {
        return;
    }
    // one webcam frame at a time: the next waits for the last one's answer
    let mut frame_in_flight = false;
    loop {
        tokio::select! {
            m = socket.recv() => {
                let input = match m {
                    Some(Ok(Message::Text(t))) => match serde_json::from_str::<ToServer>(t.as_str()) {
                        Ok(m) => Input::Message(m),
                        Err(e) => {
                            let message = format!("a message the server does not know ({e})");
                            if send(socket, &ToPage::Error { message }).await.is_err() {
                                return;
                            }
                            continue;
                        }
                    },
                    Some(Ok(Message::Binary(_))) if frame_in_flight => {
                        let message = "a webcam frame was refused: it came before the last one was answered \
                                       (send one at a time)".to_string();
                        if send(socket, &ToPage::FrameRefused { message }).await.is_err() {
                            return;
                        }
                        continue;
                    }
                    Some(Ok(Message::Binary(b))) => {
                        frame_in_flight = true;
                        Input::Frame(b.to_vec(), Instant::now())
                    }
                    Some(Ok(_)) => continue,
                    // closed, or gone: dropping the channel ends the session
                    Some(Err(_)) | None => return,
                };
                if to_session.send(input).is_err() {
                    return;
                }
            }
            out = from_session.recv() => match out {
                Some(m) => {
                    frame_in_flight &= !matches!(m, ToPage::FrameSeen { .. } | ToPage::FrameRefused { .. });
                    if send(socket, &m).await.is_err() {
                        return;
                    }
                }
                None => return,
            },
        }
    }
}

async fn send(socket: &mut WebSocket, m: &ToPage) -> Result<(), axum::Error> {
    let text = serde_json::to_string(m).expect("messages serialise");
    socket.send(Message::Text(text.into())).await
}
