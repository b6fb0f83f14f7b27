//! The Zenoh client side shared by `ris scan` and `ris stream`: a session to a running risd
//! (with a cell's credentials) and a query answered by one JSON reply or an error reason.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{anyhow, bail, Context, Result};
use serde_json::Value;

/// A client session to `connect`, logged in as the user of `credentials` (user, file whose
/// first line is the password) when the cell has `[zenoh.access]`.
pub async fn open(
    connect: &[String],
    credentials: Option<&(String, PathBuf)>,
) -> Result<zenoh::Session> {
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
    let config = crate::service::client_config(
        connect,
        password.as_ref().map(|(u, p)| (u.as_str(), p.as_str())),
    )?;
    zenoh::open(config)
        .await
        .map_err(|e| anyhow!("connecting to {connect:?}: {e}"))
}

/// Ask `key` with the JSON `body`: the reply's JSON, or the daemon's reason as the error.
pub async fn ask(session: &zenoh::Session, key: &str, body: &Value) -> Result<Value> {
    let replies = session
        .get(key)
        .payload(body.to_string())
        .timeout(Duration::from_secs(10))
        .await
        .map_err(|e| anyhow!("asking {key}: {e}"))?;
    let reply = replies
        .recv_async()
        .await
        .map_err(|_| anyhow!("no reply from {key}: is risd for this cell reachable?"))?;
    match reply.result() {
        Ok(sample) => serde_json::from_slice(&sample.payload().to_bytes())
            .context("the daemon's reply is not JSON"),
        Err(err) => {
            let text = String::from_utf8_lossy(&err.payload().to_bytes()).into_owned();
            let reason = serde_json::from_str::<Value>(&text)
                .ok()
                .and_then(|v| v["error"].as_str().map(str::to_string))
                .unwrap_or(text);
            bail!("risd refused: {reason}")
        }
    }
}
