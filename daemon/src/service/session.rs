//! The daemon's Zenoh session: its configuration (endpoints, no scouting), authentication and
//! access control, and the client configuration `ris` and the tests use.

use anyhow::{anyhow, Result};
use zenoh::Session;

use crate::config::CellConfig;
use crate::protocol::{
    cell_key, claim_key, health_key, scan_key, scans_key, stream_key, stream_sensor_key,
    verifications_key, verify_key,
};

/// A Zenoh configuration of `mode` (`peer` or `client`) with these endpoints and no multicast
/// scouting: RIS talks to the endpoints it is given, nothing else.
pub fn zenoh_config(mode: &str, listen: &[String], connect: &[String]) -> Result<zenoh::Config> {
    let mut c = zenoh::Config::default();
    for (key, value) in [
        ("mode", serde_json::to_string(mode)?),
        ("listen/endpoints", serde_json::to_string(listen)?),
        ("connect/endpoints", serde_json::to_string(connect)?),
        ("scouting/multicast/enabled", "false".to_string()),
    ] {
        c.insert_json5(key, &value)
            .map_err(|e| anyhow!("zenoh config {key} = {value}: {e}"))?;
    }
    Ok(c)
}

/// Zenoh authentication and access control for `cell` (SPEC §12 keys): operators may query
/// `scan`, `stream` and `verify`, and hold the cell's claim (a daemon logged in as an
/// operator); users may ask streamed points; operators and readers may query health and stored scans, subscribe to the cell's
/// publications and see its liveliness; everything else, publishing under `ris/<cell>/**`
/// included, is denied. `ros2` adds the cell's ROS 2 topics and liveliness tokens (see
/// [`crate::ros2::acl_keys`]) to what users may follow.
pub fn apply_access(
    config: &mut zenoh::Config,
    cell: &str,
    access: &crate::config::AccessSection,
    ros2: (Vec<String>, Vec<String>),
) -> Result<()> {
    let (ros_data, ros_alive) = ros2;
    let follow: Vec<String> = std::iter::once(cell_key(cell)).chain(ros_data).collect();
    let alive: Vec<String> = std::iter::once(health_key(cell)).chain(ros_alive).collect();
    let both: Vec<&String> = access.operators.iter().chain(&access.readers).collect();
    let mut subjects = Vec::new();
    let mut policies = Vec::new();
    if !access.operators.is_empty() {
        subjects.push(serde_json::json!({"id": "operators", "usernames": access.operators}));
        policies.push(serde_json::json!({"rules": ["scan", "claim"], "subjects": ["operators"]}));
    }
    if !both.is_empty() {
        subjects.push(serde_json::json!({"id": "users", "usernames": both}));
        policies
            .push(serde_json::json!({"rules": ["read", "follow", "follow-out", "alive"], "subjects": ["users"]}));
    }
    let acl = serde_json::json!({
        "enabled": true,
        "default_permission": "deny",
        "rules": [
            {"id": "scan", "permission": "allow", "flows": ["ingress", "egress"],
             "messages": ["query", "reply"], "key_exprs": [scan_key(cell), stream_key(cell), verify_key(cell)]},
            {"id": "read", "permission": "allow", "flows": ["ingress", "egress"],
             "messages": ["query", "reply"],
             "key_exprs": [health_key(cell), scans_key(cell), verifications_key(cell), stream_sensor_key(cell, "*", "point")]},
            {"id": "follow", "permission": "allow", "flows": ["ingress"],
             "messages": ["declare_subscriber"], "key_exprs": follow},
            {"id": "follow-out", "permission": "allow", "flows": ["egress"],
             "messages": ["put"], "key_exprs": follow},
            {"id": "claim", "permission": "allow", "flows": ["ingress", "egress"],
             "messages": ["liveliness_query", "declare_liveliness_subscriber", "liveliness_token", "reply"],
             "key_exprs": [claim_key(cell, "*")]},
            {"id": "alive", "permission": "allow", "flows": ["ingress", "egress"],
             "messages": ["liveliness_query", "declare_liveliness_subscriber", "liveliness_token", "reply"],
             "key_exprs": alive},
        ],
        "subjects": subjects,
        "policies": policies,
    });
    let users = access.users.display().to_string();
    for (key, value) in [
        (
            "transport/auth/usrpwd/dictionary_file",
            serde_json::to_string(&users)?,
        ),
        ("access_control", acl.to_string()),
    ] {
        config
            .insert_json5(key, &value)
            .map_err(|e| anyhow!("zenoh.access: {key}: {e}"))?;
    }
    Ok(())
}

/// A client configuration with `user`'s credentials (password from `password_file`, first
/// line), for `ris scan` and tests against a cell with `[zenoh.access]`.
pub fn client_config(connect: &[String], user: Option<(&str, &str)>) -> Result<zenoh::Config> {
    login_config("client", connect, user)
}

/// A configuration of `mode` (`client`: fails to open while nothing answers at `connect`;
/// `peer`: opens at once and links up whenever the endpoints answer, as a station that may
/// start before its cells) that listens nowhere, with `user`'s credentials.
pub fn login_config(
    mode: &str,
    connect: &[String],
    user: Option<(&str, &str)>,
) -> Result<zenoh::Config> {
    let mut c = zenoh_config(mode, &[], connect)?;
    if let Some((user, password)) = user {
        for (key, value) in [
            ("transport/auth/usrpwd/user", serde_json::to_string(user)?),
            (
                "transport/auth/usrpwd/password",
                serde_json::to_string(password)?,
            ),
        ] {
            c.insert_json5(key, &value)
                .map_err(|e| anyhow!("zenoh credentials {key}: {e}"))?;
        }
    }
    Ok(c)
}

/// The largest message risd's session reassembles, bytes: 16 requests of the largest size.
pub const MAX_RECEIVED: usize = 16 * crate::protocol::MAX_REQUEST;

/// Whether an endpoint listens on loopback only.
fn is_loopback(endpoint: &str) -> bool {
    let address = endpoint.split_once('/').map_or("", |(_, a)| a);
    address.starts_with("127.") || address.starts_with("[::1]") || address.starts_with("localhost:")
}

/// Open the cell's session: its endpoints, and with `[zenoh.access]` its users and access rules
/// (a cell listening beyond loopback without them is warned about).
pub async fn open(config: &CellConfig) -> Result<Session> {
    let z = &config.zenoh;
    let mut zc = zenoh_config(&z.mode, &z.listen, &z.connect)?;
    // risd receives requests (at most MAX_REQUEST bytes) and liveliness, never bulk data: a
    // message larger than this is dropped by Zenoh as it arrives, before it is reassembled, so
    // no client can make risd hold a huge body in memory.
    zc.insert_json5(
        "transport/link/rx/max_message_size",
        &MAX_RECEIVED.to_string(),
    )
    .map_err(|e| anyhow!("zenoh config transport/link/rx/max_message_size: {e}"))?;
    if let Some(access) = &z.access {
        apply_access(&mut zc, &config.name, access, crate::ros2::acl_keys(config))?;
    } else if z.listen.iter().any(|e| !is_loopback(e)) {
        tracing::warn!(listen = ?z.listen, "the cell listens beyond loopback without [zenoh.access]: anyone who reaches it may scan and read");
    }
    zenoh::open(zc).await.map_err(|e| {
        anyhow!(
            "cannot listen on {} ({}): is another risd or program using it? Give another endpoint with --listen or the file's [zenoh] listen",
            z.listen.join(", "),
            plain(&e.to_string())
        )
    })
}

/// A Zenoh error's words without the source locations it carries (` at /path/file.rs:12.`),
/// which mean nothing to a user.
pub fn plain(error: &str) -> String {
    let mut out = String::new();
    let mut rest = error;
    while let Some(i) = rest.find(" at /") {
        out.push_str(&rest[..i]);
        let tail = &rest[i + 5..];
        // The location ends at the first ".rs:<digits>" and an optional '.'.
        match tail.find(".rs:") {
            Some(j) => {
                let after = &tail[j + 4..];
                let digits = after.chars().take_while(char::is_ascii_digit).count();
                let after = &after[digits..];
                rest = after.strip_prefix('.').unwrap_or(after);
            }
            None => {
                rest = "";
            }
        }
    }
    out.push_str(rest);
    let words: Vec<&str> = out.split_whitespace().collect();
    words.join(" ").trim_end_matches(['.', '!']).to_string()
}

#[cfg(test)]
mod tests {
    #[test]
    fn zenoh_errors_lose_their_source_locations() {
        let e = "Can not create a new TCP listener bound to tcp/127.0.0.1:7447: [Address already in use (os error 98) at /root/.cargo/registry/src/index.crates.io-1949cf8c6b5b557f/zenoh-link-tcp-1.10.2/src/unicast.rs:345.] at /root/.cargo/registry/src/index.crates.io-1949cf8c6b5b557f/zenoh-1.10.2/src/net/runtime/orchestrator.rs:447.";
        let p = super::plain(e);
        assert_eq!(
            p,
            "Can not create a new TCP listener bound to tcp/127.0.0.1:7447: [Address already in use (os error 98)]"
        );
        assert_eq!(super::plain("no location here."), "no location here");
        assert_eq!(super::plain("cut at /x/y"), "cut");
    }
}
