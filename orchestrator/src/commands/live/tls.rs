//! HTTPS for `orchestrator live`: the certificate and key a person gives (PEM files), or,
//! beyond loopback without them, a certificate made at start for the address listened on,
//! self-signed, whose SHA-256 fingerprint is printed for the person to compare with the one
//! their browser shows in its warning; and a listener that hands axum connections whose TLS
//! handshake is done, so the page and its socket (`wss://`) are served as over plain TCP.

use std::net::SocketAddr;
use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use anyhow::Context;
use rustls::ServerConfig;
use rustls::pki_types::pem::{self, PemObject};
use rustls::pki_types::{CertificateDer, PrivateKeyDer, PrivatePkcs8KeyDer};
use sha2::{Digest, Sha256};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::mpsc;
use tokio_rustls::TlsAcceptor;
use tokio_rustls::server::TlsStream;

/// A handshake that takes longer is dropped (a client that connects and says nothing).
const HANDSHAKE: Duration = Duration::from_secs(10);

/// What the server proves itself with.
pub struct Identity {
    pub config: Arc<ServerConfig>,
    /// SHA-256 of the certificate (DER), as browsers show it: `AB:CD:…`.
    pub fingerprint: String,
}

/// The certificate chain (`--tls-cert`, PEM, the server's own first) and its key (`--tls-key`).
pub fn from_files(cert: &Path, key: &Path) -> anyhow::Result<Identity> {
    let named = |flag: &str, p: &Path| format!("{flag} {}", p.display());
    let chain = CertificateDer::pem_file_iter(cert)
        .and_then(|certs| certs.collect::<Result<Vec<_>, _>>())
        .map_err(|e| pem_error(e, "certificate"))
        .with_context(|| named("--tls-cert", cert))?;
    anyhow::ensure!(!chain.is_empty(), "{}: no PEM certificate in it", named("--tls-cert", cert));
    let private = PrivateKeyDer::from_pem_file(key)
        .map_err(|e| pem_error(e, "private key"))
        .with_context(|| named("--tls-key", key))?;
    identity(chain, private).with_context(|| {
        format!("{} and {} do not make a server identity", named("--tls-cert", cert), named("--tls-key", key))
    })
}

fn pem_error(e: pem::Error, what: &str) -> anyhow::Error {
    match e {
        pem::Error::NoItemsFound => anyhow::anyhow!("no PEM {what} in it"),
        e => anyhow::anyhow!("{e}"),
    }
}

/// A certificate for `names` (host names or addresses), signed by its own key, made now: the
/// key never leaves this process.
pub fn self_signed(names: Vec<String>) -> anyhow::Result<Identity> {
    let now = time::OffsetDateTime::now_utc();
    let mut params = rcgen::CertificateParams::new(names.clone())?;
    params.distinguished_name.push(rcgen::DnType::CommonName, format!("GesTHOR live on {}", names[0]));
    // a day back for clocks that disagree; a month ahead, longer than any session
    (params.not_before, params.not_after) = (now - time::Duration::days(1), now + time::Duration::days(30));
    let key = rcgen::KeyPair::generate()?;
    let cert = params.self_signed(&key)?;
    let private = PrivateKeyDer::Pkcs8(PrivatePkcs8KeyDer::from(key.serialize_der()));
    identity(vec![cert.der().clone()], private)
}

fn identity(chain: Vec<CertificateDer<'static>>, key: PrivateKeyDer<'static>) -> anyhow::Result<Identity> {
    let fingerprint = fingerprint(&chain[0]);
    // the provider the rest of the workspace's rustls (zenoh's) is built with
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let mut config = ServerConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()?
        .with_no_client_auth()
        .with_single_cert(chain, key)?;
    config.alpn_protocols = vec![b"http/1.1".to_vec()];
    Ok(Identity { config: Arc::new(config), fingerprint })
}

/// SHA-256 of a certificate's DER bytes, in colon-separated upper-case hex.
pub fn fingerprint(der: &[u8]) -> String {
    Sha256::digest(der).iter().map(|b| format!("{b:02X}")).collect::<Vec<_>>().join(":")
}

/// TCP connections after their TLS handshake. The handshakes run in tasks of their own, so a
/// slow or silent client holds up no one else's connection.
pub struct TlsListener {
    ready: mpsc::Receiver<(TlsStream<TcpStream>, SocketAddr)>,
    local: SocketAddr,
}

impl TlsListener {
    /// Starts accepting on `tcp` (inside a tokio runtime).
    pub fn new(tcp: TcpListener, config: Arc<ServerConfig>) -> std::io::Result<TlsListener> {
        let local = tcp.local_addr()?;
        let acceptor = TlsAcceptor::from(config);
        let (tx, ready) = mpsc::channel(32);
        tokio::spawn(async move {
            loop {
                let (stream, peer) = match tcp.accept().await {
                    Ok(c) => c,
                    // out of file descriptors and the like: wait a moment, as axum's own listener does
                    Err(_) => {
                        tokio::time::sleep(Duration::from_millis(100)).await;
                        continue;
                    }
                };
                if tx.is_closed() {
                    return;
                }
                let (acceptor, tx) = (acceptor.clone(), tx.clone());
                tokio::spawn(async move {
                    // a failed handshake (plain HTTP to this port, a refused certificate) ends here
                    if let Ok(Ok(tls)) = tokio::time::timeout(HANDSHAKE, acceptor.accept(stream)).await {
                        let _ = tx.send((tls, peer)).await;
                    }
                });
            }
        });
        Ok(TlsListener { ready, local })
    }
}

impl axum::serve::Listener for TlsListener {
    type Io = TlsStream<TcpStream>;
    type Addr = SocketAddr;

    async fn accept(&mut self) -> (Self::Io, Self::Addr) {
        match self.ready.recv().await {
            Some(c) => c,
            // the accepting task holds a sender for as long as this listener lives
            None => std::future::pending().await,
        }
    }

    fn local_addr(&self) -> std::io::Result<SocketAddr> {
        Ok(self.local)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_self_signed_identity_is_made_for_an_address_and_its_fingerprint_is_its_certificates() {
        let id = self_signed(vec!["192.0.2.7".into(), "example-host".into()]).unwrap();
        assert_eq!(id.fingerprint.len(), 32 * 3 - 1);
        assert!(id.fingerprint.chars().all(|c| c == ':' || c.is_ascii_hexdigit()));
        assert_eq!(fingerprint(b"abc").split(':').next(), Some("BA"));
    }

    #[test]
    fn missing_and_garbled_files_are_named_with_their_flag() {
        let tmp = tempfile::tempdir().unwrap();
        let (cert, key) = (tmp.path().join("cert.pem"), tmp.path().join("key.pem"));
        let e = format!("{:#}", from_files(&cert, &key).err().unwrap());
        assert!(e.contains("--tls-cert") && e.contains("cert.pem"), "{e}");
        std::fs::write(&cert, "not a certificate").unwrap();
        let e = format!("{:#}", from_files(&cert, &key).err().unwrap());
        assert!(e.contains("--tls-cert") && e.contains("no PEM certificate"), "{e}");
    }
}
