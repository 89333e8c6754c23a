//! Who may use the server, checked before every route as Jupyter's server does: a browser runs
//! pages of every site, and each may reach a server on this machine.
//!
//! - the Host a request names must be one the server answers to: a page of another site whose
//!   name was rebound to this machine (DNS rebinding) names its own;
//! - a browser's Origin, when it sends one, must be the server's own: another site's page may
//!   open a WebSocket or post to any address, and the browser lets it;
//! - the token printed at start, in the URL or in the cookie the page got with it: other
//!   programs, and other people beyond loopback, do not have it. The page's script and style
//!   are not asked for it: they are the same in every copy of the program, and the page's own
//!   requests for them carry no URL token.
//!
//! A refusal is a 403 with one line for the person, and one line on stderr for whoever runs it.

use std::net::IpAddr;
use std::sync::Arc;

use axum::extract::{Query, Request, State};
use axum::http::uri::Authority;
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use serde::Deserialize;

/// What the server answers to.
pub struct Access {
    /// Host names without port: lowercase, IPv6 without brackets.
    hosts: Vec<String>,
    /// None: no token is asked (`--no-token`).
    token: Option<String>,
    /// The cookie the page gets with the token: named by port, as browsers share a host's
    /// cookies among its ports.
    cookie: String,
    /// Served over HTTPS: the cookie is sent over HTTPS only.
    secure: bool,
}

impl Access {
    pub fn new(hosts: Vec<String>, token: Option<String>, port: u16, secure: bool) -> Access {
        let mut names: Vec<String> = Vec::new();
        for h in hosts.iter().map(|h| bare(&h.to_ascii_lowercase()).to_string()) {
            if !names.contains(&h) {
                names.push(h);
            }
        }
        Access { hosts: names, token, cookie: format!("gesthor-live-{port}"), secure }
    }
}

/// The names a server listening at `ip` answers to: the loopback names on loopback, the address
/// itself beyond it, the machine's `hostname` when it listens on every address (loopback
/// included), and those `allowed` (`--allow-host`).
pub fn hosts(ip: IpAddr, hostname: &str, allowed: &[String]) -> Vec<String> {
    let mut hosts = Vec::new();
    if ip.is_loopback() || ip.is_unspecified() {
        hosts.extend(["localhost", "127.0.0.1", "::1"].map(String::from));
    }
    hosts.push(if ip.is_unspecified() { hostname.to_string() } else { ip.to_string() });
    hosts.extend(allowed.iter().cloned());
    hosts
}

/// A host without IPv6's brackets or a fully qualified name's final dot.
fn bare(host: &str) -> &str {
    let host = host.strip_prefix('[').and_then(|h| h.strip_suffix(']')).unwrap_or(host);
    host.strip_suffix('.').unwrap_or(host)
}

/// The axum layer: Host, then Origin, then the token; a page opened with the token in its URL
/// gets the cookie, so that it loads again without it.
pub async fn check(State(access): State<Arc<Access>>, req: Request, next: Next) -> Response {
    let what = format!("{} {}", req.method(), req.uri().path());
    let headers = req.headers();
    let Some(host) = headers.get(header::HOST).and_then(|h| h.to_str().ok()).map(str::to_string) else {
        return refuse(&what, "no Host header", HOST_REFUSED);
    };
    if !access.answers_to(&host) {
        let why = format!("Host {host} is not one it answers to ({}; --allow-host adds one)", access.hosts.join(", "));
        return refuse(&what, &why, HOST_REFUSED);
    }
    if let Some(origin) = headers.get(header::ORIGIN) {
        let origin = origin.to_str().unwrap_or("(not ASCII)");
        if !same_origin(origin, &host) {
            return refuse(&what, &format!("a page of origin {origin} is not one of its own ({host})"), ORIGIN_REFUSED);
        }
    }
    let public = matches!(req.uri().path(), "/app.js" | "/style.css");
    let Some(token) = access.token_of(&req).or(public.then_some(Token::NotAsked)) else {
        return refuse(&what, "no token, or a wrong one", TOKEN_REFUSED);
    };
    let cookie = (token == Token::InUrl && req.uri().path() == "/").then(|| access.set_cookie());
    let mut response = next.run(req).await;
    if let Some(c) = cookie {
        response.headers_mut().append(header::SET_COOKIE, c);
    }
    response
}

const HOST_REFUSED: &str =
    "this server does not answer to that name: open the URL it printed (or start it with --allow-host NAME)\n";
const ORIGIN_REFUSED: &str = "only this server's own page may use it, not a page of another site\n";
const TOKEN_REFUSED: &str = "this server asks for the token it printed at start: open the URL it printed\n";

fn refuse(what: &str, why: &str, body: &'static str) -> Response {
    eprintln!("live: refused {what}: {why}");
    (StatusCode::FORBIDDEN, body).into_response()
}

/// Where a request's token came from.
#[derive(PartialEq)]
enum Token {
    NotAsked,
    InUrl,
    InCookie,
}

#[derive(Deserialize)]
struct InUrl {
    token: Option<String>,
}

impl Access {
    fn answers_to(&self, host: &str) -> bool {
        let Ok(authority) = host.parse::<Authority>() else { return false };
        let name = bare(authority.host()).to_ascii_lowercase();
        self.hosts.contains(&name)
    }

    /// Where the request's token came from; None when it has none, or a wrong one.
    fn token_of(&self, req: &Request) -> Option<Token> {
        let Some(token) = &self.token else { return Some(Token::NotAsked) };
        let in_url = Query::<InUrl>::try_from_uri(req.uri()).ok().and_then(|q| q.0.token);
        if in_url.is_some_and(|t| same_secret(&t, token)) {
            return Some(Token::InUrl);
        }
        cookie(req.headers(), &self.cookie).is_some_and(|t| same_secret(t, token)).then_some(Token::InCookie)
    }

    /// Kept until the browser closes; sent by the browser to this server's own pages only.
    fn set_cookie(&self) -> HeaderValue {
        let token = self.token.as_deref().unwrap_or_default();
        let secure = if self.secure { "; Secure" } else { "" };
        let c = format!("{}={token}; Path=/; HttpOnly; SameSite=Strict{secure}", self.cookie);
        HeaderValue::from_str(&c).expect("the token is hex")
    }
}

/// Whether a browser's `origin` (scheme://host[:port]) is the page's own at `host` (the Host
/// header, which the browser writes as it writes the origin's host and port). The scheme is not
/// compared: one port serves one scheme, and behind a TLS proxy (`--insecure`) the browser's
/// page is https while the server speaks http.
fn same_origin(origin: &str, host: &str) -> bool {
    match origin.split_once("://") {
        Some(("http" | "https", authority)) => authority.eq_ignore_ascii_case(host),
        _ => false,
    }
}

/// The value of cookie `name` in the request's Cookie headers.
fn cookie<'a>(headers: &'a HeaderMap, name: &str) -> Option<&'a str> {
    let pairs = headers.get_all(header::COOKIE).into_iter().filter_map(|v| v.to_str().ok());
    pairs.flat_map(|v| v.split(';')).find_map(|p| p.trim().strip_prefix(name)?.strip_prefix('='))
}

/// Equal strings, compared in a time that does not tell how much of a guess was right.
fn same_secret(a: &str, b: &str) -> bool {
    a.len() == b.len() && a.bytes().zip(b.bytes()).fold(0, |d, (x, y)| d | (x ^ y)) == 0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_host_is_compared_by_name_whatever_its_port() {
        let loopback = Access::new(hosts("127.0.0.1".parse().unwrap(), "box", &[]), None, 8480, false);
        for ok in ["localhost:8480", "127.0.0.1:8480", "[::1]:8480", "LOCALHOST", "localhost.:1"] {
            assert!(loopback.answers_to(ok), "{ok}");
        }
        for no in ["evil.example:8480", "localhost.evil.example", "box:8480", "127.0.0.2", "", "[::1"] {
            assert!(!loopback.answers_to(no), "{no}");
        }
        let everywhere = hosts("0.0.0.0".parse().unwrap(), "box", &["gesthor.example".into()]);
        let everywhere = Access::new(everywhere, None, 8480, false);
        for ok in ["box:8480", "localhost:8480", "gesthor.example", "GesTHOR.example:443"] {
            assert!(everywhere.answers_to(ok), "{ok}");
        }
        assert!(!everywhere.answers_to("0.0.0.0:8480") && !everywhere.answers_to("evil.example"));
        let one = Access::new(hosts("192.168.1.5".parse().unwrap(), "box", &[]), None, 8480, false);
        assert!(one.answers_to("192.168.1.5:8480") && !one.answers_to("localhost:8480") && !one.answers_to("box"));
    }

    #[test]
    fn an_origin_is_the_page_own_only_at_the_same_host_and_port() {
        assert!(same_origin("http://localhost:8480", "localhost:8480"));
        assert!(same_origin("https://LocalHost:8480", "localhost:8480"));
        assert!(same_origin("https://gesthor.example", "gesthor.example"));
        for no in [
            "http://evil.example",
            "http://localhost:9999",
            "http://localhost",
            "null",
            "file://",
            "ws://localhost:8480",
        ] {
            assert!(!same_origin(no, "localhost:8480"), "{no}");
        }
    }

    #[test]
    fn the_token_is_read_from_the_url_or_the_server_own_cookie() {
        let mut headers = HeaderMap::new();
        headers.append(header::COOKIE, HeaderValue::from_static("a=1; gesthor-live-8480=abc; gesthor-live-8481=def"));
        assert_eq!(cookie(&headers, "gesthor-live-8480"), Some("abc"));
        assert_eq!(cookie(&headers, "gesthor-live-848"), None);
        assert!(same_secret("abc", "abc") && !same_secret("abc", "abd") && !same_secret("abc", "abcd"));
    }
}
