//! `orchestrator live`: a person in the scene with a trained robot, in the browser. A local web
//! server runs the simulator for each open tab (one session a tab) with the checkpoints it was
//! given; the page shows what the robot sees, the map, what the policy thinks at each step and
//! the outcome; it runs a dataset program or one the person places, takes the person's gesture
//! from the program's recording, their webcam or a file they upload, and lets a wave call for
//! the intervention gesture. Every episode is recorded as GOND's files.
//!
//! - [`wire`]: the messages, one enum a direction;
//! - [`policy`]: a checkpoint acting through a `learner act` child;
//! - [`record`]: the episode's files, its simulator, and their replay;
//! - [`webcam`]: frames → landmarks → a wave, or a gesture captured;
//! - [`gesture`]: the person's own gesture, from the webcam, a video or a motion file uploaded;
//! - [`room`]: a program the person places: room, target, where person and robot stand;
//! - [`avatar`]: the person performing the gesture the robots perceive, filmed for the page;
//! - [`picture`]: pictures as the page shows them;
//! - [`session`]: one tab's simulator, policies, webcam and record;
//! - [`server`]: the page's files, the socket, the sessions open, and who may use them;
//! - [`tls`]: HTTPS, with the person's certificate or one made at start.

pub mod avatar;
pub mod gesture;
pub mod picture;
pub mod policy;
pub mod record;
pub mod room;
pub mod server;
pub mod session;
pub mod tls;
pub mod webcam;
pub mod wire;

use std::net::SocketAddr;
use std::num::NonZeroUsize;
use std::path::PathBuf;
use std::sync::Arc;

use anyhow::Context;
use clap::{Args, Subcommand};

use worker::dataset::{Dataset, Verify};

use policy::{Checkpoint, Policy};

#[derive(Args, Debug)]
#[command(args_conflicts_with_subcommands = true)]
pub struct LiveArgs {
    #[command(subcommand)]
    pub cmd: Option<LiveCmd>,
    /// A checkpoint file, a run directory (its newest complete checkpoint) or a shipped model;
    /// repeat it to choose between several on the page. The shipped models are offered beside.
    #[arg(long = "checkpoint")]
    pub checkpoints: Vec<PathBuf>,
    /// The shipped models' folder: each model in it is offered after the checkpoints named.
    #[arg(long, default_value = farm::models::DIR)]
    pub models: PathBuf,
    #[arg(long, default_value = "data/gond")]
    pub dataset: PathBuf,
    /// Where to listen. The page asks for a token printed at start (in the URL to open), and
    /// answers only to the names of this address. Beyond loopback it is served over HTTPS: with
    /// --tls-cert/--tls-key, or else a self-signed certificate made at start, whose SHA-256
    /// fingerprint is printed to check the browser's warning against.
    #[arg(long, default_value = "127.0.0.1:8480")]
    pub listen: SocketAddr,
    /// A name (or address) the server is reached by, besides those of --listen (repeat it): a
    /// request naming another Host is refused, as a page of another site rebinding its name to
    /// this machine would name its own.
    #[arg(long = "allow-host", value_name = "NAME")]
    pub allow_hosts: Vec<String>,
    /// Ask no token (for tests, or a machine and network whose every program and person you
    /// trust): any of them may then start sessions. Pages of other sites stay refused.
    #[arg(long)]
    pub no_token: bool,
    /// Sessions (tabs) run at once, at most; a tab beyond them is told the server is full. A
    /// session is its simulator in this process, a `learner act` a robot (two side by side) and,
    /// with the camera on, the landmark model: under a gigabyte with the camera (a configs/tiny
    /// checkpoint; BENCHMARKS.md) and up to a core while it runs; 4 suit two cores.
    #[arg(long, default_value_t = NonZeroUsize::new(4).expect("not zero"))]
    pub max_sessions: NonZeroUsize,
    /// Serve plain HTTP beyond loopback instead of HTTPS (behind a TLS proxy, or on a network
    /// you trust): the webcam's frames travel unencrypted.
    #[arg(long, conflicts_with = "tls_cert")]
    pub insecure: bool,
    /// The server's certificate (PEM, its chain after it) for HTTPS, on loopback too.
    #[arg(long, requires = "tls_key")]
    pub tls_cert: Option<PathBuf>,
    /// The certificate's private key (PEM).
    #[arg(long, requires = "tls_cert")]
    pub tls_key: Option<PathBuf>,
    /// Where the sessions are recorded (a folder per session, one per episode in it).
    #[arg(long, default_value = "runs/live")]
    pub out: PathBuf,
}

#[derive(Subcommand, Debug)]
pub enum LiveCmd {
    /// Step the simulator through a recorded episode's actions and check that the robot takes
    /// the recorded path and sees the recorded gestures.
    Replay {
        /// An episode folder of a session (SESSION/episode-NNN).
        episode: PathBuf,
    },
}

pub fn run(a: LiveArgs) -> anyhow::Result<()> {
    if let Some(LiveCmd::Replay { episode }) = &a.cmd {
        let r = record::replay(episode)?;
        return match r.first_difference {
            None => {
                println!("{}: {} steps replayed, the same path", episode.display(), r.steps);
                Ok(())
            }
            Some((step, what)) => anyhow::bail!("{}: step {step} differs: {what}", episode.display()),
        };
    }
    let mut offered = a.checkpoints.clone();
    offered.extend(farm::models::list(&a.models).into_iter().filter(|m| !a.checkpoints.contains(m)));
    anyhow::ensure!(
        !offered.is_empty(),
        "--checkpoint: name a checkpoint or run directory ({} holds no shipped model)",
        a.models.display()
    );
    let beyond = !a.listen.ip().is_loopback();
    // an unspecified address is reached by the machine's name
    let host = if a.listen.ip().is_unspecified() { crate::remote::hostname() } else { a.listen.ip().to_string() };
    let tls = match (&a.tls_cert, &a.tls_key) {
        (Some(cert), Some(key)) => Some((tls::from_files(cert, key)?, false)),
        _ if beyond && !a.insecure => Some((tls::self_signed(vec![host.clone()])?, true)),
        _ => None,
    };
    let dataset =
        Dataset::open(&a.dataset, Verify::Quick).with_context(|| format!("--dataset {}", a.dataset.display()))?;
    let mut checkpoints = Vec::new();
    for c in &offered {
        let ck = Checkpoint::open(c)?;
        // a checkpoint that does not load says so now, in one line, not in a tab later
        drop(Policy::start(&ck, &ck.config).with_context(|| format!("--checkpoint {}", c.display()))?);
        checkpoints.push(ck);
    }
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    // A secret, not a simulation draw: from the operating system, not the run's seed.
    let token = (!a.no_token).then(|| format!("{:032x}", rand::random::<u128>()));
    let hosts = server::access::hosts(a.listen.ip(), &host, &a.allow_hosts);
    let shared = Arc::new(session::Shared::new(Arc::new(dataset), checkpoints, a.out.clone()));
    let app = Arc::new(server::App::new(shared, a.max_sessions.get()));
    let rt = tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build()?;
    rt.block_on(async move {
        let listener =
            tokio::net::TcpListener::bind(a.listen).await.with_context(|| format!("--listen {}", a.listen))?;
        let port = listener.local_addr()?.port();
        let host = match a.listen.ip() {
            _ if !beyond => "localhost".into(),
            std::net::IpAddr::V6(ip) if !ip.is_unspecified() => format!("[{ip}]"),
            _ => host,
        };
        let scheme = if tls.is_some() { "https" } else { "http" };
        let query = token.as_ref().map(|t| format!("?token={t}")).unwrap_or_default();
        println!("GesTHOR live: open {scheme}://{host}:{port}/{query} (sessions are recorded in {})", a.out.display());
        match &tls {
            Some((id, true)) => println!(
                "the certificate was made now, self-signed, so the browser warns of it: go on if the \
                 SHA-256 fingerprint it shows is {}",
                id.fingerprint
            ),
            Some((id, false)) => println!("the certificate's SHA-256 fingerprint is {}", id.fingerprint),
            None => {}
        }
        use std::io::Write;
        std::io::stdout().flush()?;
        let app = server::router(app, server::access::Access::new(hosts, token, port, tls.is_some()));
        match tls {
            Some((id, _)) => axum::serve(tls::TlsListener::new(listener, id.config)?, app).await,
            None => axum::serve(listener, app).await,
        }
        .context("serving the page")
    })
}
