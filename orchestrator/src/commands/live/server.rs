//! The HTTP side of `orchestrator live`: the page's three files (built into the binary), the
//! WebSocket each tab opens, and how many sessions are open. Each socket gets a session on a
//! thread of its own ([`super::session`]); the socket task only carries messages both ways.

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use axum::Router;
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::{Query, State};
use axum::http::{StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use serde::Deserialize;

use super::session::{self, Input, Shared};
use super::wire::{CheckpointInfo, ToPage, ToServer};

const INDEX: &str = include_str!("page/index.html");
const APP: &str = include_str!("page/app.js");
const STYLE: &str = include_str!("page/style.css");

/// What every request sees.
pub struct App {
    pub shared: Arc<Shared>,
    /// Asked of every request when the server listens beyond loopback.
    pub token: Option<String>,
    /// Sessions whose simulator is still running.
    pub open: AtomicUsize,
    started: AtomicUsize,
}

impl App {
    pub fn new(shared: Arc<Shared>, token: Option<String>) -> App {
        App { shared, token, open: AtomicUsize::new(0), started: AtomicUsize::new(0) }
    }
}

#[derive(Deserialize)]
struct Access {
    token: Option<String>,
}

pub fn router(app: Arc<App>) -> Router {
    Router::new()
        .route("/", get(index))
        .route("/app.js", get(|| async { ([(header::CONTENT_TYPE, "text/javascript")], APP) }))
        .route("/style.css", get(|| async { ([(header::CONTENT_TYPE, "text/css")], STYLE) }))
        .route("/sessions", get(sessions))
        .route("/ws", get(socket))
        .with_state(app)
}

fn allowed(app: &App, q: &Access) -> bool {
    app.token.as_ref().is_none_or(|t| q.token.as_ref() == Some(t))
}

fn refused() -> Response {
    (StatusCode::FORBIDDEN, "this server asks for the token it printed at start: open the URL it printed\n")
        .into_response()
}

async fn index(State(app): State<Arc<App>>, Query(q): Query<Access>) -> Response {
    if !allowed(&app, &q) {
        return refused();
    }
    ([(header::CONTENT_TYPE, "text/html; charset=utf-8")], INDEX).into_response()
}

async fn sessions(State(app): State<Arc<App>>, Query(q): Query<Access>) -> Response {
    if !allowed(&app, &q) {
        return refused();
    }
    format!("{{\"open\":{}}}", app.open.load(Ordering::SeqCst)).into_response()
}

async fn socket(ws: WebSocketUpgrade, State(app): State<Arc<App>>, Query(q): Query<Access>) -> Response {
    if !allowed(&app, &q) {
        return refused();
    }
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

/// Carries one tab's messages to its session and back, until either side closes.
async fn carry(mut socket: WebSocket, app: Arc<App>) {
    let id = session_id(&app);
    let shared = &app.shared;
    let hello = ToPage::Hello {
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
        session: id.clone(),
    };
    let (to_page, mut from_session) = tokio::sync::mpsc::unbounded_channel();
    let (to_session, from_page) = std::sync::mpsc::channel();
    app.open.fetch_add(1, Ordering::SeqCst);
    let (s, a) = (app.shared.clone(), app.clone());
    let spawned = std::thread::Builder::new().name(id.clone()).spawn(move || {
        session::run(s, id, from_page, to_page);
        // the session and all it started are gone
        a.open.fetch_sub(1, Ordering::SeqCst);
    });
    if spawned.is_err() {
        app.open.fetch_sub(1, Ordering::SeqCst);
        return;
    }
    if send(&mut socket, &hello).await.is_err() {
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
                            if send(&mut socket, &ToPage::Error { message }).await.is_err() {
                                return;
                            }
                            continue;
                        }
                    },
                    Some(Ok(Message::Binary(_))) if frame_in_flight => {
                        let message = "a webcam frame was refused: it came before the last one was answered \
                                       (send one at a time)".to_string();
                        if send(&mut socket, &ToPage::FrameRefused { message }).await.is_err() {
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
                    if send(&mut socket, &m).await.is_err() {
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
