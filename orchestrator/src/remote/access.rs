//! Zenoh's access control on the learner's side of a run over TLS: what its hosts (named by
//! their certificates' common names) may send it and be sent. Everything else is denied, so a
//! host cannot publish actions, answer joins or subscribe to other slots' observations, and a
//! peer no rule names gets nothing at all.

use serde_json::json;

use super::join::JOIN_KEY;
use super::wire::{act_key_all, host_key_all, learner_key, obs_key_all, reopen_key};

/// The `access_control` section of the learner's Zenoh configuration for a run's `hosts`.
pub fn learner_rules(run_id: &str, hosts: &[String]) -> serde_json::Value {
    let (obs, act, host, learner, reopen) =
        (obs_key_all(run_id), act_key_all(run_id), host_key_all(run_id), learner_key(run_id), reopen_key(run_id));
    let rule = |id: &str, flow: &str, messages: &[&str], keys: &[&str]| json!({"id": id, "flows": [flow], "messages": messages, "key_exprs": keys, "permission": "allow"});
    let rules = vec![
        // what a host sends: its observations, its join, its presence, its interest in answers
        rule("host-obs", "ingress", &["put"], &[&obs]),
        rule("host-join", "ingress", &["query"], &[JOIN_KEY]),
        rule("host-alive", "ingress", &["liveliness_token"], &[&host]),
        rule("host-listens", "ingress", &["declare_subscriber"], &[&act, &reopen]),
        rule("host-watches", "ingress", &["declare_liveliness_subscriber", "liveliness_query"], &[&learner]),
        // what the learner sends a host: answers, grants, its presence and its interests
        rule("learner-act", "egress", &["put"], &[&act, &reopen]),
        rule("learner-grant", "egress", &["reply", "declare_queryable"], &[JOIN_KEY]),
        rule("learner-alive", "egress", &["liveliness_token"], &[&learner]),
        rule("learner-listens", "egress", &["declare_subscriber"], &[&obs]),
        rule("learner-watches", "egress", &["declare_liveliness_subscriber", "liveliness_query"], &[&host]),
    ];
    let ids: Vec<&str> = rules.iter().map(|r| r["id"].as_str().unwrap()).collect();
    // Zenoh wants every list filled: with no host trusted, the rules name the CA that trusts
    // no one (`certs`), whose certificate nobody can show.
    let names: Vec<String> = if hosts.is_empty() { vec!["nobody".into()] } else { hosts.to_vec() };
    json!({
        "enabled": true,
        "default_permission": "deny",
        "rules": rules,
        "subjects": [{"id": "hosts", "cert_common_names": names}],
        "policies": [{"rules": ids, "subjects": ["hosts"]}],
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rules_are_zenohs_and_name_only_the_run() {
        let acl = learner_rules("r1", &["gesthor-host.a.r1".into()]);
        let mut c = zenoh::Config::default();
        c.insert_json5("access_control", &acl.to_string()).unwrap();
        let text = acl.to_string();
        assert!(!text.contains("gesthor/**") && text.contains("gesthor/r1/obs/*"), "{text}");
        let none = learner_rules("r1", &[]);
        assert!(none["subjects"][0]["cert_common_names"] == json!(["nobody"]) && none["default_permission"] == "deny");
        c.insert_json5("access_control", &none.to_string()).unwrap();
    }
}
