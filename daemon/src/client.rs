//! The Zenoh client side of a cell, shared by the `ris` client commands and the station
//! (`ris console`): a session to a running risd or a router (with a cell's credentials), a
//! request answered by one JSON reply or the daemon's reason, one stored or published item,
//! and every reply to a query.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{anyhow, bail, Context, Result};
use serde::de::DeserializeOwned;
use serde::Serialize;

use crate::protocol::ErrorReply;
use crate::service::plain;

/// The Zenoh configuration of a session of `mode` (see [`crate::service::login_config`]) to
/// `connect`, logged in as the user of `credentials` (user, file whose first line is the
/// password) when the cell has `[zenoh.access]`.
pub fn login(
    mode: &str,
    connect: &[String],
    credentials: Option<&(String, PathBuf)>,
) -> Result<zenoh::Config> {
    let password = match credentials {
        Some((user, file)) => {
            let text = std::fs::read_to_string(file)
                .with_context(|| format!("--password-file: reading {}", file.display()))?;
            Some((
                user.clone(),
                text.lines().next().unwrap_or_default().to_string(),
            ))
        }
        None => None,
    };
    if connect.is_empty() {
        bail!("--connect: give the daemon's or the router's endpoint, e.g. tcp/127.0.0.1:7447");
    }
    crate::config::check_endpoints("command line", "--connect", connect)?;
    crate::service::login_config(
        mode,
        connect,
        password.as_ref().map(|(u, p)| (u.as_str(), p.as_str())),
    )
}

/// A client session to `connect` (see [`login`]); fails while no risd answers there.
pub async fn open(
    connect: &[String],
    credentials: Option<&(String, PathBuf)>,
) -> Result<zenoh::Session> {
    let config = login("client", connect, credentials)?;
    zenoh::open(config).await.map_err(|_| {
        anyhow!(
            "no risd answers at {}: start it there (risd, or systemctl start risd), or give its endpoint with --connect",
            connect.join(", ")
        )
    })
}

/// Ask `key` with `body` as JSON: the reply, or the daemon's reason as the error.
pub async fn ask<Req: Serialize, Rep: DeserializeOwned>(
    session: &zenoh::Session,
    key: &str,
    body: &Req,
) -> Result<Rep> {
    let replies = session
        .get(key)
        .payload(serde_json::to_string(body)?)
        .timeout(Duration::from_secs(10))
        .await
        .map_err(|e| anyhow!("asking {key}: {}", plain(&e.to_string())))?;
    let reply = replies.recv_async().await.map_err(|_| {
        anyhow!("no reply from {key}: no risd serves this cell there (check --cell and --connect)")
    })?;
    match reply.result() {
        Ok(sample) => serde_json::from_slice(&sample.payload().to_bytes())
            .with_context(|| format!("the daemon's reply on {key} is not what this ris expects (a risd of another version?)")),
        Err(err) => {
            let text = String::from_utf8_lossy(&err.payload().to_bytes()).into_owned();
            let reason = serde_json::from_str::<ErrorReply>(&text)
                .map(|r| r.error)
                .unwrap_or(text);
            bail!("risd refused: {reason}")
        }
    }
}

/// One item the daemon published or stored under `key` (the first good reply).
pub async fn fetch(session: &zenoh::Session, key: &str) -> Result<Vec<u8>> {
    let replies = session
        .get(key)
        .timeout(Duration::from_secs(30))
        .await
        .map_err(|e| anyhow!("asking {key}: {}", plain(&e.to_string())))?;
    while let Ok(reply) = replies.recv_async().await {
        if let Ok(sample) = reply.result() {
            return Ok(sample.payload().to_bytes().into_owned());
        }
    }
    bail!("{key} was neither published nor stored by the daemon")
}

/// Every good reply to `key` (a wildcard query): (key, payload).
pub async fn replies(session: &zenoh::Session, key: &str) -> Result<Vec<(String, Vec<u8>)>> {
    let r = session
        .get(key)
        .timeout(Duration::from_secs(30))
        .await
        .map_err(|e| anyhow!("asking {key}: {}", plain(&e.to_string())))?;
    let mut out = Vec::new();
    while let Ok(reply) = r.recv_async().await {
        if let Ok(s) = reply.result() {
            out.push((
                s.key_expr().as_str().to_string(),
                s.payload().to_bytes().into_owned(),
            ));
        }
    }
    Ok(out)
}
