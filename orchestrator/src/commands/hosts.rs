//! `orchestrator hosts`: who may join a run over TLS. `issue` makes a worker host's bundle (its
//! certificate and key, the learner's CA, the run id and secret), `revoke` refuses a host for
//! the rest of the run, `list` says who is which. Both return once a listening learner has
//! reopened its listener with the new trust.

use std::path::PathBuf;

use clap::{Args, Subcommand};

use crate::remote::certs;

#[derive(Subcommand, Debug)]
pub enum HostsCmd {
    /// Make a worker host's bundle; the run's learner trusts it from now on.
    Issue(IssueArgs),
    /// Refuse a host's certificate for the rest of the run (its links close, it cannot rejoin).
    Revoke(RevokeArgs),
    /// The hosts issued for a run, and those revoked.
    List(ListArgs),
}

#[derive(Args, Debug)]
pub struct IssueArgs {
    /// The run folder of `up --listen tls/...`.
    #[arg(long)]
    pub run: PathBuf,
    /// The host's name (letters, digits, `-`, `_`): its certificate's, and the learner's lines'.
    pub name: String,
    /// Where to write the bundle (default: RUN/tls/bundles/NAME).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

#[derive(Args, Debug)]
pub struct RevokeArgs {
    #[arg(long)]
    pub run: PathBuf,
    pub name: String,
}

#[derive(Args, Debug)]
pub struct ListArgs {
    #[arg(long)]
    pub run: PathBuf,
}

pub fn run(c: HostsCmd) -> anyhow::Result<()> {
    match c {
        HostsCmd::Issue(a) => {
            let out = a.out.unwrap_or_else(|| a.run.join("tls/bundles").join(&a.name));
            certs::issue(&a.run, &a.name, &out)?;
            let endpoint =
                std::fs::read_to_string(a.run.join("tls/endpoint")).unwrap_or_else(|_| "tls/HOST:PORT".into());
            // `up` listens on 0.0.0.0 or an address: the host dials the learner host's address.
            let dial = endpoint.replace("0.0.0.0", "LEARNER-HOST");
            println!("host `{}`: bundle in {} (owner-only; it holds the host's key)", a.name, out.display());
            println!("copy it:      scp -rp {} HOST:gesthor-{}", out.display(), a.name);
            println!("on the host:  orchestrator workers --connect {dial} --certs gesthor-{} --workers N", a.name);
        }
        HostsCmd::Revoke(a) => {
            certs::revoke(&a.run, &a.name)?;
            println!("host `{}` revoked for the rest of the run: the learner refuses its certificate", a.name);
        }
        HostsCmd::List(a) => {
            let (issued, revoked) = certs::hosts(&a.run)?;
            for n in &issued {
                println!("{n}\ttrusted");
            }
            for n in &revoked {
                println!("{n}\trevoked");
            }
            if issued.is_empty() && revoked.is_empty() {
                println!("no host issued in {}", a.run.display());
            }
        }
    }
    Ok(())
}
