//! Why a TLS link was refused. Zenoh says it only in its logs (a failed handshake is not an
//! error any call returns), so this tracing layer keeps the last such reason for the host's
//! error, and on the learner's side prints it as one line per refused connection.

use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};

use tracing::field::{Field, Visit};
use tracing_subscriber::Layer;
use tracing_subscriber::filter::{LevelFilter, Targets};

static LAST: Mutex<Option<String>> = Mutex::new(None);
static PRINT: AtomicBool = AtomicBool::new(false);

/// The layer, listening to Zenoh's TLS link and transport at debug level only.
pub fn layer<S>() -> impl Layer<S>
where
    S: tracing::Subscriber + for<'a> tracing_subscriber::registry::LookupSpan<'a>,
{
    let targets = Targets::new()
        .with_target("zenoh_link_tls", LevelFilter::DEBUG)
        .with_target("zenoh_transport", LevelFilter::DEBUG)
        .with_target("zenoh::net::runtime", LevelFilter::DEBUG);
    Refusals.with_filter(targets)
}

/// The learner's side prints each refusal (`[up] refused a TLS connection: ...`).
pub fn print_refusals() {
    PRINT.store(true, Ordering::Relaxed);
}

/// The reason of the last refused TLS link, if any.
pub fn last_refusal() -> Option<String> {
    LAST.lock().ok()?.clone()
}

struct Refusals;

/// Words of rustls's and Zenoh's messages about a certificate a side would not take.
fn refusal(message: &str) -> Option<String> {
    let m = message.to_ascii_lowercase();
    let about_certs = ["invalid peer certificate", "fatal alert", "peer sent no certificates"];
    about_certs.iter().any(|w| m.contains(w)).then(|| clean(message))
}

/// The reason alone: without Zenoh's hints, source locations and retry notes.
fn clean(message: &str) -> String {
    let mut m = message.split_whitespace().collect::<Vec<_>>().join(" ");
    for cut in [". Hint:", " at /", ". Retry"] {
        if let Some(i) = m.find(cut) {
            m.truncate(i);
        }
    }
    match m.split_once("! ") {
        Some((_, why)) => why.to_string(),
        None => m,
    }
}

#[derive(Default)]
struct Message(String);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_refusal_is_its_reason_alone() {
        let learner = "invalid peer certificate: UnknownIssuer. Hint: increase the system open file limit.";
        assert_eq!(refusal(learner).unwrap(), "invalid peer certificate: UnknownIssuer");
        let host = "Unable to connect to configured peer tls/127.0.0.1:7447! received fatal alert: UnknownCA at /x/zenoh-link-tls/src/unicast.rs:226.. Retry in 1s.";
        assert_eq!(refusal(host).unwrap(), "received fatal alert: UnknownCA");
        assert_eq!(refusal("Connection refused (os error 111)"), None);
        assert_eq!(refusal("Loading client authentication key and certificate..."), None);
    }
}

impl Visit for Message {
    fn record_debug(&mut self, field: &Field, value: &dyn std::fmt::Debug) {
        if field.name() == "message" {
            self.0 = format!("{value:?}");
        }
    }
    fn record_str(&mut self, field: &Field, value: &str) {
        if field.name() == "message" {
            self.0 = value.to_string();
        }
    }
}

impl<S: tracing::Subscriber> Layer<S> for Refusals {
    fn on_event(&self, event: &tracing::Event<'_>, _: tracing_subscriber::layer::Context<'_, S>) {
        let mut m = Message::default();
        event.record(&mut m);
        if let Some(why) = refusal(&m.0) {
            if PRINT.load(Ordering::Relaxed) {
                eprintln!("[up] refused a TLS connection: {why}");
            }
            if let Ok(mut last) = LAST.lock() {
                *last = Some(why);
            }
        }
    }
}
