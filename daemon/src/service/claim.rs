//! The claim of a cell's name on the Zenoh fabric, held from risd's first instant: a
//! liveliness token `ris/<cell>/claim/<start ns>-<zid>`. Of two daemons of one cell the one
//! whose claim sorts first (the earlier start; the session id breaks a tie) serves, the other
//! steps aside — whether it learns of the rival at its start or while it prepares. Both see the
//! same claims, so a race ends the same way for both.

use std::time::{Duration, SystemTime, UNIX_EPOCH};

use anyhow::{anyhow, Result};
use zenoh::handlers::FifoChannelHandler;
use zenoh::liveliness::LivelinessToken;
use zenoh::pubsub::Subscriber;
use zenoh::sample::{Sample, SampleKind};
use zenoh::Session;

use crate::protocol::{claim_key, health_key};

/// How long risd asks the network for other daemons of its cell.
const PEER_CHECK: Duration = Duration::from_millis(1500);

/// A daemon's hold on its cell's name.
pub(super) struct Claim {
    cell: String,
    own: String,
    _token: LivelinessToken,
    rivals: Subscriber<FifoChannelHandler<Sample>>,
}

impl Claim {
    /// Claim `cell`: refused when a daemon of the cell is ready, or claimed it first.
    pub(super) async fn stake(session: &Session, cell: &str, access: bool) -> Result<Claim> {
        if !access {
            tracing::info!(
                cell,
                "without [zenoh.access] any peer that reaches this cell can hold its name (a liveliness token under ris/{cell}/claim/ or ris/{cell}/health) and keep risd from starting"
            );
        }
        let start_ns = SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos());
        let own = format!("{start_ns:020}-{}", session.zid());
        // Subscribed before the token is declared: a rival that claims after the look-up
        // below is still seen.
        let rivals = session
            .liveliness()
            .declare_subscriber(claim_key(cell, "*"))
            .await
            .map_err(|e| anyhow!("watching the claims of cell {cell}: {e}"))?;
        let token = session
            .liveliness()
            .declare_token(claim_key(cell, &own))
            .await
            .map_err(|e| anyhow!("claiming cell {cell}: {e}"))?;
        let claim = Claim {
            cell: cell.to_string(),
            own,
            _token: token,
            rivals,
        };
        let alive = session
            .liveliness()
            .get(format!("ris/{cell}/**"))
            .timeout(PEER_CHECK)
            .await
            .map_err(|e| anyhow!("asking for other daemons of cell {cell}: {e}"))?;
        while let Ok(reply) = alive.recv_async().await {
            if let Ok(sample) = reply.result() {
                let key = sample.key_expr().as_str();
                if key == health_key(cell) {
                    return Err(claim.refusal(key));
                }
                if claim.first(key) {
                    return Err(claim.refusal(key));
                }
            }
        }
        Ok(claim)
    }

    /// Whether the claim `key` (a full key) came before this daemon's.
    fn first(&self, key: &str) -> bool {
        key.strip_prefix(&claim_key(&self.cell, ""))
            .is_some_and(|other| other != self.own && *other < *self.own)
    }

    fn refusal(&self, key: &str) -> anyhow::Error {
        anyhow!(
            "another risd already serves cell {:?} on this Zenoh network ({key}); give each cell its own [cell] name",
            self.cell
        )
    }

    /// Resolves when a daemon that claimed the cell first appears (never otherwise).
    pub(super) async fn rival(&self) -> anyhow::Error {
        loop {
            match self.rivals.recv_async().await {
                Ok(s) if s.kind() == SampleKind::Put && self.first(s.key_expr().as_str()) => {
                    return self.refusal(s.key_expr().as_str());
                }
                Ok(_) => {}
                Err(_) => std::future::pending::<()>().await,
            }
        }
    }
}
