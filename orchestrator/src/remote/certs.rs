//! Who may join a run over TLS: the learner's certificate, each worker host's bundle, and the
//! list of hosts the learner trusts now (issued, not revoked).
//!
//! Every identity (the learner, each host) is a certificate signed by a CA of its own that
//! signed nothing else; the CA's key is dropped as soon as it has signed. Trusting an identity
//! is trusting its CA certificate, so refusing one host is taking its CA out of the learner's
//! trust file: Zenoh's TLS has no revocation list, and a run CA that signed every host could
//! not un-trust one of them. Hosts trust the learner's CA; the learner trusts the hosts' CAs.
//!
//! In the run folder (`RUN/tls/`): `learner.pem`, `learner.key` (owner-only) and `learner-ca.pem`;
//! `hosts/<name>.pem` (the CA certificate of each issued host); `revoked` (a name per line);
//! `trusted-hosts.pem` (what the learner's listener trusts, rewritten on every issue and
//! revocation; it watches that file). A host's bundle (owner-only folder): `learner-ca.pem`,
//! `host.pem` (its certificate then its CA's), `host.key` and `join.json` (run id, secret, name).

use std::path::{Path, PathBuf};

use anyhow::Context;
use rcgen::{
    BasicConstraints, CertificateParams, DnType, ExtendedKeyUsagePurpose, IsCa, Issuer, KeyPair, KeyUsagePurpose,
};
use serde::{Deserialize, Serialize};

/// The certificate and key files of one side of a TLS link, and the file of what it trusts.
#[derive(Clone, Debug)]
pub struct TlsFiles {
    pub certificate: PathBuf,
    pub key: PathBuf,
    /// The CA certificates of the peers this side accepts.
    pub trusted: PathBuf,
    /// The common names of those peers (the access rules name them).
    pub peer_names: Vec<String>,
}

/// What a host needs besides its certificate to join: kept in its bundle.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct JoinInfo {
    pub run_id: String,
    pub secret: String,
    pub name: String,
}

/// The common name of a run's learner.
pub fn learner_name(run_id: &str) -> String {
    format!("gesthor-learner.{run_id}")
}

/// The common name of a run's host.
pub fn host_name(run_id: &str, name: &str) -> String {
    format!("gesthor-host.{name}.{run_id}")
}

fn tls_dir(run: &Path) -> PathBuf {
    run.join("tls")
}

/// Writes `bytes` readable by the owner only (keys and bundles), replacing nothing.
fn write_private(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    use std::io::Write;
    use std::os::unix::fs::OpenOptionsExt;
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(0o600)
        .open(path)
        .with_context(|| format!("writing {}", path.display()))?;
    f.write_all(bytes).with_context(|| format!("writing {}", path.display()))
}

fn private_dir(path: &Path) -> anyhow::Result<()> {
    use std::os::unix::fs::DirBuilderExt;
    std::fs::DirBuilder::new()
        .recursive(true)
        .mode(0o700)
        .create(path)
        .with_context(|| format!("creating {}", path.display()))
}

/// An identity: a certificate signed by a CA that signs nothing else (its key is dropped here).
/// Returns (the CA certificate, the certificate, its key), PEM.
fn identity(common_name: &str, usage: ExtendedKeyUsagePurpose) -> anyhow::Result<(String, String, String)> {
    let now = time::OffsetDateTime::now_utc();
    // a day back for clocks that disagree; a year ahead, longer than any run
    let (from, until) = (now - time::Duration::days(1), now + time::Duration::days(365));
    let mut ca = CertificateParams::new(Vec::<String>::new())?;
    ca.is_ca = IsCa::Ca(BasicConstraints::Constrained(0));
    ca.distinguished_name.push(DnType::CommonName, format!("{common_name} CA"));
    ca.key_usages = vec![KeyUsagePurpose::KeyCertSign, KeyUsagePurpose::DigitalSignature];
    (ca.not_before, ca.not_after) = (from, until);
    let ca_key = KeyPair::generate()?;
    let ca_cert = ca.self_signed(&ca_key)?;
    let issuer = Issuer::new(ca, ca_key);

    let mut leaf = CertificateParams::new(vec![common_name.to_string()])?;
    leaf.distinguished_name.push(DnType::CommonName, common_name);
    leaf.key_usages = vec![KeyUsagePurpose::DigitalSignature];
    leaf.extended_key_usages = vec![usage];
    leaf.use_authority_key_identifier_extension = true;
    (leaf.not_before, leaf.not_after) = (from, until);
    let key = KeyPair::generate()?;
    let cert = leaf.signed_by(&key, &issuer)?;
    Ok((ca_cert.pem(), cert.pem() + &ca_cert.pem(), key.serialize_pem()))
}

/// The learner's side of a run that listens over TLS: made on the first `up --listen tls/...`
/// of the run and kept for its resumes (issued bundles stay valid).
pub fn learner_files(run: &Path, run_id: &str) -> anyhow::Result<TlsFiles> {
    let dir = tls_dir(run);
    let (cert, key) = (dir.join("learner.pem"), dir.join("learner.key"));
    if !cert.exists() {
        private_dir(&dir.join("hosts"))?;
        let (ca, pem, k) = identity(&learner_name(run_id), ExtendedKeyUsagePurpose::ServerAuth)?;
        write_private(&key, k.as_bytes())?;
        farm::files::write_atomic(&dir.join("learner-ca.pem"), ca.as_bytes())?;
        farm::files::write_atomic(&cert, pem.as_bytes())?;
    }
    write_trust(run)?;
    Ok(TlsFiles {
        certificate: cert,
        key,
        trusted: dir.join("trusted-hosts.pem"),
        peer_names: trusted_hosts(run, run_id)?,
    })
}

/// The hosts issued for a run and not revoked, by name.
pub fn hosts(run: &Path) -> anyhow::Result<(Vec<String>, Vec<String>)> {
    let dir = tls_dir(run).join("hosts");
    let mut issued: Vec<String> = match std::fs::read_dir(&dir) {
        Ok(rd) => rd.filter_map(|e| e.ok()?.file_name().to_str()?.strip_suffix(".pem").map(str::to_string)).collect(),
        Err(_) => Vec::new(),
    };
    issued.sort();
    let revoked_file = tls_dir(run).join("revoked");
    let revoked: Vec<String> = std::fs::read_to_string(&revoked_file)
        .unwrap_or_default()
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .map(str::to_string)
        .collect();
    Ok((issued.into_iter().filter(|n| !revoked.contains(n)).collect(), revoked))
}

fn trusted_hosts(run: &Path, run_id: &str) -> anyhow::Result<Vec<String>> {
    Ok(hosts(run)?.0.iter().map(|n| host_name(run_id, n)).collect())
}

/// Rewrites the learner's trust file from the issued and revoked hosts. With no host to trust
/// it holds a CA whose key was never kept: TLS needs one, and it trusts no one.
fn write_trust(run: &Path) -> anyhow::Result<()> {
    let dir = tls_dir(run);
    let mut pem = String::new();
    for n in hosts(run)?.0 {
        let p = dir.join("hosts").join(format!("{n}.pem"));
        pem += &std::fs::read_to_string(&p).with_context(|| format!("reading {}", p.display()))?;
    }
    if pem.is_empty() {
        let nobody = dir.join("nobody-ca.pem");
        if !nobody.exists() {
            farm::files::write_atomic(&nobody, identity("nobody", ExtendedKeyUsagePurpose::ClientAuth)?.0.as_bytes())?;
        }
        pem = std::fs::read_to_string(&nobody)?;
    }
    // unchanged trust is not rewritten: a listening learner reopens on every change
    let path = dir.join("trusted-hosts.pem");
    if std::fs::read_to_string(&path).ok().as_deref() != Some(pem.as_str()) {
        farm::files::write_atomic(&path, pem.as_bytes())?;
    }
    Ok(())
}

/// A listening learner notes which trust it opened with (`tls/applied`: its pid and the trust
/// file's SHA-256), so `issue` and `revoke` can return once it applies.
pub fn mark_applied(run: &Path, trust: &str) -> anyhow::Result<()> {
    let line = format!("{} {}", std::process::id(), farm::files::sha256_hex(trust.as_bytes()));
    Ok(farm::files::write_atomic(&tls_dir(run).join("applied"), line.as_bytes())?)
}

/// Waits (10 s at most) until a listening learner of the run applies the trust file as it is.
fn wait_applied(run: &Path) -> anyhow::Result<()> {
    let dir = tls_dir(run);
    let want = farm::files::sha256_hex(std::fs::read_to_string(dir.join("trusted-hosts.pem"))?.as_bytes());
    let t = std::time::Instant::now();
    loop {
        let applied = std::fs::read_to_string(dir.join("applied")).unwrap_or_default();
        let mut w = applied.split_whitespace();
        let (pid, hash) = (w.next().and_then(|p| p.parse::<i32>().ok()), w.next());
        let listening = pid.is_some_and(|p| nix::sys::signal::kill(nix::unistd::Pid::from_raw(p), None).is_ok());
        if !listening || hash == Some(want.as_str()) {
            return Ok(());
        }
        anyhow::ensure!(
            t.elapsed() < std::time::Duration::from_secs(10),
            "the run's learner (pid {}) did not apply the new trust within 10 s",
            pid.unwrap_or_default()
        );
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
}

/// A host name people can type and Zenoh's access rules can hold.
fn check_name(name: &str) -> anyhow::Result<()> {
    anyhow::ensure!(
        !name.is_empty() && name.len() <= 64 && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_'),
        "host name `{name}`: use 1 to 64 letters, digits, `-` or `_`"
    );
    Ok(())
}

/// Issues host `name`'s bundle into `out` (a new owner-only folder); the learner trusts it from
/// now on (a listening learner has reopened its listener when this returns).
pub fn issue(run: &Path, name: &str, out: &Path) -> anyhow::Result<()> {
    check_name(name)?;
    let dir = tls_dir(run);
    let learner_ca = dir.join("learner-ca.pem");
    anyhow::ensure!(
        learner_ca.exists(),
        "{}: this run has no TLS certificates yet; `orchestrator up --listen tls/HOST:PORT` makes them",
        run.display()
    );
    let (issued, revoked) = hosts(run)?;
    anyhow::ensure!(!revoked.iter().any(|n| n == name), "host `{name}` was revoked in this run; choose another name");
    anyhow::ensure!(!issued.iter().any(|n| n == name), "host `{name}` already has a bundle in this run");
    anyhow::ensure!(!out.exists(), "{}: exists; nothing was overwritten (choose another --out)", out.display());
    let run_id = crate::supervise::run_dir::read_info(run)?.run_id;
    let secret = std::fs::read_to_string(run.join("secret"))
        .with_context(|| format!("{}: no secret", run.display()))?
        .trim()
        .to_string();
    let (ca, pem, key) = identity(&host_name(&run_id, name), ExtendedKeyUsagePurpose::ClientAuth)?;
    private_dir(out)?;
    std::fs::copy(&learner_ca, out.join("learner-ca.pem"))?;
    write_private(&out.join("host.key"), key.as_bytes())?;
    write_private(&out.join("host.pem"), pem.as_bytes())?;
    let join = JoinInfo { run_id, secret, name: name.into() };
    write_private(&out.join("join.json"), &serde_json::to_vec_pretty(&join)?)?;
    farm::files::write_atomic(&dir.join("hosts").join(format!("{name}.pem")), ca.as_bytes())?;
    write_trust(run)?;
    wait_applied(run)
}

/// Refuses host `name` for the rest of the run (a listening learner has reopened its listener
/// without it when this returns).
pub fn revoke(run: &Path, name: &str) -> anyhow::Result<()> {
    let (issued, revoked) = hosts(run)?;
    if revoked.iter().any(|n| n == name) {
        return Ok(());
    }
    anyhow::ensure!(
        issued.iter().any(|n| n == name),
        "no host `{name}` is trusted in {} (trusted now: {})",
        run.display(),
        if issued.is_empty() { "none".into() } else { issued.join(", ") }
    );
    use std::io::Write;
    let p = tls_dir(run).join("revoked");
    let mut f = std::fs::OpenOptions::new().append(true).create(true).open(&p)?;
    writeln!(f, "{name}").with_context(|| format!("writing {}", p.display()))?;
    write_trust(run)?;
    wait_applied(run)
}

/// A host's side, from its bundle.
pub fn host_files(bundle: &Path) -> anyhow::Result<(TlsFiles, JoinInfo)> {
    let need = |f: &str| -> anyhow::Result<PathBuf> {
        let p = bundle.join(f);
        anyhow::ensure!(p.is_file(), "{}: missing (not a bundle of `orchestrator hosts issue`)", p.display());
        Ok(p)
    };
    let j = need("join.json")?;
    let join: JoinInfo =
        serde_json::from_slice(&std::fs::read(&j)?).with_context(|| format!("{}: not a join file", j.display()))?;
    let files = TlsFiles {
        certificate: need("host.pem")?,
        key: need("host.key")?,
        trusted: need("learner-ca.pem")?,
        peer_names: vec![learner_name(&join.run_id)],
    };
    Ok((files, join))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run_folder() -> tempfile::TempDir {
        let t = tempfile::tempdir().unwrap();
        let info = crate::supervise::run_dir::RunInfo {
            run_id: "r7".into(),
            pid: 1,
            started: 0,
            workers: 1,
            policy: "ppo".into(),
            command: vec![],
        };
        std::fs::write(t.path().join("run.json"), serde_json::to_vec(&info).unwrap()).unwrap();
        std::fs::write(t.path().join("secret"), "s3").unwrap();
        t
    }

    #[test]
    fn issued_hosts_are_trusted_until_revoked_and_keys_are_owner_only() {
        use std::os::unix::fs::PermissionsExt;
        let t = run_folder();
        let run = t.path();
        assert!(issue(run, "a", &run.join("bundle-a")).unwrap_err().to_string().contains("up --listen tls/"));
        let l = learner_files(run, "r7").unwrap();
        assert!(l.peer_names.is_empty());
        issue(run, "a", &run.join("bundle-a")).unwrap();
        issue(run, "b", &run.join("bundle-b")).unwrap();
        let trust = || std::fs::read_to_string(run.join("tls/trusted-hosts.pem")).unwrap();
        let ca = |n: &str| std::fs::read_to_string(run.join(format!("tls/hosts/{n}.pem"))).unwrap();
        assert!(trust().contains(&ca("a")) && trust().contains(&ca("b")));
        let (files, join) = host_files(&run.join("bundle-a")).unwrap();
        assert_eq!((join.run_id.as_str(), join.secret.as_str(), join.name.as_str()), ("r7", "s3", "a"));
        assert_eq!(files.peer_names, vec!["gesthor-learner.r7".to_string()]);
        for f in [run.join("bundle-a/host.key"), run.join("tls/learner.key")] {
            assert_eq!(std::fs::metadata(&f).unwrap().permissions().mode() & 0o777, 0o600, "{}", f.display());
        }
        assert!(issue(run, "a", &run.join("again")).unwrap_err().to_string().contains("already"));
        assert!(issue(run, "c/d", &run.join("c")).unwrap_err().to_string().contains("host name"));
        revoke(run, "a").unwrap();
        assert!(!trust().contains(&ca("a")) && trust().contains(&ca("b")));
        assert_eq!(learner_files(run, "r7").unwrap().peer_names, vec![host_name("r7", "b")]);
        assert!(issue(run, "a", &run.join("a2")).unwrap_err().to_string().contains("revoked"));
        assert!(revoke(run, "zz").unwrap_err().to_string().contains("trusted now: b"));
        revoke(run, "b").unwrap();
        assert!(trust().contains("BEGIN CERTIFICATE"), "an empty trust file would stop the listener");
    }
}
